"""Score tables as Parquet files (``--out scores.parquet``), through pyarrow (the ``parquet`` and
``ray`` extras).

A table is written with one Arrow type per column (text: string, int: int64, float: float64,
NaN kept as NaN) and read back as the text cells the CSV writer would have written (a float as
``str(float)``, which round-trips; NaN as an empty cell), so a Parquet output resumes and reads
like a CSV one.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

from .extras import MissingExtraError

ARROW_TYPES = {"text": "string", "int": "int64", "float": "float64"}


def is_parquet(path: str | os.PathLike) -> bool:
    return Path(path).suffix.lower() == ".parquet"


def pyarrow_modules():
    """(pyarrow, pyarrow.parquet); MissingExtraError naming the extra without them."""
    try:
        import pyarrow
        import pyarrow.parquet
    except ImportError:
        raise MissingExtraError("reading or writing .parquet tables needs pyarrow: pip install 'sgc-jax[parquet]' "
                                "(or write a .csv)") from None
    return pyarrow, pyarrow.parquet


def typed_cell(kind: str, value: Any) -> Any:
    """A cell as its column's type ("text", "int" or "float"); a text cell (a CSV's, or a resumed
    row's) parsed, an empty one NaN / 0."""
    if kind == "text":
        return "" if value is None else str(value)
    if isinstance(value, str):
        value = value.strip()
        if kind == "int":
            return int(value) if value else 0
        return float(value) if value else math.nan
    return int(value) if kind == "int" else float(value)


def write_parquet(path: str | os.PathLike, rows: Sequence[Mapping[str, Any]], columns: Sequence[str],
                  kind: Callable[[str], str]) -> Path:
    """Rows as a Parquet file with these columns; ``kind(column)`` is "text", "int" or "float"."""
    pa, pq = pyarrow_modules()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    kinds = {c: kind(c) for c in columns}
    schema = pa.schema([(c, getattr(pa, ARROW_TYPES[kinds[c]])()) for c in columns])
    arrays = [pa.array([typed_cell(kinds[c], row.get(c)) for row in rows], type=schema.field(c).type) for c in columns]
    pq.write_table(pa.Table.from_arrays(arrays, schema=schema), path)
    return path


def _text(value: Any) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return ""
    return str(value)


def read_parquet_text(path: str | os.PathLike) -> tuple[list[str], list[dict[str, str]]]:
    """A Parquet table's column names and rows, each cell as the CSV writer writes it."""
    _, pq = pyarrow_modules()
    table = pq.read_table(path)
    columns = {name: table.column(name).to_pylist() for name in table.column_names}
    rows = [{name: _text(values[i]) for name, values in columns.items()} for i in range(table.num_rows)]
    return list(table.column_names), rows
