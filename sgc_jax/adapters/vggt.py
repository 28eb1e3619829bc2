"""VGGT cameras: ``extrinsic`` (S, 3, 4) world->camera and ``intrinsic`` (S, 3, 3) -> clip K, R_wc, t_wc.

VGGT's ``load_and_preprocess_images`` resizes every frame before the model sees it, so its
intrinsics live on that preprocessed grid, not on the video's:
- ``mode="crop"`` (VGGT's default): width 518, height round(H * 518 / W / 14) * 14, then the height is
  centre-cropped to 518 when larger (portrait videos);
- ``mode="pad"``: the longer side 518, the other round(. / 14) * 14, then padded to 518 x 518 (centred).
VGGT puts the principal point at the centre of that grid (W/2, H/2). :func:`read_vggt` maps K back
to the clip grid through the resize (pixel centres) and the crop or pad offset. The extrinsics are
OpenCV world->camera, as the clip format wants, and are used unchanged. VGGT's ``depth`` map (S, h, w, 1)
and ``depth_conf`` (S, h, w), when present, are kept on the preprocessed grid (:class:`VGGTDepth`) for
:mod:`.depth_alignment`; they share the units of the extrinsics' translations.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from ..io.npz import shape_text
from .common import EstimatorFormatError, camera_arrays, load_arrays, map_intrinsics, resize_factors, squeeze_batch

VGGT_SIZE = 518  # VGGT's target width (crop) or longer side (pad)
PATCH = 14  # VGGT's patch size: preprocessed sides are multiples of it
MODES = ("crop", "pad")
_PRINCIPAL_POINT_TOL_PX = 2.0  # VGGT writes cx = W/2, cy = H/2 exactly; float32 noise is far below this


@dataclasses.dataclass(frozen=True)
class VGGTGrid:
    """Where ``load_and_preprocess_images`` puts an H x W frame: preprocessed size and the map
    u_pre = (u + 0.5) * scale_x - 0.5 + offset_x (likewise v) from frame to preprocessed pixels."""

    height: int  # preprocessed grid
    width: int
    scale_x: float
    scale_y: float
    offset_x: int  # pad (> 0) or crop (< 0) offset in preprocessed pixels
    offset_y: int
    mode: str

    def to_frame(self) -> tuple[float, float, float, float]:
        """(a_x, b_x, a_y, b_y): u_frame = a_x u_pre + b_x, the inverse of the preprocessing."""
        a_x, a_y = 1.0 / self.scale_x, 1.0 / self.scale_y
        return a_x, (0.5 - self.offset_x) * a_x - 0.5, a_y, (0.5 - self.offset_y) * a_y - 0.5


def vggt_grid(height: int, width: int, mode: str = "crop") -> VGGTGrid:
    """The preprocessed grid of an H x W frame, following VGGT's ``load_and_preprocess_images``."""
    if mode not in MODES:
        raise ValueError(f"VGGT mode must be one of {MODES}, got {mode!r}")
    if mode == "crop" or width >= height:
        new_w = VGGT_SIZE
        new_h = round(height * (new_w / width) / PATCH) * PATCH
    else:
        new_h = VGGT_SIZE
        new_w = round(width * (new_h / height) / PATCH) * PATCH
    if mode == "crop":
        crop = (new_h - VGGT_SIZE) // 2 if new_h > VGGT_SIZE else 0
        return VGGTGrid(min(new_h, VGGT_SIZE), new_w, new_w / width, new_h / height, 0, -crop, mode)
    pad_top, pad_left = (VGGT_SIZE - new_h) // 2, (VGGT_SIZE - new_w) // 2
    return VGGTGrid(VGGT_SIZE, VGGT_SIZE, new_w / width, new_h / height, pad_left, pad_top, mode)


@dataclasses.dataclass
class VGGTDepth:
    """VGGT's depth (S, h, w) float32 on its preprocessed ``grid`` (<= 0 or non-finite: none), in the
    units of its camera translations, and ``conf`` (S, h, w) or None; ``frame_hw``: the frames VGGT saw."""

    depth: np.ndarray
    conf: np.ndarray | None
    grid: VGGTGrid
    frame_hw: tuple[int, int]


@dataclasses.dataclass
class Cameras:
    """Per-frame K (T, 3, 3) on the clip grid, world->camera R_wc (T, 3, 3), t_wc (T, 3), and VGGT's
    depth when it was asked for and the file has one."""

    K: np.ndarray
    R_wc: np.ndarray
    t_wc: np.ndarray
    notes: dict[str, Any]
    depth: VGGTDepth | None = None


def _images_hw(images: np.ndarray) -> tuple[int, int] | None:
    """(h, w) of VGGT's preprocessed ``images`` array ((S, 3, h, w), (S, h, w, 3), optional B=1)."""
    images = squeeze_batch(images, 4)
    if images.ndim != 4:
        return None
    if images.shape[1] == 3:
        return int(images.shape[2]), int(images.shape[3])
    if images.shape[3] == 3:
        return int(images.shape[1]), int(images.shape[2])
    return None


def read_vggt(source: Any, *, height: int, width: int, mode: str = "crop",
              source_size: tuple[int, int] | None = None, reference_compat: bool = False,
              with_depth: bool = False) -> Cameras:
    """VGGT ``predictions.npz`` (or a mapping with ``extrinsic``/``intrinsic``) -> clip cameras.

    ``height, width``: the clip grid. ``source_size``: (H, W) of the frames given to VGGT, when they
    differ from the clip grid. ``reference_compat``: keep K on VGGT's 518-px grid, unscaled, as the
    SGC authors' pipeline did (the paper calibration assumes it). ``with_depth``: also read ``depth``
    and ``depth_conf`` when the file has them (``Cameras.depth``; None otherwise).
    """
    label, arrays = load_arrays(source, "<vggt arrays>")
    for name, expected in (("extrinsic", "(S, 3, 4) world-to-camera [R | t]"),
                           ("intrinsic", "(S, 3, 3) on VGGT's preprocessed grid")):
        if name not in arrays:
            fix = "save VGGT's predictions['extrinsic'] and ['intrinsic'] (demo_gradio's predictions.npz has both)"
            if "pose_enc" in arrays:
                fix = ("convert with vggt.utils.pose_enc.pose_encoding_to_extri_intri(pose_enc, images.shape[-2:]) "
                       "and save 'extrinsic' and 'intrinsic'")
            raise EstimatorFormatError(label, name, expected, f"no such array (found {sorted(arrays)})", fix)
    extrinsic, intrinsic = camera_arrays(label, arrays, ("extrinsic", "intrinsic"))
    S = extrinsic.shape[0]

    frame_hw = tuple(source_size) if source_size else (height, width)
    grid = vggt_grid(frame_hw[0], frame_hw[1], mode)
    if "images" in arrays:
        found = _images_hw(np.asarray(arrays["images"]))
        if found is not None and found != (grid.height, grid.width):
            raise EstimatorFormatError(
                label, "images", f"{grid.height}x{grid.width} (VGGT {mode} mode of {frame_hw[0]}x{frame_hw[1]} frames)",
                f"{found[0]}x{found[1]}", _grid_fix(found, frame_hw, mode))
    principal = intrinsic[:, :2, 2].mean(0)
    centre = np.array([grid.width / 2.0, grid.height / 2.0])
    if np.abs(principal - centre).max() > _PRINCIPAL_POINT_TOL_PX:
        implied = (int(round(2 * principal[1])), int(round(2 * principal[0])))
        raise EstimatorFormatError(
            label, "intrinsic",
            f"principal point ({centre[0]:.1f}, {centre[1]:.1f}), the centre of VGGT's {grid.height}x{grid.width} grid "
            f"({mode} mode of {frame_hw[0]}x{frame_hw[1]} frames)",
            f"({principal[0]:.1f}, {principal[1]:.1f}), the centre of a {implied[0]}x{implied[1]} grid",
            _grid_fix(implied, frame_hw, mode))

    notes: dict[str, Any] = {"vggt_mode": mode, "vggt_grid": [grid.height, grid.width],
                             "vggt_frames": list(frame_hw)}
    if reference_compat:
        K = intrinsic.copy()
        notes["intrinsics"] = "VGGT 518-px grid, not rescaled (reference-compat)"
    else:
        a_x, b_x, a_y, b_y = grid.to_frame()
        K = map_intrinsics(intrinsic, a_x, b_x, a_y, b_y)
        if frame_hw != (height, width):
            K = map_intrinsics(K, *resize_factors(frame_hw, (height, width)))
        notes["intrinsics"] = f"rescaled from VGGT's {grid.height}x{grid.width} grid to {height}x{width}"
    depth = _read_depth(label, arrays, grid, frame_hw, S) if with_depth and "depth" in arrays else None
    return Cameras(K=K, R_wc=extrinsic[:, :3, :3].copy(), t_wc=extrinsic[:, :3, 3].copy(), notes=notes, depth=depth)


def _read_depth(label: str, arrays: dict[str, np.ndarray], grid: VGGTGrid, frame_hw: tuple[int, int],
                n_frames: int) -> VGGTDepth:
    """``depth`` (S, h, w, 1) or (S, h, w) and optional ``depth_conf`` (S, h, w), batch axis of 1 allowed."""
    expected = f"({n_frames}, {grid.height}, {grid.width}[, 1]) on VGGT's {grid.mode}-mode grid, one map per extrinsic"
    found = {}
    for name in ("depth", "depth_conf"):
        if name not in arrays:
            continue
        maps = np.asarray(arrays[name])
        if maps.ndim == 5 or (maps.ndim == 4 and maps.shape[-1] != 1):  # (1, S, h, w[, 1])
            maps = squeeze_batch(maps, maps.ndim - 1)
        maps = maps[..., 0] if maps.ndim == 4 and maps.shape[-1] == 1 else maps
        if maps.shape != (n_frames, grid.height, grid.width):
            same_count = maps.ndim == 3 and maps.shape[0] == n_frames
            fix = _grid_fix(maps.shape[1:3], frame_hw, grid.mode) if same_count else ""
            raise EstimatorFormatError(label, name, expected, f"shape {shape_text(np.shape(arrays[name]))}", fix)
        if not np.issubdtype(maps.dtype, np.number):
            raise EstimatorFormatError(label, name, "numeric maps", f"dtype {maps.dtype}")
        found[name] = maps.astype(np.float32, copy=False)
    return VGGTDepth(depth=found["depth"], conf=found.get("depth_conf"), grid=grid, frame_hw=tuple(frame_hw))


def _grid_fix(found_hw: tuple[int, int], frame_hw: tuple[int, int], mode: str) -> str:
    """Which mode or frame size explains a preprocessed grid of ``found_hw`` (sizes implied by a
    principal point are only known to a pixel or two)."""
    tol = 2 * _PRINCIPAL_POINT_TOL_PX
    other = "pad" if mode == "crop" else "crop"
    alt = vggt_grid(frame_hw[0], frame_hw[1], other)
    if abs(alt.height - found_hw[0]) <= tol and abs(alt.width - found_hw[1]) <= tol:
        return f"VGGT ran in {other!r} mode: pass mode={other!r} (CLI: --vggt-mode {other})"
    if abs(max(found_hw) - VGGT_SIZE) <= tol:
        return ("VGGT saw frames of another size or aspect ratio: pass their size as source_size=(H, W) "
                "(CLI: --vggt-source-size HxW)")
    return (f"these intrinsics are not on a VGGT preprocessed grid (one side {VGGT_SIZE}): if K is already on "
            "the clip grid, store it as the clip's K instead of importing it as VGGT output")
