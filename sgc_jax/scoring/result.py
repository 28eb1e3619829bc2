"""The result model of a run: per-clip summaries of the engines' per-pair arrays and the batch
table (docs/semantics.md §3.8, §4). ``ecd`` is a corpus column: each clip's ``ecd_trans`` and
``ecd_rot`` min-max normalised over the clips of the table, then the larger of the two.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from collections import Counter
from pathlib import Path
from typing import Any, Iterator, Mapping, Sequence

import numpy as np

from ..calibration import COMPONENTS, Calibration, rows_compat, sgc_score
from ..codes import CLIP_STATUSES, SCORER_STATUS_CODE
from ..engines.evidence import LOW_EVIDENCE, EvidenceLevels, cameras_outrun_tracks, pose_tracks, shortfall
from ..engines.noise_floors import floor_score, pair_floors
from ..engines.pairs import PairArrays
from ..io.parquet import typed_cell
from ..io.tables import (
    CLIP_COLUMNS,
    COLUMN_UNITS,
    FLOOR_COLUMNS,
    INTERVAL_COLUMNS,
    PAIR_COLUMNS,
    column_kind,
    format_counts,
    format_table,
    records_frame,
    write_csv,
)
from ..stats import camera_dynamics
from .reward import RewardOptions, reward
from .summary import evidence_per_pair, summarize_pairs, table_status


@dataclasses.dataclass
class ClipResult:
    """One clip's score, components (NaN-ignoring means over pairs), diagnostics and pairs."""

    clip_id: str
    group: str = ""
    status: str = "error"  # "ok" | "partial" | "error" | "low_evidence" (§3.7, §3.11)
    reason: str = ""
    warnings: str = ""  # the loader's warning codes, ";"-joined (docs/semantics.md §1.6; "" for clips built in code)
    sgc: float = float("nan")
    sgc_lo: float = float("nan")  # the score's 90 % interval, a bootstrap over pairs (§5.6)
    sgc_hi: float = float("nan")
    components: dict[str, float] = dataclasses.field(default_factory=lambda: {k: float("nan") for k in COMPONENTS})
    floors: dict[str, float] = dataclasses.field(default_factory=lambda: {k: float("nan") for k in FLOOR_COLUMNS})
    sgc_floor: float = float("nan")  # the score of the floors, the depth error counted as 0 (§3.10)
    reproj_error: float = float("nan")
    ecd_trans: float = float("nan")  # mean ||s t_g|| over pairs (% of D under spec, pose units under authors)
    ecd_rot: float = float("nan")  # mean rotation angle of R_g over pairs (deg)
    n_pairs: int = 0
    n_pairs_scored: int = 0
    evidence: float = float("nan")  # what the score rests on (§3.11): the mean pair evidence, 0-1
    pose_tracks: float = float("nan")  # mean over pairs of the tracks in accepted local poses
    parallax_px: float = float("nan")  # mean over pairs of the camera translation's parallax at depth D [px]
    static_frac: float = float("nan")  # mean over pairs of the static share of the frame with valid depth
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
    pair_floors: dict[str, np.ndarray] | None = dataclasses.field(default=None, repr=False, compare=False)
    pair_evidence: np.ndarray | None = dataclasses.field(default=None, repr=False, compare=False)

    def __repr__(self) -> str:  # the per-pair arrays would run to thousands of lines
        reason = self.reason if len(self.reason) <= 80 else self.reason[:77] + "..."
        return (f"ClipResult({self.clip_id!r}, group={self.group!r}, status={self.status!r}, sgc={self.sgc:.4g}, "
                f"pairs scored {self.n_pairs_scored}/{self.n_pairs}, engine={self.engine!r}"
                + (f", reason={reason!r}" if reason else "") + "; .record() for every column)")

    def record(self, ecd: float = float("nan")) -> dict[str, Any]:
        """The :data:`CLIP_COLUMNS` row; ``ecd`` needs a corpus (see :func:`camera_dynamics`)."""
        row = {"clip_id": self.clip_id, "group": self.group, "status": self.status, "reason": self.reason,
               "warnings": self.warnings, "sgc": self.sgc, "sgc_lo": self.sgc_lo, "sgc_hi": self.sgc_hi,
               **self.components, **self.floors,
               "sgc_floor": self.sgc_floor, "reproj_error": self.reproj_error,
               "ecd_trans": self.ecd_trans, "ecd_rot": self.ecd_rot, "ecd": ecd, "n_pairs": self.n_pairs,
               "n_pairs_scored": self.n_pairs_scored, "evidence": self.evidence, "pose_tracks": self.pose_tracks,
               "parallax_px": self.parallax_px, "static_frac": self.static_frac, "engine": self.engine,
               "mask_source": self.mask_source, "scale": self.scale, "depth_unit": self.depth_unit,
               "n_ill_conditioned": self.n_ill_conditioned, "compat": self.compat, "origin": self.origin,
               "input_sha256": self.input_sha256, "run_id": self.run_id}
        return {k: row[k] for k in CLIP_COLUMNS}

    def pair_records(self) -> list[dict[str, Any]]:
        if self.pairs is None:
            return []
        p = self.pairs
        floors = self.pair_floors if self.pair_floors is not None else pair_floors(p.columns(), self.compat)
        evidence = (self.pair_evidence if self.pair_evidence is not None
                    else evidence_per_pair(p.columns(), EvidenceLevels())[0])
        tracks = pose_tracks(p.region_status, p.region_points)
        return [{"clip_id": self.clip_id, "group": self.group, "pair": i + 1, "reason": str(p.reason[i]),
                 **{k: float(getattr(p, k)[i]) for k in COMPONENTS}, **{k: float(v[i]) for k, v in floors.items()},
                 "reproj_error": float(p.reproj_error[i]),
                 "n_tracks": int(p.n_tracks[i]), "n_regions": int(p.n_regions[i]), "n_poses": int(p.n_poses[i]),
                 "n_ill_conditioned": int(p.n_ill_conditioned[i]),
                 "t_g_norm": float(p.t_g_norm[i]), "R_g_angle_deg": float(p.R_g_angle_deg[i]),
                 "evidence": float(evidence[i]), "pose_tracks": float(tracks[i]),
                 "parallax_px": float(p.parallax_px[i]), "static_frac": float(p.static_frac[i]),
                 "engine": self.engine} for i in range(p.n_pairs)]


def pair_summaries(clips: Sequence[PairArrays], calibration: Calibration, compat: str,
                   evidence_levels: EvidenceLevels | None = None) -> list[dict[str, Any]]:
    """``summary.summarize_pairs`` of each clip's pairs (float64), one call for all clips of the
    same pair count and region slots, so NumPy's cost per call is paid once per group; the numbers
    are those of one call per clip (every reduction runs along a clip's own pairs)."""
    levels = evidence_levels or EvidenceLevels()
    by_shape: dict[tuple, list[int]] = {}
    for i, pairs in enumerate(clips):
        by_shape.setdefault(pairs.region_status.shape, []).append(i)  # (pairs, region slots)
    summaries: list[dict[str, Any]] = [{} for _ in clips]
    for members in by_shape.values():
        columns = [clips[i].columns() for i in members]
        stacked = {name: np.stack([c[name] for c in columns]) for name in columns[0]}
        s = summarize_pairs(stacked, np.ones(stacked["reason"].shape, bool), calibration, compat, levels)
        for j, i in enumerate(members):
            summaries[i] = {name: ({k: v[j] for k, v in value.items()} if isinstance(value, dict) else value[j])
                            for name, value in s.items()}
    return summaries


def summarize_clip(clip_id: str, pairs: PairArrays, calibration: Calibration, *, group: str = "",
                   engine: str = "", mask_source: str = "", origin: str = "", compat: str = "",
                   evidence_levels: EvidenceLevels | None = None, summary: Mapping[str, Any] | None = None
                   ) -> ClipResult:
    """Per-clip means over pairs (NaN ignored), status, reason, the SGC score and its evidence
    (docs/semantics.md §3.8, §3.11, §5): ``summary.summarize_pairs`` in float64, with the reasons
    in words. ``summary``: this clip's entry of ``pair_summaries`` (same calibration, compat and
    levels), when a group's clips were summarised at once."""
    levels = evidence_levels or EvidenceLevels()
    s = summary if summary is not None else pair_summaries([pairs], calibration, compat, levels)[0]
    sgc, evidence = float(s["sgc"]), float(s["evidence"])
    status = table_status(int(s["status"]), sgc)
    reasons = Counter(str(r) for r in pairs.reason)
    problems = "; ".join(f"{r} x{n}" for r, n in sorted(reasons.items()) if r != "ok")
    if status == "error":
        reason = f"no pair could be scored ({problems})" if problems else "no pair could be scored"
    elif status == "low_evidence":
        tracks = pose_tracks(pairs.region_status, pairs.region_points)
        outrun = cameras_outrun_tracks(pairs.t_g_norm, pairs.R_g_angle_deg, pairs.tracks_trans, pairs.tracks_rot_deg,
                                       levels)
        breaks = s["pair_breaks"]
        thin = shortfall(tracks, pairs.t_g_norm, pairs.R_g_angle_deg, pairs.static_frac, pairs.reason == "ok", levels,
                         outrun, breaks["tracks_lost"], breaks["no_rigid_motion"])
        reason = f"evidence {evidence:.2f} < {LOW_EVIDENCE}: " + "; ".join(part for part in (problems, thin) if part)
    else:
        reason = problems if status == "partial" else ""
    return ClipResult(
        clip_id=clip_id, group=group, status=status, reason=reason, sgc=sgc, sgc_lo=float(s["sgc_lo"]),
        sgc_hi=float(s["sgc_hi"]), components={k: float(s[k]) for k in COMPONENTS},
        floors={k: float(s[k]) for k in FLOOR_COLUMNS}, sgc_floor=float(s["sgc_floor"]),
        reproj_error=float(s["reproj_error"]), ecd_trans=float(s["ecd_trans"]), ecd_rot=float(s["ecd_rot"]),
        n_pairs=pairs.n_pairs, n_pairs_scored=int(s["n_pairs_scored"]), evidence=evidence,
        pose_tracks=float(s["pose_tracks"]), parallax_px=float(s["parallax_px"]), static_frac=float(s["static_frac"]),
        engine=engine, mask_source=mask_source, scale=float(pairs.scale), depth_unit=float(pairs.depth_unit),
        n_ill_conditioned=int(s["n_ill_conditioned"]), compat=compat, origin=origin, pairs=pairs,
        pair_floors=s["pair_floors"], pair_evidence=s["pair_evidence"])


# Per-clip columns added after tables were first written: empty where an earlier table lacks them
ADDED_COLUMNS = ("warnings",)


def clip_from_row(row: Mapping[str, str]) -> ClipResult:
    """The :class:`ClipResult` of a per-clip CSV row (as text, e.g. one kept by a resumed run):
    every column but ``ecd``; no per-pair arrays."""
    cell = {name: typed_cell(column_kind(name), row.get(name, "") if name in ADDED_COLUMNS else row[name])
            for name in CLIP_COLUMNS if name != "ecd"}
    return ClipResult(components={k: cell.pop(k) for k in COMPONENTS},
                      floors={k: cell.pop(k) for k in FLOOR_COLUMNS}, **cell)


def failed_clip(clip_id: str, message: str, *, engine: str = "", origin: str = "", compat: str = "") -> ClipResult:
    """The row of a clip that could not be loaded or scored."""
    return ClipResult(clip_id=clip_id, status="error", reason=message, engine=engine, origin=origin, compat=compat)


def _rescored(clips: Sequence[ClipResult], calibration: Calibration,
              evidence_levels: EvidenceLevels | None = None) -> list[ClipResult]:
    """The clips under ``calibration``: from their pairs (summarised together by compat), or from
    their per-clip components where a resumed run kept none."""
    summaries: list[Mapping[str, Any] | None] = [None] * len(clips)
    for compat in {c.compat for c in clips if c.pairs is not None}:
        same = [i for i, c in enumerate(clips) if c.pairs is not None and c.compat == compat]
        for i, summary in zip(same, pair_summaries([clips[i].pairs for i in same], calibration, compat,
                                                   evidence_levels)):
            summaries[i] = summary
    return [_rescored_clip(c, calibration, evidence_levels, summary) for c, summary in zip(clips, summaries)]


def _rescored_clip(clip: ClipResult, calibration: Calibration, evidence_levels: EvidenceLevels | None,
                   summary: Mapping[str, Any] | None) -> ClipResult:
    if clip.pairs is not None:
        return dataclasses.replace(
            summarize_clip(clip.clip_id, clip.pairs, calibration, group=clip.group, engine=clip.engine,
                           mask_source=clip.mask_source, origin=clip.origin, compat=clip.compat,
                           evidence_levels=evidence_levels, summary=summary),
            input_sha256=clip.input_sha256, warnings=clip.warnings)
    if clip.status == "error":
        return clip
    nan = float("nan")
    return dataclasses.replace(clip, sgc=float(sgc_score(clip.components, calibration, floors=clip.floors)),
                               sgc_lo=nan, sgc_hi=nan, sgc_floor=float(floor_score(clip.floors, calibration)),
                               run_id="")


# ----------------------------------------------------------------------------- batch table


def _json_value(value: Any) -> Any:
    if isinstance(value, (float, np.floating)):
        return None if math.isnan(value) else float(value)
    if isinstance(value, np.integer):
        return int(value)
    return value


def rescore_records(records: Sequence[dict[str, Any]], calibration: Calibration | str) -> list[dict[str, Any]]:
    """Copies of per-clip rows with ``sgc`` (and ``sgc_floor``) recomputed from their stored
    components (floors) under ``calibration`` (no geometry: the per-clip components are all the
    score needs) and ``ecd`` recomputed over these rows; ``run_id`` is emptied (no run scored them
    so), and so are ``sgc_lo`` / ``sgc_hi`` (NaN: the interval needs the per-pair components)."""
    calibration = Calibration.load(calibration)
    calibration.check_compat(rows_compat(records), "the rows")
    components = {k: np.array([float(r[k]) for r in records]) for k in COMPONENTS}
    floors = ({k: np.array([float(r.get(k, "nan")) for r in records]) for k in FLOOR_COLUMNS}
              if all(k in r for r in records for k in FLOOR_COLUMNS) else None)
    sgc = sgc_score(components, calibration, floors=floors) if records else np.array([])
    nan = float("nan")
    out = [{**r, "sgc": float(v), **({"run_id": ""} if "run_id" in r else {}),
            **({k: nan for k in INTERVAL_COLUMNS if k in r}),
            **({"sgc_floor": float(floor_score({k: float(r[k]) for k in FLOOR_COLUMNS}, calibration))}
               if "sgc_floor" in r else {})}
           for r, v in zip(records, sgc)]
    return add_ecd(out) if any("ecd_trans" in r for r in out) else out


def add_ecd(records: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Copies of per-clip rows with ``ecd`` (docs/semantics.md §4) normalised over these rows; rows without
    ``ecd_trans`` / ``ecd_rot`` get NaN."""
    nan = float("nan")
    ecd = camera_dynamics([r.get("ecd_trans", nan) for r in records], [r.get("ecd_rot", nan) for r in records])
    return [{**r, "ecd": float(e)} for r, e in zip(records, ecd)]


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
        is a function of the stored per-pair components). A clip kept without its pairs (one a
        resumed run read back) is rescored from its per-clip components, as ``rescore_records``
        does: its interval becomes NaN."""
        calibration = Calibration.load(calibration)
        for c in self.clips:
            calibration.check_compat(c.compat, f"the scores of clip {c.clip_id!r}")
        return BatchResult(_rescored(self.clips, calibration), calibration)

    def rewards(self, options: RewardOptions | None = None) -> dict[str, np.ndarray]:
        """The Scorer's reward outputs (docs/semantics.md §9.4) of these clips, (n,) each:
        ``sgc_unclipped``, ``camera_motion``, ``reward`` (float32) and ``status`` (the Scorer's
        codes, ``sgc_jax.codes.SCORER_STATUSES``), from the stored per-clip values; evidence levels
        other than the tables' defaults are applied to the clips' pairs (as a Scorer would)."""
        if self.calibration is None:
            raise ValueError("rewards need the calibration the clips were scored under (this result has none)")
        options = options or RewardOptions()
        clips = self.clips
        if options.evidence != EvidenceLevels():
            if any(c.pairs is None and c.status != "error" for c in clips):
                raise ValueError("evidence levels other than the defaults need each clip's pairs (a resumed "
                                 "run's rows have none)")
            clips = _rescored(clips, self.calibration, options.evidence)
        records = BatchResult(clips, self.calibration).to_records()
        column = lambda name: np.array([float(r[name]) for r in records], np.float64)  # noqa: E731
        summary = {k: column(k) for k in (*COMPONENTS, *FLOOR_COLUMNS, "ecd_trans", "ecd_rot", "evidence")}
        summary["status"] = np.array([SCORER_STATUS_CODE[r["status"]] for r in records], np.int32)
        return reward(summary, self.calibration, options, xp=np)

    def table(self, columns: Sequence[str] = ("clip_id", "group", "status", "sgc", *INTERVAL_COLUMNS, *COMPONENTS,
                                              "evidence")) -> str:
        """A plain-text table for terminals, with a row of units under the header (docs/semantics.md §4):
        the score, its 90 % interval over tracker noise (§5.6), the components and the evidence (§3.11)."""
        compats = {c.compat for c in self.clips if c.compat}
        units = COLUMN_UNITS[compats.pop()] if len(compats) == 1 else None
        records = self.to_records()
        legend = []
        if units and any("of D" in units.get(c, "") for c in columns):
            legend.append("D: the clip's depth unit, the median depth of its static pixels (docs/semantics.md "
                          "§3.1); sgc_lo, sgc_hi: the 90 % interval over tracker noise (§5.6)")
        # why a clip was not scored, or scored on part of its pairs or on little
        legend += [f"{r['clip_id']} ({r['status']}): {r['reason']}" for r in records
                   if r.get("reason") and r.get("status") != "ok"]
        return "\n".join([format_table(records, columns, units), *legend])


