"""Scoring entry points: ``score_clip`` and ``score_batch`` over any clip source (docs/semantics.md §4)."""

from __future__ import annotations

import sys
from typing import Any, Callable, Iterable

from tqdm.auto import tqdm

from .calibration import Calibration, default_calibration
from .config import SGCConfig
from .io.clip import Clip, ClipFormatError
from .io.loading import ClipEntry, discover_clips
from .io.result import BatchResult, ClipResult, PairArrays, failed_clip, summarize_clip

ENGINES = ("jax", "reference")


def _reference_engine(clips: list[Clip], config: SGCConfig) -> list[PairArrays]:
    from .engines import reference

    return [reference.score_pairs(clip, config) for clip in clips]


def _jax_engine(clips: list[Clip], config: SGCConfig) -> list[PairArrays]:
    from .engines import jax_engine

    return jax_engine.score_pairs_batch(clips, config)


def _engine(name: str) -> Callable[[list[Clip], SGCConfig], list[PairArrays]]:
    if name == "reference":
        return _reference_engine
    if name == "jax":
        return _jax_engine
    raise ValueError(f"engine must be one of {ENGINES}, got {name!r}")


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
                progress: bool | None = None, chunk_size: int = 16, **overrides: Any) -> BatchResult:
    """Score every clip of ``source`` (path, directory, glob, mapping, Clip or list of them).

    A clip that fails to load (:class:`ClipFormatError`: a bad input) is reported with status
    ``error`` and its message; the others are scored; an exception from an engine propagates.
    ``overrides`` are :class:`SGCConfig` fields (``use_mos=False``, ...).
    ``calibration``: None for the default of ``config.compat`` (see :func:`resolve_calibration`).
    ``progress``: a progress bar on stderr (default: when stderr is a terminal).
    """
    config = resolve_config(config, overrides)
    calibration = resolve_calibration(calibration, config)
    run = _engine(engine)
    entries = discover_clips(source, config)
    show = sys.stderr.isatty() if progress is None else progress
    results: list[ClipResult] = []
    with tqdm(total=len(entries), desc=f"sgc ({engine})", unit="clip", disable=not show) as bar:
        for start in range(0, len(entries), chunk_size):
            results.extend(_score_chunk(entries[start:start + chunk_size], run, config, calibration, engine))
            bar.update(min(chunk_size, len(entries) - start))
    return BatchResult(results, calibration)


def _score_chunk(entries: list[ClipEntry], run: Callable, config: SGCConfig, calibration: Calibration,
                 engine: str) -> list[ClipResult]:
    """Load a chunk, score the loadable clips together, keep input order and per-clip errors.

    Only :class:`ClipFormatError` (a bad input, docs/semantics.md §1.4) becomes an error row; any
    other exception, from the loader or an engine, is a bug and propagates.
    """
    loaded: dict[int, Clip] = {}
    results: dict[int, ClipResult] = {}
    for i, entry in enumerate(entries):
        try:
            loaded[i] = entry.load()
        except ClipFormatError as exc:
            results[i] = failed_clip(entry.clip_id, str(exc), engine=engine, origin=entry.origin,
                                     compat=config.compat)
    order = sorted(loaded)
    pair_arrays = run([loaded[i] for i in order], config) if order else []
    for i, pairs in zip(order, pair_arrays):
        clip = loaded[i]
        results[i] = summarize_clip(clip.clip_id, pairs, calibration, group=clip.group, engine=engine,
                                    mask_source=clip.mask_source, origin=entries[i].origin, compat=config.compat)
    return [results[i] for i in range(len(entries))]


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
    pairs = _engine(engine)([clip], config)[0]
    return summarize_clip(clip.clip_id, pairs, calibration, group=clip.group, engine=engine,
                          mask_source=clip.mask_source, origin=entries[0].origin, compat=config.compat)
