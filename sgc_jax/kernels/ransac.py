"""PnP-RANSAC: vmapped minimal-sample solves -> score -> select -> refine (docs/semantics.md
§3.2 step 6, §7.1).

``ransac_pnp_regions`` handles every region of a pair at once. Fixed shapes throughout: N padded
points, each tagged with its region 1..k (0: none). A counting sort (``pnp.label_ranks``) groups
the points by region, so each region draws its samples and scores its candidates on its own
members only, and the final refinement solves all regions jointly (each point against its own
region's pose, in ``pnp.RegionSlots`` chunks): a pair costs O(N) per Gauss-Newton step, not
O(k N). ``ransac_pnp`` is the one-region form. Poses map camera i-1 coordinates to camera i
(x_i = R x_{i-1} + t); errors are in pixels of frame i.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from ..codes import REGION_OK, REGION_REJECTED, REGION_TOO_FEW_POINTS
from ..config import MIN_CUT_PX, NOISE_CUT
from .geometry import rotation_angle_deg, so3_exp, so3_log
from .pnp import (initial_pose, label_ranks, project_columns, project_pointwise, region_onehot, region_slots,
                  solve_pnp, solve_pnp_regions, translation_for_rotation)
from .uncertainty import PoseUncertainty, leverage, pose_uncertainty, predicted_residual_chi2

class PnPResult(NamedTuple):
    """Pose (R, t) mapping camera i-1 coordinates to camera i (x_i = R x_{i-1} + t) and diagnostics.

    status: int32 region status (``codes``: REGION_OK, REGION_TOO_FEW_POINTS, REGION_REJECTED); n_members, n_inliers: int32;
    inliers (N,) bool for the final pose; reproj_px: mean reprojection error [px] of the final
    pose over all region members. From ``ransac_pnp_regions`` every field but ``inliers`` has a
    leading region axis (k,), and ``inliers`` (N,) marks each point an inlier of its own region.
    """

    R: jax.Array
    t: jax.Array
    status: jax.Array
    n_members: jax.Array
    n_inliers: jax.Array
    inliers: jax.Array
    reproj_px: jax.Array
    ambiguous: jax.Array
    uncertainty: PoseUncertainty


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


def _truncated_errors_sq(R, t, X, uv, K, member, inlier_px):
    """Inlier masks (..., N) and squared errors [px^2] truncated at inlier_px^2 (..., N), 0 off member.

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
    return inliers, jnp.where(member, err_sq, 0.0)


def _score(R, t, X, uv, K, member, inlier_px):
    """Inlier masks (..., N), inlier counts (...) and summed truncated squared errors (...)
    (``_truncated_errors_sq``)."""
    inliers, trunc = _truncated_errors_sq(R, t, X, uv, K, member, inlier_px)
    return inliers, jnp.sum(inliers, axis=-1, dtype=jnp.int32), jnp.sum(trunc, axis=-1)


def scoring_subset(key, order, start, n_members, score_points):
    """Indices (S,) into the N points and validity (S,) of the members that candidates are scored on.

    ``order`` (N,) lists the points grouped by region, each region's members in index order from
    ``start``. All members when they fit in S = score_points (members first, in index order);
    otherwise one random member per stratum of n_members / S consecutive members (distinct,
    spread evenly).
    """
    N = order.shape[0]
    i = jnp.arange(score_points)
    u = jax.random.uniform(key, (score_points,))
    stratum = jnp.floor((i + u) * (n_members / score_points)).astype(jnp.int32)
    pos = jnp.where(n_members <= score_points, i, jnp.minimum(stratum, n_members - 1))
    return order[jnp.clip(start + pos, 0, N - 1)], i < n_members


def group_by_region(region, k):
    """(N,) region ids 1..k (0: none) -> (order (N,): point indices grouped by region, members of
    a region in index order, then the points of no region; start (k,); count (k,) int32)."""
    N = region.shape[0]
    label = jnp.where((region >= 1) & (region <= k), region - 1, k)  # k: no region, last
    rank, count = label_ranks(label, k + 1)
    start = jnp.cumsum(count) - count
    order = jnp.zeros(N, jnp.int32).at[start[label] + rank].set(jnp.arange(N, dtype=jnp.int32))
    return order, start[:k], count[:k]


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


# Contenders carried through the refinement differ by more than this rotation [deg]; nearer ones
# fall into the same optimum.
DISTINCT_DEG = 0.5

# Re-admission after the final pass: members outside the noise cut whose residual the pose's
# uncertainty explains at chi-square(2) < ADMIT_CHI2 (p = 0.05) join a refit. A looser threshold
# (13.8) admits stray outliers with the pinning points, which hold the refit back.
ADMIT_CHI2 = 6.0
# Leverage check after it: a point carrying more than half of its region's pose information in
# some direction (or LEVERAGE_RATIO x the average share, on small regions) is dropped for a refit.
LEVERAGE_MAX = 0.5
LEVERAGE_RATIO = 3.0


def _noise_sigma_sq(err_sq, member, onehot, thr_sq):
    """(k,) pixel noise variance per coordinate of each region: mean e^2 / 2 over its members
    with e^2 < thr_sq (err_sq (N,) under each point's own region's pose)."""
    inl = member & (err_sq < thr_sq)
    return (_region_sums(onehot, jnp.where(inl, err_sq, 0.0))
            / (2.0 * jnp.maximum(_region_sums(onehot, inl.astype(err_sq.dtype)), 1.0)))


def _noise_cut_sq(sigma_sq, inlier_px):
    """Squared noise-level cut of sigma^2 (any shape): NOISE_CUT sigma within [min(MIN_CUT_PX,
    inlier_px), inlier_px] (docs/semantics.md §3.2 step 6)."""
    dtype = sigma_sq.dtype
    return jnp.clip(NOISE_CUT**2 * sigma_sq, jnp.asarray(jnp.minimum(MIN_CUT_PX, inlier_px) ** 2, dtype),
                    jnp.asarray(inlier_px, dtype) ** 2)


def _own_pose_errors_sq(poses, X, uv, K, onehot):
    """Squared reprojection errors (N,) [px^2] of each point under its own region's pose6
    (poses (k, 6), onehot (k, N)), finite behind the camera (the depth-floor projection; points
    of no region use the identity pose), and in_front (N,) bool."""
    k = poses.shape[0]
    Rt = jnp.concatenate([so3_exp(poses[:, :3]).reshape(k, 9), poses[:, 3:]], axis=-1)
    own = jnp.dot(onehot.T, Rt, precision=jax.lax.Precision.HIGHEST)  # (N, 12); 0 for no region
    identity = jnp.concatenate([jnp.eye(3, dtype=X.dtype).reshape(9), jnp.zeros(3, X.dtype)])
    own = own + (1.0 - jnp.sum(onehot, axis=0))[:, None] * identity
    u_hat, v_hat, in_front = project_pointwise(own[:, :9].reshape(-1, 3, 3), own[:, 9:], K, X[:, 0], X[:, 1], X[:, 2])
    return (u_hat - uv[:, 0]) ** 2 + (v_hat - uv[:, 1]) ** 2, in_front


def _pose_errors_sq(poses, X, uv, K, onehot):
    """``_own_pose_errors_sq``, +inf behind the camera and for points of no region (RANSAC's
    inlier test)."""
    err_sq, in_front = _own_pose_errors_sq(poses, X, uv, K, onehot)
    return jnp.where(in_front & (jnp.sum(onehot, axis=0) > 0), err_sq, jnp.inf)


def _region_sums(onehot, values):
    """(k, N) region membership, (N, ...) values -> (k, ...) sums over each region's points (0 for inf * 0)."""
    return jnp.dot(onehot, values, precision=jax.lax.Precision.HIGHEST)


def refine_poses(X, uv, region, K, contenders, rival_R, *, inlier_px, steps, passes, ambiguous_rot_deg,
                 ambiguous_inlier_frac, batch_axis=None):
    """Local optimisation of every region's pose6 from M contenders (contenders (M, k, 6)):
    ``passes`` least-squares fits (``solve_pnp_regions``, all regions at once) on the current
    inliers of each contender, the contender of lowest cost kept per region
    (``lowest_cost_contender``), two checks on it, then the rival.

    Per region, each pass fits the members with error < tau and is kept when the truncated cost
    sum(min(e^2, tau^2)) over the members does not increase (LO-RANSAC / MSAC; it cannot, up to
    the solver's accuracy). tau = inlier_px, except in the last pass: the noise cut
    clip(NOISE_CUT * sigma, MIN_CUT_PX, inlier_px) with sigma^2 = mean e^2 / 2 over the inliers,
    which drops stray outliers that sit just inside inlier_px when the noise is small.

    On a weakly conditioned region (a narrow depth band) the fit can slide along the valley where
    rotation trades against translation, leaving out the few clean points that pin it (tens of
    px off) or resting on one gross outlier. Each check proposes a refit, kept per region when its
    truncated cost at the noise cut is no higher:
    - re-admission: members outside the cut whose residual the pose's own uncertainty explains
      (``predicted_residual_chi2`` < ADMIT_CHI2) join a fit, then the cut is applied again and
      the fit repeated;
    - leverage: members of the fit whose ``leverage`` exceeds max(LEVERAGE_MAX, LEVERAGE_RATIO x
      the mean 6 / n) decide the pose alone, so their residuals cannot show whether they are
      outliers; the region is refitted without them.
    The rival (docs/semantics.md §3.3): from the rotation rival_R (3, 3) (the camera's) with the
    translation that best explains the pose's members within the cut (``translation_for_rotation``),
    one least-squares fit at inlier_px, then one at the cut, each on the members within the
    threshold and kept when it does not raise the truncated cost there; where its optimum at
    inlier_px costs less there than the coarse optimum, it is the coarse optimum and sets the cut.
    It replaces the pose where its cost at the cut is lower; otherwise the pose is ambiguous
    where the rival lies more than ``ambiguous_rot_deg`` away in rotation and keeps all but
    max(1, floor(ambiguous_inlier_frac m)) of the m members within the cut of the pose.
    -> (poses (k, 6), inliers (N,) at inlier_px under each point's own final pose (the quality
    rule's inputs, as in the reference engine), n_inliers (k,) int32, ambiguous (k,) bool)

    A check whose refit no region tries is skipped (it would keep nothing); ``batch_axis``, the
    name of a ``vmap`` axis this is mapped over, makes that decision once for all the mapped
    calls, so the skip stays a branch instead of both sides computed.
    """
    k = contenders.shape[1]
    dtype = X.dtype
    onehot = region_onehot(region, k, dtype)
    member = region >= 1
    thr_sq = jnp.asarray(inlier_px, dtype) ** 2
    own = lambda per_region: jnp.dot(onehot.T, per_region, precision=jax.lax.Precision.HIGHEST)  # noqa: E731
    slots = region_slots(region, k, dtype)  # one layout for all the joint solves below
    fit_regions = lambda weight, start: solve_pnp_regions(X, uv, weight.astype(dtype), region, K, start,  # noqa: E731
                                                          steps=steps, slots=slots)[0]

    def truncated_cost(err_sq, tau_point):
        return _region_sums(onehot, jnp.where(member, jnp.minimum(err_sq, tau_point), 0.0))

    def keep_if_better(poses, err_sq, candidate, cand_err_sq, tried, tau_point):
        """Each region's candidate pose replaces its pose where tried (k,), finite and of no higher
        truncated cost at tau_point -> (poses, err_sq)."""
        use = tried & jnp.all(jnp.isfinite(candidate), axis=-1) & (
            truncated_cost(cand_err_sq, tau_point) <= truncated_cost(err_sq, tau_point))
        return jnp.where(use[:, None], candidate, poses), jnp.where(own(use.astype(dtype)) > 0, cand_err_sq, err_sq)

    # Every fit runs in one loop, so the solver is traced once: ``passes`` refinement passes, then
    # the re-admission fit, its re-cut fit, the leverage fit and the rival's two fits. Per stage,
    # one branch picks the points and start of the fit and one what is kept after it
    # (``lax.switch`` on the loop index, which vmap leaves unbatched). The checks and the rival
    # use the noise cut after the passes, the rival's own where its optimum at inlier_px is the
    # coarse optimum.
    ADMIT, LEVERAGE, RIVAL = passes, passes + 2, passes + 3  # re-cut: passes + 1; rival at the cut: passes + 4

    class Stage(NamedTuple):
        poses: jax.Array  # (k, 6) current poses
        err_sq: jax.Array  # (N,) squared error of each point under its region's pose
        candidate: jax.Array  # (k, 6) the re-admission fit, for the re-cut
        tau: jax.Array  # (N,) squared cut of each point's region
        tried: jax.Array  # (k,) regions the current check proposes a refit for
        coarse: jax.Array  # (k,) the coarse optimum's truncated cost at inlier_px

    def refine_pass(stage, st):
        cut_sq = _noise_cut_sq(_noise_sigma_sq(st.err_sq, member, onehot, thr_sq), inlier_px)
        tau = own(jnp.where(stage < passes - 1, thr_sq, cut_sq))
        return member & (st.err_sq < tau), st.poses, st._replace(tau=tau)

    def admit(stage, st):
        # members outside the cut that the pose's own uncertainty explains (they sit along the
        # region's weak direction) join the fit
        sigma_sq = _noise_sigma_sq(st.err_sq, member, onehot, thr_sq)
        tau = own(_noise_cut_sq(sigma_sq, inlier_px))
        fit = member & (st.err_sq < tau)
        extra = member & ~fit & (predicted_residual_chi2(X, uv, region, K, st.poses, fit, sigma_sq) < ADMIT_CHI2)
        return fit | extra, st.poses, st._replace(tau=tau, tried=_region_sums(onehot, extra.astype(dtype)) > 0)

    def recut(stage, st):  # the cut applied again to the re-admission fit
        return member & (_pose_errors_sq(st.candidate, X, uv, K, onehot) < st.tau), st.candidate, st

    def drop_leverage(stage, st):  # points that decide the pose alone are dropped, the region refitted
        fit = member & (st.err_sq < st.tau)
        n_fit = _region_sums(onehot, fit.astype(dtype))
        limit = jnp.maximum(LEVERAGE_MAX, LEVERAGE_RATIO * 6.0 / jnp.maximum(n_fit, 1.0))
        high = fit & (leverage(X, uv, region, K, st.poses, fit) > own(limit))
        return fit & ~high, st.poses, st._replace(tried=_region_sums(onehot, high.astype(dtype)) > 0)

    def rival_start(stage, st):  # the camera's rotation, the translation that explains the pose's members
        t = translation_for_rotation(X, uv, member & (st.err_sq < st.tau), region, K, rival_R, k)
        start = jnp.concatenate([jnp.broadcast_to(so3_log(rival_R), (k, 3)), t], axis=-1)
        return member & (_pose_errors_sq(start, X, uv, K, onehot) < thr_sq), start, st._replace(candidate=start)

    def rival_recut(stage, st):
        # where the rival's optimum at inlier_px is the coarse optimum, it sets the cut
        err_sq = _pose_errors_sq(st.candidate, X, uv, K, onehot)
        lower = truncated_cost(err_sq, jnp.full_like(st.tau, thr_sq)) < st.coarse
        cut_sq = _noise_cut_sq(_noise_sigma_sq(err_sq, member, onehot, thr_sq), inlier_px)
        tau = jnp.where(own(lower.astype(dtype)) > 0, own(cut_sq), st.tau)
        return member & (err_sq < tau), st.candidate, st._replace(tau=tau)

    def keep_refit(st, refined, new_err_sq, tried):
        poses, err_sq = keep_if_better(st.poses, st.err_sq, refined, new_err_sq, tried, st.tau)
        return st._replace(poses=poses, err_sq=err_sq)

    def keep_rival_fit(st, refined, new_err_sq, tau_point):
        rival, _ = keep_if_better(st.candidate, _pose_errors_sq(st.candidate, X, uv, K, onehot), refined, new_err_sq,
                                  jnp.ones(k, bool), tau_point)
        return st._replace(candidate=rival)

    def one_fit(stage, st):
        branch = jnp.where(stage < passes, 0, stage - passes + 1)
        weight, start, st = jax.lax.switch(
            branch, (refine_pass, admit, recut, drop_leverage, rival_start, rival_recut), stage, st)
        wanted = (stage < ADMIT) | (stage > LEVERAGE) | jnp.any(st.tried)
        if batch_axis is not None:
            wanted = jax.lax.psum(wanted.astype(jnp.int32), batch_axis) > 0
        refined = jax.lax.cond(wanted, lambda: fit_regions(weight, start), lambda: start)
        new_err_sq = _pose_errors_sq(refined, X, uv, K, onehot)
        keep = jnp.select([stage < passes, stage == ADMIT, stage <= LEVERAGE, stage == RIVAL], [0, 1, 2, 3], 4)
        return jax.lax.switch(keep, (
            lambda: keep_refit(st, refined, new_err_sq, jnp.ones(k, bool)),
            lambda: st._replace(candidate=refined),
            lambda: keep_refit(st, refined, new_err_sq, st.tried),
            lambda: keep_rival_fit(st, refined, new_err_sq, jnp.full_like(st.tau, thr_sq)),
            lambda: keep_rival_fit(st, refined, new_err_sq, st.tau)))

    def start(poses):
        return Stage(poses, _pose_errors_sq(poses, X, uv, K, onehot), poses, jnp.zeros_like(X[:, 0]),
                     jnp.zeros(k, bool), jnp.zeros(k, dtype))

    # the passes for every contender, then the checks for the one of lowest cost in each region
    passed = jax.vmap(lambda poses: jax.lax.fori_loop(0, passes, one_fit, start(poses)))(contenders)
    chosen, coarse_cost = lowest_cost_contender(
        passed.err_sq, jnp.all(jnp.isfinite(passed.poses), axis=-1), region, inlier_px=inlier_px)  # (k,) each
    point_chosen = chosen[jnp.clip(region - 1, 0, k - 1)]  # points of no region: any, they are never used
    per_point = lambda a: jnp.take_along_axis(a, point_chosen[None], axis=0)[0]  # noqa: E731
    poses = jnp.take_along_axis(passed.poses, chosen[None, :, None], axis=0)[0]
    st = Stage(poses, per_point(passed.err_sq), poses, per_point(passed.tau), jnp.zeros(k, bool), coarse_cost)
    st = jax.lax.fori_loop(passes, RIVAL + 2, one_fit, st)

    rival, rival_err_sq = st.candidate, _pose_errors_sq(st.candidate, X, uv, K, onehot)
    rival_finite = jnp.all(jnp.isfinite(rival), axis=-1)
    lower = rival_finite & (truncated_cost(rival_err_sq, st.tau) < truncated_cost(st.err_sq, st.tau))
    poses = jnp.where(lower[:, None], rival, st.poses)
    err_sq = jnp.where(own(lower.astype(dtype)) > 0, rival_err_sq, st.err_sq)
    near = member & (err_sq < st.tau)
    m = _region_sums(onehot, near.astype(dtype))
    shared = _region_sums(onehot, (near & (rival_err_sq < st.tau)).astype(dtype))
    margin = jnp.maximum(1.0, jnp.floor(ambiguous_inlier_frac * m))
    apart = rotation_angle_deg(so3_exp(poses[:, :3]), so3_exp(rival[:, :3])) > ambiguous_rot_deg
    ambiguous = rival_finite & apart & (shared >= m - margin)

    inliers = member & (err_sq < thr_sq)
    return poses, inliers, _region_sums(onehot, inliers.astype(dtype)).astype(jnp.int32), ambiguous


def lowest_cost_contender(err_sq, finite, region, *, inlier_px):
    """Per region, the index (k,) of the contender of lowest truncated cost at the region's
    noise-level cut (docs/semantics.md §3.2 step 6), the cut being that of the contender with the
    lowest cost at inlier_px (the coarse optimum); ties go to the earlier contender. Also that
    lowest cost at inlier_px (k,).

    err_sq (M, N): each point's squared error under its region's pose of each of M contenders
    (``_pose_errors_sq``); finite (M, k): which contender poses are finite.
    """
    k = finite.shape[1]
    dtype = err_sq.dtype
    onehot = region_onehot(region, k, dtype)
    member = region >= 1
    thr_sq = jnp.asarray(inlier_px, dtype) ** 2
    err_sq = jnp.where(member[None], err_sq, 0.0)
    coarse_cost = jnp.where(finite, _region_sums(onehot, jnp.minimum(err_sq, thr_sq).T).T, jnp.inf)
    coarse = jnp.argmin(coarse_cost, axis=0)  # (k,)
    point_region = jnp.clip(region - 1, 0, k - 1)
    coarse_err_sq = jnp.take_along_axis(err_sq, coarse[point_region][None], axis=0)[0]
    cut_sq = _noise_cut_sq(_noise_sigma_sq(coarse_err_sq, member, onehot, thr_sq), inlier_px)  # (k,)
    point_cut_sq = jnp.dot(onehot.T, cut_sq, precision=jax.lax.Precision.HIGHEST)
    cost = jnp.where(finite, _region_sums(onehot, jnp.minimum(err_sq, point_cut_sq[None]).T).T, jnp.inf)
    return jnp.argmin(cost, axis=0), jnp.min(coarse_cost, axis=0)


def borrow_region_poses(X, uv, region, K, poses, *, inlier_px):
    """Each region tries the other regions' poses (k, 6) as hypotheses -> poses (k, 6).

    In a static scene every region moves with the camera, so a well-conditioned region's pose is
    a good hypothesis for a weak one (a narrow, far depth band), whose own minimal samples can
    settle in the wrong basin of the valley where rotation trades against translation. Per
    region, the other regions' poses are scored on its members by the summed squared error
    truncated at the region's noise-level cut (clip(NOISE_CUT sigma, MIN_CUT_PX, inlier_px), sigma
    from its own pose's inliers at inlier_px), and the best replaces its pose only where it
    scores strictly lower; the refinement (``refine_poses``) then fits it to the region's own
    inliers. A region whose points move otherwise (an unmasked object, a warped layer) keeps
    its own pose: the borrowed ones do not explain them.
    """
    k = poses.shape[0]
    dtype = X.dtype
    onehot = region_onehot(region, k, dtype)
    member = region >= 1
    finite = jnp.all(jnp.isfinite(poses), axis=-1)
    safe = jnp.where(finite[:, None], poses, 0.0)
    _, trunc = _truncated_errors_sq(so3_exp(safe[:, :3]), safe[:, 3:], X, uv, K, member, inlier_px)  # (k poses, N)
    # each region's noise-level cut, from its own pose's inliers at inlier_px
    own_trunc = jnp.sum(onehot * trunc, axis=0)  # (N,) under the point's own region's pose
    sigma_sq = _noise_sigma_sq(own_trunc, member, onehot, jnp.asarray(inlier_px, dtype) ** 2)
    point_cut_sq = jnp.dot(onehot.T, _noise_cut_sq(sigma_sq, inlier_px), precision=jax.lax.Precision.HIGHEST)
    cost = _region_sums(onehot, jnp.minimum(trunc, point_cut_sq[None]).T)  # (k regions, k poses)
    cost = jnp.where(finite[None, :], cost, jnp.inf)
    own_cost = jnp.diagonal(cost)
    lender = jnp.argmin(jnp.where(jnp.eye(k, dtype=bool), jnp.inf, cost), axis=1)
    borrow = cost[jnp.arange(k), lender] < own_cost
    return jnp.where(borrow[:, None], safe[lender], poses)


def samples_needed(inlier_frac, sample_size, confidence):
    """RANSAC's adaptive stopping rule: samples after which an all-inlier sample has been drawn
    with probability ``confidence``, log(1 - confidence) / log(1 - w^s) (inf when w = 0)."""
    p_good = jnp.clip(inlier_frac, 0.0, 1.0) ** sample_size
    return jnp.where(p_good >= 1.0, 1.0, jnp.log1p(-confidence) / jnp.log1p(-jnp.minimum(p_good, 1.0 - 1e-7)))


def _region_candidates(X, uv, K, order, start, n_members, key, *, hypotheses, sample_size, inlier_px,
                       sample_steps, lo_steps, score_points, lo_candidates, chunk, confidence, n_refined):
    """The ``n_refined`` best distinct pose6 (n_refined, 6) of one region, best first, from
    minimal samples, scoring and local optimisation.

    Samples are drawn up front (``hypotheses`` of them) and processed ``chunk`` at a time: each
    gives sample_size + 1 candidates (``sample_candidates``), scored on the region's scoring
    subset; the ``lo_candidates`` best so far are kept (lowest summed truncated squared error,
    MSAC, then draw order). Drawing stops once ``samples_needed`` for the best inlier fraction
    and ``confidence`` are done (confidence 1: all of them). Each kept candidate then gets one
    least-squares fit (``lo_steps`` Gauss-Newton steps) on its inliers, and the best of
    candidates and fits (the lowest truncated cost at the best one's noise-level cut) is returned
    with the next best more than DISTINCT_DEG apart.
    """
    N = X.shape[0]
    dtype = X.dtype
    key_sample, key_subset = jax.random.split(key)
    n_scored = min(score_points, N)
    scored_idx, scored_valid = scoring_subset(key_subset, order, start, n_members, n_scored)
    X_s, uv_s = X[scored_idx], uv[scored_idx]

    n_chunks = -(-hypotheses // chunk)
    positions = sample_distinct(key_sample, n_members, n_chunks * chunk, sample_size)
    sample_idx = order[jnp.clip(start + positions, 0, N - 1)]
    per_sample = sample_size + 1
    drawn = (jnp.arange(n_chunks * chunk) < hypotheses).reshape(n_chunks, chunk)
    n_keep = min(lo_candidates, hypotheses * per_sample)
    n_valid_scored = jnp.minimum(n_members, n_scored)
    need_factor = jnp.asarray(confidence, dtype)

    def draw(state):
        c, top_pose, top_rank, best_count = state
        idx = jax.lax.dynamic_slice_in_dim(sample_idx, c * chunk, chunk)
        poses = sample_candidates(X, uv, K, idx, sample_steps=sample_steps)
        ok = jnp.all(jnp.isfinite(poses), axis=-1) & jnp.repeat(drawn[c], per_sample)
        poses = jnp.where(ok[:, None], poses, jnp.zeros(6, dtype))
        _, count, trunc = _score(so3_exp(poses[:, :3]), poses[:, 3:], X_s, uv_s, K, scored_valid, inlier_px)
        rank = _rank_key(ok, trunc)
        all_rank = jnp.concatenate([top_rank, rank])
        _, keep = jax.lax.top_k(all_rank, n_keep)
        best_count = jnp.maximum(best_count, jnp.max(jnp.where(ok, count, 0)))
        return c + 1, jnp.concatenate([top_pose, poses])[keep], all_rank[keep], best_count

    def more(state):
        c, _, _, best_count = state
        inlier_frac = best_count / jnp.maximum(n_valid_scored, 1).astype(dtype)
        return (c < n_chunks) & (n_members >= sample_size) & (
            (c * chunk).astype(dtype) < samples_needed(inlier_frac, sample_size, need_factor))

    init = (jnp.int32(0), jnp.zeros((n_keep, 6), dtype), jnp.full(n_keep, -jnp.inf, dtype), jnp.int32(0))
    _, top_pose, top_rank, _ = jax.lax.while_loop(more, draw, init)

    # Local optimisation of the leading candidates on the scored points: one least-squares fit
    # on each one's inliers; the best of candidates and fits goes on to the full refinement.
    inl_top, _, _ = _score(so3_exp(top_pose[:, :3]), top_pose[:, 3:], X_s, uv_s, K, scored_valid, inlier_px)
    fits, _ = jax.vmap(lambda p, w: solve_pnp(X_s, uv_s, w, K, steps=lo_steps, pose0=p))(top_pose, inl_top.astype(dtype))
    fits = jnp.where(jnp.all(jnp.isfinite(fits), axis=-1, keepdims=True), fits, top_pose)
    contenders = jnp.concatenate([top_pose, fits])
    R_c = so3_exp(contenders[:, :3])
    inl, count, trunc = _score(R_c, contenders[:, 3:], X_s, uv_s, K, scored_valid, inlier_px)
    coarse = _best(trunc)
    # The pose is chosen at the coarse optimum's noise level (the final refinement's cut,
    # docs/semantics.md §3.2): at inlier_px a pose slid along an ill-conditioned valley keeps
    # every point of the region.
    err_sq = (trunc[coarse] - (jnp.sum(scored_valid) - count[coarse]) * inlier_px**2) / jnp.maximum(count[coarse], 1)
    cut = jnp.clip(NOISE_CUT * jnp.sqrt(jnp.maximum(err_sq, 0.0) / 2.0), jnp.minimum(MIN_CUT_PX, inlier_px), inlier_px)
    _, _, trunc_cut = _score(R_c, contenders[:, 3:], X_s, uv_s, K, scored_valid, cut)
    return contenders[_leading_distinct(trunc_cut, R_c, n_refined)]


def _leading_distinct(cost, R, count):
    """Indices (count,) of the lowest ``cost`` (m,), each more than DISTINCT_DEG in rotation (R
    (m, 3, 3)) from the ones before it; the lowest repeated where fewer are distinct."""
    chosen = [_best(cost)]
    for _ in range(count - 1):  # static, count is small
        near = jnp.any(jnp.stack([rotation_angle_deg(R[c][None], R) <= DISTINCT_DEG for c in chosen]), axis=0)
        rest = jnp.where(near, jnp.inf, cost)
        chosen.append(jnp.where(jnp.isfinite(jnp.min(rest)), _best(rest), chosen[0]))
    return jnp.stack(chosen)


def ransac_pnp_regions(
    X,
    uv,
    region,
    K,
    keys,
    rival_R=None,
    *,
    hypotheses,
    sample_size=4,
    inlier_px,
    min_inlier_frac,
    min_points,
    steps,
    confidence=0.99,
    sample_steps=3,
    lo_steps=3,
    score_points=512,
    lo_candidates=4,
    refine_passes=2,
    chunk=10,
    ambiguous_rot_deg=3.0,
    ambiguous_inlier_frac=0.05,
    borrow=True,
    refined_contenders=2,
    batch_axis=None,
):
    """Robust pose of every region of a pair -> PnPResult (leading axis k = len(keys)).

    X (N, 3) points in camera i-1, uv (N, 2) their pixels in frame i, region (N,) int region of
    each point (1..k, 0: none), K (3, 3) intrinsics of frame i, keys (k,): one PRNG key per
    region (same keys, same result), rival_R (3, 3): the rotation the rival starts from (the
    camera's; None: the identity). Inlier: in front of the camera and reprojection error <
    inlier_px [px]. Per region (vmapped):

    1. Samples of ``sample_size`` distinct members, ``chunk`` at a time, each giving sample_size
       + 1 candidate poses (``sample_candidates``: the Gauss-Newton fit of the sample with
       ``sample_steps`` steps, and its leave-one-out fits), scored on the members (at most
       ``score_points`` of them: all when they fit, else a stratified random subset); drawing
       stops after ``hypotheses`` samples, or earlier once RANSAC's adaptive rule
       (``samples_needed``) is met at ``confidence`` for the best inlier fraction seen.
    2. The ``lo_candidates`` best (lowest summed truncated squared error, MSAC, then draw order)
       get one least-squares fit on their inliers (local optimisation, ``lo_steps`` Gauss-Newton
       steps: it only has to pick the inlier set); the ``refined_contenders`` best of these
       (at the best one's noise-level cut, DISTINCT_DEG apart) go on.
    2b. With ``borrow`` (and k > 1), ``borrow_region_poses``: each region also scores the other
       regions' poses from step 2 on its members and takes the best one in place of its first
       contender where it scores lower.
    3. All regions together, ``refine_poses``: ``refine_passes`` least-squares fits (``steps``
       Gauss-Newton steps each) of each contender on its current inliers, the one of lowest
       cost kept per region (``lowest_cost_contender``), then its checks and the rival, which
       replaces it where it fits better and else may make it ambiguous; inliers and n_inliers
       are those of the final pose.
    Status: 1 when members < min_points; else 0 when inliers >= max(4, floor(min_inlier_frac *
    members)), the pose is finite and det(R) ~ 1; else 2. ``batch_axis``: the name of a ``vmap``
    axis the call is mapped over (``refine_poses``). Shape-like arguments (hypotheses,
    sample_size, steps, sample_steps, lo_steps, score_points, lo_candidates, refine_passes, chunk,
    borrow, refined_contenders) must be static under jit.
    """
    k = keys.shape[0]
    dtype = X.dtype
    region = jnp.where(jnp.isfinite(X).all(-1) & jnp.isfinite(uv).all(-1), region, 0).astype(jnp.int32)
    member = region >= 1
    X = jnp.where(member[:, None], X, jnp.array([0.0, 0.0, 1.0], dtype))  # padding never leaks in
    uv = jnp.where(member[:, None], uv, 0.0).astype(dtype)
    K = jnp.asarray(K, dtype)
    order, start, n_members = group_by_region(region, k)

    best = jax.vmap(
        lambda s, n, key: _region_candidates(
            X, uv, K, order, s, n, key, hypotheses=hypotheses, sample_size=sample_size, inlier_px=inlier_px,
            sample_steps=sample_steps, lo_steps=lo_steps, score_points=score_points, lo_candidates=lo_candidates,
            chunk=chunk, confidence=confidence, n_refined=refined_contenders)
    )(start, n_members, keys)  # (k, refined_contenders, 6)

    if borrow and k > 1:
        best = best.at[:, 0].set(borrow_region_poses(X, uv, region, K, best[:, 0], inlier_px=inlier_px))
    rival_R = jnp.eye(3, dtype=dtype) if rival_R is None else jnp.asarray(rival_R, dtype)
    poses, inliers, n_inliers, ambiguous = refine_poses(
        X, uv, region, K, jnp.swapaxes(best, 0, 1), rival_R, inlier_px=inlier_px, steps=steps, passes=refine_passes,
        ambiguous_rot_deg=ambiguous_rot_deg, ambiguous_inlier_frac=ambiguous_inlier_frac, batch_axis=batch_axis)
    R, t = so3_exp(poses[:, :3]), poses[:, 3:]
    onehot = region_onehot(region, k, dtype)
    err = jnp.sqrt(jnp.where(member, _own_pose_errors_sq(poses, X, uv, K, onehot)[0], 0.0))
    reproj_px = _region_sums(onehot, err) / jnp.maximum(n_members, 1).astype(dtype)

    need = jnp.maximum(4, jnp.floor(min_inlier_frac * n_members).astype(jnp.int32))
    proper = jnp.abs(jnp.linalg.det(R) - 1.0) < 1e-3
    good = (n_inliers >= need) & jnp.all(jnp.isfinite(poses), axis=-1) & proper & jnp.isfinite(reproj_px)
    status = jnp.where(
        n_members < min_points,
        REGION_TOO_FEW_POINTS,
        jnp.where(good, REGION_OK, REGION_REJECTED),
    ).astype(jnp.int32)
    uncertainty = pose_uncertainty(X, uv, region, K, poses, inliers)
    return PnPResult(R, t, status, n_members, n_inliers, inliers, reproj_px, ambiguous, uncertainty)


def ransac_pnp(X, uv, member, K, key, rival_R=None, **options):
    """Robust pose of one region -> PnPResult (no region axis); ``member`` (N,) bool masks it.

    ``ransac_pnp_regions`` with k = 1; same options. Vmaps over regions (member masks, keys) and
    pairs, but scoring every region on all N points: prefer ``ransac_pnp_regions`` for the
    regions of one pair.
    """
    res = ransac_pnp_regions(X, uv, jnp.asarray(member).astype(jnp.int32), K, key[None], rival_R, **options)
    return jax.tree.map(lambda field: field[0], res)._replace(inliers=res.inliers)
