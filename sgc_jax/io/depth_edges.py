"""Depth edges as a depth estimator leaves them (docs/semantics.md §3.6, "Smooth depth edges").

A monocular depth network predicts at a fraction of the frame's size and its output is enlarged, so
a depth edge becomes a ramp of pixels between the two surfaces' depths, points that lie on no
surface. The depth check warps them and compares them with the next frame's ramp, which parallax has
moved: a consistent world's depth error reads ~2 % (depth from half the frame's size) where it read
0.3 %. :func:`edges_and_ramps` finds them and :func:`without_ramps` makes the ramps invalid;
:func:`ramp_share` tells such depth from a sensor's or a renderer's, whose edges are steps, and
:func:`has_smooth_edges` decides it for a clip: under ``compat="spec"`` both engines leave such a
clip's ramps out before scoring (``SGCConfig.smooth_depth_edges``, :func:`ramps_left_out`); any
clip's, at any ratio, by ``sgc_jax.adapters.leave_out_depth_ramps`` or ``sgc-jax import
--depth-edge-ratio``.

Depth arrays are (T, H, W); a value is valid where finite and > 0. Neighbourhoods are 3 x 3 pixels.
"""

from __future__ import annotations

import cv2
import numpy as np

from ..config import DEPTH_EDGE_RATIO

# An edge pixel lies on a ramp where its depth is more than this share above its neighbourhood's
# smallest and below its largest: mixed, not one surface's or the other's.
RAMP_MARGIN = 0.05
# Depth whose edges are ramps (a network's output enlarged): at least this share of the edge pixels lies between
# its neighbours' depths, read on RAMP_FRAMES frames spread over the clip, where edges hold RAMP_EDGE_SHARE_MIN to
# RAMP_EDGE_SHARE_MAX of the valid depth (beyond, the depth is noise, not surfaces: 0.06-0.20 enlarged). FIT's pool
# (seeds 30-41, clean and perturbed at 0.25) reads 0.004-0.026 as rendered or stored in 8 or 16 bits, 0.37-0.40
# under the protocol's `depth` model, 0.64-0.70 enlarged 1.4x and 0.71-0.96 at 2-4x; the six real clips'
# sensor and rendered depth 0.00-0.29 (bench/history/issue-58.md "Smooth depth edges", "Ramps left out by default").
RAMP_SHARE = 0.5
RAMP_EDGE_SHARE_MIN = 0.005
RAMP_EDGE_SHARE_MAX = 0.5
RAMP_FRAMES = 4
# Depth resized with its holes (0) read as values: interpolation blends the surfaces beside a hole with 0, so
# the pixels around each hole hold depths between 0 and the surface's. A hole-border pixel (one with an
# invalid 3 x 3 neighbour) sunk more than DEPTH_EDGE_RATIO below its neighbourhood's greatest depth is such a
# blend where at least HOLE_SUNK_SHARE of the border is, and it holds HOLE_SUNK_MIN of the valid depth: the six
# real clips' sensor and rendered depth read 0.04-0.19 of the border as given or enlarged by nearest
# neighbour, 1.00 enlarged bilinearly with holes as 0 (real data, no split; bench/history/issue-58.md
# "Depth resized with its holes as zeros").
HOLE_SUNK_SHARE = 0.5
HOLE_SUNK_MIN = 0.001
_NEIGHBOURHOOD = np.ones((3, 3), np.uint8)


def valid_depth(depth: np.ndarray) -> np.ndarray:
    """Where ``depth`` is a measurement: finite and > 0."""
    with np.errstate(invalid="ignore"):
        return np.isfinite(depth) & (depth > 0)


def check_edge_ratio(ratio: float) -> None:
    """Raise unless ``ratio`` can mark an edge: a finite largest / smallest depth above 1."""
    if not (np.isfinite(ratio) and ratio > 1):
        raise ValueError(f"depth_edge_ratio must be > 1 (largest / smallest depth of a 3 x 3 neighbourhood), "
                         f"got {ratio!r}")


def depth_span(depth: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(lowest, highest) valid depth over each pixel's 3 x 3 neighbourhood, (T, H, W) float32 each;
    inf and 0 where the neighbourhood holds no valid depth (``valid``: :func:`valid_depth`)."""
    depth = np.where(valid, depth, 0).astype(np.float32, copy=False)
    hidden = np.where(valid, depth, np.float32(np.inf))
    low, high = np.empty(depth.shape, np.float32), np.empty(depth.shape, np.float32)  # C order, as dst= needs
    for frame in range(len(depth)):  # OpenCV's filters take one image; each writes into its frame's slice
        cv2.erode(hidden[frame], _NEIGHBOURHOOD, dst=low[frame])
        cv2.dilate(depth[frame], _NEIGHBOURHOOD, dst=high[frame])
    return low, high


def edges_and_ramps(depth: np.ndarray, ratio: float = DEPTH_EDGE_RATIO) -> tuple[np.ndarray, np.ndarray, int]:
    """(edges, ramps, valid count): (T, H, W) bool masks of the valid pixels whose neighbourhood's valid
    depths span more than ``ratio``, and of those whose depth lies over ``RAMP_MARGIN`` above the
    neighbourhood's least and below its greatest (on a ramp between two surfaces, on neither); and the
    number of valid pixels."""
    valid = valid_depth(depth)
    edges, ramps = _edges_and_ramps(depth, valid, *depth_span(depth, valid), ratio)
    return edges, ramps, int(valid.sum())


def _edges_and_ramps(depth, valid, low, high, ratio: float) -> tuple[np.ndarray, np.ndarray]:
    with np.errstate(over="ignore"):  # float32 depth near its largest value (an absurd depth) is no edge's
        edges = valid & (high > ratio * low)
        ramps = edges & (depth > (1 + RAMP_MARGIN) * low) & ((1 + RAMP_MARGIN) * depth < high)
    return edges, ramps


def without_ramps(depth: np.ndarray, ratio: float = DEPTH_EDGE_RATIO) -> tuple[np.ndarray, float]:
    """(``depth`` with 0, invalid, on its ramps; the share of the valid depth so left out)."""
    check_edge_ratio(ratio)
    _, ramps, valid = edges_and_ramps(depth, ratio)
    return np.where(ramps, 0, depth).astype(depth.dtype), int(ramps.sum()) / max(valid, 1)


def ramp_frames(n_frames, xp=np):
    """(RAMP_FRAMES,) int: the frames a clip's ramps are read on, round(j (n - 1) / 3), j = 0..3 (a
    frame may repeat; the set is every frame of a clip of up to 4). Written once for NumPy and
    ``jax.numpy`` (``n_frames`` traced)."""
    steps = xp.arange(RAMP_FRAMES, dtype=xp.float32) / xp.float32(RAMP_FRAMES - 1)
    return xp.round(steps * xp.asarray(n_frames - 1, xp.float32)).astype(xp.int32)


def edges_are_ramps(n_valid, n_edges, n_ramps, xp=np):
    """Whether counts of valid, edge and ramp pixels (:func:`edges_and_ramps`) are a depth network's
    enlarged output: edges hold RAMP_EDGE_SHARE_MIN to _MAX of the valid depth and at least
    RAMP_SHARE of them are ramps. In float32 on both NumPy and ``jax.numpy``, so the host and the
    device decide alike."""
    valid, edges, ramps = (xp.asarray(n, xp.float32) for n in (n_valid, n_edges, n_ramps))
    return ((edges >= xp.float32(RAMP_EDGE_SHARE_MIN) * valid) & (edges <= xp.float32(RAMP_EDGE_SHARE_MAX) * valid)
            & (ramps >= xp.float32(RAMP_SHARE) * edges) & (edges > 0))


def ramp_counts(depth: np.ndarray) -> tuple[int, int, int]:
    """(valid, edge, ramp) pixel counts of a clip's depth (T, H, W), read on :func:`ramp_frames`."""
    edges, ramps, valid = edges_and_ramps(_on_ramp_frames(depth))
    return valid, int(edges.sum()), int(ramps.sum())


def hole_border_counts(depth: np.ndarray) -> tuple[int, int, int]:
    """(valid, hole-border, sunk) pixel counts of a clip's depth (T, H, W), read on :func:`ramp_frames`:
    the valid pixels, those with an invalid 3 x 3 neighbour, and those of them more than DEPTH_EDGE_RATIO
    below their neighbourhood's greatest valid depth."""
    return edge_counts(depth)[1]


def edge_counts(depth: np.ndarray) -> tuple[tuple[int, int, int], tuple[int, int, int]]:
    """(:func:`ramp_counts`, :func:`hole_border_counts`) of a clip's depth from one 3 x 3 span of its
    ramp frames (the loader's two tests of its edges)."""
    depth = _on_ramp_frames(depth)
    valid = valid_depth(depth)
    low, high = depth_span(depth, valid)
    edges, ramps = _edges_and_ramps(depth, valid, low, high, DEPTH_EDGE_RATIO)
    border = np.stack([cv2.dilate((~v).astype(np.uint8), _NEIGHBOURHOOD) for v in valid]).astype(bool) & valid
    with np.errstate(over="ignore"):
        sunk = border & (DEPTH_EDGE_RATIO * depth < high)
    n_valid = int(valid.sum())
    return (n_valid, int(edges.sum()), int(ramps.sum())), (n_valid, int(border.sum()), int(sunk.sum()))


def _on_ramp_frames(depth: np.ndarray) -> np.ndarray:
    return depth[np.unique(ramp_frames(depth.shape[0]))]


def holes_blended(n_valid: int, n_border: int, n_sunk: int) -> bool:
    """Whether counts of :func:`hole_border_counts` are depth resized with its holes as 0."""
    return n_sunk >= HOLE_SUNK_SHARE * n_border and n_sunk >= HOLE_SUNK_MIN * n_valid and n_sunk > 0


def has_smooth_edges(depth: np.ndarray) -> bool:
    """Whether a clip's depth (T, H, W) has edges that are ramps (:func:`ramp_counts`)."""
    return bool(edges_are_ramps(*ramp_counts(depth)))


def ramps_left_out(depth: np.ndarray) -> np.ndarray:
    """``depth`` with its ramps invalid (0) where its edges are ramps (:func:`has_smooth_edges`);
    the same array otherwise."""
    return without_ramps(depth)[0] if has_smooth_edges(depth) else depth


def ramp_share(depth: np.ndarray, ratio: float = DEPTH_EDGE_RATIO) -> tuple[float, float]:
    """(edge share of the valid pixels, ramp share of the edge pixels): how much of the depth lies at
    edges, and how much of that lies between its neighbours' depths, as enlarged depth does (0.65-0.96
    on synthetic scenes enlarged 1.4-4x) and a sensor's or a renderer's does not (0.00-0.30)."""
    edges, ramps, valid = edges_and_ramps(depth, ratio)
    count = int(edges.sum())
    return count / max(valid, 1), int(ramps.sum()) / max(count, 1)
