"""The truncated (MSAC) reprojection cost of docs/semantics.md §3.2 step 6: each member's squared
pixel error, capped at the threshold, summed per region. Lower is better."""

from __future__ import annotations

import jax.numpy as jnp

from .camera import homogeneous_pixels
from .pnp import projected_pointwise
from .regions import RegionSlots, from_slots, per_chunk, region_sums, to_slots
from .so3 import so3_exp

# One truncated cost is lower than another when by more than this fraction of it, beyond float32's
# rounding of the sum: two fits of one optimum tie whatever the order of the sum, so a program
# fused otherwise (one device or several) makes the same choices.
COST_RTOL = 1e-6


def is_lower(cost_a, cost_b):
    """cost_a lower than cost_b by more than COST_RTOL of it (elementwise; finite cost_a)."""
    return jnp.isfinite(cost_a) & (cost_a < cost_b - COST_RTOL * jnp.abs(cost_b))


def truncated_errors_sq(R, t, X, uv, K, member, inlier_px):
    """(inliers (..., N), squared errors [px^2] capped at inlier_px^2 (..., N), 0 off member) of
    poses R (..., 3, 3), t (..., 3). Inlier: member, in front (z > 0) and error < inlier_px.
    Homogeneous (|p_uv - uv p_z|^2 < inlier_px^2 p_z^2): RANSAC's hot loop needs no square root,
    and its only division is the capped error."""
    pu, pv, pz = homogeneous_pixels(K, R, t, X[:, 0], X[:, 1], X[:, 2])
    du, dv = pu - uv[:, 0] * pz, pv - uv[:, 1] * pz
    num, den = du * du + dv * dv, pz * pz
    thr_sq = jnp.asarray(inlier_px, X.dtype) ** 2
    in_front = pz > 0
    inliers = member & in_front & (num < thr_sq * den)
    err_sq = jnp.where(inliers, num / jnp.where(in_front, den, 1.0), thr_sq)
    return inliers, jnp.where(member, err_sq, 0.0)


def msac_score(R, t, X, uv, K, member, inlier_px):
    """(inliers (..., N), inlier counts (...) int32, summed capped squared errors (...))."""
    inliers, trunc = truncated_errors_sq(R, t, X, uv, K, member, inlier_px)
    return inliers, jnp.sum(inliers, axis=-1, dtype=jnp.int32), jnp.sum(trunc, axis=-1)


def own_pose_errors_sq(poses, X, uv, K, slots: RegionSlots):
    """(squared errors (N,) [px^2] of each point under its own region's pose6 (poses (k, 6)),
    in_front (N,)); finite behind the camera (the depth floor), 0 and not in front for points of
    no region. Computed in the slot layout of ``slots`` (``region_slots``): each chunk's pose
    broadcast over its points, not one pose gathered per point."""
    Xs, uvs = to_slots(slots, X, jnp.array([0.0, 0.0, 1.0], X.dtype)), to_slots(slots, uv, 0.0)
    u_hat, v_hat, in_front = projected_pointwise(per_chunk(slots, so3_exp(poses[:, :3])), per_chunk(slots, poses[:, 3:]),
                                                 K, Xs[..., 0], Xs[..., 1], Xs[..., 2])
    err_sq = (u_hat - uvs[..., 0]) ** 2 + (v_hat - uvs[..., 1]) ** 2
    return from_slots(slots, err_sq, 0.0), from_slots(slots, in_front, False)


def pose_errors_sq(poses, X, uv, K, slots: RegionSlots):
    """``own_pose_errors_sq``, +inf behind the camera and for points of no region."""
    err_sq, in_front = own_pose_errors_sq(poses, X, uv, K, slots)
    return jnp.where(in_front, err_sq, jnp.inf)


def region_truncated_cost(err_sq, member, cut_sq_point, onehot):
    """(k,) per-region sums of each member's squared error capped at its region's cut (N,)."""
    return region_sums(onehot, jnp.where(member, jnp.minimum(err_sq, cut_sq_point), 0.0))
