"""Shared pieces of the estimator adapters: the error type, file-name ordering, grid changes.

Every change of resolution uses the pixel-centre convention of the clip format (pixel centres at
integer coordinates, image edges at -0.5 and W-0.5): resizing a W-wide grid to W' maps
u' = (u + 0.5) * W' / W - 0.5, as OpenCV's and Pillow's resize do.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any, Mapping

import cv2
import numpy as np

from ..io.npz import NpzError, read_npz, shape_text


class EstimatorFormatError(ValueError):
    """An estimator output that cannot be imported: names the file, the array, what was expected,
    what was found and how to fix it."""

    def __init__(self, file: Any, array: str, expected: str, found: str, fix: str = ""):
        self.file, self.array, self.expected, self.found, self.fix = str(file), array, expected, found, fix
        message = f"{self.file}: array {array!r}: expected {expected}, found {found}"
        super().__init__(message + (f"; {fix}" if fix else ""))


def natural_key(name: str) -> list:
    """Sort key that orders 'frame2' before 'frame10'."""
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", name)]


def load_arrays(source: Any, label: str | None = None) -> tuple[str, dict[str, np.ndarray]]:
    """A ``.npz`` path or a mapping of arrays -> (label for messages, dict of arrays)."""
    if isinstance(source, Mapping):
        return label or "<arrays>", {k: np.asarray(v) for k, v in source.items()}
    path = Path(os.fspath(source))
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    try:  # read_npz turns any archive it cannot read (empty, truncated, pickled) into NpzError
        return str(path), read_npz(path)
    except NpzError as exc:
        raise EstimatorFormatError(path, exc.array, exc.expected, exc.found) from None


def load_npy(path: Path) -> np.ndarray:
    """One ``.npy`` array of numbers; EstimatorFormatError naming the file for anything else."""
    try:
        return np.load(path, allow_pickle=False)
    except (ValueError, OSError, EOFError) as exc:  # object arrays, truncated or empty files
        raise EstimatorFormatError(path, "<file>", "a .npy of numeric arrays", f"{type(exc).__name__}: {exc}") from None


def squeeze_batch(array: np.ndarray, ndim: int) -> np.ndarray:
    """Drop a leading batch axis of size 1 (estimators often keep B = 1)."""
    return array[0] if array.ndim == ndim + 1 and array.shape[0] == 1 else array


def camera_arrays(label: str, arrays: Mapping[str, np.ndarray], names: tuple[str, str], count: int | None = None,
                  per: str = "extrinsic") -> tuple[np.ndarray, np.ndarray]:
    """(world->camera [R | t] (S, 3, 4) or (S, 4, 4), intrinsics (S, 3, 3)) of ``arrays[names]`` in
    float64, a batch axis of 1 dropped; S = ``count`` when given. A wrong shape or a non-finite
    value raises EstimatorFormatError naming the array (``per``: what each one belongs to)."""
    extrinsic_name, intrinsic_name = names
    extrinsic = squeeze_batch(np.asarray(arrays[extrinsic_name], np.float64), 3)
    intrinsic = squeeze_batch(np.asarray(arrays[intrinsic_name], np.float64), 3)
    if (extrinsic.ndim != 3 or extrinsic.shape[1:] not in ((3, 4), (4, 4))
            or count is not None and extrinsic.shape[0] != count):
        expected = "shape (S, 3, 4)" if count is None else f"shape ({count}, 3, 4), one per {per}"
        raise EstimatorFormatError(label, extrinsic_name, expected, f"shape {shape_text(extrinsic.shape)}")
    S = extrinsic.shape[0]
    if intrinsic.shape != (S, 3, 3):
        raise EstimatorFormatError(label, intrinsic_name, f"shape ({S}, 3, 3), one per {per}",
                                   f"shape {shape_text(intrinsic.shape)}")
    for name, array in ((extrinsic_name, extrinsic), (intrinsic_name, intrinsic)):
        if not np.isfinite(array).all():
            raise EstimatorFormatError(label, name, "finite values", f"{int((~np.isfinite(array)).sum())} non-finite")
    return extrinsic, intrinsic


def resize_factors(src_hw: tuple[int, int], dst_hw: tuple[int, int]) -> tuple[float, float, float, float]:
    """(a_x, b_x, a_y, b_y) with u_dst = a_x u_src + b_x, v_dst = a_y v_src + b_y (pixel centres)."""
    (h0, w0), (h1, w1) = src_hw, dst_hw
    a_x, a_y = w1 / w0, h1 / h0
    return a_x, 0.5 * a_x - 0.5, a_y, 0.5 * a_y - 0.5


def map_intrinsics(K: np.ndarray, a_x: float, b_x: float, a_y: float, b_y: float) -> np.ndarray:
    """(..., 3, 3) K for pixel coordinates changed by u' = a_x u + b_x, v' = a_y v + b_y."""
    A = np.array([[a_x, 0.0, b_x], [0.0, a_y, b_y], [0.0, 0.0, 1.0]])
    return np.einsum("ij,...jk->...ik", A, np.asarray(K, np.float64))


def resize_points(points: np.ndarray, src_hw: tuple[int, int], dst_hw: tuple[int, int]) -> np.ndarray:
    """(..., 2) x, y pixel coordinates on an src_hw grid -> the same points on a dst_hw grid."""
    if tuple(src_hw) == tuple(dst_hw):
        return points
    a_x, b_x, a_y, b_y = resize_factors(src_hw, dst_hw)
    out = np.array(points, np.float64, copy=True)
    out[..., 0] = a_x * out[..., 0] + b_x
    out[..., 1] = a_y * out[..., 1] + b_y
    return out.astype(points.dtype)


def resize_nearest(maps: np.ndarray, dst_hw: tuple[int, int]) -> np.ndarray:
    """(T, h, w) maps -> (T, H, W) by nearest neighbour at pixel centres (no value mixing across
    depth edges or label borders; an integer upsampling followed by this is the identity)."""
    T, h, w = maps.shape
    H, W = dst_hw
    if (h, w) == (H, W):
        return maps
    rows = np.clip(np.floor((np.arange(H) + 0.5) * h / H).astype(np.int64), 0, h - 1)
    cols = np.clip(np.floor((np.arange(W) + 0.5) * w / W).astype(np.int64), 0, w - 1)
    return maps[:, rows[:, None], cols[None, :]]


# How depth maps smaller than the clip grid are brought up to it (docs/semantics.md §1.5, "Depth maps of
# another size"): nearest neighbour (the default: no depth mixed, in blocks) or bilinear within valid depth.
DEPTH_RESIZES = ("nearest", "bilinear")
# Bilinear weights of valid depth at a target pixel below this leave it invalid: no hole is blended in.
VALID_WEIGHT_MIN = 0.999


def resize_depth(maps: np.ndarray, dst_hw: tuple[int, int], method: str = "bilinear") -> np.ndarray:
    """(T, h, w) depth (or disparity; <= 0 or non-finite invalid) -> (T, H, W) float32. ``method``
    "bilinear": where the map is smaller than the grid on either axis, OpenCV's INTER_LINEAR of depth x
    valid over that of valid, 0 (invalid) where a hole would enter; nearest neighbour brings a smaller
    map up in blocks, whose steps on every sloping surface the depth check reads as inconsistency.
    Otherwise, and for "nearest", nearest at pixel centres (``resize_nearest``)."""
    if method not in DEPTH_RESIZES:
        raise ValueError(f"unknown depth resize {method!r}; one of {DEPTH_RESIZES}")
    T, h, w = maps.shape
    H, W = dst_hw
    maps = maps.astype(np.float32, copy=False)
    if method == "nearest" or (h >= H and w >= W):
        return resize_nearest(maps, dst_hw)
    valid = np.isfinite(maps) & (maps > 0)
    out = np.empty((T, H, W), np.float32)
    for t in range(T):
        weight = cv2.resize(valid[t].astype(np.float32), (W, H), interpolation=cv2.INTER_LINEAR)
        total = cv2.resize(np.where(valid[t], maps[t], 0.0).astype(np.float32), (W, H), interpolation=cv2.INTER_LINEAR)
        out[t] = np.where(weight >= VALID_WEIGHT_MIN, total / np.maximum(weight, VALID_WEIGHT_MIN), 0.0)
    return out


def resize_frames(frames: np.ndarray, dst_hw: tuple[int, int]) -> np.ndarray:
    """(T, h, w, 3) uint8 -> (T, H, W, 3) with area averaging (downscale) or bilinear (upscale)."""
    T, h, w, _ = frames.shape
    H, W = dst_hw
    if (h, w) == (H, W):
        return frames
    interpolation = cv2.INTER_AREA if H * W < h * w else cv2.INTER_LINEAR
    return np.stack([cv2.resize(f, (W, H), interpolation=interpolation) for f in frames])


def parse_size(text: str | tuple[int, int] | None) -> tuple[int, int] | None:
    """'HxW' (or an (H, W) tuple) -> (H, W); None stays None."""
    if text is None or isinstance(text, tuple):
        return text
    match = re.fullmatch(r"\s*(\d+)\s*[xX,]\s*(\d+)\s*", str(text))
    if not match:
        raise ValueError(f"size must be HxW (height x width, e.g. 480x854), got {text!r}")
    return int(match.group(1)), int(match.group(2))
