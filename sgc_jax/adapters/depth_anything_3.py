"""Depth Anything 3: depth, cameras and intrinsics from one ``results.npz`` -> clip depth, K, R_wc, t_wc.

DA3's ``inference(..., export_format="npz")`` (or ``"mini_npz"``) writes
``exports/npz/results.npz`` with ``depth`` (N, h, w), ``conf`` (N, h, w), ``extrinsics`` (N, 3, 4)
world->camera in OpenCV's convention and ``intrinsics`` (N, 3, 3); the ``npz`` form adds ``image``
(N, h, w, 3), the processed frames. Quirks, as this reader takes them:
- **Resolution.** Everything is on DA3's processed grid h x w, not the video's: with its default
  ``upper_bound_resize`` the longer side is ``process_res`` (504) and each side is rounded to a
  multiple of 14, so the aspect ratio moves slightly and the two axes scale apart. The whole frame
  is kept (no crop), so K maps to the clip grid by the resize of each axis (pixel centres, as
  :mod:`.common`) and depth by nearest neighbour (or bilinearly, ``resize``). A crop method (``*_crop``) cuts the frame and is
  not supported.
- **Units.** Any-view models (DA3-Giant/Large/Base/Small) give depth and camera translations in
  one shared, arbitrary scale; the nested model (DA3NESTED-GIANT-LARGE) in metres. Either way
  depth and translations agree, so no alignment is needed (SGC is scale-free, docs/semantics.md
  §3.1). DA3METRIC-LARGE and DA3MONO-LARGE predict no cameras: their files have no ``extrinsics``
  and are refused here (use VGGT's cameras with Video Depth Anything, §1.5).
- **Confidence.** ``conf`` (rounded to 0.01 by the exporter; larger is surer) is kept as an option:
  ``min_conf`` makes pixels below it invalid depth (default: none; every pixel with depth > 0).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from ..io.npz import shape_text
from .common import (
    EstimatorFormatError,
    camera_arrays,
    load_arrays,
    map_intrinsics,
    resize_depth,
    resize_factors,
    squeeze_batch,
)
from .vggt import Cameras
from .video_depth_anything import Depth

DA3_FIX = "export with DepthAnything3.inference(images, export_dir=..., export_format='npz') (or 'mini_npz')"


@dataclasses.dataclass
class DA3Output:
    """Depth (T, H, W) float32 on the clip grid (0 = invalid) and cameras (K on the clip grid)."""

    depth: Depth
    cameras: Cameras


def read_da3_hw(source: Any) -> tuple[int, int]:
    """(h, w) of DA3's processed grid in a results file."""
    label, arrays = load_arrays(source, "<da3 arrays>")
    return _depth_maps(label, arrays).shape[1:]


def _depth_maps(label: str, arrays: dict[str, np.ndarray]) -> np.ndarray:
    if "depth" not in arrays:
        raise EstimatorFormatError(label, "depth", "(N, h, w) depth maps", f"no such array (found {sorted(arrays)})",
                                   DA3_FIX)
    maps = np.asarray(arrays["depth"])
    maps = maps[..., 0] if maps.ndim == 4 and maps.shape[-1] == 1 else squeeze_batch(maps, 3)
    if maps.ndim != 3 or not np.issubdtype(maps.dtype, np.number):
        raise EstimatorFormatError(label, "depth", "numeric maps of shape (N, h, w)",
                                   f"shape {shape_text(maps.shape)}, dtype {maps.dtype}")
    return maps


def read_da3(source: Any, *, height: int, width: int, min_conf: float | None = None,
             resize: str = "nearest") -> DA3Output:
    """A DA3 ``results.npz`` (or mapping) -> depth and cameras on the height x width clip grid (the
    depth brought there by ``resize_depth``'s ``resize``)."""
    label, arrays = load_arrays(source, "<da3 arrays>")
    maps = _depth_maps(label, arrays)
    N, h, w = maps.shape
    for name, expected in (("extrinsics", f"({N}, 3, 4) world-to-camera [R | t]"),
                           ("intrinsics", f"({N}, 3, 3) on DA3's {h}x{w} processed grid")):
        if name not in arrays:
            raise EstimatorFormatError(label, name, expected, f"no such array (found {sorted(arrays)})",
                                       "DA3METRIC-LARGE and DA3MONO-LARGE predict no cameras: use an any-view or "
                                       "nested DA3 model, or VGGT's cameras with Video Depth Anything's depth")
    extrinsics, intrinsics = camera_arrays(label, arrays, ("extrinsics", "intrinsics"), count=N, per="depth map")

    depth = np.nan_to_num(maps.astype(np.float32), nan=0.0, posinf=0.0, neginf=0.0)
    depth = np.where(depth > 0, depth, 0.0).astype(np.float32)
    rule = "DA3 depth, in the units of its camera translations"
    if min_conf is not None:
        if "conf" not in arrays:
            raise EstimatorFormatError(label, "conf", f"({N}, {h}, {w}) confidence (min_conf was given)",
                                       f"no such array (found {sorted(arrays)})")
        conf = squeeze_batch(np.asarray(arrays["conf"], np.float32), 3)
        if conf.shape != maps.shape:
            raise EstimatorFormatError(label, "conf", f"shape ({N}, {h}, {w}) like depth", f"shape {shape_text(conf.shape)}")
        depth = np.where(np.nan_to_num(conf, nan=-np.inf) >= min_conf, depth, 0.0).astype(np.float32)
        rule += f"; pixels of conf < {min_conf:g} invalid"
    K = map_intrinsics(intrinsics, *resize_factors((h, w), (height, width)))
    notes = {"intrinsics": f"rescaled from DA3's {h}x{w} processed grid to {height}x{width}",
             "cameras_source": "depth anything 3 extrinsics (OpenCV world->camera)"}
    cameras = Cameras(K=K, R_wc=extrinsics[:, :3, :3].copy(), t_wc=extrinsics[:, :3, 3].copy(), notes=notes)
    depth_notes = {"depth_kind": "da3", "depth_rule": rule, "depth_native_hw": [h, w], "depth_resize": resize,
                   "depth_alignment": "none: DA3's depth and camera translations share one scale"}
    return DA3Output(Depth(depth=resize_depth(depth, (height, width), resize), notes=depth_notes), cameras)
