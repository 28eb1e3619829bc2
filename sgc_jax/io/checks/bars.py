"""Bars a video holds at its frame's edges (a letterbox's black bands): lines of the frame that show
no world, given a depth and left static (docs/semantics.md §1.1, §1.6)."""

from __future__ import annotations

import numpy as np

from ...config import SGCConfig
from ..clip import Clip
from .problems import Problem

# Rule LB1 (bench/history/issue-58.md "Letterbox bars"): a band of at least BAR_MIN_SHARE of the
# frame's lines on its axis, whose every line holds, in every frame, static valid depth spanning at
# most BAR_DEPTH_SPAN (largest over least), the same over the frames, and no usable track.
BAR_MIN_SHARE = 0.02
BAR_DEPTH_SPAN = 1.01
SIDES = ("top", "bottom", "left", "right")


def bar_lines(clip: Clip, config: SGCConfig) -> dict[str, int]:
    """Per side of the frame (SIDES), how many lines from that edge are bar lines (module comment)."""
    H, W = clip.image_size
    tracked: dict[str, np.ndarray] = {}

    def tracked_lines(kind: str) -> np.ndarray:  # the rows or columns a usable track rounds into
        if not tracked:  # only where a line's depth passed: most clips' first line fails on its depth
            usable = clip.usable_tracks(config.min_track_conf)
            positions = np.rint(np.concatenate([clip.track_prev[usable], clip.track_curr[usable]]))
            for axis, name, size in ((1, "rows", H), (0, "cols", W)):
                index = positions[:, axis]
                tracked[name] = np.zeros(size, bool)
                tracked[name][index[(index >= 0) & (index < size)].astype(np.int64)] = True
        return tracked[kind]

    def one_depth(depth: np.ndarray) -> bool:  # (frames, n): valid, within BAR_DEPTH_SPAN in each frame
        low, high = depth.min(axis=1).astype(np.float64), depth.max(axis=1).astype(np.float64)
        # NaN fails every comparison; the least > 0 and the largest finite make every value valid
        return bool(np.all(low > 0) and np.all(high < np.inf) and np.all(high <= BAR_DEPTH_SPAN * low))

    def is_bar(side: str, k: int) -> bool:
        kind = "rows" if side in ("top", "bottom") else "cols"
        line = k if side in ("top", "left") else (H if kind == "rows" else W) - 1 - k
        depth, static = ((clip.depth[:, line, :], clip.static_mask[:, line, :]) if kind == "rows"
                         else (clip.depth[:, :, line], clip.static_mask[:, :, line]))
        # the first and last frames first: a line of the world fails there, at a frame's cost
        if not (one_depth(depth[:1]) and one_depth(depth[-1:]) and static.all() and one_depth(depth)):
            return False
        medians = np.median(depth, axis=1)
        return medians.max() <= BAR_DEPTH_SPAN * medians.min() and not tracked_lines(kind)[line]

    counts = {}
    for side in SIDES:
        lines = H if side in ("top", "bottom") else W
        k = 0
        while k < lines and is_bar(side, k):  # a line at a time from the edge
            k += 1
        counts[side] = k
    return counts


def check_bars(clip: Clip, config: SGCConfig) -> list[Problem]:
    """A warning where the frame holds bars (rule LB1): their depth does not follow the camera."""
    H, W = clip.image_size
    counts = bar_lines(clip, config)
    bands = []
    for side, k in counts.items():
        lines = H if side in ("top", "bottom") else W
        if k < BAR_MIN_SHARE * lines:
            continue
        kind = "rows" if side in ("top", "bottom") else "columns"
        first, last = (0, k - 1) if side in ("top", "left") else (lines - k, lines - 1)
        bands.append(f"{kind} {first}-{last} at the {side}")
    if not bands:
        return []
    return [Problem("warning", "letterbox_bars", "depth", "every row and column a view of the world",
                    f"{' and '.join(bands)} hold one depth (within {100 * (BAR_DEPTH_SPAN - 1):.0f} %) in every frame, "
                    "static, and no track: a letterbox's bars? Their depth does not follow the camera and reads as "
                    "depth error (docs/semantics.md §1.1)",
                    "crop the bars away (moving K's principal point), or leave their depth invalid (0) or out of "
                    "the static mask")]
