"""Score tables on disk and on screen: column names and types, CSV and Parquet writing and
reading, plain-text tables (docs/semantics.md §4). Nothing here computes a score."""

from __future__ import annotations

import csv
import math
import os
from collections import Counter
from pathlib import Path
from typing import Any, Iterable, Sequence

from ..calibration import COMPONENTS
from ..calibration.formula import FLOOR_COLUMNS  # each pose component's noise floor (docs/semantics.md §3.10)
from ..calibration.interval import INTERVAL_LEVEL
from .extras import MissingExtraError
from .parquet import is_parquet, read_parquet_text, write_parquet

# The score's 90 % interval (docs/semantics.md §5.6)
INTERVAL_COLUMNS = ("sgc_lo", "sgc_hi")
# What the score rests on (docs/semantics.md §3.11): per pair, and per clip the means over its pairs
EVIDENCE_COLUMNS = ("evidence", "pose_tracks", "parallax_px", "static_frac")
CLIP_COLUMNS = ("clip_id", "group", "status", "reason", "warnings", "sgc", *INTERVAL_COLUMNS, *COMPONENTS, *FLOOR_COLUMNS, "sgc_floor",
                "reproj_error", "ecd_trans", "ecd_rot", "ecd", "n_pairs", "n_pairs_scored", *EVIDENCE_COLUMNS,
                "engine", "mask_source", "scale", "depth_unit", "n_ill_conditioned", "compat", "origin",
                "input_sha256", "run_id")
PAIR_COLUMNS = ("clip_id", "group", "pair", "reason", *COMPONENTS, *FLOOR_COLUMNS, "reproj_error", "n_tracks",
                "n_regions", "n_poses", "n_ill_conditioned", "t_g_norm", "R_g_angle_deg", *EVIDENCE_COLUMNS, "engine")


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
TEXT_COLUMNS = ("clip_id", "group", "status", "reason", "warnings", "engine", "mask_source", "base", "kind", "compat", "origin",
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


def write_scores(path: str | os.PathLike, records: Sequence[dict[str, Any]]) -> Path:
    """Write per-clip rows as CSV (Parquet for a ``.parquet`` path): :data:`CLIP_COLUMNS` present in
    the rows first, then any extra columns in their order of appearance (``source`` is not written)."""
    seen: list[str] = []
    for r in records:
        seen.extend(k for k in r if k not in seen and k != "source")
    columns = [c for c in CLIP_COLUMNS if c in seen] + [c for c in seen if c not in CLIP_COLUMNS]
    return write_table(path, list(records), columns)


def _with_floors_and_interval(units: dict[str, str]) -> dict[str, str]:
    """A semantics' units with its floor columns' (each its component's) and the interval's."""
    floors = {floor: units[floor.removesuffix("_floor")] for floor in (*FLOOR_COLUMNS, "sgc_floor")}
    return {**units, **floors, **dict.fromkeys(INTERVAL_COLUMNS, f"{INTERVAL_LEVEL:.0%} interval")}


EVIDENCE_UNITS = {"evidence": "0-1", "pose_tracks": "tracks", "parallax_px": "px", "static_frac": "0-1"}
# Short units of the numeric columns under each semantics, for the unit row of printed tables
# (docs/semantics.md §4; D: the clip's median static depth).
COLUMN_UNITS = {compat: _with_floors_and_interval(units) for compat, units in {
    "spec": {"sgc": "lower=better", "local_rot_var": "deg²", "global_rot_var": "deg²", "local_trans_var": "(% of D)²",
             "global_trans_var": "(% of D)²", "depth_error": "% of depth", "reproj_error": "px",
             "ecd_trans": "% of D", "ecd_rot": "deg", "ecd": "0-1", "scale": "depth/pose", "depth_unit": "depth", **EVIDENCE_UNITS},
    "authors": {"sgc": "lower=better", "local_rot_var": "deg²", "global_rot_var": "deg²", "local_trans_var": "depth²",
                "global_trans_var": "pose²", "depth_error": "depth", "reproj_error": "px", "ecd_trans": "pose",
                "ecd_rot": "deg", "ecd": "0-1", "scale": "depth/pose", "depth_unit": "depth", **EVIDENCE_UNITS},
}.items()}


def format_table(records: Sequence[dict[str, Any]], columns: Sequence[str], units: dict[str, str] | None = None) -> str:
    """A plain-text table for terminals (floats to 4 significant digits); ``units``: a row of them
    under the header (e.g. ``COLUMN_UNITS["spec"]``)."""
    head = [list(columns)] + ([[units.get(c, "") for c in columns]] if units else [])
    rows = [[_format(r.get(c, "")) for c in columns] for r in records]
    widths = [max(len(row[i]) for row in head + rows) for i in range(len(columns))]
    line = lambda cells: "  ".join(cell.ljust(w) for cell, w in zip(cells, widths)).rstrip()  # noqa: E731
    return "\n".join([*(line(h) for h in head), line(["-" * w for w in widths]), *(line(r) for r in rows)])


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
        raise MissingExtraError("to_pandas needs pandas: pip install 'sgc-jax[viz]' (or pip install pandas)") from exc
    return pd.DataFrame(list(records), columns=list(columns))
