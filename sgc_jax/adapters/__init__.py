"""Estimator outputs -> clip files (docs/semantics.md §1): one reader per estimator, and :func:`import_clip`.

- :func:`read_vggt`: VGGT ``extrinsic`` / ``intrinsic`` (``predictions.npz``), K mapped from VGGT's
  preprocessed 518-px grid (crop or pad mode) to the clip grid.
- :func:`read_video_depth`: Video Depth Anything ``depths`` (``*_depths.npz``), ``kind="disparity"``
  (relative models) or ``"metric"``, resized to the clip grid.
- :func:`align_depth_to_vggt`: relative disparity -> depth in VGGT's camera units, by a robust fit of
  its scale and shift to VGGT's ``depth`` map.
- :func:`read_da3`: Depth Anything 3's ``results.npz``: depth, world->camera extrinsics and K
  from one model, mapped from DA3's processed grid to the clip grid.
- :func:`read_delta`: DELTA per-pair ``{a}_{a}.npy`` / ``{a}_{b}.npy`` files or dense
  ``coords`` / ``vis`` / ``conf`` arrays.
- :func:`read_cotracker`: CoTracker3 ``pred_tracks`` / ``pred_visibility`` (.npz, .pt or .npy).
- :func:`every_nth_frame`: pairs of frames a step apart from long-range tracks (``frame_step``).
- :func:`read_seganymo`: SegAnyMo palette PNG masks (indices, 0 = static).
- :func:`read_frames`: a frames folder or a video file.
- :func:`leave_out_line_tracks`: an opt-in step before scoring, the tracks that start on a line
  (which a tracker can slide along) made unusable, from the clip's frames (§1.7).
- :func:`leave_out_depth_ramps`: an opt-in step before scoring, the depth at edges made invalid,
  where a depth network's enlarged output puts ramps of points on no surface (§3.6).
- :func:`resize_depth`: depth maps brought to another grid, those smaller than it bilinearly within
  valid depth (§1.5, "Depth maps of another size").
"""

from .assemble import ImportOptions, IntrinsicsWarning, import_clip, read_tracks
from .common import DEPTH_RESIZES, EstimatorFormatError, resize_depth
from .cotracker import COTRACKER_VIS_THRESHOLD, read_cotracker
from .delta import (
    DELTA_VIS_THRESHOLD,
    LongRangeTracks,
    Tracks,
    every_nth_frame,
    read_delta,
    read_delta_dense,
    read_delta_pairs,
)
from .depth_alignment import DepthAlignmentWarning, DisparityFit, align_depth_to_vggt, fit_inverse_depth_affine
from .depth_anything_3 import DA3Output, read_da3
from .depth_ramps import DEPTH_EDGE_RATIO, leave_out_depth_ramps
from .frames import Frames, read_frames
from .line_tracks import LINE_RATIO, leave_out_line_tracks, line_structure
from .seganymo import MaskFormatWarning, Masks, grow_moving, read_mask_labels, read_seganymo
from .vggt import Cameras, VGGTDepth, VGGTGrid, read_vggt, vggt_grid
from .video_depth_anything import KINDS as DEPTH_KINDS, Depth, read_video_depth

__all__ = [
    "ImportOptions", "COTRACKER_VIS_THRESHOLD", "Cameras", "DA3Output", "DELTA_VIS_THRESHOLD", "DEPTH_EDGE_RATIO",
    "DEPTH_KINDS", "DEPTH_RESIZES", "Depth", "DepthAlignmentWarning", "DisparityFit", "EstimatorFormatError", "Frames",
    "IntrinsicsWarning", "LINE_RATIO", "LongRangeTracks", "MaskFormatWarning", "Masks", "Tracks", "VGGTDepth",
    "VGGTGrid", "align_depth_to_vggt", "every_nth_frame", "fit_inverse_depth_affine", "grow_moving", "import_clip",
    "leave_out_depth_ramps", "leave_out_line_tracks", "line_structure", "read_cotracker", "read_da3",
    "read_delta", "read_delta_dense", "read_delta_pairs", "read_frames", "read_mask_labels", "read_seganymo",
    "read_tracks", "read_vggt", "read_video_depth", "resize_depth", "vggt_grid",
]
