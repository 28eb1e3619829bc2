"""Estimator outputs -> clip files (docs/semantics.md §1): one reader per estimator, and :func:`import_clip`.

- :func:`read_vggt`: VGGT ``extrinsic`` / ``intrinsic`` (``predictions.npz``), K mapped from VGGT's
  preprocessed 518-px grid (crop or pad mode) to the clip grid.
- :func:`read_video_depth`: Video Depth Anything ``depths`` (``*_depths.npz``), ``kind="disparity"``
  (relative models) or ``"metric"``, resized to the clip grid.
- :func:`align_depth_to_vggt`: relative disparity -> depth in VGGT's camera units, by a robust fit of
  its scale and shift to VGGT's ``depth`` map.
- :func:`read_delta`: DELTA per-pair ``{a}_{a}.npy`` / ``{a}_{b}.npy`` files or dense
  ``coords`` / ``vis`` / ``conf`` arrays.
- :func:`read_seganymo`: SegAnyMo palette PNG masks (indices, 0 = static).
- :func:`read_frames`: a frames folder or a video file.
"""

from .assemble import ImportOptions, import_clip
from .common import EstimatorFormatError
from .delta import DELTA_VIS_THRESHOLD, Tracks, read_delta, read_delta_dense, read_delta_pairs
from .depth_alignment import DepthAlignmentWarning, DisparityFit, align_depth_to_vggt, fit_inverse_depth_affine
from .frames import Frames, read_frames
from .seganymo import MaskFormatWarning, Masks, read_mask_labels, read_seganymo
from .vggt import Cameras, VGGTDepth, VGGTGrid, read_vggt, vggt_grid
from .video_depth_anything import KINDS as DEPTH_KINDS, Depth, read_video_depth

__all__ = [
    "ImportOptions", "Cameras", "DELTA_VIS_THRESHOLD", "DEPTH_KINDS", "Depth", "DepthAlignmentWarning", "DisparityFit",
    "EstimatorFormatError", "Frames", "MaskFormatWarning", "Masks", "Tracks", "VGGTDepth", "VGGTGrid",
    "align_depth_to_vggt", "fit_inverse_depth_affine", "import_clip", "read_delta", "read_delta_dense",
    "read_delta_pairs", "read_frames", "read_mask_labels", "read_seganymo", "read_vggt", "read_video_depth",
    "vggt_grid",
]
