"""Each region's local pose as docs/semantics.md §3.2 step 6 and §3.3 define it: the lowest local
optimum of the truncated cost over several starts, refit at the region's noise-level cut, and
its rival from the camera's rotation. All regions of a pair are solved together."""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp

from ..config import MIN_CUT_PX, NOISE_CUT
from .joint_pnp import solve_pnp_regions
from .pnp import translation_for_rotation
from .ransac_options import RansacOptions
from .regions import HIGHEST, point_values, region_onehot, region_slots, region_sums
from .so3 import rotation_angle_deg, so3_exp, so3_log
from .truncated_cost import is_lower, pose_errors_sq, region_truncated_cost, truncated_errors_sq


def noise_sigma_sq(err_sq, member, onehot, thr_sq):
    """(k,) pixel noise variance per coordinate of each region: mean e^2 / 2 over its members with
    e^2 < thr_sq (err_sq (N,) under each point's own region's pose)."""
    inl = member & (err_sq < thr_sq)
    return region_sums(onehot, jnp.where(inl, err_sq, 0.0)) / (
        2.0 * jnp.maximum(region_sums(onehot, inl.astype(err_sq.dtype)), 1.0))


def noise_cut_sq(sigma_sq, inlier_px):
    """Squared noise-level cut: NOISE_CUT sigma within [min(MIN_CUT_PX, inlier_px), inlier_px]."""
    dtype = sigma_sq.dtype
    return jnp.clip(NOISE_CUT**2 * sigma_sq, jnp.asarray(jnp.minimum(MIN_CUT_PX, inlier_px) ** 2, dtype),
                    jnp.asarray(inlier_px, dtype) ** 2)


class LocalOptima(NamedTuple):
    """Poses (k, 6), each point's squared error under its region's pose (N,) [px^2], each
    region's truncated cost (k,) at the cut it was optimised at, and the points (N,) bool its
    pose is the least-squares fit of (the start's within-cut points where no fit was kept)."""

    poses: jax.Array
    err_sq: jax.Array
    cost: jax.Array
    fitted_on: jax.Array


class Fit(NamedTuple):
    """A local optimisation after some least-squares fits (k regions, N points)."""

    poses: jax.Array  # (k, 6)
    err_sq: jax.Array  # (N,) [px^2]
    cost: jax.Array  # (k,) truncated cost
    within: jax.Array  # (N,) bool: a member within its region's cut
    n_within: jax.Array  # (k,)
    done: jax.Array  # (k,) bool
    rounds: jax.Array  # () int32
    fitted_on: jax.Array  # (N,) bool: the points the kept pose was fitted on


def local_optima(X, uv, region, K, start, cut_sq_point, start_fitted_on, fitted_on_within, skip, *, lm_steps,
                 max_rounds, slots=None) -> LocalOptima:
    """Every region's local optimum of the truncated cost at its cut (``cut_sq_point`` (N,): each
    point's region's squared cut) from ``start`` (k, 6): least squares on the members within the
    cut, again on the new ones, each fit kept only when it lowers the cost; a region stops at its
    first fit that does not, with fewer than 4 such members, or after ``max_rounds`` fits.
    ``start_fitted_on`` (N,): the points the start was fitted on; where ``fitted_on_within`` (a
    traced bool) holds, those within its cut instead. Regions where ``skip`` (k,) holds are not
    optimised (they keep their start)."""
    k = start.shape[0]
    dtype = X.dtype
    onehot = region_onehot(region, k, dtype)
    member = region >= 1
    slots = region_slots(region, k, dtype) if slots is None else slots

    def evaluate(poses):
        err_sq = pose_errors_sq(poses, X, uv, K, slots)
        within = member & (err_sq < cut_sq_point)
        cost = region_truncated_cost(err_sq, member, cut_sq_point, onehot)
        return err_sq, within, cost, region_sums(onehot, within.astype(dtype))

    def refit(state: Fit) -> Fit:
        weight = (state.within & (point_values(onehot, state.done.astype(dtype)) == 0)).astype(dtype)
        fitted, _ = solve_pnp_regions(X, uv, weight, region, K, state.poses, steps=lm_steps, slots=slots)
        err_sq, within, cost, n_within = evaluate(fitted)
        better = ~state.done & jnp.all(jnp.isfinite(fitted), axis=-1) & is_lower(cost, state.cost)
        point_better = point_values(onehot, better.astype(dtype)) > 0
        changed = region_sums(onehot, (within != state.within).astype(dtype)) > 0
        return Fit(jnp.where(better[:, None], fitted, state.poses), jnp.where(point_better, err_sq, state.err_sq),
                   jnp.where(better, cost, state.cost), jnp.where(point_better, within, state.within),
                   jnp.where(better, n_within, state.n_within),
                   state.done | ~better | ~changed | (n_within < 4), state.rounds + 1,
                   jnp.where(point_better, weight > 0, state.fitted_on))

    err_sq, within, cost, n_within = evaluate(start)
    done = (n_within < 4) | ~jnp.all(jnp.isfinite(start), axis=-1) | skip
    final = jax.lax.while_loop(lambda s: (s.rounds < max_rounds) & jnp.any(~s.done), refit,
                               Fit(start, err_sq, cost, within, n_within, done, jnp.int32(0),
                                   jnp.where(fitted_on_within, within, start_fitted_on)))
    return LocalOptima(final.poses, final.err_sq, final.cost, final.fitted_on)


def repeated_starts(starts, X, uv, K, member, onehot, thr_sq, slots):
    """(M, k) bool: where a start (M, k, 6) leaves exactly the members within inlier_px (thr_sq
    [px^2]) of an earlier start of its region. Its local optimum there would begin by refitting the
    points the earlier start's did, so it is not run (docs/semantics.md §7.1)."""
    n_starts = starts.shape[0]
    within = jax.vmap(lambda poses: member & (pose_errors_sq(poses, X, uv, K, slots) < thr_sq))(starts)  # (M, N)
    differ = jnp.einsum("kn,ijn->ijk", onehot, (within[:, None] != within[None]).astype(onehot.dtype),
                        precision=HIGHEST)  # (M, M, k)
    earlier = jnp.tril(jnp.ones((n_starts, n_starts), bool), -1)  # [i, j]: j before i
    return jnp.any((differ == 0) & earlier[..., None], axis=1)


class RefinedPoses(NamedTuple):
    poses: jax.Array  # (k, 6)
    ambiguous: jax.Array  # (k,) bool
    fitted: jax.Array  # (N,) bool: the points each region's pose is the least-squares fit of


def _take(runs: LocalOptima, i: int) -> LocalOptima:
    """Run i of optima stacked along a leading axis."""
    return jax.tree.map(lambda a: a[i], runs)


def _lowest(optima: LocalOptima, region) -> LocalOptima:
    """Per region, the first of the lowest-cost optima among M starts (leading axis M)."""
    k = optima.poses.shape[1]
    costs = jnp.where(jnp.isfinite(optima.cost), optima.cost, jnp.inf)
    chosen = jnp.argmax(~is_lower(jnp.min(costs, axis=0), costs), axis=0)  # (k,)
    point_chosen = chosen[jnp.clip(region - 1, 0, k - 1)]
    return LocalOptima(jnp.take_along_axis(optima.poses, chosen[None, :, None], axis=0)[0],
                       jnp.take_along_axis(optima.err_sq, point_chosen[None], axis=0)[0],
                       jnp.take_along_axis(optima.cost, chosen[None], axis=0)[0],
                       jnp.take_along_axis(optima.fitted_on, point_chosen[None], axis=0)[0])


def _pose_or_rival(pose: LocalOptima, rival: LocalOptima, cut, member, onehot, options: RansacOptions
                   ) -> RefinedPoses:
    """Per region, the rival where it costs less at the final cut (N,) than the pose, and whether
    the pose is ambiguous (``refine_poses`` step 3)."""
    dtype = cut.dtype
    rival_finite = jnp.all(jnp.isfinite(rival.poses), axis=-1)
    # the rival's cost is at the final cut already; the pose's is taken again there
    lower = rival_finite & is_lower(rival.cost, region_truncated_cost(pose.err_sq, member, cut, onehot))
    poses = jnp.where(lower[:, None], rival.poses, pose.poses)
    point_lower = point_values(onehot, lower.astype(dtype)) > 0
    err_sq = jnp.where(point_lower, rival.err_sq, pose.err_sq)
    near = member & (err_sq < cut)
    m = region_sums(onehot, near.astype(dtype))
    shared = region_sums(onehot, (near & (rival.err_sq < cut)).astype(dtype))
    margin = jnp.maximum(1.0, jnp.floor(options.ambiguous_inlier_frac * m))
    apart = rotation_angle_deg(so3_exp(poses[:, :3]), so3_exp(rival.poses[:, :3])) > options.ambiguous_rot_deg
    return RefinedPoses(poses, rival_finite & apart & (shared >= m - margin),
                        jnp.where(point_lower, rival.fitted_on, pose.fitted_on))


def refine_poses(X, uv, region, K, starts, rival_R, options: RansacOptions, slots=None) -> RefinedPoses:
    """The local pose of every region from M starts (M, k, 6):

    1. each start's local optimum at inlier_px (not run where the start repeats an earlier one's
       members there: ``repeated_starts``); the lowest is the coarse optimum, and its noise-level
       cut (``noise_cut_sq``) the region's cut;
    2. the pose: the local optimum at the cut from the coarse optimum;
    3. the rival: rotation rival_R (3, 3) with the translation that best explains the pose's
       members within the cut, optimised at inlier_px (where it beats the coarse optimum, its cut
       replaces the region's), then at the cut. It replaces the pose where it costs less there;
       otherwise the pose is ambiguous where the rival lies more than ambiguous_rot_deg away and
       keeps all but max(1, floor(ambiguous_inlier_frac m)) of the pose's m members within the cut.

    ``slots``: ``region_slots(region, k)``, made here when not given."""
    k = starts.shape[1]
    dtype = X.dtype
    inlier_px = options.inlier_px
    onehot = region_onehot(region, k, dtype)
    member = region >= 1
    thr_sq = jnp.asarray(inlier_px, dtype) ** 2
    slots = region_slots(region, k, dtype) if slots is None else slots
    optimise = functools.partial(local_optima, X, uv, region, K, lm_steps=options.lm_steps,
                                 max_rounds=options.max_rounds, slots=slots)
    at_inlier_px = jnp.full(X.shape[:1], thr_sq)
    n_starts = starts.shape[0]
    repeats = repeated_starts(starts, X, uv, K, member, onehot, thr_sq, slots)
    # the runs by index: the M starts' coarse runs, then the pose, the rival at inlier_px, the rival
    pose_run, rival_coarse_run, rival_run = n_starts, n_starts + 1, n_starts + 2

    def coarse_of(runs):
        return _lowest(jax.tree.map(lambda a: a[:n_starts], runs), region)

    def cut_of(err_sq):
        return point_values(onehot, noise_cut_sq(noise_sigma_sq(err_sq, member, onehot, thr_sq), inlier_px))

    def rival_cut(runs):  # the region's cut, or the rival's where it beats the coarse optimum at inlier_px
        coarse, rival_coarse = coarse_of(runs), _take(runs, rival_coarse_run)
        rival_wins = point_values(onehot, is_lower(rival_coarse.cost, coarse.cost).astype(dtype)) > 0
        return jnp.where(rival_wins, cut_of(rival_coarse.err_sq), cut_of(coarse.err_sq))

    # Each run's start (poses, cut, points it was fitted on, whether those are the ones within the
    # cut instead), from the runs before it. One traced optimisation serves every run, one after
    # another: the program holds the least-squares loop once, and a start's loop is not vmapped
    # with the others' (each would run until the slowest is done).
    def coarse_start(i, runs):
        return starts[jnp.minimum(i, n_starts - 1)], at_inlier_px, runs.fitted_on[0], jnp.bool_(True)

    def pose_start(i, runs):
        coarse = coarse_of(runs)
        return coarse.poses, cut_of(coarse.err_sq), coarse.fitted_on, jnp.bool_(False)

    def rival_coarse_start(i, runs):
        pose = _take(runs, pose_run)
        t = translation_for_rotation(X, uv, member & (pose.err_sq < cut_of(coarse_of(runs).err_sq)), region, K,
                                     rival_R, k)
        return jnp.concatenate([jnp.broadcast_to(so3_log(rival_R), (k, 3)), t], axis=-1), at_inlier_px, \
            runs.fitted_on[0], jnp.bool_(True)

    def rival_start(i, runs):
        rival_coarse = _take(runs, rival_coarse_run)
        return rival_coarse.poses, rival_cut(runs), rival_coarse.fitted_on, jnp.bool_(False)

    def run(i, runs):
        branch = jnp.clip(i - n_starts + 1, 0, 3)
        start, cut, fitted_on, within = jax.lax.switch(branch, (coarse_start, pose_start, rival_coarse_start,
                                                                rival_start), i, runs)
        # a repeated start is not run, and left out of the coarse optimum's choice
        repeat = (i < n_starts) & repeats[jnp.minimum(i, n_starts - 1)]
        optimum = optimise(start, cut, fitted_on, within, repeat)
        optimum = optimum._replace(cost=jnp.where(repeat, jnp.inf, optimum.cost))
        return jax.tree.map(lambda a, b: a.at[i].set(b), runs, optimum)

    empty = LocalOptima(jnp.zeros((n_starts + 3, k, 6), dtype), jnp.zeros((n_starts + 3,) + X.shape[:1], dtype),
                        jnp.zeros((n_starts + 3, k), dtype), jnp.zeros((n_starts + 3,) + X.shape[:1], bool))
    runs = jax.lax.fori_loop(0, n_starts + 3, run, empty)
    pose, rival = _take(runs, pose_run), _take(runs, rival_run)
    cut = rival_cut(runs)

    return _pose_or_rival(pose, rival, cut, member, onehot, options)


def borrow_region_poses(X, uv, region, K, poses, *, inlier_px):
    """Per region, the other region's pose (poses (k, 6)) of lowest truncated cost at inlier_px on
    its members -> (k, 6); its own where no other is finite. In a static scene every region moves
    with the camera, so a well-conditioned region's pose is a good start for a weak one."""
    k = poses.shape[0]
    onehot = region_onehot(region, k, X.dtype)
    member = region >= 1
    finite = jnp.all(jnp.isfinite(poses), axis=-1)
    safe = jnp.where(finite[:, None], poses, 0.0)
    _, trunc = truncated_errors_sq(so3_exp(safe[:, :3]), safe[:, 3:], X, uv, K, member, inlier_px)  # (k poses, N)
    cost = region_sums(onehot, trunc.T)  # (k regions, k poses)
    cost = jnp.where(finite[None, :] & ~jnp.eye(k, dtype=bool), cost, jnp.inf)
    lender = jnp.argmin(cost, axis=1)
    return jnp.where(jnp.isfinite(cost[jnp.arange(k), lender])[:, None], safe[lender], poses)
