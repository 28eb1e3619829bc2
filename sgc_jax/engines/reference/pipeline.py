"""A clip's per-pair arrays (docs/semantics.md §3): every pair's reason, poses, components and depth check."""

from __future__ import annotations

import numpy as np

from ...codes import EXCLUDED_STATUSES, REGION_STATUS
from ...config import SGCConfig
from ...io.clip import Clip
from ..evidence import parallax_px
from ..pairs import PairArrays, empty_pair_arrays
from ..units import in_depth_units, translation_factor
from . import pose_search
from .camera_refit import camera_refit, strided_points, tracks_motion
from .components import global_variances, local_variances, mean_pose
from .depth_check import pair_depth_error
from .local_poses import local_poses, pair_points
from .regions import pair_region_mask
from .rotations import global_relative_pose, rotation_angle_deg
from .scale import fit_translation_scale
from .tracks import region_frame


def pair_reason(n_tracks: int, region_mask_pixels: int, n_regions: int, n_poses: int, depth_err: float,
                n_ill_conditioned: int = 0, compat: str = "spec") -> str:
    """The first problem of a pair, in pipeline order (``ok`` when every component exists)."""
    if n_tracks < 4:
        return "too_few_tracks"
    if region_mask_pixels == 0:
        return "no_static"
    if n_regions == 0:
        return "no_region"
    if n_poses == 0 and n_ill_conditioned > 0:
        return "ill_conditioned"
    if n_poses == 0:
        return "no_pose"
    if n_poses == 1 and compat != "authors":
        return "one_pose"
    if np.isnan(depth_err):
        return "no_depth_overlap"
    return "ok"


def score_pairs(clip: Clip, config: SGCConfig | None = None) -> PairArrays:
    """Every per-pair component and diagnostic of a clip (docs/semantics.md §3), as :class:`PairArrays`."""
    config = config or SGCConfig()
    clip, unit = in_depth_units(clip, config)
    n_pairs = clip.n_pairs
    points = [pair_points(clip, pair, config) for pair in range(1, clip.n_frames)]
    if config.global_pose:
        globals_ = [global_relative_pose(clip, pair, config) for pair in range(1, clip.n_frames)]
        R_g = np.stack([g[0] for g in globals_])
        t_g = np.stack([g[1] for g in globals_])
        # s maps pose units to units of D; undefined, the units are taken as shared (s = 1 / D)
        members = [(pp.X[pp.region > 0], pp.uv[pp.region > 0]) for pp in points]  # the scale fit uses them all
        scale = (fit_translation_scale(members, clip.K, R_g, t_g, config.inlier_px, 1.0 / unit)
                 if config.fits_translation_scale else 1.0 / unit)
        poses = local_poses(clip, points, config, [(R_g[p], scale * t_g[p]) for p in range(n_pairs)])
    else:  # the "w/o VGGT" variant: each pair's mean local pose stands in for the global one
        poses = local_poses(clip, points, config)
    accepted = poses["region_status"] == REGION_STATUS["ok"]
    posed = [(list(poses["R_local"][p][accepted[p]]), list(poses["t_local"][p][accepted[p]])) for p in range(n_pairs)]
    if not config.global_pose:
        means = [mean_pose(R, t) if R else (np.full((3, 3), np.nan), np.full(3, np.nan)) for R, t in posed]
        R_g = np.stack([m[0] for m in means])
        t_g = np.stack([m[1] for m in means])
        scale = 1.0
    f = translation_factor(config)
    out = empty_pair_arrays(n_pairs, config.k_seg)
    # reported in depth units per pose unit (1 when no global translation is scaled)
    out.scale, out.depth_unit = scale * unit if config.global_pose else 1.0, unit
    for key in ("R_local", "t_local", "region_status", "region_points", "region_reproj", "region_rot_std",
                "region_trans_std", "region_rot_noise", "region_trans_noise", "region_sigma_px", "region_rot_per_px",
                "region_trans_per_px", "n_tracks", "n_regions"):
        setattr(out, key, poses[key])
    for pair in range(1, clip.n_frames):
        p = pair - 1
        R_list, t_list = posed[p]
        spread = tuple(poses[name][p][accepted[p]] for name in ("region_rot_per_px", "region_trans_per_px"))
        local_rot, local_trans = local_variances(R_list, t_list, config, spread)
        global_rot, global_trans = global_variances(R_list, t_list, R_g[p], scale * t_g[p], config, spread)
        if not config.global_pose:
            global_rot = global_trans = float("nan")
        out.local_rot_var[p], out.local_trans_var[p] = local_rot, local_trans * f**2
        out.global_rot_var[p], out.global_trans_var[p] = global_rot, global_trans * f**2
        if np.isfinite(R_g[p]).all():
            out.depth_error[p] = pair_depth_error(clip, pair, R_g[p], scale * t_g[p], config)[1]
            if config.compat != "authors" and config.global_pose:
                member = points[p].region > 0
                X, uv = strided_points(points[p].X[member], points[p].uv[member])
                camera = pose_search.Pose(R_g[p], scale * t_g[p])
                refit, refit_error, warps = camera_refit(X, uv, clip.K[pair], camera, config.inlier_px)
                if R_list and warps:
                    # the camera fits the tracks worse than its refit to them: the refit warps too (§3.6 step 6)
                    out.depth_error[p] = np.fmin(out.depth_error[p],
                                                 pair_depth_error(clip, pair, refit.R, refit.t, config)[1])
                rot_deg, trans = tracks_motion(X, uv, clip.K[pair], refit, refit_error, config.inlier_px)
                out.tracks_rot_deg[p], out.tracks_trans[p] = rot_deg, trans * f
            out.t_g_norm[p] = np.linalg.norm(scale * t_g[p] if config.scale_free else t_g[p]) * f
            out.R_g_angle_deg[p] = rotation_angle_deg(np.eye(3), R_g[p])
        out.n_poses[p] = len(R_list)
        out.n_ill_conditioned[p] = int(np.isin(poses["region_status"][p], EXCLUDED_STATUSES).sum())
        out.reproj_error[p] = np.mean(poses["region_reproj"][p][accepted[p]]) if R_list else np.nan
        static_pixels = int(pair_region_mask(clip, region_frame(pair, config), config).sum())
        out.static_frac[p] = static_pixels / (clip.image_size[0] * clip.image_size[1])
        out.reason[p] = pair_reason(int(out.n_tracks[p]), static_pixels, int(out.n_regions[p]), len(R_list),
                                    out.depth_error[p], int(out.n_ill_conditioned[p]), config.compat)
    out.parallax_px = parallax_px(clip.K[1:].astype(np.float64), out.t_g_norm, config.scale_free)
    return out
