"""Scoring a corpus across machines with Ray (docs/semantics.md §4.2; ``sgc-jax score --ray auto``).

This process (the driver) lists the clips and owns the output; scorer actors, one per worker
process, each score shards of the file list with :func:`~sgc_jax.scoring.streaming.stream_scores` on
their own devices and send the results back. The driver hands them on in input order as the
shards finish, claims clip ids in input order (the first file with an id keeps it, as in one
process) and resumes the same way. Input paths must be readable from every node (a shared
folder, or a URL: :mod:`sgc_jax.io.remote`). Needs the ``ray`` extra: ``pip install 'sgc-jax[ray]'``.
"""

from __future__ import annotations

import collections
import dataclasses
import math
import time
from typing import Any, Iterator

from ..io.clip import ClipFormatError
from ..io.extras import MissingExtraError
from ..io.loading import ClipEntry
from .options import RunOptions
from .readers import ReaderProcesses, reading_plan
from .streaming import Done, Scoring, Streamed, StreamStats, error_result, stream_scores

SHARDS_PER_SCORER = 2  # tasks queued per scorer, so it starts the next shard as soon as one ends


def connect(address: str | None) -> Any:
    """The ``ray`` module, initialised: as it is when this process already is, else with
    ``ray.init(address)`` ("auto": the cluster this machine belongs to; "local": a new cluster
    on this machine; "host:port" or "ray://host:port")."""
    try:
        import ray
    except ImportError:
        raise MissingExtraError("scoring with Ray needs the ray extra: pip install 'sgc-jax[ray]'") from None
    if not ray.is_initialized():
        ray.init(address=address, include_dashboard=False)
    return ray


class ShardScorer:
    """A Ray actor's state: one engine (its compiled programs kept between shards) on the devices
    of its worker process, and its reader processes, where its share of ``cores`` reads in them."""

    def __init__(self, scoring: Scoring, options: RunOptions, cores: int | None = None) -> None:
        if scoring.engine == "jax":  # each worker process would otherwise compile every program
            from ..engines.jax_engine.compile_cache import enable_compilation_cache

            enable_compilation_cache()
        self.scoring, self.options = scoring, options
        readers, in_processes = reading_plan(None, options.read_in, cores)
        self.readers = ReaderProcesses(readers, scoring.engine, scoring.config) if in_processes else None

    def score(self, entries: list[ClipEntry], done: Done) -> tuple[list[Streamed], StreamStats]:
        stats = StreamStats()
        return list(stream_scores(entries, self.scoring, done=done, options=self.options, stats=stats,
                                  reader_processes=self.readers)), stats


def _scorers(ray: Any, count: int | None) -> tuple[int, dict[str, float]]:
    """How many scorers (``count``, else one per GPU of the cluster, else one per node) and the
    resources each asks for: a GPU each, or an equal share of them when more scorers than GPUs
    are asked for (likewise a CPU each without GPUs), so every scorer can be placed."""
    resources = ray.cluster_resources()
    gpus, cpus = int(resources.get("GPU", 0)), resources.get("CPU", 1.0)
    if count is None:
        count = gpus or max(1, sum(1 for node in ray.nodes() if node.get("Alive")))
    share = lambda total: math.floor(min(1.0, total / count) * 1e4) / 1e4  # noqa: E731  Ray's resolution
    return count, ({"num_gpus": share(gpus)} if gpus else {"num_cpus": share(cpus)})


def ray_stream_scores(entries: list[ClipEntry], scoring: Scoring, *, done: Done | None = None,
                      options: RunOptions = RunOptions(ray_address="auto"),
                      stats: StreamStats | None = None) -> Iterator[Streamed]:
    """:func:`~sgc_jax.scoring.streaming.stream_scores` with the clips scored by Ray actors, every
    entry's result in input order. ``options``: ``ray_address`` and ``ray_scorers`` (default one
    actor per GPU of the cluster, else per node); ``chunk_size`` clips per task at most (fewer
    when the corpus would not reach every scorer); ``devices``, ``lanes`` and ``read_in`` for each
    actor, with its share of the cluster's cores for the host's."""
    ray = connect(options.ray_address)
    stats = stats if stats is not None else StreamStats()
    done = done or {}
    start = time.perf_counter()
    count, resources = _scorers(ray, options.ray_scorers)
    actor = ray.remote(ShardScorer).options(scheduling_strategy="SPREAD", **resources)
    cores = max(1, int(ray.cluster_resources().get("CPU", 1) // count))  # each scorer's share
    pool = [actor.remote(scoring, options, cores) for _ in range(count)]
    shard_size = max(1, min(options.chunk_size, -(-len(entries) // count)))
    shards = [entries[i:i + shard_size] for i in range(0, len(entries), shard_size)]

    def submit(k: int):
        # workers claim no ids (each would see only its shard): the driver claims them below
        shard = [dataclasses.replace(e, id_owners=None) for e in shards[k]]
        ids = {e.clip_id for e in shard}
        return pool[k % count].score.remote(shard, {key: row for key, row in done.items() if key[0] in ids})

    try:
        in_flight = collections.deque((k, submit(k)) for k in range(min(len(shards), SHARDS_PER_SCORER * count)))
        following = len(in_flight)
        while in_flight:
            k, ref = in_flight.popleft()
            if following < len(shards):
                in_flight.append((following, submit(following)))
                following += 1
            items, shard_stats = ray.get(ref)
            _add_stats(stats, shard_stats)
            for entry, item in zip(shards[k], items):
                yield _claimed(entry, item, scoring, stats)
    finally:
        for scorer in pool:
            ray.kill(scorer)
        stats.wall_s += time.perf_counter() - start


def _add_stats(stats: StreamStats, shard: StreamStats) -> None:
    stats.scored += shard.scored
    stats.resumed += shard.resumed
    stats.errors += shard.errors
    stats.input_wait_s += shard.input_wait_s  # summed over the scorers, which wait in parallel
    stats.summary_s += shard.summary_s


def _claimed(entry: ClipEntry, item: Streamed, scoring: Scoring, stats: StreamStats) -> Streamed:
    """The item, or an error row when another file claimed its id first (in input order)."""
    if item.load_failed:
        return item
    try:
        entry.claim_id()
    except ClipFormatError as exc:
        stats.errors += 1
        stats.resumed -= item.kept_row is not None
        stats.scored -= item.kept_row is None
        return Streamed(error_result(entry, exc, item.result.input_sha256, scoring), None)
    return item
