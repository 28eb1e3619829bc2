"""Build one clip from the estimators' outputs (and optional frames), on one pixel grid.

Depth and cameras come from VGGT (cameras) with Video Depth Anything (depth), or both from one
Depth Anything 3 file; tracks from DELTA or CoTracker3; masks from SegAnyMo. The clip grid is
``size`` when given, else the frames' size, else the masks' size, else the depth maps' size.
Every piece is brought to that grid by its estimator's own rule (see each module); tracks are
assumed to be on it unless ``track_size`` says where the tracker ran. Relative (disparity) depth
is fitted to VGGT's depth map when the cameras file has one (:mod:`.depth_alignment`).
"""

from __future__ import annotations

import dataclasses
import os
import warnings
from typing import Any

import numpy as np

from ..config import SGCConfig
from ..io.arrays import clip_from_arrays
from ..io.checks.cameras import focal_spread
from ..io.clip import Clip
from ..io.depth_edges import check_edge_ratio, without_ramps
from .common import DEPTH_RESIZES, parse_size, resize_frames, resize_points
from .cotracker import holds_cotracker, read_cotracker
from .delta import DELTA_VIS_THRESHOLD, Tracks, every_nth_frame, read_delta
from .depth_alignment import align_depth_to_vggt
from .depth_anything_3 import read_da3, read_da3_hw
from .frames import read_frames
from .line_tracks import STRUCTURE_WINDOW_PX, leave_out_line_tracks
from .seganymo import grow_moving, read_mask_hw, read_seganymo
from .vggt import read_vggt
from .video_depth_anything import Depth, read_depth_hw, read_video_depth

# Per-frame focal lengths spread more than this (RMS of their log) may be a zoom rather than an estimator's
# scatter, whose harm bench/unseen_scenes.py --focal-jitter measures from 0.5-1 % on (§1.5): the import
# then warns that one K is used.
ZOOM_SPREAD = 0.03


class IntrinsicsWarning(UserWarning):
    """The per-frame K an estimator gave spread like a zoom's, and one K was used for the clip."""


def _label(source: Any) -> str:
    return os.fspath(source) if isinstance(source, (str, os.PathLike)) else "<arrays>"


@dataclasses.dataclass(frozen=True)
class ImportOptions:
    """How estimator outputs are read and brought to the clip grid (docs/semantics.md §1.5)."""

    depth_kind: str | None = None  # "disparity" (relative VDA models) or "metric"; required unless reference_compat
    depth_scale: float | None = None  # depth = scale / disparity, or scale * metric (default 1)
    depth_key: str = "depths"  # array name in the depth file
    size: tuple[int, int] | str | None = None  # clip grid HxW (default: frames, else masks, else depth)
    vggt_mode: str = "crop"  # VGGT's load_and_preprocess_images mode: "crop" or "pad"
    vggt_source_size: tuple[int, int] | str | None = None  # HxW of the frames VGGT saw, when not the clip grid
    track_size: tuple[int, int] | str | None = None  # HxW of the frames DELTA saw, when not the clip grid
    vis_threshold: float | None = None  # visibility above this is visible (None: the tracker's own, DELTA 0.8, CoTracker3 0.6)
    da3_min_conf: float | None = None  # Depth Anything 3: depth of conf below this is invalid (None: all kept)
    reference_compat: bool = False  # the SGC authors' pipeline (K at 518 px, depth = VDA / 1000, no threshold)
    align_depth: bool = True  # fit the disparity's scale and shift to VGGT's depth
    line_ratio: float | None = None  # leave out the tracks that start on a line (§1.7; needs frames); None: keep all
    frame_step: int = 1  # keep frames 0, k, 2k, ...: pairs k frames apart (§1.5; needs long-range tracks)
    max_depth: float | None = None  # depth beyond this (the clip's units) is invalid: a sky (§3.1); None: all kept
    depth_edge_ratio: float | None = None  # ramps at edges whose 3x3 neighbourhood spans more: invalid (§3.6)
    per_frame_intrinsics: bool = False  # keep the estimator's K per frame (a zoom); default one K, their median (§1.5)
    mask_grow_px: int = 0  # grow each frame's moving-object mask by this many px (§1.5, "Motion masks"; needs masks)
    depth_resize: str = "nearest"  # depth maps smaller than the grid: "nearest" or "bilinear" (§1.5, "Depth maps of another size")

    @property
    def fits_disparity(self) -> bool:
        """The disparity is fitted to VGGT's depth map (which the cameras file must then hold)."""
        return self.align_depth and self.depth_kind == "disparity" and not self.reference_compat


def _same_frame_counts(counts: dict[str, int | None]) -> None:
    """Raise unless every estimator output given (count not None) has as many frames."""
    counts = {name: n for name, n in counts.items() if n is not None}
    if len(set(counts.values())) != 1:
        listing = ", ".join(f"{k}: {v}" for k, v in counts.items())
        raise ValueError(f"the estimator outputs disagree on the number of frames ({listing}); "
                         "run every estimator on the same frames (e.g. the same --target_fps / --max_len)")


def read_tracks(source: Any, *, frame_names: list[str] | None = None, vis_threshold: float | None = None,
                reference_compat: bool = False) -> Tracks:
    """DELTA (a folder of per-pair files, or dense coords/vis/conf) or CoTracker3 (pred_tracks and
    pred_visibility in an .npz, .pt or .npy) tracks, told apart by the file's suffix and names."""
    if not (isinstance(source, (str, os.PathLike)) and os.path.isdir(source)) and holds_cotracker(source):
        return read_cotracker(source, vis_threshold=vis_threshold)
    return read_delta(source, frame_names=frame_names, reference_compat=reference_compat,
                      vis_threshold=DELTA_VIS_THRESHOLD if vis_threshold is None else vis_threshold)


def _check_depth_sources(cameras: Any, depth: Any, da3: Any, o: ImportOptions) -> None:
    if da3 is not None and (cameras is not None or depth is not None or o.depth_kind is not None):
        raise ValueError("a Depth Anything 3 file (da3=, CLI --da3) gives depth and cameras: drop --cameras, --depth "
                         "and --depth-kind (cameras=, depth=, depth_kind=), or drop --da3")
    if da3 is None and (cameras is None or depth is None):
        raise ValueError("depth and cameras are needed: da3= (CLI --da3, Depth Anything 3's results.npz), or "
                         "cameras= and depth= (CLI --cameras, --depth: VGGT and Video Depth Anything)")
    if da3 is not None and o.reference_compat:
        raise ValueError("reference-compat reproduces the authors' VGGT + Video Depth Anything pipeline; "
                         "a Depth Anything 3 clip is scored with the default semantics")


def _check_options(o: ImportOptions, has_masks: bool) -> None:
    """Raise on a frame step, a depth limit or a mask growth that cannot be applied."""
    if o.max_depth is not None and not (np.isfinite(o.max_depth) and o.max_depth > 0):
        raise ValueError(f"max_depth must be a depth > 0 in the clip's units, got {o.max_depth!r}")
    if o.depth_edge_ratio is not None:
        check_edge_ratio(o.depth_edge_ratio)
    if isinstance(o.frame_step, bool) or not isinstance(o.frame_step, (int, np.integer)) or o.frame_step < 1:
        raise ValueError(f"frame_step must be a whole number >= 1 (1: every frame), got {o.frame_step!r}")
    if isinstance(o.mask_grow_px, bool) or not isinstance(o.mask_grow_px, (int, np.integer)) or o.mask_grow_px < 0:
        raise ValueError(f"mask_grow_px must be a whole number of pixels >= 0, got {o.mask_grow_px!r}")
    if o.mask_grow_px and not has_masks:
        raise ValueError("growing the moving-object masks (--mask-grow) needs masks (--masks)")
    if o.depth_resize not in DEPTH_RESIZES:
        raise ValueError(f"depth_resize must be one of {DEPTH_RESIZES}, got {o.depth_resize!r}")
    if o.depth_resize != "nearest" and o.reference_compat:
        raise ValueError("reference-compat reproduces the authors' pipeline, which brings depth to the grid by "
                         "nearest neighbour: drop --depth-resize or --reference-compat")
    if o.frame_step > 1 and o.reference_compat:
        raise ValueError("reference-compat reproduces the authors' pipeline, which pairs consecutive frames: "
                         "drop the frame step (--frame-step) or --reference-compat")


def _kept_frames(n_frames: int, step: int) -> np.ndarray:
    """Frames 0, step, 2 step, ... of ``n_frames`` (every frame at step 1); at least two."""
    kept = np.arange(0, n_frames, step)
    if len(kept) < 2:
        raise ValueError(f"a frame step of {step} keeps {len(kept)} of the {n_frames} frames; a clip needs 2")
    return kept


def _depth_and_cameras(cameras: Any, depth: Any, da3: Any, grid: tuple[int, int], o: ImportOptions):
    """(Cameras, Depth) on the clip grid: both from one DA3 file, or VGGT's and VDA's."""
    H, W = grid
    if da3 is not None:
        read = read_da3(da3, height=H, width=W, min_conf=o.da3_min_conf, resize=o.depth_resize)
        return read.cameras, read.depth
    cams = read_vggt(cameras, height=H, width=W, mode=o.vggt_mode, source_size=o.vggt_source_size,
                     reference_compat=o.reference_compat, with_depth=o.fits_disparity)
    return cams, read_video_depth(depth, height=H, width=W, kind=o.depth_kind, depth_scale=o.depth_scale,
                                  key=o.depth_key, reference_compat=o.reference_compat, resize=o.depth_resize)


def import_clip(*, tracks: Any, cameras: Any = None, depth: Any = None, da3: Any = None, masks: Any = None,
                frames: Any = None, clip_id: str | None = None, group: str = "", meta: dict | None = None,
                options: ImportOptions | None = None, **option_fields: Any) -> Clip:
    """VGGT ``cameras`` with Video Depth Anything ``depth``, or Depth Anything 3 ``da3`` (both from
    one file); DELTA or CoTracker3 ``tracks``; SegAnyMo ``masks`` -> a Clip.

    Paths or mappings of arrays (see :mod:`sgc_jax.adapters`); ``options`` (or its fields as
    keywords, e.g. ``depth_kind="disparity"``): an ImportOptions. ``reference_compat`` reproduces
    the SGC authors' pipeline so the paper calibration applies; ``align_depth``, with
    ``depth_kind="disparity"`` and a ``depth`` map in the VGGT file, fits the disparity's scale and
    shift to it so depth and cameras share units; ``line_ratio`` (with ``frames``) leaves out the tracks
    that start on a line (docs/semantics.md §1.7); ``frame_step`` K keeps frames 0, K, 2K, ... and
    pairs them K apart (long-range tracks only, §1.5). Every choice is recorded in ``meta["import"]``;
    the clip is validated like a loaded one (problems raise or warn).
    """
    o = dataclasses.replace(options or ImportOptions(), **option_fields)
    o = dataclasses.replace(o, size=parse_size(o.size), vggt_source_size=parse_size(o.vggt_source_size),
                            track_size=parse_size(o.track_size))
    _check_depth_sources(cameras, depth, da3, o)
    _check_options(o, masks is not None)
    if o.line_ratio is not None and frames is None:
        raise ValueError("leaving out the tracks on lines (--leave-out-line-tracks) reads the frames: give them (--frames)")
    loaded_frames = read_frames(frames) if frames is not None else None
    names = loaded_frames.names if loaded_frames is not None else None
    H, W = o.size or (loaded_frames.frames.shape[1:3] if loaded_frames is not None
                      else read_mask_hw(masks) or (read_da3_hw(da3) if da3 is not None
                                                   else read_depth_hw(depth, o.depth_key)))
    H, W = int(H), int(W)

    track_data = read_tracks(tracks, frame_names=names, vis_threshold=o.vis_threshold,
                             reference_compat=o.reference_compat)
    names = names or track_data.frame_names
    cams, depth_data = _depth_and_cameras(cameras, depth, da3, (H, W), o)
    T = depth_data.depth.shape[0]
    mask_data = grow_moving(read_seganymo(masks, height=H, width=W, frame_names=names, n_frames=T), int(o.mask_grow_px))
    depth_label = f"depth and cameras ({_label(da3)})" if da3 is not None else f"depth ({_label(depth)})"
    _same_frame_counts({f"cameras ({_label(cameras)})": None if da3 is not None else len(cams.K),
                        depth_label: T, f"tracks ({_label(tracks)})": track_data.n_frames,
                        f"masks ({_label(masks)})": None if mask_data.static_mask is None else len(mask_data.static_mask),
                        f"frames ({_label(frames)})": None if loaded_frames is None else len(loaded_frames.frames)})
    if da3 is None:
        depth_data = align_depth_to_vggt(depth_data, cams.depth, static_mask=mask_data.static_mask,
                                         enabled=o.align_depth)
    depth_data = _depth_left_out(depth_data, o)

    kept = _kept_frames(T, o.frame_step)
    if o.frame_step > 1:
        track_data = every_nth_frame(track_data, o.frame_step)
    track_prev, track_curr = track_data.track_prev, track_data.track_curr
    if o.track_size is not None:
        track_prev = resize_points(track_prev, o.track_size, (H, W))
        track_curr = resize_points(track_curr, o.track_size, (H, W))
    K, cams.notes["intrinsics"] = _clip_intrinsics(cams.K[kept] if cams.K.ndim == 3 else cams.K, cams.notes["intrinsics"], o)
    arrays: dict[str, Any] = dict(depth=depth_data.depth[kept], K=K, R_wc=cams.R_wc[kept], t_wc=cams.t_wc[kept],
                                  track_prev=track_prev, track_curr=track_curr,
                                  track_vis=track_data.track_vis, track_conf=track_data.track_conf)
    if mask_data.static_mask is not None:
        arrays["static_mask"] = mask_data.static_mask[kept]
    if loaded_frames is not None:
        arrays["frames"] = resize_frames(loaded_frames.frames[kept], (H, W))

    record = {"reference_compat": bool(o.reference_compat), "grid": [H, W],
              "sources": {"cameras": _label(da3 if da3 is not None else cameras),
                          "depth": _label(da3 if da3 is not None else depth), "tracks": _label(tracks),
                          "masks": None if masks is None else _label(masks),
                          "frames": None if frames is None else _label(frames)},
              **cams.notes, **depth_data.notes, **track_data.notes, **mask_data.notes}
    if o.track_size is not None:
        record["track_size"] = list(o.track_size)
    if o.frame_step > 1:
        record["frame_step"] = {"step": o.frame_step, "frames_kept": len(kept), "of": T}
    clip_meta = {**(meta or {}), "import": record}
    if group:
        clip_meta["group"] = group
    clip_id = clip_id or clip_meta.get("clip_id") or "clip"
    clip_meta["clip_id"] = clip_id
    arrays["meta"] = clip_meta
    keep_all = SGCConfig(max_tracks=max(track_prev.shape[1], 1))
    clip = clip_from_arrays(arrays, clip_id=clip_id, config=keep_all)
    return clip if o.line_ratio is None else _without_line_tracks(clip, o.line_ratio)


def _clip_intrinsics(K: np.ndarray, note: str, o: ImportOptions) -> tuple[np.ndarray, str]:
    """(K for the clip, its note): one K in every frame, the median of each entry over the frames, unless the
    per-frame estimates are kept (``per_frame_intrinsics``, ``reference_compat``). An estimator's focal
    lengths scatter from frame to frame, and the depth check reads a focal change between two frames as
    depth disagreement; one K off by a constant factor costs little (§1.5, "One K for a clip")."""
    if K.ndim == 2 or o.per_frame_intrinsics or o.reference_compat:
        return K, note
    spread = focal_spread(K)
    shared = np.repeat(np.median(K.astype(np.float64), axis=0, keepdims=True), len(K), axis=0).astype(K.dtype)
    note = f"{note}; one K for the clip, the median of {len(K)} frames' (focal lengths spread {100 * spread:.2f} % RMS)"
    if spread > ZOOM_SPREAD:
        warnings.warn(IntrinsicsWarning(
            f"the per-frame focal lengths spread {100 * spread:.1f} % RMS: if the video zooms, keep them "
            "(--per-frame-intrinsics); one K, their median, is used"), stacklevel=3)
    return shared, note


def _depth_left_out(depth: Depth, o: ImportOptions) -> Depth:
    """``depth`` with values beyond ``max_depth`` (a sky, §3.1), then those on ramps at edges spanning
    more than ``depth_edge_ratio`` (an enlarged network's, §3.6), set to 0, invalid; each share of the
    valid depth recorded in its notes."""
    values, notes = depth.depth, dict(depth.notes)
    if o.max_depth is not None:
        beyond = values > o.max_depth
        share = int(beyond.sum()) / max(int(np.count_nonzero(values > 0)), 1)
        notes["max_depth"] = {"limit": float(o.max_depth), "invalid_frac": round(share, 4)}
        values = np.where(beyond, 0, values).astype(values.dtype)
    if o.depth_edge_ratio is not None:
        values, share = without_ramps(values, o.depth_edge_ratio)
        notes["depth_ramps"] = {"ratio": float(o.depth_edge_ratio), "invalid_frac": round(share, 4)}
    return depth if values is depth.depth else dataclasses.replace(depth, depth=values, notes=notes)


def _without_line_tracks(clip: Clip, max_ratio: float) -> Clip:
    """The imported clip with its line-like tracks left out (§1.7), the share recorded in meta."""
    out = leave_out_line_tracks(clip, max_ratio)
    visible = int(clip.track_vis.sum())
    left_out = 1.0 - int(out.track_vis.sum()) / visible if visible else 0.0
    record = {**clip.meta["import"], "line_tracks": {"max_ratio": float(max_ratio), "window_px": STRUCTURE_WINDOW_PX,
                                                     "left_out": round(left_out, 4)}}
    return dataclasses.replace(out, meta={**clip.meta, "import": record})
