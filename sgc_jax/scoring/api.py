"""Scoring entry points over any clip source (docs/semantics.md §4): ``score_batch``,
``iter_scores``, ``score_clip``."""

from __future__ import annotations

import dataclasses
import os
from typing import Any, Iterator

from ..calibration import Calibration, default_calibration
from ..config import SGCConfig
from ..engines.jax_engine.compile_cache import enable_compilation_cache
from ..io.loading import ClipEntry, discover_clips
from .engine_steps import ENGINES, engine_steps
from .journal import ScoresJournal, run_id, run_record
from .options import RunOptions
from .progress import Progress
from .result import BatchResult, ClipResult, summarize_clip
from .streaming import Scoring, Streamed, StreamStats, stream_scores


def resolve_config(config: SGCConfig | dict | None, overrides: dict[str, Any]) -> SGCConfig:
    """``config`` (an SGCConfig, a dict of its fields, or None for the defaults) with ``overrides``."""
    if config is None:
        config = SGCConfig()
    elif isinstance(config, dict):
        config = SGCConfig.from_dict(config)
    return config.replace(**overrides) if overrides else config


def resolve_calibration(calibration: Calibration | str | None, config: SGCConfig) -> Calibration:
    """``calibration``, or the semantics' default (``sgc-spec-2026``, or ``sgc-paper-2026`` for
    compat="authors"); one fitted for the other semantics raises CalibrationMismatchError."""
    calibration = Calibration.load(default_calibration(config.compat) if calibration is None else calibration)
    calibration.check_compat(config.compat, "the scores")
    return calibration


def prepare_run(source: Any, config, calibration, engine: str, options: dict) -> tuple:
    """(entries, Scoring, RunOptions, run record) of a call's arguments; ``options`` are RunOptions
    or SGCConfig fields. Turns on the persistent program cache for the JAX engine."""
    if engine not in ENGINES:
        raise ValueError(f"engine must be one of {ENGINES}, got {engine!r}")
    run_options, overrides = RunOptions.split(options)
    config = resolve_config(config, overrides)
    calibration = resolve_calibration(calibration, config)
    if engine == "jax":
        enable_compilation_cache()
    record = run_record(config, calibration, engine)
    return discover_clips(source, config), Scoring(config, calibration, engine, run_id(record)), run_options, record


def _stream(entries: list[ClipEntry], scoring: Scoring, options: RunOptions, done, stats) -> Iterator[Streamed]:
    if options.ray_address is None:
        return stream_scores(entries, scoring, done=done, options=options, stats=stats)
    from .cluster import ray_stream_scores

    return ray_stream_scores(entries, scoring, done=done, options=options, stats=stats)


def score_batch(source: Any, *, config: SGCConfig | dict | None = None, calibration: Calibration | str | None = None,
                engine: str = "jax", progress: bool | None = None, out: str | os.PathLike | None = None,
                pairs_out: str | os.PathLike | None = None, resume: bool = False, stats: StreamStats | None = None,
                **options: Any) -> BatchResult:
    """Score every clip of ``source`` (a path, directory, glob, URL, mapping, Clip, or a list of them).

    A clip that fails to load (ClipFormatError) gets status ``error`` and its message; an
    exception from an engine propagates. ``calibration``: None for the default of
    ``config.compat``. ``progress``: a bar on stderr (default: when stderr is a terminal).
    ``out`` / ``pairs_out``: per-clip / per-pair tables (CSV, or Parquet by the suffix) written as
    clips finish; ``resume``: keep the rows ``out`` holds for the same input and run, score the
    rest (docs/semantics.md §4.1). ``stats``: a StreamStats to fill. ``options``: SGCConfig fields
    (``inlier_px=6``) and RunOptions fields: ``chunk_size``, ``readers``, ``read_in``,
    ``devices``, ``lanes``, ``ray_address``, ``ray_scorers`` (an unknown name raises TypeError).
    The JAX engine keeps its compiled programs in the persistent cache (``SGC_JAX_COMPILATION_CACHE``
    moves it or turns it off)."""
    entries, scoring, run_options, record = prepare_run(source, config, calibration, engine, options)
    if resume and out is None:
        raise ValueError("resume=True needs out: the output file to resume")
    journal = ScoresJournal(out, pairs_out, record, resume=resume) if out is not None else None
    clips: list[Streamed] = []
    try:
        with Progress(len(entries), engine, progress) as bar:
            for item in _stream(entries, scoring, run_options, journal.done if journal else None, stats):
                clips.append(item)
                if journal is not None and item.kept_row is None:
                    journal.append([item.result])
                bar.advance()
        if journal is not None:
            journal.finish([item.kept_row if item.kept_row is not None else item.result for item in clips])
    finally:
        if journal is not None:
            journal.close()
    return BatchResult([item.result for item in clips], scoring.calibration)


def iter_scores(source: Any, *, config: SGCConfig | dict | None = None, calibration: Calibration | str | None = None,
                engine: str = "jax", progress: bool | None = None, stats: StreamStats | None = None,
                **options: Any) -> Iterator[ClipResult]:
    """Each clip's ClipResult as soon as it is scored, in input order (arguments as ``score_batch``'s
    but ``out``, ``pairs_out`` and ``resume``: it writes no table): for corpora too large to hold.
    ``ecd`` needs the whole corpus: compute it afterwards with ``sgc_jax.camera_dynamics``."""
    entries, scoring, run_options, _ = prepare_run(source, config, calibration, engine, options)
    with Progress(len(entries), engine, progress) as bar:
        for item in _stream(entries, scoring, run_options, None, stats):
            bar.advance()
            yield item.result


def score_clip(source: Any, *, config: SGCConfig | dict | None = None, calibration: Calibration | str | None = None,
               engine: str = "jax", **overrides: Any) -> ClipResult:
    """Score one clip; raises ClipFormatError on a structural problem. ``overrides``: SGCConfig fields."""
    run_fields = sorted(set(overrides) & {f.name for f in dataclasses.fields(RunOptions)})
    if run_fields:
        raise TypeError(f"score_clip scores one clip in this process; {run_fields} are options of score_batch")
    entries, scoring, _, _ = prepare_run(source, config, calibration, engine, overrides)
    if len(entries) != 1:
        raise ValueError(f"score_clip expects one clip, the source holds {len(entries)}; use score_batch")
    clip = entries[0].load()
    steps = engine_steps(engine, scoring.config, devices=1)  # one clip: one device
    pairs = steps.collect(steps.dispatch([steps.prepare(clip)]))[0]
    result = summarize_clip(clip.clip_id, pairs, scoring.calibration, group=clip.group, engine=engine,
                            mask_source=clip.mask_source, origin=entries[0].origin, compat=scoring.config.compat)
    return dataclasses.replace(result, warnings=";".join(clip.warnings))
