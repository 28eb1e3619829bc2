"""PnP-RANSAC for one region (SPEC §3.6): vmapped minimal-sample solves -> score -> select -> refine.

Fixed shapes throughout: N is the padded point count and ``member`` (N,) masks the region, so
``ransac_pnp`` vmaps over regions (different masks, same points) and over pairs. Poses map camera
i-1 coordinates to camera i (x_i = R x_{i-1} + t); errors are in pixels of frame i.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from .geometry import so3_exp
from .pnp import initial_pose, project_columns, solve_pnp

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


def scoring_subset(key, member, score_points):
    """Indices (S,) into the N points and validity (S,) of the members that candidates are scored on.

    All members when they fit in S = score_points (members first, in index order); otherwise one
    random member per stratum of n_members / S consecutive members (distinct, spread evenly).
    """
    N = member.shape[0]
    n_members = jnp.sum(member, dtype=jnp.int32)
    member_idx = jnp.nonzero(member, size=N, fill_value=0)[0]
    i = jnp.arange(score_points)
    u = jax.random.uniform(key, (score_points,))
    stratum = jnp.floor((i + u) * (n_members / score_points)).astype(jnp.int32)
    pos = jnp.where(n_members <= score_points, i, jnp.minimum(stratum, n_members - 1))
    pos = jnp.minimum(pos, N - 1)
    return member_idx[pos], i < n_members


def sample_candidates(X, uv, K, sample_idx, *, sample_steps):
    """Candidate poses (H * (k + 1), 6) from H samples of k points (sample_idx (H, k)).

    Per sample: the k-point fit (``initial_pose``, then ``solve_pnp`` Gauss-Newton with
    ``sample_steps`` steps) and the k leave-one-out ``initial_pose`` fits of k - 1 points (exact
    for 3 points), so a sample with one outlier still yields a clean candidate, as P3P-based
    RANSAC gets from every inlier triple.
    """
    H, k = sample_idx.shape
    Xs, uvs = X[sample_idx], uv[sample_idx]
    masks = jnp.concatenate([jnp.ones((1, k), X.dtype), 1.0 - jnp.eye(k, dtype=X.dtype)])  # (k + 1, k)

    def one_sample(Xs, uvs):
        starts = jax.vmap(lambda w: initial_pose(Xs, uvs, w, K))(masks)
        full, _ = solve_pnp(Xs, uvs, masks[0], K, steps=sample_steps, pose0=starts[0])
        return starts.at[0].set(full)

    return jax.vmap(one_sample)(Xs, uvs).reshape(H * (k + 1), 6)


def _rank_key(finite, trunc):
    """Float key for top_k: higher is better. MSAC: the lowest summed truncated squared error
    (inliers contribute e^2, everything else inlier_px^2), not the most inliers. On a weakly
    conditioned region (narrow, far) a pose slid along the rotation/translation valley keeps
    every true inlier under inlier_px and picks up a few outliers, so it wins an inlier count
    while its residuals on the true inliers are several times larger; the truncated error
    prefers the pose that fits the inliers tightly."""
    return jnp.where(finite, -trunc, -jnp.inf)


def _best(trunc):
    """Index of the lowest summed truncated squared error (MSAC), ties -> lowest index."""
    return jnp.argmin(trunc)


# Final refinement pass: inliers re-selected at NOISE_CUT * (estimated pixel noise sigma), never
# tighter than MIN_CUT_PX nor looser than inlier_px. 3.5 sigma keeps 99.8% of Gaussian inliers.
NOISE_CUT = 3.5
MIN_CUT_PX = 1.0


def _pose_errors_sq(pose, X, uv, K):
    """Squared reprojection errors (N,) [px^2] of pose6; +inf for points behind the camera."""
    u_hat, v_hat, in_front = project_columns(so3_exp(pose[:3]), pose[3:], K, X[:, 0], X[:, 1], X[:, 2])
    err_sq = (u_hat - uv[:, 0]) ** 2 + (v_hat - uv[:, 1]) ** 2
    return jnp.where(in_front, err_sq, jnp.inf)


def refine_pose(X, uv, member, K, pose, *, inlier_px, steps, passes):
    """Local optimisation of pose6: ``passes`` least-squares ``solve_pnp`` fits on the inliers.

    Each pass fits the members with error < tau and is kept when the truncated cost
    sum(min(e^2, tau^2)) over the members does not increase (LO-RANSAC / MSAC; it cannot, up to
    the solver's accuracy). tau = inlier_px, except in the last pass: clip(NOISE_CUT * sigma,
    MIN_CUT_PX, inlier_px) with sigma^2 = mean e^2 / 2 over the inliers, which drops stray
    outliers that sit just inside inlier_px when the noise is small. -> (pose6, inliers, n_inliers)
    with the inliers of the final pose at inlier_px.
    """
    thr_sq = jnp.asarray(inlier_px, X.dtype) ** 2
    min_cut_sq = jnp.asarray(min(MIN_CUT_PX, inlier_px) ** 2, X.dtype)

    def one_pass(p, state):
        pose, err_sq = state
        inl = member & (err_sq < thr_sq)
        sigma_sq = jnp.sum(jnp.where(inl, err_sq, 0.0)) / (2.0 * jnp.maximum(jnp.sum(inl), 1))
        tau_sq = jnp.where(p < passes - 1, thr_sq, jnp.clip(NOISE_CUT**2 * sigma_sq, min_cut_sq, thr_sq))
        fit = member & (err_sq < tau_sq)
        refined, _ = solve_pnp(X, uv, fit.astype(X.dtype), K, steps=steps, pose0=pose)
        new_err_sq = _pose_errors_sq(refined, X, uv, K)
        cost = jnp.sum(jnp.where(member, jnp.minimum(err_sq, tau_sq), 0.0))
        new_cost = jnp.sum(jnp.where(member, jnp.minimum(new_err_sq, tau_sq), 0.0))
        better = jnp.all(jnp.isfinite(refined)) & (new_cost <= cost)
        return jnp.where(better, refined, pose), jnp.where(better, new_err_sq, err_sq)

    pose, err_sq = jax.lax.fori_loop(0, passes, one_pass, (pose, _pose_errors_sq(pose, X, uv, K)))
    inliers = member & (err_sq < thr_sq)
    return pose, inliers, jnp.sum(inliers, dtype=jnp.int32)


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
    sample_steps=3,
    score_points=512,
    lo_candidates=4,
    refine_passes=2,
):
    """Robust pose of one region -> PnPResult.

    X (N, 3) points in camera i-1, uv (N, 2) their pixels in frame i, member (N,) bool region mask,
    K (3, 3) intrinsics of frame i, key: PRNG key (same key, same result). Inlier: in front of the
    camera and reprojection error < inlier_px [px].

    1. ``hypotheses`` samples of ``sample_size`` distinct members; each gives sample_size + 1
       candidate poses (``sample_candidates``: the Gauss-Newton fit of the sample with
       ``sample_steps`` steps, and its leave-one-out fits).
    2. All candidates are scored in one vmapped pass on the members (at most ``score_points`` of
       them: all when they fit, else a stratified random subset). The ``lo_candidates`` best
       (lowest summed truncated squared error, MSAC, then lowest index) get one
       least-squares fit on their inliers (local optimisation); the best of these goes on.
    3. ``refine_pose``: ``refine_passes`` least-squares fits (``steps`` Gauss-Newton steps each)
       on the current inliers; inliers and n_inliers are those of the final pose.
    Status: 1 when members < min_points; else 0 when inliers >= max(4, floor(min_inlier_frac *
    members)), the pose is finite and det(R) ~ 1; else 2. Static shapes: vmaps over regions
    (member masks, keys) and pairs. Shape-like arguments (hypotheses, sample_size, steps,
    sample_steps, score_points, lo_candidates, refine_passes) must be static under jit.
    """
    N = X.shape[0]
    dtype = X.dtype
    member = member.astype(bool)
    X = jnp.where(member[:, None], X, jnp.array([0.0, 0.0, 1.0], dtype))  # padding never leaks in
    uv = jnp.where(member[:, None], uv, 0.0).astype(dtype)
    K = jnp.asarray(K, dtype)
    n_members = jnp.sum(member, dtype=jnp.int32)
    key_sample, key_subset = jax.random.split(key)

    member_idx = jnp.nonzero(member, size=N, fill_value=0)[0]
    sample_idx = member_idx[sample_distinct(key_sample, n_members, hypotheses, sample_size)]
    poses = sample_candidates(X, uv, K, sample_idx, sample_steps=sample_steps)
    finite = jnp.all(jnp.isfinite(poses), axis=-1)
    poses = jnp.where(finite[:, None], poses, jnp.zeros(6, dtype))
    R_c, t_c = so3_exp(poses[:, :3]), poses[:, 3:]

    n_scored = min(score_points, N)
    scored_idx, scored_valid = scoring_subset(key_subset, member, n_scored)
    X_s, uv_s = X[scored_idx], uv[scored_idx]
    _, _, trunc = _score(R_c, t_c, X_s, uv_s, K, scored_valid, inlier_px)
    rank = _rank_key(finite, trunc)
    _, top = jax.lax.top_k(rank, min(lo_candidates, poses.shape[0]))

    # Local optimisation of the leading candidates on the scored points: one least-squares fit
    # on each one's inliers; the best of candidates and fits goes on to the full refinement.
    inl_top, _, _ = _score(R_c[top], t_c[top], X_s, uv_s, K, scored_valid, inlier_px)
    fits, _ = jax.vmap(lambda p, w: solve_pnp(X_s, uv_s, w, K, steps=steps, pose0=p))(
        poses[top], inl_top.astype(dtype)
    )
    fits = jnp.where(jnp.all(jnp.isfinite(fits), axis=-1, keepdims=True), fits, poses[top])
    contenders = jnp.concatenate([poses[top], fits])
    _, _, trunc = _score(so3_exp(contenders[:, :3]), contenders[:, 3:], X_s, uv_s, K, scored_valid, inlier_px)
    best_pose = contenders[_best(trunc)]

    pose, inliers, n_inliers = refine_pose(
        X, uv, member, K, best_pose, inlier_px=inlier_px, steps=steps, passes=refine_passes
    )

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
