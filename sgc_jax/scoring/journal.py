"""A run's per-clip (and per-pair) table (CSV or Parquet) written as clips finish, and read back to resume the run
(docs/semantics.md §4.1).

Every row names its input (``clip_id``, ``input_sha256``: the file's bytes) and its run
(``run_id``: a hash of the package version, engine, configuration and calibration, kept in full in
``<out>.run.json``). ``--resume`` keeps the complete rows of the same input and run (but error rows), scores the
rest, and the table is rewritten in input order when the run ends, so a run killed at any point
and resumed writes the same table as one that never stopped.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import os
import threading
from pathlib import Path
from typing import Any, Iterable, Mapping

from ..calibration import Calibration
from ..config import SGCConfig
from ..io.parquet import is_parquet, pyarrow_modules, typed_cell
from ..io.remote import is_url, open_file, version_key
from ..io.tables import CLIP_COLUMNS, PAIR_COLUMNS, read_table_text, write_csv_rows, write_table
from ..version import __version__
from .result import ClipResult, add_ecd

RUN_ID_LENGTH = 16


def run_record(config: SGCConfig, calibration: Calibration, engine: str) -> dict[str, Any]:
    """Everything a clip's numbers depend on besides its input: version, engine, config, calibration."""
    return {"sgc_jax_version": __version__, "engine": engine, "config": config.to_dict(),
            "calibration": calibration.to_dict()}


def run_id(record: Mapping[str, Any]) -> str:
    """``RUN_ID_LENGTH`` hex digits of the SHA-256 of a ``run_record`` (canonical JSON)."""
    text = json.dumps(record, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:RUN_ID_LENGTH]


class FileDigests:
    """SHA-256 of input files, each read once per run (a batch file's clips share its digest);
    safe to use from several threads."""

    def __init__(self) -> None:
        self._digests: dict[tuple, str] = {}
        self._lock = threading.Lock()

    def of(self, path: str | os.PathLike) -> str:
        """The file's SHA-256 (hex); ``path`` may be a URL (``remote``)."""
        text, url = os.fspath(path), is_url(path)
        if url:
            key = (text, *version_key(text))
        else:
            stat = os.stat(path)
            key = (text, stat.st_size, stat.st_mtime_ns)
        with self._lock:
            if key in self._digests:
                return self._digests[key]
        digest = hashlib.sha256()
        with (open_file(text)[0] if url else open(path, "rb")) as f:
            for block in iter(lambda: f.read(1 << 22), b""):
                digest.update(block)
        with self._lock:
            return self._digests.setdefault(key, digest.hexdigest())


def _complete_rows(path: Path, columns: tuple[str, ...]) -> list[dict[str, str]]:
    """The rows of a CSV this module wrote that were written completely: the text up to its last
    newline, rows with every column (a killed run may leave half a line). A file with other
    columns (another version's) gives none."""
    if not path.is_file():
        return []
    with path.open(newline="") as f:
        text = f.read()
    reader = csv.DictReader(io.StringIO(text[:text.rfind("\n") + 1]))
    if tuple(reader.fieldnames or ()) != columns:
        return []
    return [row for row in reader if None not in row.values()]


class _TableFile:
    """One output table of a run. Rows are appended to a CSV log as clips finish: the table
    itself when it is a CSV, ``<table>.journal.csv`` beside a Parquet table (which cannot be
    appended to), written whole by ``finish`` and the log removed."""

    def __init__(self, path: Path, columns: tuple[str, ...]) -> None:
        self.path, self.columns = path, columns
        self.log = path.with_name(path.name + ".journal.csv") if is_parquet(path) else path
        if is_parquet(path):
            pyarrow_modules()  # a missing pyarrow is said before the run, not after it
        self._file = None

    def earlier_rows(self) -> list[dict[str, str]]:
        """The complete rows an earlier run left: a finished table's, then its log's."""
        rows = []
        if self.log != self.path and self.path.is_file():
            header, table = read_table_text(self.path)
            rows = table if tuple(header) == self.columns else []
        return rows + _complete_rows(self.log, self.columns)

    def start(self, kept: Iterable[Mapping[str, Any]]) -> None:
        """Begin the run's log with the rows kept from an earlier run (a stale table is removed)."""
        _write_rows_atomically(self.log, kept, self.columns)
        if self.log != self.path:  # after the log holds the kept rows: a kill in between loses none
            self.path.unlink(missing_ok=True)
        self._file = self.log.open("a", newline="")

    def append(self, rows: list[dict[str, Any]]) -> None:
        """Rows written with one call and flushed to the OS (a killed process loses nothing written)."""
        if not rows:
            return
        buffer = io.StringIO()
        write_csv_rows(buffer, rows, self.columns, header=False)
        self._file.write(buffer.getvalue())
        self._file.flush()

    def finish(self, rows: Iterable[Mapping[str, Any]]) -> None:
        self.close()
        _write_rows_atomically(self.path, rows, self.columns)
        if self.log != self.path:
            self.log.unlink(missing_ok=True)

    def close(self) -> None:
        if self._file is not None and not self._file.closed:
            self._file.close()


def _write_rows_atomically(path: Path, rows: Iterable[Mapping[str, Any]], columns: tuple[str, ...]) -> None:
    temporary = path.with_name(f"{path.stem}.partial{path.suffix}")  # the suffix chooses the format
    write_table(temporary, list(rows), columns)
    os.replace(temporary, path)


class ScoresJournal:
    """The output files of one run: ``out`` (per clip) and optionally ``pairs_out`` (per pair),
    each a CSV or a ``.parquet`` table.

    On opening, the complete rows of an earlier run with the same ``run_id`` are kept when
    ``resume`` (``done`` maps (clip_id, input_sha256) to them; error rows are not kept), everything else is dropped; then
    ``append`` adds each batch of results as it finishes (flushed, so a killed run loses at most
    the batch being written), and ``finish`` rewrites both files in input order with ``ecd``
    normalised over the whole table.
    """

    def __init__(self, out: str | os.PathLike, pairs_out: str | os.PathLike | None, run: Mapping[str, Any],
                 *, resume: bool) -> None:
        self.out = Path(out)
        self.pairs_out = Path(pairs_out) if pairs_out is not None else None
        self.run_id = run_id(run)
        self.done: dict[tuple[str, str], dict[str, str]] = {}  # (clip_id, input_sha256) -> row
        self._clips = _TableFile(self.out, CLIP_COLUMNS)
        self._pairs = _TableFile(self.pairs_out, PAIR_COLUMNS) if self.pairs_out is not None else None
        kept_pairs: list[dict[str, str]] = []
        if resume:
            for row in self._clips.earlier_rows():
                # error rows are read again (a duplicate id, say, depends on the other inputs)
                if row["run_id"] == self.run_id and row["input_sha256"] and row["status"] != "error":
                    self.done.setdefault((row["clip_id"], row["input_sha256"]), row)
            if self._pairs is not None:
                # pairs are flushed before their clip's row, so a kept clip has all of its pairs
                kept_ids = {row["clip_id"] for row in self.done.values()}
                kept_pairs = [r for r in self._pairs.earlier_rows() if r["clip_id"] in kept_ids]
        self.out.parent.mkdir(parents=True, exist_ok=True)
        run_file = self.out.with_name(self.out.name + ".run.json")
        run_file.write_text(json.dumps({"run_id": self.run_id, **run}, indent=1, default=str))
        self._clips.start(self.done.values())
        if self._pairs is not None:
            self._pairs.start(kept_pairs)
        self._pairs_kept = kept_pairs

    def append(self, results: Iterable[ClipResult]) -> None:
        """Add finished clips (``ecd`` left empty until ``finish``): pairs first, then the clips."""
        results = list(results)
        if self._pairs is not None:
            self._pairs.append([row for c in results for row in c.pair_records()])
        self._clips.append([c.record() for c in results])

    def finish(self, clips: list[ClipResult | dict[str, str]]) -> None:
        """Rewrite both files with every clip of the run in input order: new results and kept rows
        (``done`` values, written back unchanged but for ``ecd``)."""
        self.close()
        # a kept row's text and the float it reads as are written alike (str(float) round-trips)
        records = add_ecd([c.record() if isinstance(c, ClipResult) else
                           {**c, "ecd_trans": typed_cell("float", c["ecd_trans"]), "ecd_rot": typed_cell("float", c["ecd_rot"])} for c in clips])
        self._clips.finish(records)
        if self._pairs is not None:
            kept = {}
            for row in self._pairs_kept:
                kept.setdefault(row["clip_id"], []).append(row)
            self._pairs.finish([row for c in clips for row in (
                c.pair_records() if isinstance(c, ClipResult) else kept.get(c["clip_id"], []))])

    def close(self) -> None:
        for table in (self._clips, self._pairs):
            if table is not None:
                table.close()

