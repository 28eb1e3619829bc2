"""How well the data pin down each region's local pose, and the region-quality rule (docs/semantics.md §3.3).

A region of a few tracks over a small image patch, or a near-planar one seen almost head-on,
can be fitted to well under a pixel by poses tens of degrees apart: rotation trades against
translation, or the planar two-fold ambiguity leaves two minima. Such a pose says nothing about
the video's geometry. ``pose_uncertainty`` measures it from the Gauss-Newton normal matrix at the
refined pose; ``region_quality`` turns that, the inlier count, the image extent and RANSAC's
ambiguity flag into the region statuses ``ill_conditioned`` and ``ambiguous``, which the
variances leave out.

Units: rotation standard deviations in degrees, translations in depth units, extents in pixels.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from ..codes import REGION_AMBIGUOUS, REGION_ILL_CONDITIONED, REGION_OK
from .fence import materialise
from .geometry import so3_exp
from .pnp import block_normals, point_columns, pointwise_residuals, region_onehot, solve_spd


class PoseUncertainty(NamedTuple):
    """Per region (k,): rot_std_deg, RMS rotation error [deg] = sqrt(trace of the rotation
    covariance); trans_std, RMS translation error [depth units]; extent_px, RMS distance of the
    inlier pixels from their centroid [px]; sigma_px, the inlier residual standard deviation per
    image coordinate [px]. NaN where a region has fewer than 4 inliers."""

    rot_std_deg: jax.Array
    trans_std: jax.Array
    extent_px: jax.Array
    sigma_px: jax.Array


class InlierJacobians(NamedTuple):
    """Each point's residual and its Jacobian rows at its own region's pose, for the inlier fit.

    du, dv (N,) residuals [px] (0 for points of no region); J_u, J_v (N, 6) d residual / d(w fx,
    dt fx / mean depth), the pixel-scaled parameters of ``solve_pnp`` with the left-perturbed
    pose exp([w]) R, t + dt; onehot (k, N) inlier membership; normal (k, 6, 6) J^T J and
    covariance (k, 6, 6) its inverse, per region; mean_depth (k,) mean inlier distance; fx.
    """

    du: jax.Array
    dv: jax.Array
    J_u: jax.Array
    J_v: jax.Array
    onehot: jax.Array
    normal: jax.Array
    covariance: jax.Array
    mean_depth: jax.Array
    fx: jax.Array


def inlier_jacobians(X, uv, region, K, poses, inliers) -> InlierJacobians:
    """Residuals, Jacobians and normal matrices of every region's inliers at poses (k, 6).

    X (N, 3) points in camera i-1, uv (N, 2) pixels in frame i, region (N,) in 1..k (0: none),
    inliers (N,) bool (each point an inlier of its own region's pose). The normal matrix is
    formed in the pixel-scaled parameters, where float32 solves it accurately.
    """
    k = poses.shape[0]
    dtype = X.dtype
    onehot = region_onehot(region, k, dtype) * inliers[None, :].astype(dtype)
    own = jnp.clip(region - 1, 0, k - 1)
    cols = point_columns(X, uv, (region >= 1).astype(dtype))
    (du, dv), (RX, grad_u, grad_v) = pointwise_residuals(so3_exp(poses[:, :3])[own], poses[:, 3:][own], K, cols)

    n = jnp.sum(onehot, axis=1)
    mean_depth = (onehot @ jnp.linalg.norm(X, axis=-1)) / jnp.maximum(n, 1.0)
    fx = K[0, 0]
    scale_t = (mean_depth / fx)[own]  # d(dt) per unit of the scaled parameter, per point

    def jacobian_rows(grad):
        """(N, 6) d residual / d(w fx, dt fx / depth): w . (RX x grad) + dt . grad."""
        rx = jnp.stack(RX, -1)
        g = jnp.stack(grad, -1)
        return jnp.concatenate([jnp.cross(rx, g) / fx, g * scale_t[:, None]], axis=-1)

    J_u, J_v = jacobian_rows(grad_u), jacobian_rows(grad_v)
    normal = block_normals(onehot, J_u.T, J_v.T)
    # Materialised: gathered per point (``_hat_blocks``), the unrolled solves would otherwise be
    # fused into the gather and recomputed for every point (it tripled the time of the checks).
    covariance = materialise(jax.vmap(lambda A: jax.vmap(lambda e: solve_spd(A, e))(jnp.eye(6, dtype=dtype)))(normal))
    return InlierJacobians(du, dv, J_u, J_v, onehot, normal, covariance, mean_depth, fx)


def pose_uncertainty(X, uv, region, K, poses, inliers) -> PoseUncertainty:
    """Covariance of each region's pose6 (k, 6) from its inliers' Gauss-Newton normal matrix.

    Arguments as ``inlier_jacobians``. With the Jacobian J (2 n, 6) of the inlier residuals and
    sigma^2 = sum e^2 / (2 n - 6): Cov(w, dt) = sigma^2 (J^T J)^-1.
    """
    jac = inlier_jacobians(X, uv, region, K, poses, inliers)
    onehot, covariance, mean_depth, fx = jac.onehot, jac.covariance, jac.mean_depth, jac.fx
    n = jnp.sum(onehot, axis=1)
    sq = onehot @ (jac.du * jac.du + jac.dv * jac.dv)
    sigma_sq = sq / jnp.maximum(2.0 * n - 6.0, 1.0)
    rot_var = sigma_sq * jnp.trace(covariance[:, :3, :3], axis1=-2, axis2=-1) / fx**2
    trans_var = sigma_sq * jnp.trace(covariance[:, 3:, 3:], axis1=-2, axis2=-1) * (mean_depth / fx) ** 2

    centroid = (onehot @ uv) / jnp.maximum(n, 1.0)[:, None]
    spread = onehot @ jnp.sum(uv**2, axis=-1) / jnp.maximum(n, 1.0) - jnp.sum(centroid**2, axis=-1)
    enough = n >= 4
    nan = jnp.asarray(jnp.nan, X.dtype)
    return PoseUncertainty(
        rot_std_deg=jnp.where(enough, jnp.degrees(jnp.sqrt(jnp.maximum(rot_var, 0.0))), nan),
        trans_std=jnp.where(enough, jnp.sqrt(jnp.maximum(trans_var, 0.0)), nan),
        extent_px=jnp.where(enough, jnp.sqrt(jnp.maximum(spread, 0.0)), nan),
        sigma_px=jnp.where(enough, jnp.sqrt(sigma_sq), nan),
    )


def rule_rot_std_deg(uncertainty: PoseUncertainty, quality_noise_px):
    """The rotation uncertainty the rule judges (k,) [deg]: ``rot_std_deg`` with the residual
    sigma capped at ``quality_noise_px``. Residuals beyond a tracker's noise are misfit (a moving
    object or a non-rigid warp inside the region), the inconsistency SGC measures; they must not
    make a region look ill-conditioned and drop out."""
    cap = jnp.minimum(1.0, quality_noise_px / jnp.maximum(uncertainty.sigma_px, 1e-12))
    return uncertainty.rot_std_deg * cap


def rot_std_limit_deg(focal_px, max_rot_std_deg, max_rot_std_px):
    """The largest rotation uncertainty the rule accepts [deg]: ``max_rot_std_deg``, or the angle
    ``max_rot_std_px`` pixels subtend at ``focal_px`` when that is larger. A coarse image cannot
    pin a rotation down to less than its pixels subtend (at fx = 111 px one pixel is 0.5 deg);
    without the pixel term the rule would leave out most regions of a small clip, and with them
    part of the real inconsistency the perturbation ladders measure."""
    return jnp.maximum(max_rot_std_deg, jnp.degrees(max_rot_std_px / focal_px))


def region_quality(status, n_inliers, uncertainty: PoseUncertainty, ambiguous, image_diagonal_px, focal_px, *,
                   min_region_points, max_rot_std_deg, max_rot_std_px, min_region_extent, quality_noise_px):
    """Region statuses (k,) after the quality rule: an accepted pose (``REGION_OK``) becomes
    ``REGION_AMBIGUOUS`` when RANSAC found a rival pose for the same inliers and the residual sigma
    is within ``quality_noise_px``, else
    ``REGION_ILL_CONDITIONED`` when it has fewer than ``min_region_points`` inliers, a rotation std
    (``rule_rot_std_deg``) above ``rot_std_limit_deg``, or inliers spread less than
    ``min_region_extent`` x the image diagonal (RMS radius). ``focal_px``: mean of fx and fy of the
    frame the region is projected into."""
    limit_deg = rot_std_limit_deg(focal_px, max_rot_std_deg, max_rot_std_px)
    weak = ((n_inliers < min_region_points) | ~(rule_rot_std_deg(uncertainty, quality_noise_px) <= limit_deg)
            | ~(uncertainty.extent_px >= min_region_extent * image_diagonal_px))
    checked = jnp.where(weak, REGION_ILL_CONDITIONED, status)
    # Ambiguity is two motions fitting the same points to noise level; with residuals beyond
    # quality_noise_px the region's points do not move rigidly, which SGC must see.
    checked = jnp.where(ambiguous & (uncertainty.sigma_px <= quality_noise_px), REGION_AMBIGUOUS, checked)
    return jnp.where(status == REGION_OK, checked, status).astype(jnp.int32)
