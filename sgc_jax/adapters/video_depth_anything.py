"""Video Depth Anything: ``depths`` (T, h, w) from ``*_depths.npz`` (``run.py --save_npz``) -> clip depth.

Which model wrote the file decides what the numbers mean, so the caller must say it:
- ``kind="disparity"``: the relative models (``video_depth_anything_vit*.pth``) predict
  affine-invariant inverse depth. Rule: depth = depth_scale / disparity where disparity > 0, invalid
  (0) elsewhere. The unknown shift of the affine ambiguity is taken as zero, so the result is depth
  up to one global scale (``depth_scale``, default 1). :func:`import_clip` replaces this by a fitted
  scale and shift when VGGT's depth is available (:mod:`.depth_alignment`).
- ``kind="metric"``: the metric models (``metric_video_depth_anything_*``) predict depth in metres.
  Rule: depth = depth_scale * value, invalid where value <= 0.
VDA writes depth at its input frame size (``--max_res`` may have shrunk it); maps of another size are
brought to the clip grid by nearest neighbour at pixel centres (no depth mixed across edges), or
those smaller than it bilinearly within valid depth (``resize="bilinear"``, ``resize_depth``).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from ..io.npz import shape_text
from .common import EstimatorFormatError, load_arrays, resize_depth, squeeze_batch

KINDS = ("disparity", "metric")
AUTHORS_DIVISOR = 1000.0  # the SGC authors' pipeline: depth = VDA output / 1000, used directly


@dataclasses.dataclass
class Depth:
    """(T, H, W) float32 depth on the clip grid (0 = invalid) and how it was made; for
    ``kind="disparity"`` also the model's raw disparity (T, H, W) float32 on the clip grid."""

    depth: np.ndarray
    notes: dict[str, Any]
    disparity: np.ndarray | None = None


def read_depth_hw(source: Any, key: str = "depths") -> tuple[int, int]:
    """(h, w) of the maps in a VDA file, without converting them."""
    return _read_maps(source, key)[1].shape[1:]


def _read_maps(source: Any, key: str) -> tuple[str, np.ndarray]:
    label, arrays = load_arrays(source, "<depth arrays>")
    if key not in arrays:
        raise EstimatorFormatError(label, key, "(T, H, W) float depth maps", f"no such array (found {sorted(arrays)})",
                                   "Video Depth Anything's run.py --save_npz writes 'depths'; "
                                   "name another key with key=... (CLI: --depth-key)")
    maps = np.asarray(arrays[key])
    maps = maps[:, 0] if maps.ndim == 4 and maps.shape[1] == 1 else squeeze_batch(maps, 3)
    if maps.ndim != 3:
        raise EstimatorFormatError(label, key, "shape (T, H, W)", f"shape {shape_text(maps.shape)}")
    if not np.issubdtype(maps.dtype, np.number):
        raise EstimatorFormatError(label, key, "numeric depth maps", f"dtype {maps.dtype}")
    return label, maps


def read_video_depth(source: Any, *, height: int, width: int, kind: str | None = None,
                     depth_scale: float | None = None, key: str = "depths",
                     reference_compat: bool = False, resize: str = "nearest") -> Depth:
    """A VDA ``*_depths.npz`` (or mapping) -> (T, height, width) depth, by the rule of ``kind``, maps
    of another size brought to the grid by ``resize_depth``'s ``resize``.

    ``reference_compat``: the SGC authors' rule, depth = output / 1000 used directly (no inversion),
    which the paper calibration assumes; ``kind`` may then be omitted and ``depth_scale`` must be.
    """
    label, maps = _read_maps(source, key)
    maps = np.nan_to_num(maps.astype(np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    native = list(maps.shape[1:])
    if reference_compat:
        if kind == "metric" or depth_scale is not None:
            raise ValueError("reference-compat depth is the relative model's output / 1000, as in the authors' "
                             "pipeline; it cannot be combined with kind='metric' or a depth_scale")
        depth = maps / AUTHORS_DIVISOR
        rule = f"depth = VDA output / {AUTHORS_DIVISOR:g}, used directly (reference-compat: larger = nearer)"
    else:
        if kind not in KINDS:
            raise ValueError(
                f"{label}: say what the Video Depth Anything output is: kind='disparity' for the relative models "
                "(video_depth_anything_vit*.pth: affine-invariant inverse depth) or kind='metric' for "
                f"metric_video_depth_anything_* (metres); got {kind!r} (CLI: --depth-kind disparity|metric)")
        scale = 1.0 if depth_scale is None else float(depth_scale)
        if not scale > 0:
            raise ValueError(f"depth_scale must be > 0, got {depth_scale!r}")
        if kind == "disparity":
            positive = maps > 0
            depth = np.where(positive, scale / np.where(positive, maps, 1.0), 0.0)
            rule = f"depth = {scale:g} / disparity (disparity <= 0 -> invalid); relative depth, shift assumed 0"
        else:
            depth = np.where(maps > 0, maps * scale, 0.0)
            rule = f"depth = {scale:g} * metric depth"
    depth = resize_depth(depth.astype(np.float32), (height, width), resize)
    disparity = None
    if kind == "disparity" and not reference_compat:
        disparity = resize_depth(maps.astype(np.float32), (height, width), resize)
    notes = {"depth_kind": "authors" if reference_compat else kind, "depth_rule": rule, "depth_native_hw": native,
             "depth_resize": resize}
    return Depth(depth=depth, notes=notes, disparity=disparity)
