"""Scoring a corpus as a stream (docs/semantics.md §4.1).

Readers hash, read, validate and prepare the clips ahead of the device, at most ``chunk_size`` at a
time (memory does not grow with the corpus); ``lanes`` scoring threads each score one clip (with
several devices or on an accelerator, a group: ``devices.clips_per_call``) at a time, and every
finished clip is handed on at once, in input order. Clip ids are claimed in input order by the
generator's thread, so the first file with an id keeps it whatever order the readers finish in.
"""

from __future__ import annotations

import collections
import concurrent.futures
import contextlib
import dataclasses
import time
from typing import Iterator, Mapping, NamedTuple

from ..calibration import Calibration
from ..config import SGCConfig
from ..engines.pairs import PairArrays
from ..io.clip import ClipFormatError
from ..io.loading import ClipEntry
from .engine_steps import engine_steps
from .journal import FileDigests
from .options import RunOptions
from .readers import THREAD_READERS, Read, ReaderProcesses, read_entry, reading_plan
from .result import ClipResult, clip_from_row, failed_clip, pair_summaries, summarize_clip

Done = Mapping[tuple[str, str], Mapping[str, str]]  # rows of an earlier run's output by (clip_id, input_sha256)


@dataclasses.dataclass
class StreamStats:
    """What a stream did: clips handed on (``scored``, ``resumed`` from an earlier output,
    ``errors``), its wall time, the time the scoring thread waited for a clip to be read (an
    upper bound of the device's wait for input) and the time the lanes spent summarising scored
    clips (in their own threads, beside the other lanes' programs)."""

    scored: int = 0
    resumed: int = 0
    errors: int = 0
    wall_s: float = 0.0
    input_wait_s: float = 0.0
    summary_s: float = 0.0

    @property
    def input_wait_share(self) -> float:
        return self.input_wait_s / self.wall_s if self.wall_s > 0 else 0.0


class Streamed(NamedTuple):
    """One clip handed on: its result and, for a clip resumed from an earlier output, that row (text)."""

    result: ClipResult
    kept_row: Mapping[str, str] | None
    load_failed: bool = False  # the clip could not be loaded (so it claimed no id)


class Scoring(NamedTuple):
    """What every clip of a stream is scored with."""

    config: SGCConfig
    calibration: Calibration
    engine: str
    run_id: str = ""


def error_result(entry: ClipEntry, error: ClipFormatError, sha256: str, scoring: Scoring) -> ClipResult:
    """The error row of a clip that could not be loaded or whose id another file has."""
    result = failed_clip(entry.clip_id, str(error), engine=scoring.engine, origin=entry.origin,
                         compat=scoring.config.compat)
    return dataclasses.replace(result, input_sha256=sha256, run_id=scoring.run_id)


class _Stream:
    """One pass of ``stream_scores``: entries read ahead in ``queue``, prepared clips gathered into
    ``group`` (one bucket), groups scored in lanes (``pending``), results handed on in order."""

    def __init__(self, entries, scoring: Scoring, done: Done, options: RunOptions, stats: StreamStats,
                 processes: ReaderProcesses | None, stack: contextlib.ExitStack):
        self.scoring, self.done, self.options, self.stats, self.processes = scoring, done, options, stats, processes
        self.steps = engine_steps(scoring.engine, scoring.config, options.devices, options.lanes)
        self.digests = FileDigests()
        threads = concurrent.futures.ThreadPoolExecutor
        readers, _ = reading_plan(options.readers, options.read_in)
        # with reader processes, threads read only the clips given in memory
        self.pool = stack.enter_context(threads(max_workers=THREAD_READERS if processes else readers,
                                                thread_name_prefix="sgc-read"))
        self.lanes = stack.enter_context(threads(max_workers=self.steps.lanes, thread_name_prefix="sgc-score"))
        self.done_sha256 = collections.defaultdict(set)
        for clip_id, sha256 in done:
            self.done_sha256[clip_id].add(sha256)
        self.upcoming = iter(entries)
        self.queue: collections.deque = collections.deque()  # (entry, future of its Read), input order
        self.group: list[Read] = []  # read, waiting to be scored together
        self.pending: collections.deque = collections.deque()  # futures of (rows, summary seconds), input order

    def _submit(self, entry: ClipEntry) -> concurrent.futures.Future:
        if self.processes is not None and entry.path is not None:  # clips given in memory stay here
            return self.processes.submit(entry, frozenset(self.done_sha256.get(entry.clip_id, ())))
        return self.pool.submit(read_entry, entry, self.steps.prepare, self.digests, self.done)

    def _fill(self) -> None:
        while len(self.queue) < max(1, self.options.chunk_size, self.steps.group_size):
            entry = next(self.upcoming, None)
            if entry is None:
                return
            self.queue.append((entry, self._submit(entry)))

    def _summarized(self, reads: list[Read], pairs: list[PairArrays]) -> tuple[list[ClipResult], float]:
        """A group's rows, summarised at once in its lane's thread (beside the other lanes' programs,
        so the scoring thread goes on feeding the devices) -> (rows, seconds spent)."""
        s = self.scoring
        begin = time.perf_counter()
        summaries = pair_summaries(pairs, s.calibration, s.config.compat)
        results = [dataclasses.replace(
            summarize_clip(read.identity.clip_id, clip_pairs, s.calibration, group=read.identity.group,
                           engine=s.engine, mask_source=read.identity.mask_source, origin=read.entry.origin,
                           compat=s.config.compat, summary=summary),
            input_sha256=read.sha256, run_id=s.run_id, warnings=read.identity.warnings)
            for read, clip_pairs, summary in zip(reads, pairs, summaries)]
        return results, time.perf_counter() - begin

    def _launch(self) -> Iterator[Streamed]:
        """Score and summarise the group in a lane; with every lane busy and one more group behind
        them, hand on the oldest."""
        reads, prepared, steps = list(self.group), [r.prepared for r in self.group], self.steps
        self.pending.append(self.lanes.submit(lambda: self._summarized(reads, steps.collect(steps.dispatch(prepared)))))
        self.group.clear()
        if len(self.pending) > steps.lanes:
            yield from self._land()

    def _land(self) -> Iterator[Streamed]:
        results, seconds = self.pending.popleft().result()
        self.stats.scored += len(results)
        self.stats.summary_s += seconds
        for result in results:
            yield Streamed(result, None)

    def _drain(self) -> Iterator[Streamed]:
        """Everything in flight, in input order."""
        if self.group:
            yield from self._launch()
        while self.pending:
            yield from self._land()

    def _not_scored(self, entry: ClipEntry, read: Read, error: ClipFormatError | None) -> Iterator[Streamed]:
        yield from self._drain()  # results go in input order
        if error is not None:
            self.stats.errors += 1
            yield Streamed(error_result(read.entry, error, read.sha256, self.scoring), None,
                           load_failed=read.error is not None)
        else:
            self.stats.resumed += 1
            kept_row = self.done[(entry.clip_id, read.sha256)]
            yield Streamed(clip_from_row(kept_row), kept_row)

    def __iter__(self) -> Iterator[Streamed]:
        self._fill()
        while self.queue:
            begin = time.perf_counter()
            entry, future = self.queue.popleft()
            read = future.result()._replace(entry=entry)  # a reader process returns a copy
            self.stats.input_wait_s += time.perf_counter() - begin
            self._fill()
            error = read.error
            if error is None:
                try:
                    read.entry.claim_id()  # in input order: the first file with an id keeps it
                except ClipFormatError as exc:
                    error = exc
            if error is not None or read.resumed:
                yield from self._not_scored(entry, read, error)
                continue
            if self.group and self.steps.group_key(read.prepared) != self.steps.group_key(self.group[0].prepared):
                yield from self._launch()
            self.group.append(read)
            if len(self.group) == self.steps.group_size:
                yield from self._launch()
        yield from self._drain()

    def cancel(self) -> None:
        for future in [*(future for _, future in self.queue), *self.pending]:
            future.cancel()


def stream_scores(entries: list[ClipEntry], scoring: Scoring, *, done: Done | None = None,
                  options: RunOptions = RunOptions(), stats: StreamStats | None = None,
                  reader_processes: ReaderProcesses | None = None) -> Iterator[Streamed]:
    """Every entry's result, in input order, as soon as it is known.

    ``done``: rows of an earlier run's output; those inputs are not read again and come back with
    their row (``Streamed.kept_row``). A clip that fails to load is an error row; any other
    exception propagates. ``options``: readers, devices and lanes (the results depend on none)."""
    _, in_processes = reading_plan(options.readers, options.read_in)
    if reader_processes is not None and reader_processes.setup != (scoring.engine, scoring.config):
        raise ValueError("reader_processes were started for another engine or configuration")
    stats = stats if stats is not None else StreamStats()
    start = time.perf_counter()
    with contextlib.ExitStack() as stack:
        processes = reader_processes
        if processes is None and in_processes:
            readers, _ = reading_plan(options.readers, options.read_in)
            processes = stack.enter_context(ReaderProcesses(readers, scoring.engine, scoring.config))
        stream = _Stream(entries, scoring, done or {}, options, stats, processes, stack)
        try:
            yield from stream
        finally:
            stream.cancel()
            stats.wall_s += time.perf_counter() - start
