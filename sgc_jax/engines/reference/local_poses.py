"""A pair's points and its regions' local poses (docs/semantics.md §3.2-3.3), spec and authors."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ...codes import REGION_STATUS
from ...config import NOISE_BLOCK_FRAC, SGCConfig
from ...io.clip import Clip
from . import pose_search
from .region_pose import floor_noise, pose_inliers, region_quality, reprojection_errors, solve_region_pose
from .regions import layer_count, pair_region_mask, partition_regions
from .tracks import point_regions, region_frame, usable_points


def region_seed(config: SGCConfig, pair: int, region: int) -> int:
    return (config.seed * 1_000_003 + pair * 1_009 + region) % (2**31 - 1)


class PairPoints(NamedTuple):
    """A pair's points (docs/semantics.md §3.2 steps 1-5): labels (H, W) of the region frame's regions,
    X (n, 3) in camera pair-1, uv (n, 2) in frame pair and uv_prev (n, 2) in frame pair-1 of the
    usable tracks with depth, their region (n,) (0: none) and n_usable, the usable tracks with or
    without depth."""

    labels: np.ndarray
    X: np.ndarray
    uv: np.ndarray
    uv_prev: np.ndarray
    region: np.ndarray
    n_usable: int


def pair_points(clip: Clip, pair: int, config: SGCConfig) -> PairPoints:
    X, uv, uv_prev, n_usable = usable_points(clip, pair, config)
    frame, where = region_frame(pair, config), uv_prev if config.reads_previous_frame else uv
    layers = layer_count(pair_region_mask(clip, frame, config), where, config)
    labels = partition_regions(clip, frame, config, layers)
    return PairPoints(labels, X, uv, uv_prev, point_regions(labels, where, config.track_pixel_offset), n_usable)


class RegionPose(NamedTuple):
    """One region's local pose before the quality rule: status (``ok``, ``rejected`` or
    ``too_few_points``), R, t (NaN unless found) and whether a rival makes it ambiguous (spec)."""

    status: int
    R: np.ndarray
    t: np.ndarray
    ambiguous: bool = False


def accepted_status(X: np.ndarray, uv: np.ndarray, K: np.ndarray, R: np.ndarray, t: np.ndarray,
                    config: SGCConfig) -> int:
    """``ok`` when the pose is finite and proper and its inliers (in front, error < inlier_px)
    number >= max(4, floor(min_inlier_frac * n)), else ``rejected`` (docs/semantics.md §3.2 step 6)."""
    if not (np.isfinite(R).all() and np.isfinite(t).all()) or abs(np.linalg.det(R) - 1.0) >= 1e-3:
        return REGION_STATUS["rejected"]
    inliers = pose_inliers(X, uv, K, R, t, config.inlier_px)
    needed = max(4, int(np.floor(config.min_inlier_frac * len(X))))
    return REGION_STATUS["ok"] if inliers.sum() >= needed else REGION_STATUS["rejected"]


NAN_POSE = (np.full((3, 3), np.nan), np.full(3, np.nan))


def spec_region_poses(points: PairPoints, K: np.ndarray, reference_pose: tuple[np.ndarray, np.ndarray] | None,
                      config: SGCConfig, pair: int) -> list[RegionPose]:
    """Every region's local pose of a pair under ``compat="spec"`` (docs/semantics.md §3.2 step 6),
    searched by ``pose_search.region_pose``: the region's own triples, then the other regions'
    coarse optima and ``reference_pose`` (R_g, s t_g) as further starts; R_g (the identity without
    it) is the rival's rotation."""
    n_triples = SPEC_TRIPLES_PER_HYPOTHESIS * config.ransac_hypotheses
    K = K.astype(np.float64)
    # the rival's rotation (docs/semantics.md §3.3): the camera's, or none (identity) without it
    rival_rotation = (reference_pose[0].astype(np.float64) if reference_pose is not None
                      and np.isfinite(reference_pose[0]).all() else np.eye(3))
    members = [points.region == r for r in range(1, points.labels.max() + 1)]
    searches = []
    for region, member in enumerate(members, start=1):
        rng = np.random.default_rng(region_seed(config, pair, region))
        searches.append(pose_search.search_region(points.X[member], points.uv[member], K, config.inlier_px,
                                                            n_triples, rng) if member.sum() >= config.min_points else None)
    out = []
    for member, search in zip(members, searches):
        if member.sum() < config.min_points:
            out.append(RegionPose(REGION_STATUS["too_few_points"], *NAN_POSE))
            continue
        if search is None:
            out.append(RegionPose(REGION_STATUS["rejected"], *NAN_POSE))
            continue
        others = [s.optima[0] for s in searches if s is not None and s is not search]
        if reference_pose is not None:
            others.append(pose_search.Pose(*reference_pose))
        X, uv = points.X[member], points.uv[member]
        found = pose_search.region_pose(X, uv, K, search, others, rival_rotation, config.inlier_px,
                                                  config.ambiguous_rot_deg, config.ambiguous_inlier_frac)
        out.append(RegionPose(accepted_status(X, uv, K, *found.pose, config), *found.pose, found.ambiguous))
    return out


def authors_region_poses(points: PairPoints, K: np.ndarray, config: SGCConfig, pair: int) -> list[RegionPose]:
    """Every region's local pose of a pair by ``cv2.solvePnPRansac`` with the authors' settings."""
    out = []
    for region in range(1, points.labels.max() + 1):
        member = points.region == region
        status, R, t = solve_region_pose(points.X[member], points.uv[member], K, config,
                                            region_seed(config, pair, region))
        out.append(RegionPose(status, R, t))
    return out


# Random triples of the spec search per RANSAC hypothesis of the JAX engine (whose adaptive stop
# usually ends far sooner): the reference is meant to be the harder searcher of the two, and with
# 30 (3000 triples at the default) it reaches the same optima under every seed tried.
SPEC_TRIPLES_PER_HYPOTHESIS = 30


def local_poses(clip: Clip, points: list[PairPoints], config: SGCConfig,
                reference_poses: list[tuple[np.ndarray, np.ndarray]] | None = None) -> dict[str, np.ndarray]:
    """Per pair and region (k_seg slots): status, R, t, point count, reprojection error, pose
    uncertainty; plus per pair n_tracks and n_regions (docs/semantics.md §3.2-3.3). ``points``
    per pair (``pair_points``); ``reference_poses`` per pair (R_g, s t_g), a start of the spec
    search."""
    n_pairs, k = clip.n_pairs, config.k_seg
    out = {
        "R_local": np.full((n_pairs, k, 3, 3), np.nan), "t_local": np.full((n_pairs, k, 3), np.nan),
        "region_status": np.full((n_pairs, k), REGION_STATUS["empty"], np.int32),
        "region_points": np.zeros((n_pairs, k), np.int32), "region_reproj": np.full((n_pairs, k), np.nan),
        "region_rot_std": np.full((n_pairs, k), np.nan), "region_trans_std": np.full((n_pairs, k), np.nan),
        "region_rot_noise": np.full((n_pairs, k), np.nan), "region_trans_noise": np.full((n_pairs, k), np.nan),
        "region_sigma_px": np.full((n_pairs, k), np.nan), "region_rot_per_px": np.full((n_pairs, k), np.nan),
        "region_trans_per_px": np.full((n_pairs, k), np.nan),
        "n_tracks": np.array([pp.n_usable for pp in points], np.int32),
        "n_regions": np.array([pp.labels.max() for pp in points], np.int32),
    }
    block_px = NOISE_BLOCK_FRAC * float(np.hypot(*clip.image_size))  # the floors' squares
    for pair in range(1, clip.n_frames):
        p, pp, K = pair - 1, points[pair - 1], clip.K[pair]
        if pp.n_usable < 4:
            continue
        if config.compat == "authors":
            poses = authors_region_poses(pp, K, config, pair)
        else:
            poses = spec_region_poses(pp, K, reference_poses[p] if reference_poses else None, config, pair)
        for j, pose in enumerate(poses):
            member = pp.region == j + 1
            X, uv = pp.X[member], pp.uv[member]
            status = pose.status
            if status == REGION_STATUS["ok"]:
                good, sigma, usual, per_px = region_quality(X, uv, K, pose.R, pose.t, clip.image_size, config)
                out["region_rot_std"][p, j], out["region_trans_std"][p, j] = usual
                out["region_rot_per_px"][p, j], out["region_trans_per_px"][p, j] = per_px
                out["region_sigma_px"][p, j] = sigma
                if config.compat != "authors":  # no floors there
                    out["region_rot_noise"][p, j], out["region_trans_noise"][p, j] = floor_noise(
                        X, uv, K, pose.R, pose.t, usual, sigma, block_px, config.inlier_px)
                if config.applies_quality_rule and pose.ambiguous and sigma <= config.quality_noise_px:
                    status = REGION_STATUS["ambiguous"]
                elif config.applies_quality_rule and not good:
                    status = REGION_STATUS["ill_conditioned"]
            out["region_status"][p, j], out["region_points"][p, j] = status, member.sum()
            if pose.status == REGION_STATUS["ok"]:
                out["R_local"][p, j], out["t_local"][p, j] = pose.R, pose.t
                out["region_reproj"][p, j] = float(reprojection_errors(X, uv, K, pose.R, pose.t).mean())
    return out
