"""Tracks as points: usable tracks, their pixels, back-projection and projection (docs/semantics.md §1.2, §3.2 step 5)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ...config import SGCConfig
from ...io.clip import Clip


class UsablePoints(NamedTuple):
    """A pair's usable tracks with valid depth (docs/semantics.md §3.2 steps 3-4): X (n, 3) in camera
    pair-1, uv (n, 2) in frame pair, uv_prev (n, 2) in frame pair-1, and n_usable, the usable
    tracks with or without depth."""

    X: np.ndarray
    uv: np.ndarray
    uv_prev: np.ndarray
    n_usable: int


def usable_points(clip: Clip, pair: int, config: SGCConfig) -> UsablePoints:
    usable = clip.usable_tracks(config.min_track_conf, repeats=config.counts_repeated_tracks)[pair - 1]
    prev, curr = clip.track_prev[pair - 1][usable].astype(np.float64), clip.track_curr[pair - 1][usable].astype(np.float64)
    X, has_depth = back_project_tracks(clip, pair, prev, config.track_pixel_offset)
    return UsablePoints(X[has_depth], curr[has_depth], prev[has_depth], int(usable.sum()))


def track_pixels(uv: np.ndarray, offset: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """(column, row) int64 (n,) of the pixels points uv (n, 2) are read at: floor(x + offset),
    floor(y + offset); 0.5 reads the nearest pixel, 0 the floor pixel (``SGCConfig.track_pixel_offset``).
    A non-zero offset is added in float32, as the JAX engine does, so both read the same pixel."""
    shifted = uv.astype(np.float32) + np.float32(offset) if offset else uv
    return np.floor(shifted[:, 0]).astype(np.int64), np.floor(shifted[:, 1]).astype(np.int64)


def back_project_tracks(clip: Clip, pair: int, prev: np.ndarray, offset: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Frame pair-1 pixels prev (n, 2) back-projected from that frame's depth at their pixels
    (``track_pixels`` at ``offset``; docs/semantics.md §3.2 steps 3-4): X (n, 3) in camera pair-1,
    and where the depth is valid (n,); depth 1 stands in where it is not."""
    H, W = clip.image_size
    col, row = track_pixels(prev, offset)
    col, row = np.clip(col, 0, W - 1), np.clip(row, 0, H - 1)
    Z = clip.depth[pair - 1][row, col].astype(np.float64)
    has_depth = np.isfinite(Z) & (Z > 0)
    return back_project(clip.K[pair - 1], prev, np.where(has_depth, Z, 1.0)), has_depth


def region_frame(pair: int, config: SGCConfig) -> int:
    """The frame whose partition gives pair ``pair``'s regions: pair (frame i) or, under
    ``region_frame="previous"``, pair - 1 (docs/semantics.md §3.2 steps 2 and 5)."""
    return pair - 1 if config.reads_previous_frame else pair


def back_project(K: np.ndarray, uv: np.ndarray, Z: np.ndarray) -> np.ndarray:
    """Points X (n, 3) = Z K^-1 (u, v, 1) of pixels uv (n, 2) at depths Z (n,) (docs/semantics.md
    §3.2 step 3; the skew K[0, 1] included)."""
    rays = np.linalg.solve(K.astype(np.float64), np.column_stack([uv, np.ones(len(uv))]).T).T
    return rays * Z[:, None]


def project(K: np.ndarray, cam: np.ndarray) -> np.ndarray:
    """Pixels (n, 2) of camera-frame points cam (n, 3): K (x / z, y / z, 1), the skew included;
    |z| floored at 1e-12."""
    z = np.where(np.abs(cam[:, 2]) > 1e-12, cam[:, 2], 1e-12)
    return (np.column_stack([cam[:, :2] / z[:, None], np.ones(len(cam))]) @ K.astype(np.float64).T)[:, :2]


def point_regions(labels: np.ndarray, uv: np.ndarray, offset: float = 0.0) -> np.ndarray:
    """Region label (n,) at the pixels of uv (n, 2) (``track_pixels`` at ``offset``); 0 outside the
    image or outside every region."""
    H, W = labels.shape
    col, row = track_pixels(uv, offset)
    inside = (col >= 0) & (col < W) & (row >= 0) & (row < H)
    out = np.zeros(len(uv), np.int32)
    out[inside] = labels[row[inside], col[inside]]
    return out
