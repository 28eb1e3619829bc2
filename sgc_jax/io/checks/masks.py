"""The static mask: its coverage, and whether the tracks on it or off it fit the cameras (an inverted
mask; docs/semantics.md §1.2, §1.6)."""

from __future__ import annotations

import numpy as np

from ...config import SGCConfig
from ..clip import Clip
from .motion_fits import POSE_MISFIT_MIN_PX, side_residuals
from .problems import Problem, frames_list

STATIC_COVERAGE_WARN = 0.05  # static mask below this fraction of a frame: inverted mask?
# A motion mask given as the static one: the tracks off the static mask miss the camera's motion by at
# most this fraction of what those on it miss (over POSE_MISFIT_MIN_PX), the poses as given. Rule M1
# (bench/history/issue-58.md "A motion mask given as the static one").
MASK_SIDE_RATIO = 0.4


def static_coverage(clip: Clip) -> np.ndarray:
    """(T,) the share of each frame the static mask covers."""
    return np.count_nonzero(clip.static_mask.reshape(clip.n_frames, -1), axis=1) / clip.static_mask[0].size


def mask_side_residuals(clip: Clip, config: SGCConfig,
                        fits: dict[int, dict[str, tuple[float, float]]] | None = None) -> tuple[float, float]:
    """(on the static mask, off it): ``side_residuals`` of the usable tracks on either side."""
    return side_residuals(clip, config, fits, on_static=False)


def check_mask_inverted(residuals: tuple[float, float], mask_source: str = "static_mask") -> list[Problem]:
    """From ``mask_side_residuals``: a warning where the tracks off the static mask fit the camera's
    motion far better (MASK_SIDE_RATIO) than those on it, which miss it by over POSE_MISFIT_MIN_PX:
    a motion mask given as the static one (or, from ``dynamic_mask``, a static mask given as that)."""
    on, off = residuals
    if not (np.isfinite(on) and on > POSE_MISFIT_MIN_PX and off < MASK_SIDE_RATIO * on):
        return []
    dynamic = mask_source == "dynamic_mask"
    return [Problem(
        "warning", "static_mask_inverted", mask_source,
        "dynamic_mask true on the moving objects" if dynamic else "static_mask true on the static background",
        f"the tracks on the static part miss the camera's motion by {on:.2g} px (median), those on the moving "
        f"part by {off:.2g} px",
        "this looks like a static mask: give it as static_mask" if dynamic else
        "this looks like a motion mask: give it as dynamic_mask, or invert it (static_mask = ~mask)")]


def check_mask(clip: Clip) -> list[Problem]:
    """Static-mask coverage per frame (an inverted mask leaves almost nothing static)."""
    if clip.mask_source == "none":
        return [Problem("info", "no_mask", "static_mask", "",
                        "no static_mask or dynamic_mask: the whole frame counts as static (nothing moves)")]
    coverage = static_coverage(clip)
    low = np.flatnonzero(coverage < STATIC_COVERAGE_WARN)
    problems = []
    if low.size:
        problems.append(Problem("warning", "static_mask_tiny", clip.mask_source,
                                f"static background on at least {100 * STATIC_COVERAGE_WARN:.0f}% of each frame",
                                f"{100 * coverage[low[0]]:.1f}% static in frames {frames_list(low, clip.n_frames)}",
                                "an inverted mask? static_mask is true on the static background; "
                                "moving-object masks go in dynamic_mask"))
    problems.append(Problem("info", "mask_coverage", clip.mask_source, "",
                            f"static on {100 * coverage.mean():.0f}% of pixels (min {100 * coverage.min():.0f}% "
                            "in one frame)"))
    return problems
