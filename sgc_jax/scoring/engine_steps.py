"""How each engine scores clips in three steps, so one streaming loop drives both (docs/semantics.md §7)."""

from __future__ import annotations

from typing import Any, Callable, NamedTuple

from ..config import SGCConfig
from ..engines.pairs import PairArrays
from ..io.clip import Clip
from .devices import clips_per_call, default_lanes, scoring_devices, vectorizes

ENGINES = ("jax", "reference")


class Engine(NamedTuple):
    """``prepare`` (host arrays of one clip; runs in a reader), ``dispatch`` (starts the device
    work on a group of up to ``group_size`` prepared clips of one ``group_key``; returns without
    waiting) and ``collect`` (waits; the group's per-pair arrays). ``lanes``: groups in flight at
    once, each in a scoring thread of its own."""

    prepare: Callable[[Clip], Any]
    dispatch: Callable[[list[Any]], Any]
    collect: Callable[[Any], list[PairArrays]]
    group_size: int = 1
    group_key: Callable[[Any], Any] = lambda prepared: None
    lanes: int = 1


def prepare_step(engine: str, config: SGCConfig) -> Callable[[Clip], Any]:
    """The engine's host-side preparation of a clip (NumPy only; touches no device)."""
    if engine == "jax":
        from ..engines.jax_engine.dispatch import prepare_clip

        return lambda clip: prepare_clip(clip, config)
    if engine == "reference":
        return lambda clip: clip
    raise ValueError(f"engine must be one of {ENGINES}, got {engine!r}")


def engine_steps(name: str, config: SGCConfig, devices: int | None = None, lanes: int | None = None) -> Engine:
    """The steps of ``"jax"`` (over the first ``devices`` local devices, all when None: on CPU one
    clip per program call on each, on accelerators groups of one bucket in one call) or
    ``"reference"`` (which computes in ``collect``, one clip at a time unless ``lanes`` says
    otherwise)."""
    prepare = prepare_step(name, config)
    if name == "jax":
        from ..engines.jax_engine.dispatch import device_steps

        spread = scoring_devices(devices)
        size = clips_per_call(spread)
        start, collect = device_steps(config, spread, size, vectorizes(spread))
        by_bucket = (lambda prepared: prepared.bucket) if size > 1 else (lambda prepared: None)
        return Engine(prepare, start, collect, size, by_bucket, lanes or default_lanes(spread))
    from ..engines import reference  # prepare_step refused any other name

    return Engine(prepare, lambda group: group[0], lambda clip: [reference.score_pairs(clip, config)],
                  lanes=lanes or 1)
