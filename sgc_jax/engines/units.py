"""The scale-free units of ``compat="spec"`` (docs/semantics.md §4), shared by both engines.

Depth estimators and camera estimators each use units of their own (Video Depth Anything's
relative models are known up to scale, VGGT normalises its scene). Under ``compat="spec"`` both
engines therefore see depth in units of the clip's depth unit D, the median depth of its static,
valid pixels, and report translations and the depth error in percent of D; the global
translations are brought to the same units by a per-clip scale fit. ``compat="authors"`` keeps
the raw units (D = 1, factors 1).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from ..config import CAMERA_TRANSLATION_RESOLUTION, SGCConfig
from ..io.clip import Clip, without_absurd_depth
from ..io.depth_edges import ramps_left_out
from ..stats import exact_median

PERCENT = 100.0


def depth_unit(clip: Clip, config: SGCConfig) -> float:
    """D, in the clip's depth units: the median depth over the static (all pixels with
    ``use_mos=False``), valid pixels of every frame; over all valid pixels when none is static;
    1 when the clip has no valid depth, and always 1 under ``compat="authors"``."""
    if not config.scale_free:
        return 1.0
    valid = np.isfinite(clip.depth) & (clip.depth > 0)
    static = valid & clip.static_mask if config.use_mos else valid
    values = clip.depth[static] if static.any() else clip.depth[valid]
    return exact_median(values) if values.size else 1.0


def in_depth_units(clip: Clip, config: SGCConfig) -> tuple[Clip, float]:
    """(the clip both engines score, D): a network's ramps at depth edges left out where the edges are
    ramps (``config.leaves_out_depth_ramps``, docs/semantics.md §3.6), absurd depth made invalid (NaN,
    §1.2), then depth / D. Float64 division, then float32, so that scaling a clip's depth by s gives
    the same normalised depth up to one rounding."""
    depth = ramps_left_out(clip.depth) if config.leaves_out_depth_ramps else clip.depth
    depth = without_absurd_depth(depth)
    if depth is not clip.depth:
        clip = dataclasses.replace(clip, depth=depth)
    unit = depth_unit(clip, config)
    if unit == 1.0:
        return clip, unit
    # each element divided in float64 and rounded once to float32, in the ufunc's buffered chunks
    depth = np.divide(clip.depth, np.float64(unit), out=np.empty_like(clip.depth, dtype=np.float32),
                      dtype=np.float64, casting="unsafe")
    return dataclasses.replace(clip, depth=depth), unit


def resolved_translation(t_g: Any, t_prev: Any, t_curr: Any, xp=np) -> Any:
    """A pair's camera translation t_g (..., 3) from the cameras' t_wc (..., 3) of frames i-1 and i,
    0 where |t_g| is within float32's resolution of them, ``CAMERA_TRANSLATION_RESOLUTION`` (|t_prev|
    + |t_curr|) (docs/semantics.md §3.4): cameras that hold their centre translate by rounding only.
    Written once for NumPy and ``jax.numpy``."""
    size = xp.linalg.norm(t_prev, axis=-1) + xp.linalg.norm(t_curr, axis=-1)
    held = xp.linalg.norm(t_g, axis=-1) <= CAMERA_TRANSLATION_RESOLUTION * size
    return xp.where(held[..., None], xp.zeros_like(t_g), t_g)


def translation_factor(config: SGCConfig) -> float:
    """Multiplies translations in units of D to give the reported unit (percent of D in spec)."""
    return PERCENT if config.scale_free else 1.0
