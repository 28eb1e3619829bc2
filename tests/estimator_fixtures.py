"""Write a synthetic clip as the four estimators write their outputs, each at its own resolution.

These writers follow the estimators' code, not sgc_jax.adapters, so that the adapters are tested
against an independent statement of each format:
- VGGT (facebookresearch/vggt, load_fn.load_and_preprocess_images + demo predictions.npz):
  ``extrinsic`` (S, 3, 4) world->camera, ``intrinsic`` (S, 3, 3) on the preprocessed grid,
  ``images`` (S, 3, h, w); crop mode: width 518, height round(H * 518 / W / 14) * 14, centre crop
  to 518; pad mode: longer side 518, padded to 518 x 518. Resizing is PIL's (pixel centres).
  Optionally ``depth`` (S, h, w, 1) and ``depth_conf`` (S, h, w) (= 1 + exp(.)) on the same grid, in
  the units of the translations (VGGT's normalised scene scale: here the scene times a factor).
- Video Depth Anything (run.py --save_npz): ``depths`` (T, h, w) float32 in ``*_depths.npz``;
  relative models give affine-invariant inverse depth (here gain / depth + shift).
- DELTA as in the SGC authors' pipeline (gen_data.py): ``{a}_{a}.npy`` / ``{a}_{b}.npy`` float32
  (N, 4) = x, y, vis, conf; dense: ``coords`` (T, N, 2), ``vis`` (T, N), ``conf`` (T, N).
- SegAnyMo / SAM2: DAVIS-style palette PNGs, index 0 = background, k = object k.
- Depth Anything 3 (ByteDance-Seed/Depth-Anything-3, export_to_npz): ``exports/npz/results.npz``
  with ``image`` (N, h, w, 3), ``depth`` (N, h, w), ``conf`` (N, h, w) rounded to 0.01,
  ``extrinsics`` (N, 3, 4) world->camera and ``intrinsics`` (N, 3, 3), all on the processed grid
  of ``upper_bound_resize``: longest side 504, each side a multiple of 14, no crop.
- CoTracker3 (facebookresearch/co-tracker predictors): ``pred_tracks`` (1, T, N, 2) in the input
  video's pixels, ``pred_visibility`` (1, T, N) bool (visibility x confidence > 0.6).
"""

from __future__ import annotations

import pickle
from pathlib import Path

import cv2
import numpy as np
from PIL import Image

from sgc_jax.io.clip import Clip

# DAVIS 2017 palette, first entries (index 0 black, then the usual object colours).
DAVIS_PALETTE = [0, 0, 0, 128, 0, 0, 0, 128, 0, 128, 128, 0, 0, 0, 128, 128, 0, 128, 0, 128, 128]


def frame_names(clip: Clip) -> list[str]:
    return [f"{t:05d}" for t in range(clip.n_frames)]


def vggt_preprocess(height: int, width: int, mode: str) -> tuple[int, int, float, float, float, float]:
    """(h_pre, w_pre, s_x, s_y, off_x, off_y) of VGGT's load_and_preprocess_images, restated."""
    target = 518
    if mode == "pad" and height > width:
        new_h, new_w = target, round(width * (target / height) / 14) * 14
    else:
        new_w, new_h = target, round(height * (target / width) / 14) * 14
    if mode == "crop":
        start_y = (new_h - target) // 2 if new_h > target else 0
        return min(new_h, target), new_w, new_w / width, new_h / height, 0.0, -float(start_y)
    pad_top, pad_left = (target - new_h) // 2, (target - new_w) // 2
    return target, target, new_w / width, new_h / height, float(pad_left), float(pad_top)


def vggt_intrinsics(K: np.ndarray, height: int, width: int, mode: str) -> tuple[np.ndarray, tuple[int, int]]:
    """K of an H x W frame as VGGT reports it on its preprocessed grid (pixel centres move by
    u_pre = (u + 0.5) * s - 0.5 + offset)."""
    h_pre, w_pre, s_x, s_y, off_x, off_y = vggt_preprocess(height, width, mode)
    A = np.array([[s_x, 0, 0.5 * s_x - 0.5 + off_x], [0, s_y, 0.5 * s_y - 0.5 + off_y], [0, 0, 1]])
    return A @ K, (h_pre, w_pre)


def write_vggt(path: Path, clip: Clip, mode: str = "crop", with_images: bool = True,
               depth: tuple[np.ndarray, np.ndarray | None] | None = None, units: float = 1.0) -> Path:
    """``depth``: (depth, depth_conf) on the preprocessed grid (see :func:`vggt_depth_maps`);
    ``units``: VGGT's scene scale, applied to the translations (the depth maps carry their own)."""
    H, W = clip.image_size
    intrinsic, (h_pre, w_pre) = vggt_intrinsics(clip.K, H, W, mode)
    extrinsic = np.concatenate([clip.R_wc, units * clip.t_wc[:, :, None]], axis=2)
    arrays = {"extrinsic": extrinsic.astype(np.float32), "intrinsic": intrinsic.astype(np.float32)}
    if with_images:
        arrays["images"] = np.zeros((clip.n_frames, 3, h_pre, w_pre), np.float32)
    if depth is not None:
        arrays["depth"] = depth[0].astype(np.float32)
        if depth[1] is not None:
            arrays["depth_conf"] = depth[1].astype(np.float32)
    np.savez_compressed(path, **arrays)
    return path


def to_vggt_grid(maps: np.ndarray, height: int, width: int, mode: str, fill: np.ndarray | float = 0.0) -> np.ndarray:
    """(T, H, W) maps of an H x W frame -> (T, h_pre, w_pre) as VGGT sees them: nearest resize to the
    resized size, then the centre crop or the padding (``fill``: the padding's values)."""
    h_pre, w_pre, s_x, s_y, off_x, off_y = vggt_preprocess(height, width, mode)
    resized = upsample_nearest(maps, (round(s_y * height), round(s_x * width)))
    out = np.broadcast_to(np.asarray(fill, maps.dtype), (len(maps), h_pre, w_pre)).copy()
    top, left = int(off_y), int(off_x)
    if top < 0:  # crop
        out[:] = resized[:, -top:-top + h_pre]
    else:
        out[:, top:top + resized.shape[1], left:left + resized.shape[2]] = resized
    return out


def vggt_depth_maps(clip: Clip, mode: str = "crop", *, units: float = 1.0, noise: float = 0.0,
                    outlier_frac: float = 0.0, moving_factor: float = 1.0, low_conf_frac: float = 0.0,
                    seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """VGGT-like (depth (S, h, w, 1), depth_conf (S, h, w)) of ``clip`` on the preprocessed grid:
    true depth times ``units``, times exp(N(0, noise)); ``outlier_frac`` of the pixels times a
    log-uniform factor in [1/3, 3] (half of them low-confidence); moving pixels (not static_mask)
    times ``moving_factor``; ``low_conf_frac`` of the others low-confidence. The padding (pad mode)
    holds confident garbage depth, as VGGT predicts some depth on the white border."""
    rng = np.random.default_rng(seed)
    H, W = clip.image_size
    depth = units * clip.depth.astype(np.float64) * np.exp(noise * rng.standard_normal(clip.depth.shape))
    depth = np.where(clip.static_mask, depth, moving_factor * depth)
    outlier = rng.random(depth.shape) < outlier_frac
    depth = np.where(outlier, depth * np.exp(rng.uniform(-np.log(3), np.log(3), depth.shape)), depth)
    low = np.where(outlier, rng.random(depth.shape) < 0.5, rng.random(depth.shape) < low_conf_frac)
    conf = 1.0 + np.exp(np.where(low, rng.normal(-2.0, 0.5, depth.shape), rng.normal(1.5, 0.5, depth.shape)))
    shape = (clip.n_frames,) + vggt_preprocess(H, W, mode)[:2]
    pad_depth = units * rng.uniform(0.5, 50.0, shape)
    return (to_vggt_grid(depth, H, W, mode, pad_depth)[..., None],
            to_vggt_grid(conf, H, W, mode, np.full(shape, 5.0)))


def upsample_nearest(maps: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """(T, h, w) -> (T, H, W) with H, W >= h, w, each output pixel taking the source pixel under its centre."""
    T, h, w = maps.shape
    rows = np.floor((np.arange(size[0]) + 0.5) * h / size[0]).astype(int)
    cols = np.floor((np.arange(size[1]) + 0.5) * w / size[1]).astype(int)
    return maps[:, rows[:, None], cols[None, :]]


def write_vda(path: Path, clip: Clip, size: tuple[int, int], kind: str = "disparity", scale: float = 1.0,
              shift: float = 0.0) -> Path:
    """VDA output at its own resolution ``size`` (here: the exact depth, nearest-upsampled); relative
    models: disparity = scale / depth + shift."""
    depth = upsample_nearest(clip.depth.astype(np.float64), size)
    valid = np.isfinite(depth) & (depth > 0)
    if kind == "disparity":
        values = np.where(valid, scale / np.where(valid, depth, 1.0) + shift, 0.0)
    else:
        values = np.where(valid, depth / scale, 0.0)
    np.savez_compressed(path, depths=values.astype(np.float32))
    return path


def delta_vis(visible: np.ndarray) -> np.ndarray:
    """DELTA-like visibility probabilities: high for visible points, low otherwise."""
    return np.where(visible, 0.97, 0.03).astype(np.float32)


def write_delta_pairs(directory: Path, clip: Clip, names: list[str] | None = None) -> Path:
    directory.mkdir(parents=True, exist_ok=True)
    names = names or frame_names(clip)
    for i in range(1, clip.n_frames):
        a, b = names[i - 1], names[i]
        P = clip.n_tracks
        query = np.c_[clip.track_prev[i - 1], np.full(P, 0.99), np.ones(P)].astype(np.float32)
        target = np.c_[clip.track_curr[i - 1], delta_vis(clip.track_vis[i - 1]), clip.track_conf[i - 1]]
        np.save(directory / f"{a}_{a}.npy", query)
        np.save(directory / f"{a}_{b}.npy", target.astype(np.float32))
    return directory


def write_delta_dense(path: Path, coords: np.ndarray, vis: np.ndarray, conf: np.ndarray) -> Path:
    """DELTA demo_2d.py's dense_2d_track.pkl (a pickled dict of arrays)."""
    with open(path, "wb") as handle:
        pickle.dump({"coords": coords, "vis": vis, "conf": conf}, handle, protocol=pickle.HIGHEST_PROTOCOL)
    return path


def object_labels(static_mask: np.ndarray) -> np.ndarray:
    """(T, H, W) uint8 ids: 0 static, k = k-th connected moving region (as SegAnyMo numbers objects)."""
    labels = np.zeros(static_mask.shape, np.uint8)
    for t, static in enumerate(static_mask):
        _, components = cv2.connectedComponents((~static).astype(np.uint8), connectivity=8)
        labels[t] = np.minimum(components, 255)
    return labels


def write_palette_png(path: Path, labels: np.ndarray, palette: list[int] | None = None) -> Path:
    image = Image.fromarray(labels.astype(np.uint8), mode="P")
    image.putpalette(palette or DAVIS_PALETTE)
    image.save(path)
    return path


def write_seganymo(directory: Path, clip: Clip, size: tuple[int, int], names: list[str] | None = None,
                   palette: list[int] | None = None) -> Path:
    directory.mkdir(parents=True, exist_ok=True)
    names = names or frame_names(clip)
    labels = upsample_nearest(object_labels(clip.static_mask), size)
    for name, frame in zip(names, labels):
        write_palette_png(directory / f"{name}.png", frame, palette)
    return directory


def write_frames(directory: Path, clip: Clip, names: list[str] | None = None) -> Path:
    directory.mkdir(parents=True, exist_ok=True)
    names = names or frame_names(clip)
    for name, frame in zip(names, clip.frames):
        cv2.imwrite(str(directory / f"{name}.png"), cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
    return directory


def write_all(root: Path, clip: Clip, *, vggt_mode: str = "crop", depth_size: tuple[int, int] | None = None,
              mask_size: tuple[int, int] | None = None, depth_scale: float = 1.0) -> dict[str, Path]:
    """Every estimator's output for ``clip`` under ``root``; returns the paths by input name."""
    H, W = clip.image_size
    root.mkdir(parents=True, exist_ok=True)
    return {
        "cameras": write_vggt(root / "predictions.npz", clip, vggt_mode),
        "depth": write_vda(root / "clip_depths.npz", clip, depth_size or (H, W), scale=depth_scale),
        "tracks": write_delta_pairs(root / "delta", clip),
        "masks": write_seganymo(root / "seganymo", clip, mask_size or (H, W)),
        "frames": write_frames(root / "frames", clip),
    }


def da3_processed_hw(height: int, width: int, process_res: int = 504) -> tuple[int, int]:
    """DA3's ``upper_bound_resize``: the longer side to ``process_res``, each side to a multiple of 14."""
    scale = process_res / max(height, width)
    return max(14, round(height * scale / 14) * 14), max(14, round(width * scale / 14) * 14)


def write_da3(path: Path, clip: Clip, *, units: float = 1.0, conf: np.ndarray | None = None,
              with_extrinsics: bool = True) -> Path:
    """DA3's results.npz of ``clip``: depth (times ``units``, as the translations) nearest-upsampled
    to the processed grid, K moved onto it through the resize (pixel centres)."""
    H, W = clip.image_size
    h, w = da3_processed_hw(H, W)
    s_x, s_y = w / W, h / H
    A = np.array([[s_x, 0, 0.5 * s_x - 0.5], [0, s_y, 0.5 * s_y - 0.5], [0, 0, 1]])
    depth = upsample_nearest(units * clip.depth.astype(np.float64), (h, w))
    arrays = {"image": np.zeros((clip.n_frames, h, w, 3), np.uint8), "depth": np.round(depth, 6).astype(np.float32),
              "conf": np.round(conf if conf is not None else np.full((clip.n_frames, h, w), 2.0), 2).astype(np.float32),
              "intrinsics": (A @ clip.K).astype(np.float32)}
    if with_extrinsics:
        arrays["extrinsics"] = np.concatenate([clip.R_wc, units * clip.t_wc[:, :, None]], axis=2).astype(np.float32)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, **arrays)
    return path


def write_cotracker(path: Path, tracks: np.ndarray, visibility: np.ndarray) -> Path:
    """CoTracker3's (pred_tracks (T, N, 2), pred_visibility (T, N)) with their batch axis, as .npz,
    .pt (torch.save of the tuple) or .npy (the tracks alone), by the suffix."""
    pred_tracks, pred_visibility = tracks[None].astype(np.float32), visibility[None]
    if path.suffix == ".pt":
        import torch

        torch.save((torch.from_numpy(pred_tracks), torch.from_numpy(pred_visibility)), path)
    elif path.suffix == ".npy":
        np.save(path, pred_tracks)
    else:
        np.savez_compressed(path, pred_tracks=pred_tracks, pred_visibility=pred_visibility)
    return path


def long_range_tracks_of(clip: Clip, n_tracks: int, seed: int = 0, occlusion_rel: float = 0.02
                         ) -> tuple[np.ndarray, np.ndarray]:
    """CoTracker-like (tracks (T, N, 2), visibility (T, N)) of a rigid ``clip``: static pixels of
    frame 0 (pixel centres, valid depth) back-projected and projected into every frame through the
    clip's own cameras; visible where in the image, in front, and within ``occlusion_rel`` of the
    depth map there (else occluded)."""
    rng = np.random.default_rng(seed)
    T, (H, W) = clip.n_frames, clip.image_size
    rows, cols = np.nonzero(clip.static_mask[0] & (clip.depth[0] > 0))
    pick = rng.choice(len(rows), size=min(n_tracks, len(rows)), replace=False)
    u, v = cols[pick].astype(np.float64), rows[pick].astype(np.float64)
    z = clip.depth[0][rows[pick], cols[pick]].astype(np.float64)
    cam0 = np.linalg.solve(clip.K[0], np.stack([u * z, v * z, z]))  # (3, N) in camera 0
    world = clip.R_wc[0].T @ (cam0 - clip.t_wc[0][:, None])
    tracks, visible = np.zeros((T, len(pick), 2)), np.zeros((T, len(pick)), bool)
    for t in range(T):
        cam = clip.R_wc[t] @ world + clip.t_wc[t][:, None]
        pix = clip.K[t] @ cam
        x, y = pix[0] / pix[2], pix[1] / pix[2]
        tracks[t] = np.stack([x, y], -1)
        inside = (cam[2] > 0) & (x > -0.5) & (x < W - 0.5) & (y > -0.5) & (y < H - 0.5)
        r, c = np.clip(np.round(y).astype(int), 0, H - 1), np.clip(np.round(x).astype(int), 0, W - 1)
        seen = clip.depth[t][r, c]
        visible[t] = inside & (np.abs(seen - cam[2]) < occlusion_rel * cam[2])
    return tracks.astype(np.float32), visible
