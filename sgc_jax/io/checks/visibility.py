"""The visibility's direction: whether the hidden tracks fit the cameras' motion far better than the
visible ones (an occlusion flag stored as ``track_vis``; docs/semantics.md §1.2, §1.6)."""

from __future__ import annotations

import numpy as np

from ...config import SGCConfig
from ..clip import Clip, repeated_tracks
from .masks import MASK_SIDE_RATIO
from .motion_fits import POSE_MISFIT_MIN_PX, sampled_pairs, side_residuals
from .problems import Problem

# Visibility stored the other way round (TAPIR's and BootsTAP's `occluded`, or 1 - a visibility): most
# tracks read hidden, and the hidden ones fit the camera's motion (the poses as given) within
# MASK_SIDE_RATIO of what the visible ones miss, which is over POSE_MISFIT_MIN_PX. Rule H2: the mask
# line's limits, kept where FIT's random pool fires on none (bench/history/issue-58.md "Visibility
# stored the other way round").
VISIBLE_SHARE_MAX = 0.5


def visible_share(clip: Clip, config: SGCConfig) -> float:
    """The share of the candidate tracks (``Clip.candidate_tracks``) of the sampled pairs that are visible,
    a repeat of another candidate's positions counted once (a track array's padding slots); NaN
    without any."""
    pairs = sampled_pairs(clip)
    prev, curr = clip.track_prev[pairs - 1], clip.track_curr[pairs - 1]
    candidates = clip.candidate_tracks(config.min_track_conf, pairs=pairs)
    candidates &= ~repeated_tracks(prev, curr, candidates)
    n = np.count_nonzero(candidates)
    return float(np.count_nonzero(candidates & clip.track_vis[pairs - 1]) / n) if n else float("nan")


def check_vis_inverted(clip: Clip, config: SGCConfig,
                       fits: dict[int, dict[str, tuple[float, float]]] | None = None) -> list[Problem]:
    """A warning where under VISIBLE_SHARE_MAX of the candidate tracks are visible and the hidden ones
    fit the camera's motion far better (MASK_SIDE_RATIO) than the visible ones, which miss it by over
    POSE_MISFIT_MIN_PX (rule H2)."""
    share = visible_share(clip, config)
    if not share < VISIBLE_SHARE_MAX:
        return []
    seen, hidden = side_residuals(clip, config, fits, visible=False)
    if not (np.isfinite(seen) and seen > POSE_MISFIT_MIN_PX and hidden < MASK_SIDE_RATIO * seen):
        return []
    return [Problem(
        "warning", "track_vis_inverted", "track_vis", "track_vis true where a track is visible",
        f"{100 * share:.0f}% of the tracks visible; the visible ones miss the camera's motion by {seen:.2g} px "
        f"(median), the hidden ones by {hidden:.2g} px",
        "this looks like an occlusion flag (TAPIR's `occluded`) or an inverted visibility: store track_vis = ~occluded")]
