"""PnP-RANSAC for one region (SPEC §3.6): vmapped minimal-sample solves -> score -> select -> refine.

Fixed shapes throughout: N is the padded point count and ``member`` (N,) masks the region, so the
function vmaps over regions (different masks, same points) and over pairs.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from .geometry import so3_exp
from .pnp import project_columns, solve_pnp

STATUS_OK = 0
STATUS_TOO_FEW_POINTS = 1  # members < min_points
STATUS_REJECTED = 2  # too few inliers, non-finite, or not a proper rotation


class PnPResult(NamedTuple):
    """Pose (R, t) mapping camera i-1 coordinates to camera i (x_i = R x_{i-1} + t) and diagnostics.

    status: int32 (0 ok, 1 too few points, 2 rejected); n_members, n_inliers: int32;
    inliers (N,) bool for the final pose; reproj_px: mean reprojection error [px] of the final
    pose over all region members.
    """

    R: jax.Array
    t: jax.Array
    status: jax.Array
    n_members: jax.Array
    n_inliers: jax.Array
    inliers: jax.Array
    reproj_px: jax.Array


def sample_distinct(key, n, hypotheses, sample_size):
    """(hypotheses, sample_size) int32 positions in [0, n), distinct within each row, uniform.

    Draws the j-th pick among the n - j positions not yet taken (rank, then skip the taken ones in
    ascending order). Rows are meaningless when n < sample_size.
    """
    u = jax.random.uniform(key, (hypotheses, sample_size))
    picks = []
    for j in range(sample_size):  # static, sample_size is small
        n_left = jnp.maximum(n - j, 1)
        r = jnp.minimum(jnp.floor(u[:, j] * n_left).astype(jnp.int32), n_left - 1)
        if picks:
            taken = jnp.sort(jnp.stack(picks, -1), axis=-1)
            for i in range(j):
                r = r + (r >= taken[:, i]).astype(jnp.int32)
        picks.append(r)
    return jnp.stack(picks, -1)


def reprojection_error_px(R, t, X, uv, K):
    """(error [px] (..., N), in_front (..., N)) of poses R (..., 3, 3), t (..., 3) on X (N, 3), uv (N, 2)."""
    u_hat, v_hat, in_front = project_columns(R, t, K, X[:, 0], X[:, 1], X[:, 2])
    return jnp.hypot(u_hat - uv[:, 0], v_hat - uv[:, 1]), in_front


def _score(R, t, X, uv, K, member, inlier_px):
    """Inlier masks (..., N), inlier counts (...) and summed truncated squared errors (...).

    Inlier: member, in front of the camera (z > 0) and error < inlier_px (strict). Evaluated
    homogeneously (|p_uv - uv p_z|^2 < inlier_px^2 p_z^2), the hot loop of RANSAC: no sqrt, and
    the only division is the truncated error.
    """
    P = K @ jnp.concatenate([R, t[..., None]], axis=-1)  # (..., 3, 4)
    x, y, z = X[:, 0], X[:, 1], X[:, 2]

    def row(i):
        return P[..., i, 0, None] * x + P[..., i, 1, None] * y + P[..., i, 2, None] * z + P[..., i, 3, None]

    pu, pv, pz = row(0), row(1), row(2)
    du, dv = pu - uv[:, 0] * pz, pv - uv[:, 1] * pz
    num, den = du * du + dv * dv, pz * pz
    thr_sq = jnp.asarray(inlier_px, X.dtype) ** 2
    in_front = pz > 0
    inliers = member & in_front & (num < thr_sq * den)
    err_sq = jnp.where(inliers, num / jnp.where(in_front, den, 1.0), thr_sq)
    trunc = jnp.where(member, err_sq, 0.0)
    return inliers, jnp.sum(inliers, axis=-1, dtype=jnp.int32), jnp.sum(trunc, axis=-1)


def ransac_pnp(
    X,
    uv,
    member,
    K,
    key,
    *,
    hypotheses,
    sample_size=4,
    inlier_px,
    min_inlier_frac,
    min_points,
    steps,
):
    """Robust pose of one region -> PnPResult.

    X (N, 3) points in camera i-1, uv (N, 2) their pixels in frame i, member (N,) bool region mask,
    K (3, 3) intrinsics of frame i, key: PRNG key. ``hypotheses`` minimal samples of
    ``sample_size`` distinct members are each solved by ``solve_pnp``; all are scored on all
    members at once (inlier: error < inlier_px, in front of the camera); the best (most inliers,
    then lowest truncated error, then lowest index) is refined twice by ``solve_pnp`` on its
    current inliers. Accepted (status 0) when inliers >= max(4, floor(min_inlier_frac * members)),
    the pose is finite and R is a proper rotation.
    """
    N = X.shape[0]
    dtype = X.dtype
    member = member.astype(bool)
    n_members = jnp.sum(member, dtype=jnp.int32)

    member_idx = jnp.nonzero(member, size=N, fill_value=0)[0]
    sample_idx = member_idx[sample_distinct(key, n_members, hypotheses, sample_size)]
    ones = jnp.ones(sample_size, dtype)
    solve_sample = jax.vmap(lambda Xs, uvs: solve_pnp(Xs, uvs, ones, K, steps=steps))
    poses, _ = solve_sample(X[sample_idx], uv[sample_idx])

    finite = jnp.all(jnp.isfinite(poses), axis=-1)
    poses = jnp.where(finite[:, None], poses, jnp.zeros(6, dtype))
    R_h, t_h = so3_exp(poses[:, :3]), poses[:, 3:]
    _, count, trunc = _score(R_h, t_h, X, uv, K, member, inlier_px)
    count = jnp.where(finite, count, -1)
    trunc = jnp.where(count == jnp.max(count), trunc, jnp.inf)
    best = jnp.argmin(trunc)

    pose = poses[best]
    inliers, n_inliers, _ = _score(R_h[best], t_h[best], X, uv, K, member, inlier_px)
    for _ in range(2):  # refine on the current inliers; keep the refined pose unless it lost inliers
        refined, _ = solve_pnp(X, uv, inliers.astype(dtype), K, steps=steps, pose0=pose)
        refined_ok = jnp.all(jnp.isfinite(refined))
        refined = jnp.where(refined_ok, refined, pose)
        new_inliers, new_n, _ = _score(so3_exp(refined[:3]), refined[3:], X, uv, K, member, inlier_px)
        better = refined_ok & (new_n >= n_inliers)
        pose = jnp.where(better, refined, pose)
        inliers = jnp.where(better, new_inliers, inliers)
        n_inliers = jnp.where(better, new_n, n_inliers)

    R, t = so3_exp(pose[:3]), pose[3:]
    err, _ = reprojection_error_px(R, t, X, uv, K)
    reproj_px = jnp.sum(jnp.where(member, err, 0.0)) / jnp.maximum(n_members, 1)

    need = jnp.maximum(4, jnp.floor(min_inlier_frac * n_members).astype(jnp.int32))
    proper = jnp.abs(jnp.linalg.det(R) - 1.0) < 1e-3
    good = (n_inliers >= need) & jnp.all(jnp.isfinite(pose)) & proper & jnp.isfinite(reproj_px)
    status = jnp.where(
        n_members < min_points,
        STATUS_TOO_FEW_POINTS,
        jnp.where(good, STATUS_OK, STATUS_REJECTED),
    ).astype(jnp.int32)
    return PnPResult(R, t, status, n_members, n_inliers.astype(jnp.int32), inliers, reproj_px)
