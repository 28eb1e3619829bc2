"""The clip schema (docs/semantics.md §1): :class:`Clip`, :class:`ClipFormatError`, the limits of
valid values, and writing clips as single-clip and batch files. Reading them is
:mod:`sgc_jax.io.loading` (files, sources) and :mod:`sgc_jax.io.arrays` (arrays -> a clip).

Pixel grid: x = column, y = row, pixel centres at integer coordinates. Poses are world->camera
(OpenCV): x_cam = R_wc @ X_world + t_wc. Pair i (i = 1..T-1) goes from frame i-1 to frame i and
its tracks live at index i-1 of the (T-1, P) track arrays.
"""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from ..stats import exact_median
from .npz import write_npz

# Values beyond these are not measurements and count as invalid points (docs/semantics.md §1.2):
# a track position more than TRACK_REACH image sizes outside the image, a depth more than
# DEPTH_RATIO_LIMIT times larger or smaller than the clip's median depth. They would otherwise
# overflow float32 arithmetic in one engine and not in the other.
TRACK_REACH = 1.0
DEPTH_RATIO_LIMIT = 1e6


class ClipFormatError(ValueError):
    """A structural problem with a clip: missing array, wrong rank or shape, non-finite camera."""

    def __init__(self, clip_id: str, array: str, expected: str, found: str, detail: str = ""):
        self.clip_id, self.array, self.expected, self.found, self.detail = clip_id, array, expected, found, detail
        message = f"clip {clip_id!r}: array {array!r}: expected {expected}, found {found}"
        super().__init__(message + (f" ({detail})" if detail else ""))

    def __reduce__(self):  # pickled by its fields (a reader process sends it back), not by its message
        return type(self), (self.clip_id, self.array, self.expected, self.found, self.detail)


@dataclasses.dataclass
class Clip:
    """One validated clip; arrays are NumPy, shapes use T frames, H x W pixels, P tracks."""

    clip_id: str
    depth: np.ndarray  # (T, H, W) float32; <= 0, non-finite or absurd (without_absurd_depth) = invalid
    K: np.ndarray  # (T, 3, 3) float64 pinhole intrinsics
    R_wc: np.ndarray  # (T, 3, 3) float64 world -> camera rotation
    t_wc: np.ndarray  # (T, 3) float64 world -> camera translation
    static_mask: np.ndarray  # (T, H, W) bool, true on static background
    track_prev: np.ndarray  # (T-1, P, 2) float32 positions in frame i-1
    track_curr: np.ndarray  # (T-1, P, 2) float32 positions in frame i
    track_vis: np.ndarray  # (T-1, P) bool, visible in frame i
    track_conf: np.ndarray  # (T-1, P) float32 tracker confidence in frame i
    mask_source: str = "static_mask"  # "static_mask" | "dynamic_mask" | "none" (whole frame static)
    frames: np.ndarray | None = None  # (T, H, W, 3) uint8, plots only
    meta: dict = dataclasses.field(default_factory=dict)
    warnings: tuple[str, ...] = ()  # the content checks' warning codes when loaded (docs/semantics.md §1.6)

    def __repr__(self) -> str:  # the arrays would flood a notebook cell
        H, W = self.image_size
        group = f", group {self.group!r}" if self.group else ""
        return (f"Clip({self.clip_id!r}{group}: {self.n_frames} frames, {H}x{W}, {self.n_tracks} tracks per pair, "
                f"masks from {self.mask_source}{', with frames' if self.frames is not None else ''})")

    @property
    def n_frames(self) -> int:
        return int(self.depth.shape[0])

    @property
    def n_pairs(self) -> int:
        return self.n_frames - 1

    @property
    def n_tracks(self) -> int:
        return int(self.track_prev.shape[1])

    @property
    def image_size(self) -> tuple[int, int]:
        """(H, W) in pixels."""
        return int(self.depth.shape[1]), int(self.depth.shape[2])

    @property
    def group(self) -> str:
        return str(self.meta.get("group", ""))

    def usable_tracks(self, min_track_conf: float, *, repeats: bool = True, pairs: np.ndarray | None = None
                      ) -> np.ndarray:
        """(T-1, P) bool: visible, confident, both positions within reach (docs/semantics.md §1.2);
        ``repeats=False``: and not a repeat of an earlier such track (``repeated_tracks``); ``pairs``
        (1-based): those pairs' rows alone, (len(pairs), P)."""
        rows = slice(None) if pairs is None else np.asarray(pairs) - 1
        usable = self.track_vis[rows] & self.candidate_tracks(min_track_conf, pairs=pairs)
        return usable if repeats else usable & ~repeated_tracks(self.track_prev[rows], self.track_curr[rows], usable)

    def candidate_tracks(self, min_track_conf: float, *, pairs: np.ndarray | None = None) -> np.ndarray:
        """``usable_tracks`` without the visibility: confident, both positions within reach."""
        H, W = self.image_size
        rows = slice(None) if pairs is None else np.asarray(pairs) - 1
        return ((self.track_conf[rows] >= min_track_conf) & within_reach(self.track_prev[rows], H, W)
                & within_reach(self.track_curr[rows], H, W))


def within_reach(track: np.ndarray, H: int, W: int) -> np.ndarray:
    """(...,) bool for positions (..., 2) in pixels: finite and at most TRACK_REACH image sizes
    outside the H x W image. Per coordinate, not reduced over the last axis (that is slow)."""
    x, y = track[..., 0], track[..., 1]
    return ((x >= -TRACK_REACH * W) & (x <= (1 + TRACK_REACH) * W)
            & (y >= -TRACK_REACH * H) & (y <= (1 + TRACK_REACH) * H))  # NaN compares false


def repeated_tracks(track_prev: np.ndarray, track_curr: np.ndarray, usable: np.ndarray) -> np.ndarray:
    """(T-1, P) bool: the ``usable`` tracks whose frame i-1 and frame i positions (T-1, P, 2) both
    equal (==) those of a usable track of lower index in the same pair: one measurement given again
    (docs/semantics.md §1.2). A 32-bit hash of the positions finds the pairs that may hold one (a
    standard clip's in ~1.7 ms on a CPU); only those are compared exactly."""
    multiplier = np.uint64(0x9E3779B97F4A7C15)
    # C order, as the (x, y) pair's view as one uint64 needs (a transposed or Fortran-ordered array is
    # not); + 0.0 makes -0.0 0.0
    prev, curr = (np.ascontiguousarray(a, np.float32) + np.float32(0.0) for a in (track_prev, track_curr))
    with np.errstate(over="ignore"):  # the hash wraps around by design
        mixed = (prev.view(np.uint64)[..., 0] * multiplier ^ curr.view(np.uint64)[..., 0]) * multiplier
    key = np.where(usable, (mixed >> np.uint64(32)).astype(np.uint32) | np.uint32(1), np.uint32(0))  # unusable: 0
    ordered = np.sort(key, axis=-1)
    repeated = np.zeros(usable.shape, bool)
    for pair in np.flatnonzero(np.any((ordered[:, 1:] == ordered[:, :-1]) & (ordered[:, 1:] > 0), axis=-1)):
        index = np.flatnonzero(usable[pair])
        row = np.concatenate([prev[pair, index], curr[pair, index]], axis=-1)
        by_position = np.lexsort((index, *row.T[::-1]))  # by x, y at i-1, x, y at i; then by index
        row = row[by_position]
        same = np.all(row[1:] == row[:-1], axis=-1)
        repeated[pair, index[by_position[1:][same]]] = True
    return repeated


def no_reading(depth: np.ndarray) -> np.ndarray | bool:
    """Where integer depth holds its dtype's largest value, the no-reading code of 16-bit depth
    PNGs (7-Scenes, Kinect): invalid depth (docs/semantics.md §1.2). False for float and 8-bit depth
    (an 8-bit map is a picture, whose 255 is its nearest surface)."""
    if depth.dtype.kind != "u" or depth.dtype.itemsize < 2:
        return False
    return depth == np.iinfo(depth.dtype).max


def without_absurd_depth(depth: np.ndarray) -> np.ndarray:
    """``depth`` with NaN where a positive, finite value lies beyond DEPTH_RATIO_LIMIT of the median
    of those values (docs/semantics.md §1.2); the same array when nothing is absurd."""
    positive = np.isfinite(depth) & (depth > 0)
    if not positive.any():
        return depth
    lo, hi = depth.min(where=positive, initial=np.inf), depth.max(where=positive, initial=-np.inf)
    if hi <= lo * DEPTH_RATIO_LIMIT:  # lo <= median <= hi: no value can be that far from the median
        return depth
    median = exact_median(depth[positive])
    absurd = positive & ((depth > median * DEPTH_RATIO_LIMIT) | (depth < median / DEPTH_RATIO_LIMIT))
    return np.where(absurd, np.float32(np.nan), depth).astype(depth.dtype) if absurd.any() else depth


def relative_poses(clip: Clip) -> tuple[np.ndarray, np.ndarray]:
    """(T-1, 3, 3) R_rel and (T-1, 3) t_rel, float64, mapping camera i-1's coordinates to camera i's
    from the stored poses (R_rel = R_wc[i] R_wc[i-1]^T, t_rel = t_wc[i] - R_rel t_wc[i-1])."""
    R, t = clip.R_wc.astype(np.float64), clip.t_wc.astype(np.float64)
    R_rel = R[1:] @ np.swapaxes(R[:-1], 1, 2)
    return R_rel, t[1:] - np.einsum("pij,pj->pi", R_rel, t[:-1])


# ----------------------------------------------------------------------------- files


def clip_to_arrays(clip: Clip) -> dict[str, np.ndarray]:
    """The clip arrays (docs/semantics.md §1.2) of a clip (inverse of :func:`~sgc_jax.io.arrays.clip_from_arrays`)."""
    arrays = dict(
        depth=clip.depth, K=clip.K, R_wc=clip.R_wc, t_wc=clip.t_wc,
        track_prev=clip.track_prev, track_curr=clip.track_curr,
        track_vis=clip.track_vis, track_conf=clip.track_conf,
        meta=np.asarray(json.dumps({**clip.meta, "clip_id": clip.clip_id})),
    )
    if clip.mask_source != "none":
        arrays["static_mask"] = clip.static_mask
    if clip.frames is not None:
        arrays["frames"] = clip.frames
    return arrays


def _path_first(function: str, path: Any, second: str) -> Path:
    """``path`` as a Path, or a TypeError that says the path comes first (``save_clip(clip, path)``)."""
    if not isinstance(path, (str, os.PathLike)):
        raise TypeError(f"{function}(path, {second}): the path comes first; got {type(path).__name__} as the path")
    return Path(path)


def save_clip(path: str | os.PathLike, clip: Clip) -> Path:
    """Write one clip as an ``.npz`` (``npz.write_npz``: members deflated where that pays); returns the path."""
    path = _path_first("save_clip", path, "clip")
    path.parent.mkdir(parents=True, exist_ok=True)
    return write_npz(path, clip_to_arrays(clip))


def _pad_to(array: np.ndarray, shape: tuple[int, ...], fill: Any = 0) -> np.ndarray:
    out = np.full(shape, fill, dtype=array.dtype)
    out[tuple(slice(0, s) for s in array.shape)] = array
    return out


def save_batch(path: str | os.PathLike, clips: list[Clip]) -> Path:
    """Stack clips into one batch file padded to common (T, H, W, P) (docs/semantics.md §1.3)."""
    path = _path_first("save_batch", path, "clips")
    if not clips:
        raise ValueError("save_batch needs at least one clip")
    T = max(c.n_frames for c in clips)
    H = max(c.image_size[0] for c in clips)
    W = max(c.image_size[1] for c in clips)
    P = max(c.n_tracks for c in clips)
    eye = np.broadcast_to(np.eye(3), (T, 3, 3))

    def pad_frames(a: np.ndarray, tail: np.ndarray) -> np.ndarray:
        return np.concatenate([a, np.broadcast_to(tail, (T - len(a),) + a.shape[1:])])

    stacked: dict[str, list] = {k: [] for k in (
        "depth", "K", "R_wc", "t_wc", "static_mask", "track_prev", "track_curr", "track_vis", "track_conf")}
    for c in clips:
        stacked["depth"].append(_pad_to(c.depth, (T, H, W)))
        stacked["K"].append(pad_frames(c.K, c.K[-1]))
        stacked["R_wc"].append(pad_frames(c.R_wc, eye[0]))
        stacked["t_wc"].append(pad_frames(c.t_wc, np.zeros(3)))
        stacked["static_mask"].append(_pad_to(c.static_mask, (T, H, W), False))
        stacked["track_prev"].append(_pad_to(c.track_prev, (T - 1, P, 2)))
        stacked["track_curr"].append(_pad_to(c.track_curr, (T - 1, P, 2)))
        stacked["track_vis"].append(_pad_to(c.track_vis, (T - 1, P), False))
        stacked["track_conf"].append(_pad_to(c.track_conf, (T - 1, P)))
    arrays = {k: np.stack(v) for k, v in stacked.items()}
    arrays.update(
        n_frames=np.array([c.n_frames for c in clips]),
        n_tracks=np.array([c.n_tracks for c in clips]),
        heights=np.array([c.image_size[0] for c in clips]),
        widths=np.array([c.image_size[1] for c in clips]),
        clip_id=np.array([c.clip_id for c in clips]),
        mask_source=np.array([c.mask_source for c in clips]),
        meta=np.array([json.dumps({**c.meta, "clip_id": c.clip_id}) for c in clips]),
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    return write_npz(path, arrays)
