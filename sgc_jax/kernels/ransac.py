"""PnP-RANSAC: vmapped minimal-sample solves -> score -> select -> refine (docs/semantics.md
§3.2 step 6, §7.1).

``ransac_pnp_regions`` handles every region of a pair at once. Fixed shapes throughout: N padded
points, each tagged with its region 1..k (0: none). A counting sort (``pnp.label_ranks``) groups
the points by region, so each region draws its samples and scores its candidates on its own
members only, and the local optimisation solves all regions jointly (each point against its own
region's pose, in ``pnp.RegionSlots`` chunks): a pair costs O(N) per least-squares step, not
O(k N). ``ransac_pnp`` is the one-region form. Poses map camera i-1 coordinates to camera i
(x_i = R x_{i-1} + t); errors are in pixels of frame i.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp

from ..codes import REGION_OK, REGION_REJECTED, REGION_TOO_FEW_POINTS
from ..config import MIN_CUT_PX, NOISE_CUT
from .geometry import rotation_angle_deg, so3_exp, so3_log
from .pnp import (initial_pose, label_ranks, project_columns, project_pointwise, region_onehot, region_slots,
                  solve_pnp, solve_pnp_regions, translation_for_rotation)
from .uncertainty import PoseUncertainty, pose_uncertainty


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


# RANSAC's adaptive stop counts the members within this many pixels of a candidate (at most
# inlier_px): within inlier_px (8 px) nearly every member of a warped or mixed region fits some
# early candidate, so the draws stopped after one chunk while better basins were still to be found
# (docs/semantics.md §7.1; bench/RESULTS.md).
ADAPTIVE_PX = 2.0
# ... and draws this many times the samples its rule needs: one sample of inliers only is not
# enough where a region's cost has optima of nearly equal cost; its lowest basin must be drawn.
ADAPTIVE_DRAWS = 3

# One truncated cost is lower than another when by more than this fraction of it, beyond
# float32's rounding of the sum: two fits that reach the same optimum tie, whatever the order of
# the sum (a program fused otherwise, on one device or several, makes the same choices).
COST_RTOL = 1e-6


def _lower(cost_a, cost_b):
    """cost_a lower than cost_b by more than COST_RTOL of it (elementwise, finite cost_a)."""
    return jnp.isfinite(cost_a) & (cost_a < cost_b - COST_RTOL * jnp.abs(cost_b))


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


class LocalOptima(NamedTuple):
    """Poses (k, 6), each point's squared error under its region's pose (N,) [px^2], and each
    region's truncated cost (k,) at the threshold they were optimised at."""

    poses: jax.Array
    err_sq: jax.Array
    cost: jax.Array


def local_optima(X, uv, region, K, start, tau_sq_point, *, steps, max_rounds, slots=None):
    """Every region's local optimum of the truncated cost at its threshold, from ``start`` (k, 6)
    (docs/semantics.md §3.2 step 6): least squares on the members within the threshold
    (``tau_sq_point`` (N,): each point's region's squared threshold), repeated on the new ones
    until they stop changing, each fit kept only when it lowers the truncated cost; a region
    stops at its first fit that does not, with fewer than 4 such members, or after
    ``max_rounds`` fits -> LocalOptima.

    All regions fit together (``solve_pnp_regions``, at most ``steps`` Levenberg-Marquardt steps
    per fit); the loop runs until every region (and, under ``vmap``, every mapped call) has
    stopped.
    """
    k = start.shape[0]
    dtype = X.dtype
    onehot = region_onehot(region, k, dtype)
    member = region >= 1
    own = lambda per_region: jnp.dot(onehot.T, per_region, precision=jax.lax.Precision.HIGHEST)  # noqa: E731
    slots = region_slots(region, k, dtype) if slots is None else slots

    def evaluate(poses):
        err_sq = _pose_errors_sq(poses, X, uv, K, onehot)
        within = member & (err_sq < tau_sq_point)
        cost = _region_sums(onehot, jnp.where(member, jnp.minimum(err_sq, tau_sq_point), 0.0))
        return err_sq, within, cost, _region_sums(onehot, within.astype(dtype))

    def fit(state):
        poses, err_sq, cost, within, n_within, done, rounds = state
        fitted, _ = solve_pnp_regions(X, uv, (within & (own(done.astype(dtype)) == 0)).astype(dtype), region, K,
                                      poses, steps=steps, slots=slots)
        new_err_sq, new_within, new_cost, new_n = evaluate(fitted)
        better = ~done & jnp.all(jnp.isfinite(fitted), axis=-1) & _lower(new_cost, cost)
        point_better = own(better.astype(dtype)) > 0
        changed = _region_sums(onehot, (new_within != within).astype(dtype)) > 0
        return (jnp.where(better[:, None], fitted, poses), jnp.where(point_better, new_err_sq, err_sq),
                jnp.where(better, new_cost, cost), jnp.where(point_better, new_within, within),
                jnp.where(better, new_n, n_within), done | ~better | ~changed | (new_n < 4), rounds + 1)

    def more(state):
        return (state[-1] < max_rounds) & jnp.any(~state[-2])

    err_sq, within, cost, n_within = evaluate(start)
    done = (n_within < 4) | ~jnp.all(jnp.isfinite(start), axis=-1)
    poses, err_sq, cost, *_ = jax.lax.while_loop(more, fit, (start, err_sq, cost, within, n_within, done, 0))
    return LocalOptima(poses, err_sq, cost)


def refine_poses(X, uv, region, K, starts, rival_R, *, inlier_px, steps, max_rounds, ambiguous_rot_deg,
                 ambiguous_inlier_frac):
    """The local pose of every region from M starts (starts (M, k, 6)), as docs/semantics.md
    §3.2 step 6 and §3.3 define it:

    1. each start's local optimum at inlier_px (``local_optima``); the lowest truncated cost is
       the coarse optimum, whose noise-level cut clip(NOISE_CUT sigma, min(MIN_CUT_PX,
       inlier_px), inlier_px) (sigma^2 = mean e^2 / 2 over its members within inlier_px) is the
       region's cut tau;
    2. the pose: the local optimum at tau from the coarse optimum;
    3. the rival: from the rotation rival_R (3, 3) (the camera's) with the translation that best
       explains the pose's members within tau (``translation_for_rotation``), the local optimum
       at inlier_px (where it costs less than the coarse optimum, it is the coarse optimum and
       its cut is tau), then at tau. It replaces the pose where it costs less at tau; otherwise
       the pose is ambiguous where the rival lies more than ``ambiguous_rot_deg`` away in
       rotation and keeps all but max(1, floor(ambiguous_inlier_frac m)) of the m members within
       tau of the pose.
    -> (poses (k, 6), inliers (N,) at inlier_px under each point's own final pose (the quality
    rule's inputs), n_inliers (k,) int32, ambiguous (k,) bool)
    """
    k = starts.shape[1]
    dtype = X.dtype
    onehot = region_onehot(region, k, dtype)
    member = region >= 1
    thr_sq = jnp.asarray(inlier_px, dtype) ** 2
    own = lambda per_region: jnp.dot(onehot.T, per_region, precision=jax.lax.Precision.HIGHEST)  # noqa: E731
    slots = region_slots(region, k, dtype)  # one layout for every joint solve
    optimise = functools.partial(local_optima, X, uv, region, K, steps=steps, max_rounds=max_rounds, slots=slots)
    at_inlier_px = jnp.full(X.shape[:1], thr_sq)

    def cut_of(err_sq):
        return own(_noise_cut_sq(_noise_sigma_sq(err_sq, member, onehot, thr_sq), inlier_px))

    def truncated_cost(err_sq, tau_sq_point):
        return _region_sums(onehot, jnp.where(member, jnp.minimum(err_sq, tau_sq_point), 0.0))

    # one start after another: vmapped, each fit's loop would run until the slowest start is done
    coarse_all = jax.lax.map(lambda start: optimise(start, at_inlier_px), starts)
    costs = jnp.where(jnp.isfinite(coarse_all.cost), coarse_all.cost, jnp.inf)
    chosen = jnp.argmax(~_lower(jnp.min(costs, axis=0), costs), axis=0)  # (k,) the first of the lowest
    point_chosen = chosen[jnp.clip(region - 1, 0, k - 1)]
    coarse = LocalOptima(jnp.take_along_axis(coarse_all.poses, chosen[None, :, None], axis=0)[0],
                         jnp.take_along_axis(coarse_all.err_sq, point_chosen[None], axis=0)[0],
                         jnp.take_along_axis(coarse_all.cost, chosen[None], axis=0)[0])
    tau = cut_of(coarse.err_sq)
    pose = optimise(coarse.poses, tau)

    t = translation_for_rotation(X, uv, member & (pose.err_sq < tau), region, K, rival_R, k)
    rival_start = jnp.concatenate([jnp.broadcast_to(so3_log(rival_R), (k, 3)), t], axis=-1)
    rival_coarse = optimise(rival_start, at_inlier_px)
    tau = jnp.where(own(_lower(rival_coarse.cost, coarse.cost).astype(dtype)) > 0, cut_of(rival_coarse.err_sq), tau)
    rival = optimise(rival_coarse.poses, tau)

    rival_finite = jnp.all(jnp.isfinite(rival.poses), axis=-1)
    # the rival's cost is at the final cut already; the pose's is re-taken there (the rival's cut may replace it)
    lower = rival_finite & _lower(rival.cost, truncated_cost(pose.err_sq, tau))
    poses = jnp.where(lower[:, None], rival.poses, pose.poses)
    err_sq = jnp.where(own(lower.astype(dtype)) > 0, rival.err_sq, pose.err_sq)
    near = member & (err_sq < tau)
    m = _region_sums(onehot, near.astype(dtype))
    shared = _region_sums(onehot, (near & (rival.err_sq < tau)).astype(dtype))
    margin = jnp.maximum(1.0, jnp.floor(ambiguous_inlier_frac * m))
    apart = rotation_angle_deg(so3_exp(poses[:, :3]), so3_exp(rival.poses[:, :3])) > ambiguous_rot_deg
    ambiguous = rival_finite & apart & (shared >= m - margin)

    inliers = member & (err_sq < thr_sq)
    return poses, inliers, _region_sums(onehot, inliers.astype(dtype)).astype(jnp.int32), ambiguous


def borrow_region_poses(X, uv, region, K, poses, *, inlier_px):
    """For each region, the other region's pose (poses (k, 6)) of lowest truncated cost at
    inlier_px on its members -> (k, 6); its own pose where no other is finite.

    In a static scene every region moves with the camera, so a well-conditioned region's pose is
    a good start for a weak one (a narrow, far depth band), whose own minimal samples can settle
    in the wrong basin of the valley where rotation trades against translation.
    """
    k = poses.shape[0]
    onehot = region_onehot(region, k, X.dtype)
    member = region >= 1
    finite = jnp.all(jnp.isfinite(poses), axis=-1)
    safe = jnp.where(finite[:, None], poses, 0.0)
    _, trunc = _truncated_errors_sq(so3_exp(safe[:, :3]), safe[:, 3:], X, uv, K, member, inlier_px)  # (k poses, N)
    cost = _region_sums(onehot, trunc.T)  # (k regions, k poses)
    cost = jnp.where(finite[None, :] & ~jnp.eye(k, dtype=bool), cost, jnp.inf)
    lender = jnp.argmin(cost, axis=1)
    return jnp.where(jnp.isfinite(cost[jnp.arange(k), lender])[:, None], safe[lender], poses)


def samples_needed(inlier_frac, sample_size, confidence):
    """RANSAC's adaptive stopping rule: samples after which an all-inlier sample has been drawn
    with probability ``confidence``, log(1 - confidence) / log(1 - w^s) (inf when w = 0)."""
    p_good = jnp.clip(inlier_frac, 0.0, 1.0) ** sample_size
    return jnp.where(p_good >= 1.0, 1.0, jnp.log1p(-confidence) / jnp.log1p(-jnp.minimum(p_good, 1.0 - 1e-7)))


def _region_candidates(X, uv, K, order, start, n_members, key, *, hypotheses, sample_size, inlier_px,
                       sample_steps, lo_steps, score_points, lo_candidates, fit_points, chunk, confidence):
    """The best pose6 (6,) of one region from minimal samples, scoring and one least-squares fit.

    Samples are drawn up front (``hypotheses`` of them) and processed ``chunk`` at a time: each
    gives sample_size + 1 candidates (``sample_candidates``), scored on the region's scoring
    subset; the ``lo_candidates`` best so far are kept (lowest summed truncated squared error,
    MSAC, then draw order). Drawing stops once ADAPTIVE_DRAWS x ``samples_needed`` for the best
    fraction of members within ADAPTIVE_PX (at most inlier_px) of a candidate and ``confidence``
    are done (confidence 1: all of them). Each kept candidate then gets one least-squares fit
    (``lo_steps`` Gauss-Newton steps) on its inliers among at most ``fit_points`` of the scored
    members, spread evenly; the lowest truncated cost at inlier_px (on all scored members) of
    candidates and fits is returned.
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
    close_sq = jnp.minimum(jnp.asarray(ADAPTIVE_PX, dtype), inlier_px) ** 2

    def draw(state):
        c, top_pose, top_rank, best_count = state
        idx = jax.lax.dynamic_slice_in_dim(sample_idx, c * chunk, chunk)
        poses = sample_candidates(X, uv, K, idx, sample_steps=sample_steps)
        ok = jnp.all(jnp.isfinite(poses), axis=-1) & jnp.repeat(drawn[c], per_sample)
        poses = jnp.where(ok[:, None], poses, jnp.zeros(6, dtype))
        inliers, trunc_sq = _truncated_errors_sq(so3_exp(poses[:, :3]), poses[:, 3:], X_s, uv_s, K, scored_valid,
                                                 inlier_px)
        rank = _rank_key(ok, jnp.sum(trunc_sq, axis=-1))
        all_rank = jnp.concatenate([top_rank, rank])
        _, keep = jax.lax.top_k(all_rank, n_keep)
        close = jnp.sum(inliers & (trunc_sq < close_sq), axis=-1, dtype=jnp.int32)
        best_count = jnp.maximum(best_count, jnp.max(jnp.where(ok, close, 0)))
        return c + 1, jnp.concatenate([top_pose, poses])[keep], all_rank[keep], best_count

    def more(state):
        c, _, _, best_count = state
        close_frac = best_count / jnp.maximum(n_valid_scored, 1).astype(dtype)
        return (c < n_chunks) & (n_members >= sample_size) & (
            (c * chunk).astype(dtype) < ADAPTIVE_DRAWS * samples_needed(close_frac, sample_size, need_factor))

    init = (jnp.int32(0), jnp.zeros((n_keep, 6), dtype), jnp.full(n_keep, -jnp.inf, dtype), jnp.int32(0))
    _, top_pose, _, _ = jax.lax.while_loop(more, draw, init)

    # one least-squares fit of each leading candidate on its inliers among fit_points of the
    # scored members (every m / fit_points-th): enough to tell its basin, a quarter of the cost
    n_fit = min(fit_points, n_scored)
    n_valid = jnp.minimum(n_members, n_scored)
    i = jnp.arange(n_fit)
    fit_idx = jnp.where(n_valid <= n_fit, i, (i * n_valid) // n_fit)
    X_f, uv_f = X_s[fit_idx], uv_s[fit_idx]
    inl_top, _, _ = _score(so3_exp(top_pose[:, :3]), top_pose[:, 3:], X_f, uv_f, K, i < n_valid, inlier_px)
    fits, _ = jax.vmap(lambda p, w: solve_pnp(X_f, uv_f, w, K, steps=lo_steps, pose0=p))(top_pose, inl_top.astype(dtype))
    fits = jnp.where(jnp.all(jnp.isfinite(fits), axis=-1, keepdims=True), fits, top_pose)
    candidates = jnp.concatenate([top_pose, fits])
    _, _, trunc = _score(so3_exp(candidates[:, :3]), candidates[:, 3:], X_s, uv_s, K, scored_valid, inlier_px)
    return candidates[_best(trunc)]


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
    lo_candidates=16,
    fit_points=128,
    max_rounds=5,
    chunk=10,
    ambiguous_rot_deg=3.0,
    ambiguous_inlier_frac=0.05,
    borrow=True,
    global_t=None,
):
    """Robust pose of every region of a pair -> PnPResult (leading axis k = len(keys)).

    X (N, 3) points in camera i-1, uv (N, 2) their pixels in frame i, region (N,) int region of
    each point (1..k, 0: none), K (3, 3) intrinsics of frame i, keys (k,): one PRNG key per
    region (same keys, same result), rival_R (3, 3): the camera's rotation R_g (None: the
    identity), global_t (3,): the camera's translation s t_g in the units of X (None: not
    known). Inlier: in front of the camera and reprojection error < inlier_px [px].

    1. Per region (vmapped), ``_region_candidates``: samples of ``sample_size`` distinct
       members, ``chunk`` at a time, each giving sample_size + 1 candidate poses
       (``sample_candidates``), scored on the members (at most ``score_points`` of them: all
       when they fit, else a stratified random subset); drawing stops after ``hypotheses``
       samples, or earlier after ADAPTIVE_DRAWS x the samples RANSAC's adaptive rule needs at
       ``confidence``; the ``lo_candidates`` best get one least-squares fit (``lo_steps``
       Gauss-Newton steps, on at most ``fit_points`` of the scored members), and the best of all
       starts the region's search.
    2. Starts besides it: with ``borrow`` (and k > 1) the pair's other region pose that fits the
       region best (``borrow_region_poses``), and the camera's pose (rival_R, global_t).
    3. All regions together, ``refine_poses``: the coarse optimum, the pose at the noise-level
       cut and the rival (docs/semantics.md §3.2 step 6, §3.3), each local optimum at most
       ``max_rounds`` least-squares fits of at most ``steps`` Levenberg-Marquardt steps.
    Status: 1 when members < min_points; else 0 when inliers (of the final pose) >= max(4,
    floor(min_inlier_frac * members)), the pose is finite and det(R) ~ 1; else 2. Shape-like
    arguments (hypotheses, sample_size, steps, sample_steps, lo_steps, score_points,
    lo_candidates, fit_points, max_rounds, chunk, borrow) must be static under jit.
    """
    k = keys.shape[0]
    dtype = X.dtype
    region = jnp.where(jnp.isfinite(X).all(-1) & jnp.isfinite(uv).all(-1), region, 0).astype(jnp.int32)
    member = region >= 1
    X = jnp.where(member[:, None], X, jnp.array([0.0, 0.0, 1.0], dtype))  # padding never leaks in
    uv = jnp.where(member[:, None], uv, 0.0).astype(dtype)
    K = jnp.asarray(K, dtype)
    order, start, n_members = group_by_region(region, k)

    own_best = jax.vmap(
        lambda s, n, key: _region_candidates(
            X, uv, K, order, s, n, key, hypotheses=hypotheses, sample_size=sample_size, inlier_px=inlier_px,
            sample_steps=sample_steps, lo_steps=lo_steps, score_points=score_points, lo_candidates=lo_candidates,
            fit_points=fit_points, chunk=chunk, confidence=confidence)
    )(start, n_members, keys)  # (k, 6)

    rival_R = jnp.eye(3, dtype=dtype) if rival_R is None else jnp.asarray(rival_R, dtype)
    starts = [own_best]
    if borrow and k > 1:
        starts.append(borrow_region_poses(X, uv, region, K, own_best, inlier_px=inlier_px))
    if global_t is not None:
        # the camera's rotation with the translation of the members the camera's motion explains:
        # s t_g carries the scale fit's float32 rounding, which a change of units moves; the
        # members within inlier_px of it, and the linear fit on them, do not move
        global_t = jnp.asarray(global_t, dtype)
        err, in_front = reprojection_error_px(rival_R, global_t, X, uv, K)
        t = translation_for_rotation(X, uv, member & in_front & (err < inlier_px), region, K, rival_R, k)
        t = jnp.where(jnp.all(jnp.isfinite(global_t)), t, jnp.nan)  # no finite camera pose: no start
        starts.append(jnp.concatenate([jnp.broadcast_to(so3_log(rival_R), (k, 3)), t], axis=-1))
    poses, inliers, n_inliers, ambiguous = refine_poses(
        X, uv, region, K, jnp.stack(starts), rival_R, inlier_px=inlier_px, steps=steps, max_rounds=max_rounds,
        ambiguous_rot_deg=ambiguous_rot_deg, ambiguous_inlier_frac=ambiguous_inlier_frac)
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
