"""Depth given as each pixel's distance from the camera centre (range, as Hypersim's depth or a
renderer's ray-length pass) instead of its z coordinate (docs/semantics.md §1.1, "Depth is z").

Read as z, a range map places every point off the optical axis too far, by the length of its ray
K⁻¹ (u, v, 1), 1 / cos of its angle off the axis (15 % at the sides of a 60° frame, 41 % at 90°):
a rigid world no longer warps onto itself and a consistent clip scores well above 0 (the real
clips 0.014-0.21 -> 0.034-0.42).
:func:`depth_from_range` converts; :func:`depth_reading_misfits` tells the two readings apart from
the clip's cameras: each sampled pixel of frame i−1 moved by the camera's motion (its translation's
scale fitted) lands where frame i's depth should read its new z, and a range map read either way
misses by a pattern that follows the pixel's place in the frame. The same warp tells a depth map
stored mirrored (a renderer's or OpenGL's bottom-up rows) from one stored as the frames are: read
mirrored back, it warps far better (``FLIPS``).

Depth arrays are (T, H, W) or (H, W); K (T, 3, 3) or (3, 3); pixel centres at integer coordinates
(x = column, y = row), as everywhere in a clip (docs/semantics.md §1.1).
"""

from __future__ import annotations

import warnings
from typing import NamedTuple, Sequence

import numpy as np

from .clip import Clip

PAIRS = 3  # frame pairs looked at, spread over the clip (a loader check: the cost stays flat)
POINTS = 1024  # pixels of frame i-1 sampled per pair, on a regular grid
BLOCKS = (4, 6)  # the frame cut into rows x columns; a misfit is read per block, so noise averages out
MIN_BLOCK_POINTS = 12
MIN_BLOCKS = 6
# A pair's depth follows the camera where the better reading moved by it misfits at most 1 / this of
# the depth left in place: a still video under moving cameras fits neither reading, and the range
# reading less badly (added after rule R1's first run told 11 of 12 such adversaries range).
FOLLOWS_CAMERA = 2.0
# The translation's scale is searched around the tracks' fit: this many log-spaced factors over
# [1 / SCALE_SPAN, SCALE_SPAN], then as many again over one step around the best.
SCALE_SPAN, SCALE_STEPS = 1.5, 7
# A depth map mirrored against its frame: both maps of a pair read with their rows, their columns, or both
# (a half turn) in reverse order ((rows, columns) reversed).
FLIPS = {"up-down": (True, False), "left-right": (False, True), "turned 180°": (True, True)}


def ray_lengths(K: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """|K⁻¹ (u, v, 1)| at the pixel centres (u, v) = (cols, rows): a range over its z (>= 1)."""
    x = (cols - K[0, 2]) / K[0, 0]
    y = (rows - K[1, 2]) / K[1, 1]
    return np.sqrt(1.0 + x * x + y * y)


def _along_rays(maps_in: np.ndarray, K: np.ndarray, power: int) -> np.ndarray:
    """Each pixel of the maps times its ray's length |K⁻¹ (u, v, 1)| to ``power`` (±1); shapes and dtypes as
    :func:`depth_from_range` takes and gives them."""
    single = maps_in.ndim == 2
    maps = maps_in[None] if single else maps_in
    Ks = np.broadcast_to(K, (len(maps), 3, 3)) if np.ndim(K) == 2 else np.asarray(K)
    if Ks.shape != (len(maps), 3, 3):
        raise ValueError(f"K must be (3, 3) per frame of the maps {maps_in.shape}; got {np.shape(K)}")
    H, W = maps.shape[1:]
    rows, cols = np.mgrid[0:H, 0:W].astype(np.float64)
    out = np.stack([m * ray_lengths(k.astype(np.float64), rows, cols) ** power for m, k in zip(maps, Ks)])
    out = out.astype(maps_in.dtype if np.issubdtype(maps_in.dtype, np.floating) else np.float32)
    return out[0] if single else out


def depth_from_range(range_maps: np.ndarray, K: np.ndarray) -> np.ndarray:
    """z depth, the range maps' shape (float dtypes kept, others float32): (T, H, W) maps with a
    (T, 3, 3) K or one (3, 3) K for every frame, or one (H, W) map with a (3, 3) K."""
    return _along_rays(range_maps, K, -1)


def range_from_depth(depth: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Range maps (each pixel's distance from the camera centre) of z depth: :func:`depth_from_range`'s
    inverse, with its shapes and dtypes."""
    return _along_rays(depth, K, 1)


def _group_medians(values: np.ndarray, group: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(groups, their sizes, the median of ``values`` in each) for integer ``group`` >= 0: one sort
    of ``group`` + a monotone map of each value into [0, 1), which keeps the values' order inside a
    group (float64: 1e-13 apart at 1e3 groups, far finer than a depth misfit needs)."""
    if values.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
    keyed = np.sort(group + 0.5 + np.arctan(values) / np.pi)
    owner = np.floor(keyed).astype(np.int64)
    starts = np.flatnonzero(np.r_[True, owner[1:] != owner[:-1]])
    counts = np.diff(np.r_[starts, len(keyed)])
    middle = np.tan((keyed - owner - 0.5) * np.pi)
    return owner[starts], counts, 0.5 * (middle[starts + (counts - 1) // 2] + middle[starts + counts // 2])


def _block_misfits(error: np.ndarray, block: np.ndarray, trial: np.ndarray, n_trials: int) -> np.ndarray:
    """(n_trials,) per trial: the median over its blocks (with MIN_BLOCK_POINTS or more points) of
    |the block's median signed error|; NaN with fewer than MIN_BLOCKS such blocks."""
    groups, counts, medians = _group_medians(error, trial * BLOCKS[0] * BLOCKS[1] + block)
    full = counts >= MIN_BLOCK_POINTS
    trials, n_blocks, misfit = _group_medians(np.abs(medians[full]), groups[full] // (BLOCKS[0] * BLOCKS[1]))
    out = np.full(n_trials, np.nan)
    out[trials[n_blocks >= MIN_BLOCKS]] = misfit[n_blocks >= MIN_BLOCKS]
    return out


class DepthReadings(NamedTuple):
    """``depth_reading_misfits``: the clip's depth misfit (relative) read as z and as range over the
    pairs whose depth follows the camera; where asked, as z again and (``flipped``, by the name of
    each of ``FLIPS``) with both maps of each pair read so, over the pairs that follow the camera
    under any of these readings (NaN and None where not read)."""

    as_z: float
    as_range: float
    mirrored_as_z: float = float("nan")
    flipped: dict[str, float] | None = None


class _Reading(NamedTuple):
    """One way of moving a pair's sampled points: frame i−1's points turned into camera i's axes,
    (n, 3), NaN where the reading has no depth, the translation t (3,) whose scale the trials vary,
    whether both depths are range, and whether both maps are read mirrored ((rows, columns))."""

    turned: np.ndarray
    t: np.ndarray
    as_range: bool
    mirrored: tuple[bool, bool] = (False, False)


def _pair_readings(clip: Clip, pair: int, R: np.ndarray, t: np.ndarray, mirrored: bool = False
                   ) -> tuple[list[_Reading], np.ndarray]:
    """(the readings as z, as range, and left in place (R = I, t = 0, as z), or (``mirrored``) as z
    with each of FLIPS; each sampled point's block): frame pair−1's static, valid depth sampled on a
    regular grid of about POINTS pixels."""
    H, W = clip.image_size
    stride = max(1, int(np.sqrt(H * W / POINTS)))
    rows, cols = (a.ravel() for a in np.mgrid[stride // 2:H:stride, stride // 2:W:stride])
    if mirrored:  # the static pixels; each reading's depth NaN where its mirrored map has none
        rows, cols = (a[clip.static_mask[pair - 1][rows, cols]] for a in (rows, cols))
        depths = [clip.depth[pair - 1][H - 1 - rows if up_down else rows, W - 1 - cols if left_right else cols]
                  for up_down, left_right in FLIPS.values()]
        depths = [np.where(np.isfinite(d) & (d > 0), d, np.nan).astype(np.float64) for d in depths]
    else:
        depth = clip.depth[pair - 1][rows, cols].astype(np.float64)
        keep = np.isfinite(depth) & (depth > 0) & clip.static_mask[pair - 1][rows, cols]
        rows, cols, depth = rows[keep], cols[keep], depth[keep]
    K_prev = clip.K[pair - 1].astype(np.float64)
    rays = np.c_[cols, rows, np.ones(len(rows))] @ np.linalg.inv(K_prev).T
    block = (rows * BLOCKS[0] // H) * BLOCKS[1] + cols * BLOCKS[1] // W
    if mirrored:
        return [_Reading((rays * d[:, None]) @ R.T, t, False, flip) for d, flip in zip(depths, FLIPS.values())], block
    as_range = depth / ray_lengths(K_prev, rows, cols)
    points, points_as_range = rays * depth[:, None], rays * as_range[:, None]
    return [_Reading(points @ R.T, t, False), _Reading(points_as_range @ R.T, t, True),
            _Reading(points, np.zeros(3), False)], block


def _misfits(clip: Clip, pair: int, block: np.ndarray, readings: Sequence[_Reading],
             scales: Sequence[np.ndarray]) -> list[np.ndarray]:
    """Per reading, per scale of its ``scales``: ``_block_misfits`` of its points moved by (R, s t)
    against frame pair's depth at the landing pixel (read as range where the reading is). Every
    reading's trials are projected at once."""
    if not readings:
        return []
    H, W = clip.image_size
    K_curr = clip.K[pair].astype(np.float64)
    counts = [len(s) for s in scales]
    owner = np.repeat(np.arange(len(readings)), counts)  # (trials,) the reading of each trial
    turned = np.stack([r.turned for r in readings])[owner]
    t = np.stack([r.t for r in readings])[owner]
    moved = turned + np.concatenate(scales)[:, None, None] * t[:, None, :]  # (trials, points, 3)
    with np.errstate(divide="ignore", invalid="ignore"):
        landing = moved @ K_curr.T
        u, v = landing[..., 0] / landing[..., 2] + 0.5, landing[..., 1] / landing[..., 2] + 0.5
    # the landing pixel is the one whose centre is nearest: floor(u + 0.5); flat indices gather fastest
    landed = np.flatnonzero((moved[..., 2] > 0) & (u >= 0) & (u < W) & (v >= 0) & (v < H))
    trial, point = np.divmod(landed, moved.shape[1])
    col, row = u.ravel()[landed].astype(np.int64), v.ravel()[landed].astype(np.int64)
    pixel = row * W + col
    read_pixel = pixel
    mirrored = np.array([r.mirrored for r in readings])  # (readings, 2): rows, columns
    if mirrored.any():
        mirrored = mirrored[owner[trial]]
        read_pixel = np.where(mirrored[:, 0], H - 1 - row, row) * W + np.where(mirrored[:, 1], W - 1 - col, col)
    read = clip.depth[pair].ravel()[read_pixel].astype(np.float64)
    as_range = np.array([r.as_range for r in readings])
    if as_range.any():
        read = np.where(as_range[owner[trial]], read / ray_lengths(K_curr, row, col), read)
    good = np.isfinite(read) & (read > 0) & clip.static_mask[pair].ravel()[pixel]
    trial, point, z = trial[good], point[good], moved[..., 2].ravel()[landed[good]]
    error = (read[good] - z) / z
    first = np.r_[0, np.cumsum(counts)]  # each reading's first trial
    out = []
    for j, count in enumerate(counts):
        mine = (trial >= first[j]) & (trial < first[j + 1])
        out.append(_block_misfits(error[mine], block[point[mine]], trial[mine] - first[j], count))
    return out


def _least(clip: Clip, pair: int, block: np.ndarray, readings: Sequence[_Reading],
           fitted: Sequence[float]) -> list[float]:
    """Per reading, the least finite misfit over a coarse then a fine log grid of scales around its
    ``fitted`` scale (at 0 alone where the tracks fit no translation: a turn, which tells the
    readings apart alone)."""
    factors = np.geomspace(1 / SCALE_SPAN, SCALE_SPAN, SCALE_STEPS)
    step = factors[1] / factors[0]
    coarse = _misfits(clip, pair, block, readings, [np.zeros(1) if s == 0 else s * factors for s in fitted])
    refine = [j for j, s in enumerate(fitted) if s != 0 and np.isfinite(coarse[j]).any()]
    fine = dict(zip(refine, _misfits(clip, pair, block, [readings[j] for j in refine],
                                     [fitted[j] * factors[int(np.nanargmin(coarse[j]))]
                                      * np.geomspace(1 / step, step, SCALE_STEPS) for j in refine])))
    least = []
    for j, scale in enumerate(fitted):
        if scale == 0:
            least.append(float(coarse[j][0]))
        else:  # no finite coarse misfit: nothing refined, NaN
            least.append(float(np.nanmin(np.r_[coarse[j], fine[j]])) if j in fine else float("nan"))
    return least


def _least_mirrored(clip: Clip, pair: int, R: np.ndarray, t: np.ndarray, scale: float) -> list[float]:
    """Per reading of FLIPS, ``_least``'s misfit (the scale searched as for z and range)."""
    readings, block = _pair_readings(clip, pair, R, t, mirrored=True)
    return _least(clip, pair, block, readings, [scale] * len(readings))


def _following(rows: list[list[float]]) -> np.ndarray:
    """The rows (per pair: its moving readings' misfits, then left in place's) of pairs whose depth
    follows the camera: as z and as range finite, and left in place missing by at least
    FOLLOWS_CAMERA times the least moving reading; (pairs, readings), without left in place."""
    kept = [row[:-1] for row in rows
            if np.isfinite(row[:2]).all() and not row[-1] < FOLLOWS_CAMERA * np.nanmin(row[:-1])]
    return np.array(kept).reshape(len(kept), len(rows[0]) - 1 if rows else 0)


def depth_reading_misfits(clip: Clip, poses: Sequence[tuple[int, np.ndarray, np.ndarray, float]],
                          mirrored_above: float | None = None) -> DepthReadings:
    """``DepthReadings``: the median over at most PAIRS of ``poses`` (pair, the camera's relative R
    and t from frame pair−1 to pair, the translation's scale fitted to the tracks) of each reading's depth misfit (relative; the median over blocks of
    the block's median); NaN where no pair can tell. A pair whose depth, left where it is, misfits
    less than FOLLOWS_CAMERA times the best reading moved by the camera does not follow the camera (a
    still video under moving cameras) and tells nothing. ``mirrored_above``: where the as-z misfit is
    NaN or above it, each map is read mirrored too (FLIPS), a pair then following the camera where
    left in place misfits FOLLOWS_CAMERA times the least of all its moving readings."""
    usable = [p for p in poses if np.isfinite(p[3]) and p[3] >= 0]
    chosen = np.unique(np.linspace(0, len(usable) - 1, min(PAIRS, len(usable))).round().astype(np.int64))
    rows = []
    for i in chosen:
        pair, R, t, scale = usable[i]
        moves, block = _pair_readings(clip, pair, R, t)
        as_z, as_range, left_in_place = _least(clip, pair, block, moves, [scale, scale, 0.0])
        rows.append([as_z, as_range, left_in_place])
    kept = _following(rows)
    as_z, as_range = np.median(kept, axis=0) if len(kept) else (float("nan"), float("nan"))
    if mirrored_above is None or as_z <= mirrored_above or not rows:
        return DepthReadings(float(as_z), float(as_range))
    for i, row in zip(chosen, rows):
        row[2:2] = _least_mirrored(clip, *usable[i])
    kept = _following(rows)[:, [0, *range(2, 2 + len(FLIPS))]]
    if not len(kept):
        return DepthReadings(float(as_z), float(as_range))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a mirrored reading NaN in every pair: NaN
        mirrored_as_z, *flipped = np.nanmedian(kept, axis=0)
    return DepthReadings(float(as_z), float(as_range), float(mirrored_as_z),
                         {name: float(m) for name, m in zip(FLIPS, flipped)})
