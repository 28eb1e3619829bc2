"""Tracks on lines, from the clip's frames (docs/semantics.md §1.7): a tracker whose track starts on a
straight edge (a tile's grout, a stripe) can slide along it, the aperture problem, and report a
motion that is a fraction of the true one with a perfect patch match. Such a track's structure
tensor has one eigenvalue near 0.

:func:`line_structure` measures it; :func:`leave_out_line_tracks` makes the line-like tracks unusable, an
opt-in step before scoring for trackers that slide (pyramidal LK); the default score keeps every
track, and clips without frames cannot take it.
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np

from ..io.clip import Clip

#: Window of the structure tensor [px] and the eigenvalue ratio under which a track sits on a line,
#: the ratio chosen on the FIT split's scenes retracked by LK (bench/line_tracks.py; docs/semantics.md §1.7).
STRUCTURE_WINDOW_PX = 9
LINE_RATIO = 0.05


def line_structure(frame: np.ndarray, xy: np.ndarray, window: int = STRUCTURE_WINDOW_PX
                   ) -> tuple[np.ndarray, np.ndarray]:
    """The image structure around positions xy (P, 2) [px, x right, y down; the nearest pixel] of an
    RGB or grey frame (H, W[, 3]), from the structure tensor summed over a window x window box:
    lambda_min / lambda_max (P,), 0 on a straight edge or a uniform patch, up to 1 at a corner; and
    the unit direction (P, 2) of lambda_min, along the edge."""
    gray = frame.astype(np.float32)
    if gray.ndim == 3:
        gray = gray.mean(axis=-1)
    gx, gy = cv2.Sobel(gray, cv2.CV_32F, 1, 0, ksize=3), cv2.Sobel(gray, cv2.CV_32F, 0, 1, ksize=3)
    xx, yy, xy_ = (cv2.boxFilter(a, -1, (window, window)) for a in (gx * gx, gy * gy, gx * gy))
    col = np.clip(np.rint(np.nan_to_num(xy[:, 0])).astype(np.int64), 0, gray.shape[1] - 1)
    row = np.clip(np.rint(np.nan_to_num(xy[:, 1])).astype(np.int64), 0, gray.shape[0] - 1)
    a, b, c = (m[row, col].astype(np.float64) for m in (xx, xy_, yy))
    values, vectors = np.linalg.eigh(np.stack([np.stack([a, b], -1), np.stack([b, c], -1)], -2))
    values = np.maximum(values, 0.0)  # a sum of outer products: negative only by rounding
    ratio = np.where(values[:, 1] > 0, values[:, 0] / np.where(values[:, 1] > 0, values[:, 1], 1.0), 0.0)
    return ratio, vectors[:, :, 0]


def leave_out_line_tracks(clip: Clip, max_ratio: float = LINE_RATIO,
                          window: int = STRUCTURE_WINDOW_PX) -> Clip:
    """The clip with every track whose frame i-1 position has a :func:`line_structure` ratio below
    ``max_ratio`` made unusable (``track_vis`` False); the rest as they are."""
    if clip.frames is None:
        raise ValueError(f"clip {clip.clip_id!r}: leave_out_line_tracks reads the frames, and the clip has none "
                         "(array 'frames', (T, H, W, 3) uint8)")
    if not 0.0 <= max_ratio < 1.0:
        raise ValueError(f"max_ratio must be in [0, 1), got {max_ratio!r}")
    vis = clip.track_vis.copy()
    for pair in range(clip.n_pairs):  # host-side preparation, one image filter per frame
        ratio, _ = line_structure(clip.frames[pair], clip.track_prev[pair].astype(np.float64), window)
        vis[pair] &= ratio >= max_ratio
    return dataclasses.replace(clip, track_vis=vis)
