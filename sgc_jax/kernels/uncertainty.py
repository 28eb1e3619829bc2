"""How well the data pin down each region's pose, and the region-quality rule (docs/semantics.md §3.3).

A few tracks over a small patch, or a near-planar patch seen head-on, fit to well under a pixel
under poses tens of degrees apart. ``pose_uncertainty`` measures that from the Gauss-Newton normal
matrix at the refined pose; ``region_quality`` turns it, the inlier count, the image extent and
RANSAC's ambiguity flag into the statuses ill_conditioned and ambiguous, which the variances leave
out. Rotation in degrees, translation in the units of X, extents in pixels.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from ..codes import REGION_AMBIGUOUS, REGION_ILL_CONDITIONED, REGION_OK
from ..config import BLOCKS_PER_AXIS
from ..stats import cut_variance_factor
from .fence import materialise
from .linalg import solve_spd
from .pnp import point_columns, pointwise_residuals
from .ransac_options import QualityRule
from .regions import HIGHEST, block_normals, region_onehot
from .so3 import so3_exp


class PoseUncertainty(NamedTuple):
    """Per region (k,); NaN with fewer than 4 inliers."""

    rot_std_deg: jax.Array  # RMS rotation error, sqrt(trace of the rotation covariance) [deg]
    trans_std: jax.Array  # RMS translation error [units of X]
    extent_px: jax.Array  # RMS distance of the inlier pixels from their centroid [px]
    sigma_px: jax.Array  # inlier residual standard deviation per image coordinate [px]
    rot_noise_deg: jax.Array  # RMS rotation error the noise floors count (``block_covariance``) [deg]
    trans_noise: jax.Array  # RMS translation error the noise floors count [units of X]
    rot_per_px_deg: jax.Array  # RMS rotation error per px of tracking error: the geometry alone [deg / px]
    trans_per_px: jax.Array  # RMS translation error per px of tracking error [units of X / px]


class InlierJacobians(NamedTuple):
    """Each point's residual and Jacobian rows at its own region's pose, in the pixel-scaled
    parameters (w fx, dt fx / mean depth) of the left-perturbed pose exp([w]) R, t + dt."""

    du: jax.Array  # (N,) [px], 0 for points of no region
    dv: jax.Array
    J_u: jax.Array  # (N, 6)
    J_v: jax.Array
    onehot: jax.Array  # (k, N) inlier membership
    normal: jax.Array  # (k, 6, 6) J^T J
    covariance: jax.Array  # (k, 6, 6) its inverse
    mean_dist: jax.Array  # (k,) mean distance |X| of the inliers from the camera
    fx: jax.Array


def inlier_jacobians(X, uv, region, K, poses, inliers) -> InlierJacobians:
    """At poses (k, 6): X (N, 3), uv (N, 2), region (N,) 1..k (0: none), inliers (N,) bool (of its
    own region's pose). Scaled so that float32 solves the normal matrix accurately."""
    k = poses.shape[0]
    dtype = X.dtype
    onehot = region_onehot(region, k, dtype) * inliers[None, :].astype(dtype)
    own = jnp.clip(region - 1, 0, k - 1)
    cols = point_columns(X, uv, (region >= 1).astype(dtype))
    (du, dv), (RX, grad_u, grad_v) = pointwise_residuals(so3_exp(poses[:, :3])[own], poses[:, 3:][own], K, cols)
    n = jnp.sum(onehot, axis=1)
    mean_dist = (onehot @ jnp.linalg.norm(X, axis=-1)) / jnp.maximum(n, 1.0)
    fx = K[0, 0]
    scale_t = (mean_dist / fx)[own]  # d(dt) per unit of the scaled parameter, per point

    def jacobian_rows(grad):  # (N, 6): w . (RX x grad) + dt . grad
        return jnp.concatenate([jnp.cross(jnp.stack(RX, -1), jnp.stack(grad, -1)) / fx,
                                jnp.stack(grad, -1) * scale_t[:, None]], axis=-1)

    J_u, J_v = jacobian_rows(grad_u), jacobian_rows(grad_v)
    normal = block_normals(onehot, J_u.T, J_v.T)
    # materialised: gathered per point later, the unrolled solves would be recomputed per point
    covariance = materialise(jax.vmap(lambda A: jax.vmap(lambda e: solve_spd(A, e))(jnp.eye(6, dtype=dtype)))(normal))
    return InlierJacobians(du, dv, J_u, J_v, onehot, normal, covariance, mean_dist, fx)


def block_of(uv, block_px):
    """(N, 2) pixels -> (N,) int32 square on a grid of side block_px, clamped to BLOCKS_PER_AXIS a side."""
    cell = jnp.clip(jnp.floor(uv / block_px), 0, BLOCKS_PER_AXIS - 1).astype(jnp.int32)
    return cell[:, 1] * BLOCKS_PER_AXIS + cell[:, 0]


def block_covariance(jac: InlierJacobians, uv, region, block_px):
    """The cluster-robust covariance (k, 6, 6) of each region's pose over squares of side block_px,
    which counts errors the inliers of one square share: A (sum_b g_b g_b^T) A G/(G-1) (2n-1)/(2n-6),
    A = (J^T J)^-1, g_b = J_b^T e_b over the inliers in square b, G the squares holding any."""
    k = jac.onehot.shape[0]
    n = jnp.sum(jac.onehot, axis=1)
    weight = jnp.sum(jac.onehot, axis=0)  # (N,) 1 for an inlier of its region's pose
    segments = k * BLOCKS_PER_AXIS * BLOCKS_PER_AXIS
    key = jnp.clip(region - 1, 0, k - 1) * BLOCKS_PER_AXIS * BLOCKS_PER_AXIS + block_of(uv, block_px)
    gradient = weight[:, None] * (jac.J_u * jac.du[:, None] + jac.J_v * jac.dv[:, None])  # (N, 6)
    g = jax.ops.segment_sum(gradient, key, num_segments=segments).reshape(k, -1, 6)
    G = jnp.sum(jax.ops.segment_sum(weight, key, num_segments=segments).reshape(k, -1) > 0, axis=1).astype(n.dtype)
    correction = G / jnp.maximum(G - 1.0, 1.0) * (2.0 * n - 1.0) / jnp.maximum(2.0 * n - 6.0, 1.0)
    meat = jnp.einsum("kbi,kbj->kij", g, g, precision=HIGHEST)
    return jac.covariance @ meat @ jac.covariance * correction[:, None, None]


def pose_uncertainty(X, uv, region, K, poses, inliers, block_px=jnp.inf, cut_px=jnp.inf) -> PoseUncertainty:
    """Covariance sigma^2 (J^T J)^-1 of each region's pose6 (k, 6), sigma^2 = sum e^2 / (2 n - 6)
    over its n inliers (arguments as ``inlier_jacobians``); the noise the floors count is the larger
    of it and ``block_covariance`` over squares of side block_px (inf: one square, the usual), times
    ``stats.cut_variance_factor`` of the inliers' cut cut_px (their error < cut_px; inf: none)."""
    jac = inlier_jacobians(X, uv, region, K, poses, inliers)
    onehot, covariance, mean_dist, fx = jac.onehot, jac.covariance, jac.mean_dist, jac.fx
    n = jnp.sum(onehot, axis=1)
    sigma_sq = (onehot @ (jac.du * jac.du + jac.dv * jac.dv)) / jnp.maximum(2.0 * n - 6.0, 1.0)
    blocks = block_covariance(jac, uv, region, block_px)
    trace = lambda cov, part: jnp.trace(cov[:, part, part], axis1=-2, axis2=-1)  # noqa: E731
    rot, trans = slice(0, 3), slice(3, 6)
    rot_trace, trans_trace = trace(covariance, rot), trace(covariance, trans)
    rot_var = sigma_sq * rot_trace / fx**2
    trans_var = sigma_sq * trans_trace * (mean_dist / fx) ** 2
    # the same per px² of tracking error: the geometry alone, defined where a fit is exact (sigma 0)
    rot_per_px_sq = rot_trace / fx**2
    trans_per_px_sq = trans_trace * (mean_dist / fx) ** 2
    cut = cut_variance_factor(sigma_sq, cut_px, xp=jnp)
    rot_noise = cut * jnp.maximum(rot_var, trace(blocks, rot) / fx**2)
    trans_noise = cut * jnp.maximum(trans_var, trace(blocks, trans) * (mean_dist / fx) ** 2)
    centroid = (onehot @ uv) / jnp.maximum(n, 1.0)[:, None]
    spread = onehot @ jnp.sum(uv**2, axis=-1) / jnp.maximum(n, 1.0) - jnp.sum(centroid**2, axis=-1)
    enough = n >= 4
    nan = jnp.asarray(jnp.nan, X.dtype)
    root = lambda v: jnp.where(enough, jnp.sqrt(jnp.maximum(v, 0.0)), nan)  # noqa: E731
    return PoseUncertainty(rot_std_deg=jnp.degrees(root(rot_var)), trans_std=root(trans_var),
                           extent_px=root(spread), sigma_px=root(sigma_sq),
                           rot_noise_deg=jnp.degrees(root(rot_noise)), trans_noise=root(trans_noise),
                           rot_per_px_deg=jnp.degrees(root(rot_per_px_sq)), trans_per_px=root(trans_per_px_sq))


def rule_rot_std_deg(uncertainty: PoseUncertainty, quality_noise_px):
    """The rotation uncertainty the rule judges (k,) [deg]: with the residual sigma capped at
    quality_noise_px, since misfit beyond a tracker's noise is the inconsistency SGC measures and
    must not make a region look ill-conditioned."""
    cap = jnp.minimum(1.0, quality_noise_px / jnp.maximum(uncertainty.sigma_px, 1e-12))
    return uncertainty.rot_std_deg * cap


def rot_std_limit_deg(focal_px, max_rot_std_deg, max_rot_std_px):
    """The largest rotation uncertainty accepted [deg]: max_rot_std_deg, or the angle
    max_rot_std_px subtend at focal_px when larger (a coarse image cannot pin a rotation down
    below what its pixels subtend)."""
    return jnp.maximum(max_rot_std_deg, jnp.degrees(max_rot_std_px / focal_px))


def region_quality(status, n_inliers, uncertainty: PoseUncertainty, ambiguous, image_diagonal_px, focal_px,
                   rule: QualityRule):
    """Region statuses (k,) after the rule: an accepted pose becomes ambiguous when RANSAC found a
    rival for its inliers and its residual sigma is within quality_noise_px, else ill_conditioned
    with fewer than min_region_points inliers, a judged rotation std above the limit, or inliers
    spread less than min_region_extent x the diagonal. focal_px: mean of fx and fy."""
    limit_deg = rot_std_limit_deg(focal_px, rule.max_rot_std_deg, rule.max_rot_std_px)
    weak = ((n_inliers < rule.min_region_points) | ~(rule_rot_std_deg(uncertainty, rule.quality_noise_px) <= limit_deg)
            | ~(uncertainty.extent_px >= rule.min_region_extent * image_diagonal_px))
    checked = jnp.where(weak, REGION_ILL_CONDITIONED, status)
    # residuals beyond the noise: the points do not move rigidly, which SGC must see
    checked = jnp.where(ambiguous & (uncertainty.sigma_px <= rule.quality_noise_px), REGION_AMBIGUOUS, checked)
    return jnp.where(status == REGION_OK, checked, status).astype(jnp.int32)
