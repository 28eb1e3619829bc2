"""Scoring entry points: ``score_clip`` and ``score_batch`` over any clip source (docs/semantics.md §4)."""

from __future__ import annotations

import os
import sys
from typing import Any, Iterator

from tqdm.auto import tqdm

from .calibration import Calibration, default_calibration
from .config import SGCConfig
from .io.journal import ScoresJournal, run_id, run_record
from .io.loading import discover_clips
from .io.result import BatchResult, ClipResult, summarize_clip
from .streaming import StreamStats, Streamed, engine_steps, stream_scores

ENGINES = ("jax", "reference")


def resolve_config(config: SGCConfig | dict | None, overrides: dict[str, Any]) -> SGCConfig:
    """The config to score with: ``config`` (an :class:`SGCConfig`, a dict of its fields, or None for the
    defaults) with ``overrides`` (SGCConfig fields) replaced."""
    if config is None:
        config = SGCConfig()
    elif isinstance(config, dict):
        config = SGCConfig.from_dict(config)
    return config.replace(**overrides) if overrides else config


def resolve_calibration(calibration: Calibration | str | None, config: SGCConfig) -> Calibration:
    """The calibration to score with: the semantics' default when None (``sgc-spec-2026`` for
    compat="spec", ``sgc-paper-2026`` for compat="authors"); one fitted for the other semantics
    raises :class:`~sgc_jax.calibration.CalibrationMismatchError`."""
    calibration = Calibration.load(default_calibration(config.compat) if calibration is None else calibration)
    calibration.check_compat(config.compat, "the scores")
    return calibration


def score_batch(source: Any, *, config: SGCConfig | dict | None = None,
                calibration: Calibration | str | None = None, engine: str = "jax",
                progress: bool | None = None, chunk_size: int = 16, out: str | os.PathLike | None = None,
                pairs_out: str | os.PathLike | None = None, resume: bool = False, readers: int | None = None,
                read_in: str = "auto", devices: int | None = None, lanes: int | None = None,
                ray_address: str | None = None, ray_scorers: int | None = None,
                stats: StreamStats | None = None, **overrides: Any) -> BatchResult:
    """Score every clip of ``source`` (path, directory, glob, mapping, Clip or list of them).

    A clip that fails to load (:class:`ClipFormatError`: a bad input) is reported with status
    ``error`` and its message; the others are scored; an exception from an engine propagates.
    ``overrides`` are :class:`SGCConfig` fields (``use_mos=False``, ...).
    ``calibration``: None for the default of ``config.compat`` (see :func:`resolve_calibration`).
    ``progress``: a progress bar on stderr (default: when stderr is a terminal).
    ``chunk_size``: clips read ahead of the device (memory is bounded by it) by ``readers``
    threads or processes (``read_in``: "auto", "threads", "processes"; by default two threads,
    or on a host of more than 4 cores one process per core but two; docs/semantics.md §4.1).
    ``out`` / ``pairs_out``: per-clip / per-pair tables written as clips finish, CSV or Parquet
    by the suffix (docs/semantics.md §4.1); ``resume``: keep the rows ``out`` already holds for the same input file content and
    run (version, engine, config, calibration) and score only the rest.
    ``devices``: the JAX engine spreads the clips one per device over the first that many local
    devices (default: all of them; several GPUs, or ``--xla_force_host_platform_device_count``
    on a CPU); ``lanes``: clips scored at once (default: one per core up to two on CPU devices, two
    on an accelerator; docs/semantics.md §4.1); the numbers depend on neither.
    ``ray_address``: score on a Ray cluster instead of this process ("auto", "local", an address;
    :mod:`sgc_jax.cluster`), with ``ray_scorers`` actors (default one per GPU, else per node).
    ``stats``: a :class:`~sgc_jax.streaming.StreamStats` to fill (timings, counts).
    """
    config = resolve_config(config, overrides)
    calibration = resolve_calibration(calibration, config)
    if engine not in ENGINES:
        raise ValueError(f"engine must be one of {ENGINES}, got {engine!r}")
    if resume and out is None:
        raise ValueError("resume=True needs out: the output file to resume")
    entries = discover_clips(source, config)
    run = run_record(config, calibration, engine)
    journal = ScoresJournal(out, pairs_out, run, resume=resume) if out is not None else None
    show = sys.stderr.isatty() if progress is None else progress
    clips: list[Streamed] = []
    try:
        with tqdm(total=len(entries), desc=f"sgc ({engine})", unit="clip", disable=not show) as bar:
            done = journal.done if journal else None
            if ray_address is None:
                stream = stream_scores(entries, config=config, calibration=calibration, engine=engine,
                                       run_id=run_id(run), done=done, read_ahead=chunk_size, readers=readers,
                                       read_in=read_in, devices=devices, lanes=lanes, stats=stats)
            else:
                from .cluster import ray_stream_scores

                stream = ray_stream_scores(entries, config=config, calibration=calibration, engine=engine,
                                           run_id=run_id(run), done=done, address=ray_address, scorers=ray_scorers,
                                           shard_size=chunk_size, devices=devices, lanes=lanes, read_in=read_in,
                                           stats=stats)
            for item in stream:
                clips.append(item)
                if journal is not None and item.kept_row is None:
                    journal.append([item.result])
                bar.update(1)
        if journal is not None:
            journal.finish([item.kept_row if item.kept_row is not None else item.result for item in clips])
    finally:
        if journal is not None:
            journal.close()
    return BatchResult([item.result for item in clips], calibration)


def iter_scores(source: Any, *, config: SGCConfig | dict | None = None,
                calibration: Calibration | str | None = None, engine: str = "jax", chunk_size: int = 16,
                readers: int | None = None, read_in: str = "auto", devices: int | None = None,
                lanes: int | None = None, **overrides: Any) -> Iterator[ClipResult]:
    """Each clip's :class:`ClipResult` as soon as it is scored, in input order (arguments as
    :func:`score_batch`): for corpora too large to hold every result. ``ecd`` needs the whole
    corpus: compute it afterwards with :func:`~sgc_jax.io.result.camera_dynamics`."""
    config = resolve_config(config, overrides)
    calibration = resolve_calibration(calibration, config)
    entries = discover_clips(source, config)
    run = run_id(run_record(config, calibration, engine))
    for item in stream_scores(entries, config=config, calibration=calibration, engine=engine, run_id=run,
                              read_ahead=chunk_size, readers=readers, read_in=read_in, devices=devices,
                              lanes=lanes):
        yield item.result


def score_clip(source: Any, *, config: SGCConfig | dict | None = None,
               calibration: Calibration | str | None = None, engine: str = "jax",
               **overrides: Any) -> ClipResult:
    """Score one clip; raises :class:`ClipFormatError` on a structural problem."""
    config = resolve_config(config, overrides)
    calibration = resolve_calibration(calibration, config)
    entries = discover_clips(source, config)
    if len(entries) != 1:
        raise ValueError(f"score_clip expects one clip, the source holds {len(entries)}; use score_batch")
    clip = entries[0].load()
    steps = engine_steps(engine, config, devices=1)  # one clip: one device
    pairs = steps.collect(steps.dispatch([steps.prepare(clip)]))[0]
    return summarize_clip(clip.clip_id, pairs, calibration, group=clip.group, engine=engine,
                          mask_source=clip.mask_source, origin=entries[0].origin, compat=config.compat)
