"""PnP-RANSAC over every region of a pair: minimal samples -> scored candidates -> starts ->
local optima (docs/semantics.md §3.2 step 6, §7.1).

Fixed shapes: N padded points, each tagged with its region 1..k (0: none). A counting sort groups
them by region, so each region draws and scores on its own members, and the local optimisation
solves all regions jointly: a pair costs O(N) per least-squares step, not O(k N). Poses map
camera i-1 to camera i (Y = R X + t); errors are in pixels of frame i.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from ..codes import REGION_OK, REGION_REJECTED, REGION_TOO_FEW_POINTS
from .joint_pnp import polish_poses
from .lanes import while_loop_by_lane
from .local_optimum import borrow_region_poses, refine_poses
from .pnp import gauss_newton_updates, initial_pose, projected_columns, solve_pnp, translation_for_rotation
from .ransac_options import RansacOptions
from .regions import group_by_region, region_onehot, region_slots, region_sums
from .so3 import so3_exp, so3_log
from .truncated_cost import msac_score, own_pose_errors_sq, truncated_errors_sq
from .uncertainty import PoseUncertainty, pose_uncertainty

# The adaptive stop counts the members within this many pixels of a candidate (at most
# inlier_px): within 8 px nearly every member of a warped region fits some early candidate, and
# the draws stopped while better basins were still to be found (bench/history/issue-20.md,
# "Both engines search until the optimum stops moving").
ADAPTIVE_PX = 2.0
# ... and draws this many times the samples its rule asks for: where a region's cost has optima of
# nearly equal cost, one all-inlier sample is not enough to reach the lowest.
ADAPTIVE_DRAWS = 3


class PnPResult(NamedTuple):
    """Each region's pose (R, t) and diagnostics, leading axis k (none from ``ransac_pnp``)."""

    R: jax.Array  # (k, 3, 3)
    t: jax.Array  # (k, 3)
    status: jax.Array  # (k,) int32: REGION_OK, REGION_TOO_FEW_POINTS or REGION_REJECTED
    n_members: jax.Array  # (k,) int32
    n_inliers: jax.Array  # (k,) int32, of the final pose
    inliers: jax.Array  # (N,) bool: an inlier of its own region's final pose
    reproj_px: jax.Array  # (k,) mean reprojection error over the members [px]
    ambiguous: jax.Array  # (k,) bool: a rival pose fits the same members (docs/semantics.md §3.3)
    uncertainty: PoseUncertainty
    fitted: jax.Array  # (N,) bool: the points its region's final pose is the least-squares fit of


def sample_distinct(key, n, hypotheses, sample_size):
    """(hypotheses, sample_size) int32 positions in [0, n), distinct within a row, uniform; the
    j-th pick ranks among the n - j positions left, skipping the taken ones. Meaningless for n < sample_size."""
    u = jax.random.uniform(key, (hypotheses, sample_size))
    picks = []
    for j in range(sample_size):  # static and small
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
    u_hat, v_hat, in_front = projected_columns(R, t, K, X[:, 0], X[:, 1], X[:, 2])
    return jnp.hypot(u_hat - uv[:, 0], v_hat - uv[:, 1]), in_front


def scoring_subset(key, order, start, n_members, score_points):
    """(indices (S,) of the members candidates are scored on, valid (S,)), S = score_points: all
    members in index order when they fit, else one random member per stratum of n / S consecutive
    ones. ``order`` (N,) lists the points by region, this region's from ``start``."""
    N = order.shape[0]
    i = jnp.arange(score_points)
    u = jax.random.uniform(key, (score_points,))
    stratum = jnp.floor((i + u) * (n_members / score_points)).astype(jnp.int32)
    pos = jnp.where(n_members <= score_points, i, jnp.minimum(stratum, n_members - 1))
    return order[jnp.clip(start + pos, 0, N - 1)], i < n_members


def sample_candidates(sample_X, sample_uv, K, *, sample_updates):
    """Candidate poses (H, 6) from H samples of s points (sample_X (H, s, 3), sample_uv (H, s, 2)):
    each sample's fit (``initial_pose``, then ``sample_updates`` Gauss-Newton updates)."""
    weight = jnp.ones(sample_X.shape[1], sample_X.dtype)

    def one_sample(Xs, uvs):
        return gauss_newton_updates(Xs, uvs, weight, K, initial_pose(Xs, uvs, weight, K), updates=sample_updates)

    return jax.vmap(one_sample)(sample_X, sample_uv)


def samples_needed(inlier_frac, sample_size, confidence):
    """RANSAC's adaptive rule: samples after which an all-inlier one has been drawn with
    probability ``confidence``, log(1 - confidence) / log(1 - w^s) (inf for w = 0)."""
    p_good = jnp.clip(inlier_frac, 0.0, 1.0) ** sample_size
    return jnp.where(p_good >= 1.0, 1.0, jnp.log1p(-confidence) / jnp.log1p(-jnp.minimum(p_good, 1.0 - 1e-7)))


class Draws(NamedTuple):
    """A region's sampling so far: the best candidates, ranked by minus their truncated cost (MSAC:
    on a weak region a pose slid along the rotation/translation valley can win an inlier count
    while fitting the true inliers several times worse)."""

    chunk: jax.Array  # () int32 chunks drawn
    top_pose: jax.Array  # (lo_candidates, 6)
    top_rank: jax.Array  # (lo_candidates,)
    best_close: jax.Array  # () int32 most scored members within ADAPTIVE_PX of one candidate


class DrawInputs(NamedTuple):
    """What a region's draws read: its minimal samples' points, the members they are scored on."""

    sample_X: jax.Array  # (n_chunks chunk, sample_size, 3)
    sample_uv: jax.Array  # (n_chunks chunk, sample_size, 2)
    drawn: jax.Array  # (n_chunks, chunk) bool: within ``hypotheses``
    scored_X: jax.Array  # (score_points, 3)
    scored_uv: jax.Array  # (score_points, 2)
    scored_valid: jax.Array  # (score_points,) bool
    K: jax.Array  # (3, 3)
    n_members: jax.Array  # () int32
    n_valid: jax.Array  # () int32 scored members
    inlier_px: jax.Array  # () RansacOptions' values, passed in: the loop closes over no traced value
    confidence: jax.Array  # ()


def draw_chunk(state: Draws, x: DrawInputs, options: RansacOptions) -> Draws:
    """The next ``options.chunk`` minimal samples' candidates scored and merged into the leading ones."""
    o, dtype = options, x.scored_X.dtype
    at = state.chunk * o.chunk
    poses = sample_candidates(jax.lax.dynamic_slice_in_dim(x.sample_X, at, o.chunk),
                              jax.lax.dynamic_slice_in_dim(x.sample_uv, at, o.chunk), x.K,
                              sample_updates=o.sample_updates)
    ok = jnp.all(jnp.isfinite(poses), axis=-1) & x.drawn[state.chunk]
    poses = jnp.where(ok[:, None], poses, jnp.zeros(6, dtype))
    inliers, trunc_sq = truncated_errors_sq(so3_exp(poses[:, :3]), poses[:, 3:], x.scored_X, x.scored_uv, x.K,
                                            x.scored_valid, x.inlier_px)
    all_rank = jnp.concatenate([state.top_rank, jnp.where(ok, -jnp.sum(trunc_sq, axis=-1), -jnp.inf)])
    _, keep = jax.lax.top_k(all_rank, state.top_rank.shape[0])
    close_sq = jnp.minimum(jnp.asarray(ADAPTIVE_PX, dtype), x.inlier_px) ** 2
    close = jnp.sum(inliers & (trunc_sq < close_sq), axis=-1, dtype=jnp.int32)
    return Draws(state.chunk + 1, jnp.concatenate([state.top_pose, poses])[keep], all_rank[keep],
                 jnp.maximum(state.best_close, jnp.max(jnp.where(ok, close, 0))))


def draws_needed(state: Draws, x: DrawInputs, options: RansacOptions):
    """() bool: the region draws another chunk (RANSAC's adaptive stop, ``region_start``)."""
    o, dtype = options, x.scored_X.dtype
    close_frac = state.best_close / jnp.maximum(x.n_valid, 1).astype(dtype)
    needed = ADAPTIVE_DRAWS * samples_needed(close_frac, o.sample_size, x.confidence)
    return ((state.chunk < x.drawn.shape[0]) & (x.n_members >= o.sample_size)
            & ((state.chunk * o.chunk).astype(dtype) < needed))


def region_start(X, uv, K, order, start, n_members, key, options: RansacOptions):
    """The best pose6 (6,) of one region from its minimal samples (``options.chunk`` at a time,
    until ``hypotheses`` or ADAPTIVE_DRAWS x ``samples_needed`` of them) and one least-squares fit
    of each of the ``lo_candidates`` best on at most ``fit_points`` scored members: the lowest
    truncated cost at inlier_px on the scored members of candidates and fits. Under vmap a region
    whose draws have stopped leaves the batch (``while_loop_by_lane``)."""
    o, N, dtype = options, X.shape[0], X.dtype
    key_sample, key_subset = jax.random.split(key)
    n_scored = min(o.score_points, N)
    scored_idx, scored_valid = scoring_subset(key_subset, order, start, n_members, n_scored)
    X_s, uv_s = X[scored_idx], uv[scored_idx]
    n_chunks = -(-o.hypotheses // o.chunk)
    positions = sample_distinct(key_sample, n_members, n_chunks * o.chunk, o.sample_size)
    sample_idx = order[jnp.clip(start + positions, 0, N - 1)]
    drawn = (jnp.arange(n_chunks * o.chunk) < o.hypotheses).reshape(n_chunks, o.chunk)
    n_keep = min(o.lo_candidates, o.hypotheses)
    n_valid = jnp.minimum(n_members, n_scored)
    inputs = DrawInputs(X[sample_idx], uv[sample_idx], drawn, X_s, uv_s, scored_valid, K, n_members, n_valid,
                        jnp.asarray(o.inlier_px, dtype), jnp.asarray(o.confidence, dtype))
    init = Draws(jnp.int32(0), jnp.zeros((n_keep, 6), dtype), jnp.full(n_keep, -jnp.inf, dtype), jnp.int32(0))
    top_pose = while_loop_by_lane(lambda s, x: draws_needed(s, x, o), lambda s, x: draw_chunk(s, x, o), init,
                                  inputs).top_pose

    # one fit of each leading candidate on its inliers among fit_points evenly spread scored
    # members: enough to tell its basin, at a quarter of the cost
    n_fit = min(o.fit_points, n_scored)
    i = jnp.arange(n_fit)
    fit_idx = jnp.where(n_valid <= n_fit, i, (i * n_valid) // n_fit)
    X_f, uv_f = X_s[fit_idx], uv_s[fit_idx]
    inl_top, _, _ = msac_score(so3_exp(top_pose[:, :3]), top_pose[:, 3:], X_f, uv_f, K, i < n_valid, o.inlier_px)
    fits, _ = jax.vmap(lambda p, w: solve_pnp(X_f, uv_f, w, K, steps=o.lo_steps, pose0=p))(top_pose,
                                                                                          inl_top.astype(dtype))
    fits = jnp.where(jnp.all(jnp.isfinite(fits), axis=-1, keepdims=True), fits, top_pose)
    candidates = jnp.concatenate([top_pose, fits])
    _, _, trunc = msac_score(so3_exp(candidates[:, :3]), candidates[:, 3:], X_s, uv_s, K, scored_valid, o.inlier_px)
    return candidates[jnp.argmin(trunc)]  # ties: the first


def camera_start(X, uv, region, K, rival_R, global_t, inlier_px, k):
    """The camera's rotation with the translation of the members its motion explains (k, 6): s t_g
    carries the scale fit's float32 rounding, which a change of units moves; the members within
    inlier_px of it, and the linear fit on them, do not move. NaN without a finite camera pose."""
    err, in_front = reprojection_error_px(rival_R, global_t, X, uv, K)
    t = translation_for_rotation(X, uv, (region >= 1) & in_front & (err < inlier_px), region, K, rival_R, k)
    t = jnp.where(jnp.all(jnp.isfinite(global_t)), t, jnp.nan)
    return jnp.concatenate([jnp.broadcast_to(so3_log(rival_R), (k, 3)), t], axis=-1)


def ransac_pnp_regions(X, uv, region, K, keys, options: RansacOptions, rival_R=None, global_t=None,
                       noise_block_px=jnp.inf) -> PnPResult:
    """Robust pose of every region of a pair -> PnPResult (leading axis k = len(keys)).

    X (N, 3) points in camera i-1, uv (N, 2) their pixels in frame i, region (N,) 1..k (0: none),
    K (3, 3) of frame i, keys (k,) one PRNG key per region; rival_R (3, 3) the camera's rotation R_g
    (None: the identity) and global_t (3,) its translation s t_g in the units of X (None: unknown).
    Starts of each region's search: its best RANSAC candidate (``region_start``), with
    ``options.borrow`` the pair's other region pose that fits it best, and the camera's pose; then
    ``refine_poses``, and ``polish_poses`` on the points each pose is the fit of. Status:
    too_few_points with fewer than min_points members; ok with inliers >= max(4, floor(min_inlier_frac
    members)), a finite pose and det(R) ~ 1; else rejected.
    noise_block_px: side [px] of the squares of the noise the floors count (``pose_uncertainty``)."""
    k, dtype = keys.shape[0], X.dtype
    region = jnp.where(jnp.isfinite(X).all(-1) & jnp.isfinite(uv).all(-1), region, 0).astype(jnp.int32)
    member = region >= 1
    X = jnp.where(member[:, None], X, jnp.array([0.0, 0.0, 1.0], dtype))  # padding never leaks in
    uv = jnp.where(member[:, None], uv, 0.0).astype(dtype)
    K = jnp.asarray(K, dtype)
    order, start, n_members = group_by_region(region, k)
    own_best = jax.vmap(lambda s, n, key: region_start(X, uv, K, order, s, n, key, options))(start, n_members, keys)

    rival_R = jnp.eye(3, dtype=dtype) if rival_R is None else jnp.asarray(rival_R, dtype)
    starts = [own_best]
    if options.borrow and k > 1:
        starts.append(borrow_region_poses(X, uv, region, K, own_best, inlier_px=options.inlier_px))
    if global_t is not None:
        starts.append(camera_start(X, uv, region, K, rival_R, jnp.asarray(global_t, dtype), options.inlier_px, k))
    slots = region_slots(region, k, dtype)
    refined = refine_poses(X, uv, region, K, jnp.stack(starts), rival_R, options, slots)
    poses = polish_poses(X, uv, refined.fitted.astype(dtype), region, K, refined.poses, slots)

    R, t = so3_exp(poses[:, :3]), poses[:, 3:]
    onehot = region_onehot(region, k, dtype)
    err_sq, in_front = own_pose_errors_sq(poses, X, uv, K, slots)
    inliers = member & in_front & (err_sq < jnp.asarray(options.inlier_px, dtype) ** 2)
    n_inliers = region_sums(onehot, inliers.astype(dtype)).astype(jnp.int32)
    reproj_px = region_sums(onehot, jnp.sqrt(jnp.where(member, err_sq, 0.0))) / jnp.maximum(n_members, 1).astype(dtype)
    need = jnp.maximum(4, jnp.floor(options.min_inlier_frac * n_members).astype(jnp.int32))
    proper = jnp.abs(jnp.linalg.det(R) - 1.0) < 1e-3
    good = (n_inliers >= need) & jnp.all(jnp.isfinite(poses), axis=-1) & proper & jnp.isfinite(reproj_px)
    status = jnp.where(n_members < options.min_points, REGION_TOO_FEW_POINTS, jnp.where(good, REGION_OK, REGION_REJECTED))
    uncertainty = pose_uncertainty(X, uv, region, K, poses, inliers, noise_block_px, cut_px=options.inlier_px)
    return PnPResult(R, t, status.astype(jnp.int32), n_members, n_inliers, inliers, reproj_px,
                     refined.ambiguous, uncertainty, refined.fitted)


def ransac_pnp(X, uv, member, K, key, options: RansacOptions, rival_R=None) -> PnPResult:
    """Robust pose of one region (``member`` (N,) bool) -> PnPResult without the region axis."""
    res = ransac_pnp_regions(X, uv, jnp.asarray(member).astype(jnp.int32), K, key[None], options, rival_R)
    return jax.tree.map(lambda field: field[0], res)._replace(inliers=res.inliers, fitted=res.fitted)
