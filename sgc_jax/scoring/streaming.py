"""Scoring a corpus as a stream (docs/semantics.md §4.1).

Readers hash, read, validate and pad the clips ahead of the device, at most ``read_ahead`` of
them at a time (memory does not grow with the corpus): threads, or on a host of many cores
processes for the clip files (``reading_plan``); ``lanes`` scoring threads each score
one clip (with several devices, a group of one clip per device, the clip axis sharded over them)
at a time, and every finished clip is handed on at once, in input order. Clip ids are claimed in
input order by the generator's thread, so the first file with an id keeps it whatever order the
readers finish in.
"""

from __future__ import annotations

import collections
import concurrent.futures
import contextlib
import dataclasses
import time
from typing import Any, Callable, Iterator, Mapping, NamedTuple

from .calibration import Calibration
from .config import SGCConfig
from .io.clip import Clip, ClipFormatError
from .io.journal import FileDigests
from .io.loading import ClipEntry
from .io.result import ClipResult, PairArrays, clip_from_row, failed_clip, summarize_clip
from .readers import THREAD_READERS, Read, ReaderProcesses, prepare_step, read_entry, reading_plan


class Engine(NamedTuple):
    """How an engine scores clips in three steps: ``prepare`` (host arrays of one clip; runs in a
    reader thread), ``dispatch`` (starts the device work on a group of up to ``group_size``
    prepared clips of one ``group_key``, returns without waiting) and ``collect`` (waits,
    returns the group's per-pair arrays). ``lanes``: groups scored at once, each dispatched and
    collected in a scoring thread of its own."""

    prepare: Callable[[Clip], Any]
    dispatch: Callable[[list[Any]], Any]
    collect: Callable[[Any], list[PairArrays]]
    group_size: int = 1
    group_key: Callable[[Any], Any] = lambda prepared: None
    lanes: int = 1


def engine_steps(name: str, config: SGCConfig, devices: int | None = None, lanes: int | None = None) -> Engine:
    """The :class:`Engine` steps of ``"jax"`` (clips spread one per device over the first
    ``devices`` local devices, all when None; ``lanes`` groups at once, by default
    ``jax_engine.default_lanes``) or ``"reference"`` (which computes in ``collect``, one clip at a
    time unless ``lanes`` says otherwise)."""
    if lanes is not None and lanes < 1:
        raise ValueError(f"lanes must be at least 1, got {lanes}")
    if name == "jax":
        from .engines import jax_engine

        spread = jax_engine.scoring_devices(devices)
        lanes = lanes or jax_engine.default_lanes(spread)
        prepare = prepare_step(name, config)
        collect = lambda dispatched: jax_engine.collect(dispatched, config)  # noqa: E731
        if len(spread) == 1:
            return Engine(prepare, lambda group: jax_engine.dispatch(group[0], config), collect, lanes=lanes)
        return Engine(prepare, lambda group: jax_engine.dispatch_group(group, config, spread), collect,
                      len(spread), lambda prepared: prepared.bucket, lanes)
    if name == "reference":
        from .engines import reference

        return Engine(prepare_step(name, config), lambda group: group[0],
                      lambda clip: [reference.score_pairs(clip, config)], lanes=lanes or 1)
    raise ValueError(f"engine must be one of ('jax', 'reference'), got {name!r}")


@dataclasses.dataclass
class StreamStats:
    """What a stream did: clips handed on (``scored``, ``resumed`` from an earlier run's output,
    ``errors``), its wall time and the time the scoring thread waited for a clip to be read (an
    upper bound of the time the device waited for input)."""

    scored: int = 0
    resumed: int = 0
    errors: int = 0
    wall_s: float = 0.0
    input_wait_s: float = 0.0

    @property
    def input_wait_share(self) -> float:
        return self.input_wait_s / self.wall_s if self.wall_s > 0 else 0.0


class Streamed(NamedTuple):
    """One clip handed on by :func:`stream_scores`: its result and, for a clip resumed from an
    earlier run's output, that output's row (text, as written)."""

    result: ClipResult
    kept_row: Mapping[str, str] | None
    load_failed: bool = False  # the clip could not be loaded (so it claimed no id)


def error_result(entry: ClipEntry, error: ClipFormatError, sha256: str, engine: str, config: SGCConfig,
                 run_id: str) -> ClipResult:
    """The error row of a clip that could not be loaded or whose id another file has."""
    result = failed_clip(entry.clip_id, str(error), engine=engine, origin=entry.origin, compat=config.compat)
    return dataclasses.replace(result, input_sha256=sha256, run_id=run_id)


def stream_scores(entries: list[ClipEntry], *, config: SGCConfig, calibration: Calibration, engine: str,
                  run_id: str = "", done: Mapping[tuple[str, str], Mapping[str, str]] | None = None,
                  read_ahead: int = 16, readers: int | None = None, read_in: str = "auto",
                  devices: int | None = None, lanes: int | None = None, stats: StreamStats | None = None,
                  reader_processes: ReaderProcesses | None = None) -> Iterator[Streamed]:
    """Every entry's result, in input order, as soon as it is known.

    ``done``: rows of an earlier run's output by (clip_id, input_sha256); those inputs are not
    read again and come back with their row (``Streamed.kept_row``). A clip that fails to load
    (:class:`ClipFormatError`) is an error row; any other exception propagates. ``readers`` and
    ``read_in``: ``reading_plan`` (clips given in memory are always read in threads).
    ``devices``: the JAX engine spreads clips over the first that many local devices (all when
    None), one clip per device at a time; ``lanes``: clips (groups) scored at once
    (``engine_steps``). The results depend on none of these.
    """
    readers, in_processes = reading_plan(readers, read_in)
    if reader_processes is not None and reader_processes.setup != (engine, config):
        raise ValueError("reader_processes were started for another engine or configuration")
    steps = engine_steps(engine, config, devices, lanes)
    digests, done = FileDigests(), done or {}
    stats = stats if stats is not None else StreamStats()
    start = time.perf_counter()

    def finished(read: Read, pairs: PairArrays) -> Streamed:
        identity = read.identity
        result = summarize_clip(identity.clip_id, pairs, calibration, group=identity.group, engine=engine,
                                mask_source=identity.mask_source, origin=read.entry.origin, compat=config.compat)
        stats.scored += 1
        return Streamed(dataclasses.replace(result, input_sha256=read.sha256, run_id=run_id), None)

    def failed(read: Read, error: ClipFormatError) -> Streamed:
        stats.errors += 1
        return Streamed(error_result(read.entry, error, read.sha256, engine, config, run_id), None,
                        load_failed=read.error is not None)

    threads = concurrent.futures.ThreadPoolExecutor
    with contextlib.ExitStack() as stack:
        processes = reader_processes
        if processes is None and in_processes:
            processes = stack.enter_context(ReaderProcesses(readers, engine, config))
        # with reader processes, threads read only the clips given in memory
        pool = stack.enter_context(threads(max_workers=THREAD_READERS if processes is not None else readers,
                                           thread_name_prefix="sgc-read"))
        lanes_pool = stack.enter_context(threads(max_workers=steps.lanes, thread_name_prefix="sgc-score"))
        done_sha256 = collections.defaultdict(set)
        for clip_id, sha256 in done:
            done_sha256[clip_id].add(sha256)

        def submit(entry: ClipEntry) -> concurrent.futures.Future:
            if processes is not None and entry.path is not None:  # clips given in memory stay here
                return processes.submit(entry, frozenset(done_sha256.get(entry.clip_id, ())))
            return pool.submit(read_entry, entry, steps.prepare, digests, done)

        queue: collections.deque = collections.deque()  # (entry, future of its Read), input order
        upcoming = iter(entries)

        def fill() -> None:
            while len(queue) < max(1, read_ahead):
                entry = next(upcoming, None)
                if entry is None:
                    return
                queue.append((entry, submit(entry)))

        group: list[Read] = []  # read, waiting to be scored together (one bucket)
        pending: collections.deque = collections.deque()  # (reads, future of their per-pair arrays), input order

        def launch() -> Iterator[Streamed]:
            """Score the group in a lane; with every lane busy and one more group queued behind
            them, hand on the oldest first."""
            prepared = [r.prepared for r in group]
            pending.append((list(group), lanes_pool.submit(lambda: steps.collect(steps.dispatch(prepared)))))
            group.clear()
            if len(pending) > steps.lanes:
                yield from land()

        def land() -> Iterator[Streamed]:
            reads, future = pending.popleft()
            for read, pairs in zip(reads, future.result()):
                yield finished(read, pairs)

        def drain() -> Iterator[Streamed]:  # everything in flight, in input order
            if group:
                yield from launch()
            while pending:
                yield from land()

        try:
            fill()
            while queue:
                begin = time.perf_counter()
                entry, future = queue.popleft()
                read = future.result()._replace(entry=entry)  # a reader process returns a copy
                stats.input_wait_s += time.perf_counter() - begin
                fill()
                error = read.error
                if error is None:
                    try:
                        read.entry.claim_id()  # in input order: the first file with an id keeps it
                    except ClipFormatError as exc:
                        error = exc
                if error is not None or read.resumed:
                    yield from drain()  # results go in input order
                    if error is not None:
                        yield failed(read, error)
                    else:
                        stats.resumed += 1
                        kept_row = done[(entry.clip_id, read.sha256)]
                        yield Streamed(clip_from_row(kept_row), kept_row)
                    continue
                if group and steps.group_key(read.prepared) != steps.group_key(group[0].prepared):
                    yield from launch()
                group.append(read)
                if len(group) == steps.group_size:
                    yield from launch()
            yield from drain()
        finally:
            for future in [*(future for _, future in queue), *(future for _, future in pending)]:
                future.cancel()
            stats.wall_s += time.perf_counter() - start
