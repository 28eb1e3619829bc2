"""Results: per-pair arrays of one clip, per-clip summaries, and the batch table
(docs/semantics.md §3.7, §4).

Column names are fixed (:data:`CLIP_COLUMNS`, :data:`PAIR_COLUMNS`) so scripts can rely on them.
``ecd`` (docs/semantics.md §4) is a corpus column: each clip's ``ecd_trans`` and ``ecd_rot``
min-max normalised over the clips of the table, then the larger of the two.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import os
from collections import Counter
from pathlib import Path
from typing import Any, Iterable, Iterator, Mapping, Sequence

import numpy as np

from ..calibration import COMPONENTS, Calibration, rows_compat, sgc_score
from ..codes import CLIP_STATUSES, PAIR_REASONS, REGION_EMPTY
from ..stats import min_max
from .parquet import is_parquet, read_parquet_text, typed_cell, write_parquet

CLIP_COLUMNS = ("clip_id", "group", "status", "reason", "sgc", *COMPONENTS, "reproj_error", "ecd_trans",
                "ecd_rot", "ecd", "n_pairs", "n_pairs_scored", "engine", "mask_source", "scale",
                "depth_unit", "n_ill_conditioned", "compat", "origin", "input_sha256", "run_id")
PAIR_COLUMNS = ("clip_id", "group", "pair", "reason", *COMPONENTS, "reproj_error", "n_tracks", "n_regions",
                "n_poses", "n_ill_conditioned", "t_g_norm", "R_g_angle_deg", "engine")


@dataclasses.dataclass
class PairArrays:
    """Per-pair values of one clip; index p is pair p+1 (frames p -> p+1); k region slots.

    Units (docs/semantics.md §4): rotations in degrees (variances deg^2); under compat="spec"
    translation variances in (% of D)^2, ``depth_error`` in % and ``t_g_norm`` in % of D per frame,
    while R_local / t_local / region_trans_std are the raw poses in units of D; under
    compat="authors" raw depth and pose units. Reprojection errors in pixels.
    """

    local_rot_var: np.ndarray  # (n_pairs,)
    local_trans_var: np.ndarray
    global_rot_var: np.ndarray
    global_trans_var: np.ndarray
    depth_error: np.ndarray
    reproj_error: np.ndarray  # mean over accepted regions of their mean reprojection error
    n_tracks: np.ndarray  # usable tracks (visible, confident)
    n_regions: np.ndarray
    n_poses: np.ndarray  # accepted local poses
    n_ill_conditioned: np.ndarray  # poses left out by the region-quality rule (ill_conditioned, ambiguous)
    t_g_norm: np.ndarray  # ||t_g||, ECD input
    R_g_angle_deg: np.ndarray  # rotation angle of R_g, ECD input
    reason: np.ndarray  # (n_pairs,) str, one of codes.PAIR_REASONS
    R_local: np.ndarray  # (n_pairs, k, 3, 3), NaN where no pose (ok, ill_conditioned, ambiguous)
    t_local: np.ndarray  # (n_pairs, k, 3)
    region_status: np.ndarray  # (n_pairs, k) int, codes.REGION_STATUS
    region_points: np.ndarray  # (n_pairs, k) tracks per region
    region_reproj: np.ndarray  # (n_pairs, k) mean reprojection error px
    region_rot_std: np.ndarray  # (n_pairs, k) RMS rotation uncertainty of the pose, deg (NaN: no pose)
    region_trans_std: np.ndarray  # (n_pairs, k) RMS translation uncertainty, depth units
    scale: float = 1.0  # translation scale s applied to t_g (1 when not fitted)
    depth_unit: float = 1.0  # D: the clip's median static depth, input depth units (1 under compat="authors")

    @property
    def n_pairs(self) -> int:
        return len(self.reason)

    def __repr__(self) -> str:  # the arrays run to thousands of lines
        k = self.region_status.shape[1] if self.region_status.ndim == 2 else 0
        return (f"PairArrays({self.n_pairs} pairs, {k} region slots; reasons: "
                f"{format_counts((str(r) for r in self.reason), PAIR_REASONS) or 'none'})")

    def components(self) -> dict[str, np.ndarray]:
        return {k: getattr(self, k) for k in COMPONENTS}


def empty_pair_arrays(n_pairs: int, k: int) -> PairArrays:
    nan = lambda *shape: np.full(shape, np.nan)  # noqa: E731
    zeros = lambda *shape: np.zeros(shape, np.int32)  # noqa: E731
    return PairArrays(
        local_rot_var=nan(n_pairs), local_trans_var=nan(n_pairs), global_rot_var=nan(n_pairs),
        global_trans_var=nan(n_pairs), depth_error=nan(n_pairs), reproj_error=nan(n_pairs),
        n_tracks=zeros(n_pairs), n_regions=zeros(n_pairs), n_poses=zeros(n_pairs), n_ill_conditioned=zeros(n_pairs),
        t_g_norm=nan(n_pairs), R_g_angle_deg=nan(n_pairs), reason=np.full(n_pairs, "ok", dtype=object),
        R_local=nan(n_pairs, k, 3, 3), t_local=nan(n_pairs, k, 3),
        region_status=np.full((n_pairs, k), REGION_EMPTY, np.int32),
        region_points=zeros(n_pairs, k), region_reproj=nan(n_pairs, k), region_rot_std=nan(n_pairs, k),
        region_trans_std=nan(n_pairs, k),
    )


def _nanmean(values: np.ndarray) -> float:
    values = np.asarray(values, np.float64)
    finite = ~np.isnan(values)
    return float(values[finite].mean()) if finite.any() else float("nan")


@dataclasses.dataclass
class ClipResult:
    """One clip's score, components (NaN-ignoring means over pairs), diagnostics and pairs."""

    clip_id: str
    group: str = ""
    status: str = "error"  # "ok" | "partial" | "error"
    reason: str = ""
    sgc: float = float("nan")
    components: dict[str, float] = dataclasses.field(default_factory=lambda: {k: float("nan") for k in COMPONENTS})
    reproj_error: float = float("nan")
    ecd_trans: float = float("nan")  # mean ||s t_g|| over pairs (% of D under spec, pose units under authors)
    ecd_rot: float = float("nan")  # mean rotation angle of R_g over pairs (deg)
    n_pairs: int = 0
    n_pairs_scored: int = 0
    engine: str = ""
    mask_source: str = ""
    scale: float = 1.0  # translation scale s (docs/semantics.md §4)
    depth_unit: float = float("nan")  # D, input depth units
    n_ill_conditioned: int = 0  # local poses left out by the region-quality rule, all pairs
    compat: str = ""  # the semantics the components were computed with: "spec" | "authors"
    origin: str = ""  # the file (file[member] in a batch file) or <memory>
    input_sha256: str = ""  # SHA-256 of the input file's bytes ("" for clips given in memory)
    run_id: str = ""  # the run that scored it (docs/semantics.md §4.1; "" once re-scored)
    pairs: PairArrays | None = None

    def __repr__(self) -> str:  # the per-pair arrays would run to thousands of lines
        reason = self.reason if len(self.reason) <= 80 else self.reason[:77] + "..."
        return (f"ClipResult({self.clip_id!r}, group={self.group!r}, status={self.status!r}, sgc={self.sgc:.4g}, "
                f"pairs scored {self.n_pairs_scored}/{self.n_pairs}, engine={self.engine!r}"
                + (f", reason={reason!r}" if reason else "") + "; .record() for every column)")

    def record(self, ecd: float = float("nan")) -> dict[str, Any]:
        """The :data:`CLIP_COLUMNS` row; ``ecd`` needs a corpus (see :func:`camera_dynamics`)."""
        row = {"clip_id": self.clip_id, "group": self.group, "status": self.status, "reason": self.reason,
               "sgc": self.sgc, **self.components, "reproj_error": self.reproj_error,
               "ecd_trans": self.ecd_trans, "ecd_rot": self.ecd_rot, "ecd": ecd, "n_pairs": self.n_pairs,
               "n_pairs_scored": self.n_pairs_scored, "engine": self.engine,
               "mask_source": self.mask_source, "scale": self.scale, "depth_unit": self.depth_unit,
               "n_ill_conditioned": self.n_ill_conditioned, "compat": self.compat, "origin": self.origin,
               "input_sha256": self.input_sha256, "run_id": self.run_id}
        return {k: row[k] for k in CLIP_COLUMNS}

    def pair_records(self) -> list[dict[str, Any]]:
        if self.pairs is None:
            return []
        p = self.pairs
        return [{"clip_id": self.clip_id, "group": self.group, "pair": i + 1, "reason": str(p.reason[i]),
                 **{k: float(getattr(p, k)[i]) for k in COMPONENTS}, "reproj_error": float(p.reproj_error[i]),
                 "n_tracks": int(p.n_tracks[i]), "n_regions": int(p.n_regions[i]), "n_poses": int(p.n_poses[i]),
                 "n_ill_conditioned": int(p.n_ill_conditioned[i]),
                 "t_g_norm": float(p.t_g_norm[i]), "R_g_angle_deg": float(p.R_g_angle_deg[i]),
                 "engine": self.engine} for i in range(p.n_pairs)]


def summarize_clip(clip_id: str, pairs: PairArrays, calibration: Calibration, *, group: str = "",
                   engine: str = "", mask_source: str = "", origin: str = "", compat: str = "") -> ClipResult:
    """Per-clip means over pairs (NaN ignored), status, reason and the SGC score (docs/semantics.md §3.8, §5)."""
    components = {k: _nanmean(getattr(pairs, k)) for k in COMPONENTS}
    sgc = float(sgc_score(components, calibration))
    reasons = Counter(str(r) for r in pairs.reason)
    scored = reasons.get("ok", 0)
    problems = "; ".join(f"{r} x{n}" for r, n in sorted(reasons.items()) if r != "ok")
    if math.isnan(sgc):
        status, reason = "error", f"no pair could be scored ({problems})" if problems else "no pair could be scored"
    elif scored < pairs.n_pairs:
        status, reason = "partial", problems
    else:
        status, reason = "ok", ""
    return ClipResult(
        clip_id=clip_id, group=group, status=status, reason=reason, sgc=sgc, components=components,
        reproj_error=_nanmean(pairs.reproj_error), ecd_trans=_nanmean(pairs.t_g_norm),
        ecd_rot=_nanmean(pairs.R_g_angle_deg), n_pairs=pairs.n_pairs, n_pairs_scored=scored,
        engine=engine, mask_source=mask_source, scale=float(pairs.scale), depth_unit=float(pairs.depth_unit),
        n_ill_conditioned=int(np.sum(pairs.n_ill_conditioned)), compat=compat, origin=origin, pairs=pairs)


def clip_from_row(row: Mapping[str, str]) -> ClipResult:
    """The :class:`ClipResult` of a per-clip CSV row (as text, e.g. one kept by a resumed run):
    every column but ``ecd``; no per-pair arrays."""
    cell = {name: typed_cell(column_kind(name), row[name]) for name in CLIP_COLUMNS if name != "ecd"}
    return ClipResult(components={k: cell.pop(k) for k in COMPONENTS}, **cell)


def camera_dynamics(ecd_trans: Any, ecd_rot: Any) -> np.ndarray:
    """ECD (docs/semantics.md §4) per clip: max of min-max(mean ||t_g||) and min-max(mean angle of R_g) over the corpus.

    (n,) x2 -> (n,) in [0, 1]; NaN inputs are ignored by the scaling; a clip with one NaN input
    takes the other; a constant column scales to 0.
    """
    trans, rot = min_max(ecd_trans), min_max(ecd_rot)
    both = np.stack([trans, rot])
    return np.where(np.isnan(both).all(axis=0), np.nan, np.nanmax(np.where(np.isnan(both), -np.inf, both), axis=0))


def failed_clip(clip_id: str, message: str, *, engine: str = "", origin: str = "", compat: str = "") -> ClipResult:
    """The row of a clip that could not be loaded or scored."""
    return ClipResult(clip_id=clip_id, status="error", reason=message, engine=engine, origin=origin, compat=compat)


# ----------------------------------------------------------------------------- batch table


def _json_value(value: Any) -> Any:
    if isinstance(value, (float, np.floating)):
        return None if math.isnan(value) else float(value)
    if isinstance(value, np.integer):
        return int(value)
    return value


def write_csv(path: str | os.PathLike, rows: Sequence[dict], columns: Sequence[str]) -> Path:
    """Rows as CSV with these columns (others ignored), NaN as an empty cell; parent dirs made."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as f:
        write_csv_rows(f, rows, columns, header=True)
    return path


def write_table(path: str | os.PathLike, rows: Sequence[dict], columns: Sequence[str]) -> Path:
    """``write_csv``, or a Parquet file (typed columns, :func:`column_kind`) for a ``.parquet`` path."""
    if is_parquet(path):
        return write_parquet(path, rows, columns, column_kind)
    return write_csv(path, rows, columns)


def write_csv_rows(f, rows: Iterable[dict], columns: Sequence[str], *, header: bool) -> None:
    """``write_csv``'s rows (and header) on an open text file."""
    writer = csv.DictWriter(f, fieldnames=list(columns), extrasaction="ignore")
    if header:
        writer.writeheader()
    for row in rows:
        writer.writerow({k: ("" if isinstance(v, float) and math.isnan(v) else v) for k, v in row.items()})


INT_COLUMNS = ("n_pairs", "n_pairs_scored", "pair", "n_tracks", "n_regions", "n_poses", "n_ill_conditioned")
TEXT_COLUMNS = ("clip_id", "group", "status", "reason", "engine", "mask_source", "base", "kind", "compat", "origin",
                 "input_sha256", "run_id")


def column_kind(name: str) -> str:
    """A table column's type: "text", "int" or "float" (a Parquet file's column types)."""
    return "text" if name in TEXT_COLUMNS else "int" if name in INT_COLUMNS else "float"


def read_table_text(path: str | os.PathLike) -> tuple[list[str], list[dict[str, str]]]:
    """A table file's header and rows as text cells: CSV, or Parquet by its ``.parquet`` suffix."""
    if is_parquet(path):
        return read_parquet_text(path)
    with Path(path).open(newline="") as f:
        reader = csv.DictReader(f)
        rows = list(reader)
        return list(reader.fieldnames or []), rows


def _parse_column(name: str, values: list[str]) -> list[Any]:
    if name in TEXT_COLUMNS:
        return values
    if name in INT_COLUMNS:
        return [int(v) if v != "" else 0 for v in values]
    try:  # a numeric column: every non-empty cell parses (as int when every cell is an integer)
        return [int(v) for v in values]
    except ValueError:
        pass
    try:
        return [float(v) if v != "" else float("nan") for v in values]
    except ValueError:
        return values


def read_scores(paths: str | os.PathLike | Sequence[str | os.PathLike]) -> list[dict[str, Any]]:
    """Per-clip rows of one or more CSVs (or ``.parquet`` files) written by ``to_csv`` /
    ``sgc-jax score --out``.

    Numeric columns come back as float (empty cell -> NaN) or int, text columns as str; extra
    columns (e.g. a study's ``base``, ``kind``, ``severity``) are kept. Each row gets ``source``,
    the file it came from; a file without ``clip_id`` (e.g. one row per group) gets ``row<i>``.
    Missing component columns raise ``ValueError`` naming the file.
    """
    if isinstance(paths, (str, os.PathLike)):
        paths = [paths]
    records: list[dict[str, Any]] = []
    for path in paths:
        header, rows = read_table_text(path)
        missing = [k for k in COMPONENTS if k not in header]
        if missing:
            raise ValueError(f"{path}: not a per-clip scores CSV, columns {missing} are missing (found {header})")
        columns = {name: _parse_column(name, [r[name] or "" for r in rows]) for name in header}
        for i in range(len(rows)):
            record = {name: columns[name][i] for name in header}
            record.setdefault("clip_id", f"row{i}")
            records.append({**record, "source": os.fspath(path)})
    return records


def rescore_records(records: Sequence[dict[str, Any]], calibration: Calibration | str) -> list[dict[str, Any]]:
    """Copies of per-clip rows with ``sgc`` recomputed from their stored components under
    ``calibration`` (no geometry: the per-clip components are all the score needs) and ``ecd``
    recomputed over these rows; ``run_id`` is emptied (no run scored them so)."""
    calibration = Calibration.load(calibration)
    calibration.check_compat(rows_compat(records), "the rows")
    components = {k: np.array([float(r[k]) for r in records]) for k in COMPONENTS}
    sgc = sgc_score(components, calibration) if records else np.array([])
    out = [{**r, "sgc": float(v), **({"run_id": ""} if "run_id" in r else {})} for r, v in zip(records, sgc)]
    return add_ecd(out) if any("ecd_trans" in r for r in out) else out


def add_ecd(records: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Copies of per-clip rows with ``ecd`` (docs/semantics.md §4) normalised over these rows; rows without
    ``ecd_trans`` / ``ecd_rot`` get NaN."""
    nan = float("nan")
    ecd = camera_dynamics([r.get("ecd_trans", nan) for r in records], [r.get("ecd_rot", nan) for r in records])
    return [{**r, "ecd": float(e)} for r, e in zip(records, ecd)]


def write_scores(path: str | os.PathLike, records: Sequence[dict[str, Any]]) -> Path:
    """Write per-clip rows as CSV (Parquet for a ``.parquet`` path): :data:`CLIP_COLUMNS` present in
    the rows first, then any extra columns in their order of appearance (``source`` is not written)."""
    seen: list[str] = []
    for r in records:
        seen.extend(k for k in r if k not in seen and k != "source")
    columns = [c for c in CLIP_COLUMNS if c in seen] + [c for c in seen if c not in CLIP_COLUMNS]
    return write_table(path, list(records), columns)


def format_table(records: Sequence[dict[str, Any]], columns: Sequence[str]) -> str:
    """A plain-text table for terminals (floats to 4 significant digits)."""
    rows = [[_format(r.get(c, "")) for c in columns] for r in records]
    widths = [max(len(c), *(len(row[i]) for row in rows)) if rows else len(c) for i, c in enumerate(columns)]
    line = lambda cells: "  ".join(cell.ljust(w) for cell, w in zip(cells, widths))  # noqa: E731
    return "\n".join([line(columns), line(["-" * w for w in widths]), *(line(r) for r in rows)])


@dataclasses.dataclass
class BatchResult:
    """Scores of many clips, in input order; ``result["sgc"]`` gives a column as an array."""

    clips: list[ClipResult]
    calibration: Calibration | None = None

    def __len__(self) -> int:
        return len(self.clips)

    def __repr__(self) -> str:  # a summary: the default repr of thousands of clips floods a notebook
        return (f"BatchResult: {self._summary()}\n"
                "  .table() prints them; .to_records(), .to_pandas(), .to_csv(path) give every column")

    def _summary(self) -> str:
        """``"8 clips (ok 7, error 1), engine jax, calibration 'sgc-spec-2026'"``."""
        statuses = format_counts((c.status for c in self.clips), CLIP_STATUSES) or "none"
        engines = "/".join(dict.fromkeys(c.engine for c in self.clips if c.engine)) or "none"
        calibration = repr(self.calibration.name) if self.calibration else "none"
        return f"{len(self.clips)} clips ({statuses}), engine {engines}, calibration {calibration}"

    def __iter__(self) -> Iterator[ClipResult]:
        return iter(self.clips)

    def __getitem__(self, key: str | int) -> Any:
        if isinstance(key, int):
            return self.clips[key]
        if key not in CLIP_COLUMNS:
            raise KeyError(f"unknown column {key!r}; columns: {CLIP_COLUMNS}")
        values = [r[key] for r in self.to_records()]
        return np.array(values, dtype=np.float64 if isinstance(values[0], float) else object) if values else np.array([])

    def clip(self, clip_id: str) -> ClipResult:
        for c in self.clips:
            if c.clip_id == clip_id:
                return c
        raise KeyError(f"no clip {clip_id!r} in this result")

    @property
    def clip_ids(self) -> list[str]:
        return [c.clip_id for c in self.clips]

    @property
    def sgc(self) -> np.ndarray:
        return self["sgc"]

    @property
    def ecd(self) -> np.ndarray:
        """Estimated camera dynamics (docs/semantics.md §4) of each clip, normalised over this batch."""
        return camera_dynamics([c.ecd_trans for c in self.clips], [c.ecd_rot for c in self.clips])

    def to_records(self) -> list[dict[str, Any]]:
        """One dict per clip with :data:`CLIP_COLUMNS` (``ecd`` normalised over this batch)."""
        return [c.record(float(e)) for c, e in zip(self.clips, self.ecd)]

    def pair_records(self) -> list[dict[str, Any]]:
        """One dict per pair with :data:`PAIR_COLUMNS`."""
        return [row for c in self.clips for row in c.pair_records()]

    def to_csv(self, path: str | os.PathLike, pairs_path: str | os.PathLike | None = None) -> Path:
        if pairs_path is not None:
            write_csv(pairs_path, self.pair_records(), PAIR_COLUMNS)
        return write_csv(path, self.to_records(), CLIP_COLUMNS)

    def to_json(self, path: str | os.PathLike | None = None, *, pairs: bool = True) -> str:
        """JSON text ``{"clips": [...], "pairs": [...]}`` (NaN -> null); written when ``path``."""
        payload = {"calibration": self.calibration.name if self.calibration else None,
                   "clips": [{k: _json_value(v) for k, v in r.items()} for r in self.to_records()]}
        if pairs:
            payload["pairs"] = [{k: _json_value(v) for k, v in r.items()} for r in self.pair_records()]
        text = json.dumps(payload, indent=1)
        if path is not None:
            Path(path).write_text(text)
        return text

    def to_pandas(self, pairs: bool = False):
        """A DataFrame of the clips (or of the pairs); needs pandas."""
        if pairs:
            return records_frame(self.pair_records(), PAIR_COLUMNS)
        return records_frame(self.to_records(), CLIP_COLUMNS)

    def rescore(self, calibration: Calibration | str) -> "BatchResult":
        """The same components under another calibration (no geometry is recomputed: the score
        is a function of the stored per-pair components)."""
        calibration = Calibration.load(calibration)
        for c in self.clips:
            calibration.check_compat(c.compat, f"the scores of clip {c.clip_id!r}")
        clips = [dataclasses.replace(summarize_clip(c.clip_id, c.pairs, calibration, group=c.group, engine=c.engine,
                                                    mask_source=c.mask_source, origin=c.origin, compat=c.compat),
                                     input_sha256=c.input_sha256)
                 if c.pairs is not None else c
                 for c in self.clips]
        return BatchResult(clips, calibration)

    def table(self, columns: Sequence[str] = ("clip_id", "group", "status", "sgc", *COMPONENTS)) -> str:
        """A plain-text table for terminals."""
        return format_table(self.to_records(), columns)


def format_counts(values: Iterable[str], order: Sequence[str] = ()) -> str:
    """``"ok 7, partial 1"``: each distinct value with its count, in ``order`` then alphabetically."""
    counts = Counter(values)
    keys = [k for k in order if k in counts] + sorted(k for k in counts if k not in order)
    return ", ".join(f"{k} {counts[k]}" for k in keys)


def _format(value: Any) -> str:
    if isinstance(value, float):
        return "nan" if math.isnan(value) else f"{value:.4g}"
    return str(value)


def records_frame(records, columns):
    """A pandas DataFrame of row dicts with the given column order; needs pandas."""
    try:
        import pandas as pd
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError("to_pandas needs pandas: pip install pandas") from exc
    return pd.DataFrame(list(records), columns=list(columns))
