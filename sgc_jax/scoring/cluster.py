"""Scoring a corpus across machines with Ray (docs/semantics.md §4.2; ``sgc-jax score --ray auto``).

This process (the driver) lists the clips and owns the output; scorer actors, one per worker
process, each score shards of the file list with :func:`~sgc_jax.streaming.stream_scores` on
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
from typing import Any, Iterator, Mapping

from .calibration import Calibration
from .config import SGCConfig
from .io.clip import ClipFormatError
from .io.loading import ClipEntry
from .readers import ReaderProcesses, reading_plan
from .streaming import StreamStats, Streamed, error_result, stream_scores

SHARD_SIZE = 16  # clips per task: large enough to keep a scorer's device busy, small enough to spread
SHARDS_PER_SCORER = 2  # tasks queued per scorer, so it starts the next shard as soon as one ends


def connect(address: str | None) -> Any:
    """The ``ray`` module, initialised: as it is when this process already is, else with
    ``ray.init(address)`` ("auto": the cluster this machine belongs to; "local": a new cluster
    on this machine; "host:port" or "ray://host:port")."""
    try:
        import ray
    except ImportError:
        raise ImportError("scoring with Ray needs the ray extra: pip install 'sgc-jax[ray]'") from None
    if not ray.is_initialized():
        ray.init(address=address, include_dashboard=False)
    return ray


class ShardScorer:
    """A Ray actor's state: one engine (its compiled programs kept between shards) on the devices
    of its worker process. The JAX engine's persistent compilation cache is on (each worker
    process would otherwise compile every program), unless ``SGC_JAX_COMPILATION_CACHE=off``."""

    def __init__(self, config: SGCConfig, calibration: Calibration, engine: str, run_id: str,
                 devices: int | None, lanes: int | None = None, read_in: str = "auto",
                 cores: int | None = None) -> None:
        if engine == "jax":
            from .engines.compile_cache import enable_compilation_cache

            enable_compilation_cache()
        self.options = dict(config=config, calibration=calibration, engine=engine, run_id=run_id, devices=devices,
                            lanes=lanes, read_in=read_in)
        # reader processes, where this scorer's share of ``cores`` reads in them, kept from shard to shard
        readers, in_processes = reading_plan(None, read_in, cores)
        self.options["reader_processes"] = ReaderProcesses(readers, engine, config) if in_processes else None

    def score(self, entries: list[ClipEntry], done: Mapping[tuple[str, str], Mapping[str, str]]
              ) -> tuple[list[Streamed], StreamStats]:
        stats = StreamStats()
        return list(stream_scores(entries, done=done, stats=stats, **self.options)), stats


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


def ray_stream_scores(entries: list[ClipEntry], *, config: SGCConfig, calibration: Calibration, engine: str,
                      run_id: str = "", done: Mapping[tuple[str, str], Mapping[str, str]] | None = None,
                      address: str | None = "auto", scorers: int | None = None, shard_size: int = SHARD_SIZE,
                      devices: int | None = None, lanes: int | None = None, read_in: str = "auto",
                      stats: StreamStats | None = None) -> Iterator[Streamed]:
    """:func:`~sgc_jax.streaming.stream_scores` with the clips scored by Ray actors: every
    entry's result in input order. ``scorers``: how many actors (default: one per GPU of the
    cluster, else one per node); ``shard_size``: clips per task at most (fewer when the corpus is
    too small to reach every scorer otherwise); ``devices``: local devices each actor uses (default
    all it sees); ``lanes``: clips each actor scores at once (``streaming.engine_steps``);
    ``read_in``: as ``stream_scores``, with each actor's share of the cluster's cores for the
    host's (``readers.reading_plan``); reader processes are kept from shard to shard."""
    ray = connect(address)
    stats = stats if stats is not None else StreamStats()
    done = done or {}
    start = time.perf_counter()
    count, resources = _scorers(ray, scorers)
    actor = ray.remote(ShardScorer).options(scheduling_strategy="SPREAD", **resources)
    cores = max(1, int(ray.cluster_resources().get("CPU", 1) // count))  # each scorer's share
    pool = [actor.remote(config, calibration, engine, run_id, devices, lanes, read_in, cores) for _ in range(count)]
    shard_size = max(1, min(shard_size, -(-len(entries) // count)))  # a small corpus still reaches every scorer
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
            stats.scored += shard_stats.scored
            stats.resumed += shard_stats.resumed
            stats.errors += shard_stats.errors
            stats.input_wait_s += shard_stats.input_wait_s  # summed over the scorers, which wait in parallel
            for entry, item in zip(shards[k], items):
                if not item.load_failed:
                    try:
                        entry.claim_id()
                    except ClipFormatError as exc:
                        stats.errors += 1
                        stats.resumed -= item.kept_row is not None
                        stats.scored -= item.kept_row is None
                        item = Streamed(error_result(entry, exc, item.result.input_sha256, engine, config, run_id),
                                        None)
                yield item
    finally:
        for scorer in pool:
            ray.kill(scorer)
        stats.wall_s += time.perf_counter() - start
