"""Plain NumPy + OpenCV reference scorer of docs/semantics.md §3 (§7.2; the oracle and the speed baseline).

Readable and faithful rather than fast: loops over pairs and regions. Local poses under
``compat="spec"`` come from ``pose_search.search_region`` (P3P starts, the local optimum and
the noise-level cut of §3.2); under ``compat="authors"`` from ``cv2.solvePnPRansac`` with the
authors' settings (SOLVEPNP_ITERATIVE, 100 iterations, 8 px, confidence 0.99), whose adaptive
RANSAC now and then accepts a wrong pose on small or far regions, left visible in the per-pair
diagnostics as the authors' code leaves it.

One module per step of §3, in pipeline order: ``rotations`` (and the global relative pose, §3.4),
``regions`` (§3.2 steps 1-4), ``tracks`` (step 5), ``region_pose`` (one region's pose, its
uncertainty and quality, §3.2 step 6, §3.3, §3.10), ``pose_search`` (the spec search inside it),
``local_poses`` (a pair's regions), ``components`` (§3.5), ``depth_check`` (§3.6),
``camera_refit`` (§3.6 step 6, §3.11), ``scale`` (§3.4) and ``pipeline`` (``score_pairs``: a clip's
per-pair arrays). This module re-exports each one's public names.

Conventions: poses map camera i-1 coordinates to camera i coordinates (x_i = R x_{i-1} + t);
rotations in degrees in every output; depth and local translations in units of D under "spec"
(``units.in_depth_units``), in the input's depth units under "authors".
"""

from .camera_refit import camera_refit, strided_points, tracks_motion
from .components import geometry_weights, global_variances, local_variances, mean_pose, pose_weights, trimmed_mean_iqr
from .depth_check import (
    PairDepthError,
    affine_depth_map,
    at_pixel_centre,
    depth_error,
    depth_error_map,
    hole_squares,
    pair_depth_check,
    pair_depth_error,
    pair_depth_map,
    previous_view,
    seen_from_previous,
    warp_depth,
    warp_source,
)
from .local_poses import (
    NAN_POSE,
    SPEC_TRIPLES_PER_HYPOTHESIS,
    PairPoints,
    RegionPose,
    accepted_status,
    authors_region_poses,
    local_poses,
    pair_points,
    region_seed,
    spec_region_poses,
)
from .pipeline import pair_reason, score_pairs
from .region_pose import (
    block_covariance,
    floor_noise,
    pixel_extent,
    pose_inliers,
    pose_uncertainty,
    region_quality,
    reprojection_errors,
    rot_std_limit_deg,
    solve_region_pose,
    uncertainty_per_px,
)
from .regions import (
    depth_regions,
    grid_regions,
    kmeans_1d,
    layer_count,
    pair_region_mask,
    partition_regions,
    spatial_regions,
    valid_depth,
)
from .rotations import (
    global_relative_pose,
    nearest_rotation,
    rotation_angle_deg,
    rotation_angle_deg_authors,
    so3_exp,
    so3_log,
)
from .scale import fit_translation_scale, scale_equations, weighted_median
from .tracks import (
    UsablePoints,
    back_project,
    back_project_tracks,
    point_regions,
    project,
    region_frame,
    track_pixels,
    usable_points,
)

__all__ = [
    "global_relative_pose",
    "nearest_rotation",
    "rotation_angle_deg",
    "rotation_angle_deg_authors",
    "so3_exp",
    "so3_log",
    "depth_regions",
    "grid_regions",
    "kmeans_1d",
    "layer_count",
    "pair_region_mask",
    "partition_regions",
    "spatial_regions",
    "valid_depth",
    "back_project",
    "back_project_tracks",
    "point_regions",
    "project",
    "region_frame",
    "track_pixels",
    "usable_points",
    "UsablePoints",
    "block_covariance",
    "floor_noise",
    "pixel_extent",
    "pose_inliers",
    "pose_uncertainty",
    "region_quality",
    "reprojection_errors",
    "rot_std_limit_deg",
    "solve_region_pose",
    "uncertainty_per_px",
    "accepted_status",
    "authors_region_poses",
    "local_poses",
    "NAN_POSE",
    "pair_points",
    "PairPoints",
    "region_seed",
    "RegionPose",
    "spec_region_poses",
    "SPEC_TRIPLES_PER_HYPOTHESIS",
    "geometry_weights",
    "global_variances",
    "local_variances",
    "mean_pose",
    "pose_weights",
    "trimmed_mean_iqr",
    "affine_depth_map",
    "at_pixel_centre",
    "depth_error",
    "depth_error_map",
    "hole_squares",
    "pair_depth_check",
    "pair_depth_error",
    "pair_depth_map",
    "PairDepthError",
    "previous_view",
    "seen_from_previous",
    "warp_depth",
    "warp_source",
    "camera_refit",
    "strided_points",
    "tracks_motion",
    "fit_translation_scale",
    "scale_equations",
    "weighted_median",
    "pair_reason",
    "score_pairs",
]
