"""Every region's pose of a pair at once: Levenberg-Marquardt on the slot layout, one pass over the
N points per step (docs/semantics.md §7.1). Poses and pixels as in ``pnp``."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .lanes import while_loop_by_lane
from .linalg import small_matmul, solve_spd
from .pnp import point_columns, pointwise_residuals, pose_jacobian_rows
from .regions import RegionSlots, block_sums, per_chunk, region_slots, to_slots
from .so3 import so3_exp, so3_log

# A region stops once a step would lower its squared error by less than LM_RTOL of it (float32
# resolves ~1e-7), its damping passes LM_MAX_DAMPING (no step lowers it), or its step is below
# LM_ATOL_PX in pixel-scaled units.
LM_RTOL = 1e-6
LM_ATOL_PX = 1e-4
LM_MAX_DAMPING = 1e8
# A final Gauss-Newton step is taken where it moves a pose by less than this [px-scaled units]:
# a settled fit is ~1e-3 away, a start of the search tens.
POLISH_PX = 0.05
# A least-squares step reads every point of a pair: from this many pairs at once on, a batch whose
# pairs are nearly all done leaves them behind (``while_loop_by_lane``); the CPU's groups of
# PAIRS_AT_ONCE run to their slowest pair.
PAIR_LANES = 16


class Linearisation(NamedTuple):
    """Per region at a pose, in pixel-scaled parameters: squared error (k,), J^T J (k, 6, 6), J^T r (k, 6)."""

    cost: jax.Array
    normal: jax.Array
    grad: jax.Array


class Proposal(NamedTuple):
    """The damped step from a pose, before the error is taken there (k regions)."""

    delta: jax.Array  # (k, 6) in (w [rad], dt)
    predicted: jax.Array  # (k,) drop of the squared error the linear model predicts
    negligible: jax.Array  # (k,) bool: the prediction or the step below the stop's resolution


class LMState(NamedTuple):
    R: jax.Array  # (k, 3, 3)
    t: jax.Array  # (k, 3)
    at: Linearisation  # at (R, t)
    damping: jax.Array  # (k,) Nielsen's mu
    growth: jax.Array  # (k,) Nielsen's nu
    done: jax.Array  # (k,) bool
    step: jax.Array  # () int32
    proposal: Proposal  # from (R, t) at this damping
    started: jax.Array  # () bool: ``at`` is (R, t)'s; the first pass only linearises there


class Problem(NamedTuple):
    """A pair's weighted points in the slot layout, and each region's pixel scaling of the pose."""

    cols: tuple  # (x, y, z, u, v, sqrt_w), each (n_chunks, SLOT_CHUNK)
    slots: RegionSlots
    scale: jax.Array  # (k, 6) pixel-scaled units per parameter unit
    K: jax.Array  # (3, 3)


def problem_of(X, uv, weight, region, K, k: int, slots: RegionSlots | None = None) -> Problem:
    """The slot layout of X (N, 3), uv (N, 2), weight (N,) by region (N,) in 1..k, and the
    scaling: rotation by fx, translation by fx / the region's mean point distance."""
    dtype = X.dtype
    slots = region_slots(region, k, dtype) if slots is None else slots
    weight = jnp.where((region >= 1) & (region <= k), weight, 0.0)
    cols = point_columns(to_slots(slots, X, jnp.array([0.0, 0.0, 1.0], dtype)), to_slots(slots, uv, 0.0),
                         to_slots(slots, weight, 0.0))  # (n_chunks, SLOT_CHUNK) each
    x, y, z, _, _, sqrt_w = cols
    valid = (sqrt_w > 0).astype(dtype)
    sums = block_sums(slots.chunk_onehot, jnp.stack([valid * jnp.sqrt(x * x + y * y + z * z), valid]))
    mean_dist = sums[:, 0] / jnp.maximum(sums[:, 1], 1.0)
    # finite for an empty region
    scale = jnp.concatenate([jnp.broadcast_to(K[0, 0], (k, 3)),
                             jnp.broadcast_to((K[0, 0] / jnp.maximum(mean_dist, 1e-12))[:, None], (k, 3))], axis=-1)
    return Problem(cols, slots, scale, K)


def scaled_jacobians(problem: Problem, R, t):
    """Residuals (du, dv) and pixel-scaled Jacobian rows (J_u, J_v), (6, n_chunks, SLOT_CHUNK) each."""
    slots = problem.slots
    chunk_scale = problem.scale[slots.chunk_region].T[..., None]  # (6, n_chunks, 1)
    (du, dv), (RX, grad_u, grad_v) = pointwise_residuals(per_chunk(slots, R), per_chunk(slots, t), problem.K,
                                                         problem.cols)
    return (du, dv), (pose_jacobian_rows(RX, grad_u) / chunk_scale, pose_jacobian_rows(RX, grad_v) / chunk_scale)


# J^T J's 21 distinct entries (i <= j), and where each of the 36 lies among them
NORMAL_UPPER = [(i, j) for i in range(6) for j in range(i, 6)]
NORMAL_INDEX = np.array([[NORMAL_UPPER.index((min(i, j), max(i, j))) for j in range(6)] for i in range(6)])


def slot_values(du, dv, J_u, J_v) -> list:
    """The 28 values a slot adds: J^T J's 21 distinct products (NORMAL_UPPER), J^T r's 6, the cost."""
    return ([J_u[i] * J_u[j] + J_v[i] * J_v[j] for i, j in NORMAL_UPPER] + [J_u[i] * du + J_v[i] * dv for i in range(6)]
            + [du * du + dv * dv])


def per_region(problem: Problem, chunk_sums) -> Linearisation:
    """The 28 values' sums within chunks (28, n_chunks) -> the regions' Linearisation."""
    sums = block_sums(problem.slots.chunk_onehot, chunk_sums)  # (k, 28)
    return Linearisation(sums[:, 27], sums[:, NORMAL_INDEX], sums[:, 21:27])


def linearise(problem: Problem, R, t) -> Linearisation:
    """Every region's squared error, J^T J and J^T r at poses R (k, 3, 3), t (k, 3): the 28 values
    a slot adds summed within chunks by one reduction of 28 operands, whose loop makes each slot's
    Jacobian once for all of them (bench/history/issue-61.md "The least-squares step's sums in one
    reduction of 28 operands")."""
    (du, dv), (J_u, J_v) = scaled_jacobians(problem, R, t)
    values = slot_values(du, dv, J_u, J_v)
    zeros = tuple(jnp.zeros((), v.dtype) for v in values)
    sums = jax.lax.reduce(tuple(values), zeros, lambda a, b: tuple(x + y for x, y in zip(a, b)), (values[0].ndim - 1,))
    return per_region(problem, jnp.stack(sums))


def polish_poses(X, uv, weight, region, K, poses, slots: RegionSlots | None = None):
    """poses (k, 6) moved by one undamped Gauss-Newton step on their points (arguments as
    ``solve_pnp_regions``), each where that step is finite and below POLISH_PX: a settled fit resolves its optimum only to where the
    drop of its cost is float32's rounding (a square root of that in the pose), the step to first
    order, so a polished pose is a smooth function of the data (docs/semantics.md §7.1)."""
    k = poses.shape[0]
    problem = problem_of(X, uv, weight, region, K, k, slots)
    R, t = so3_exp(poses[:, :3]), poses[:, 3:]
    at = linearise(problem, R, t)
    scaled = -jax.vmap(solve_spd)(at.normal, at.grad)
    small = jnp.all(jnp.isfinite(scaled), -1) & (jnp.max(jnp.abs(scaled), -1) < POLISH_PX)
    delta = jnp.where(small[:, None], scaled / problem.scale, 0.0)
    polished = jnp.concatenate([so3_log(small_matmul(so3_exp(delta[:, :3]), R)), t + delta[:, 3:]], axis=-1)
    return jnp.where((small & jnp.all(jnp.isfinite(poses), -1))[:, None], polished, poses)


def solve_pnp_regions(X, uv, weight, region, K, pose0, *, steps, slots: RegionSlots | None = None):
    """Minimise each region's sum weight |project(R X + t) - uv|^2 -> (pose6 (k, 6), converged (k,)).

    X (N, 3), uv (N, 2), weight (N,), region (N,) in 1..k (0: none), pose0 (k, 6) starts; at most
    ``steps`` steps. Each region has its own damping (Nielsen's update) on the left perturbation
    exp([w]) R, t + dt in pixel-scaled parameters (w by fx, dt by fx / the region's mean point
    distance), and takes a step only where it lowers its error, so a start tens of degrees off
    descends instead of diverging. ``slots``: ``region_slots(region, k)``, made here when not given.
    Needs >= 3 weighted points per region."""
    k = pose0.shape[0]
    dtype = X.dtype

    def propose(at: Linearisation, damping, scale) -> Proposal:
        diag = jnp.diagonal(at.normal, axis1=1, axis2=2)
        damped = at.normal + (damping[:, None] * diag + 1e-12)[:, :, None] * jnp.eye(6, dtype=dtype)
        delta = -jax.vmap(solve_spd)(damped, at.grad) / scale
        scaled = delta * scale
        predicted = -(2.0 * jnp.sum(at.grad * scaled, -1) + jnp.einsum("ki,kij,kj->k", scaled, at.normal, scaled))
        negligible = (predicted <= LM_RTOL * at.cost + LM_ATOL_PX**2) | (jnp.max(jnp.abs(scaled), -1) < LM_ATOL_PX)
        return Proposal(delta, predicted, negligible)

    def step(state: LMState, problem: Problem) -> LMState:
        at, damping, growth, done, proposal = state.at, state.damping, state.growth, state.done, state.proposal
        first = ~state.started  # the proposal is the start itself (delta 0): take its linearisation
        delta = proposal.delta
        R_new, t_new = small_matmul(so3_exp(delta[:, :3]), state.R), state.t + delta[:, 3:]
        new = linearise(problem, R_new, t_new)
        rho = (at.cost - new.cost) / jnp.maximum(proposal.predicted, 1e-30)
        # taken only where the error drops by more than float32's rounding of the sum, so that
        # programs fused otherwise (one device or several) take the same steps; settled where the
        # drop, the model's prediction or the step is below that: nothing is left to gain
        lower = jnp.isfinite(new.cost) & (new.cost < at.cost)
        significant = lower & (at.cost - new.cost > LM_RTOL * at.cost + LM_ATOL_PX**2)
        settled = ~done & ((lower & ~significant) | proposal.negligible)
        accept = ~done & (first | (~settled & significant))
        damping = jnp.where(accept, jnp.maximum(damping * jnp.maximum(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3), 1e-12),
                            jnp.where(done, damping, damping * growth))
        growth = jnp.where(accept, 2.0, jnp.where(done, growth, growth * 2.0))
        damping, growth = jnp.where(first, state.damping, damping), jnp.where(first, state.growth, growth)
        done = jnp.where(first, done | ~jnp.isfinite(new.cost), done | settled | (damping > LM_MAX_DAMPING))
        pick = lambda new, old: jnp.where(accept.reshape((k,) + (1,) * (new.ndim - 1)), new, old)  # noqa: E731
        at = jax.tree.map(pick, new, at)
        return LMState(pick(R_new, state.R), pick(t_new, state.t), at, damping, growth, done,
                       state.step + state.started.astype(jnp.int32), propose(at, damping, problem.scale),
                       jnp.bool_(True))

    def more(state: LMState, problem: Problem):
        # a region whose next step is negligible would only be marked settled by it: the loop ends
        # once every region is done or there, without the error at that step (the same poses)
        return (state.step < steps) & jnp.any(~state.done & ~state.proposal.negligible)

    zeros = jnp.zeros((k, 6), dtype)
    unmoved = Proposal(zeros, jnp.full(k, jnp.inf, dtype), jnp.zeros(k, bool))
    unknown = Linearisation(jnp.full(k, jnp.inf, dtype), jnp.zeros((k, 6, 6), dtype), zeros)
    state = LMState(so3_exp(pose0[:, :3]), pose0[:, 3:], unknown, jnp.full(k, 1e-3, dtype), jnp.full(k, 2.0, dtype),
                    ~jnp.all(jnp.isfinite(pose0), axis=-1), jnp.int32(0), unmoved, jnp.bool_(False))
    # under vmap a pair whose regions are all done leaves the batch's steps (``while_loop_by_lane``)
    final = while_loop_by_lane(more, step, state, problem_of(X, uv, weight, region, K, k, slots), min_lanes=PAIR_LANES)
    done = final.done | (final.proposal.negligible & (final.step < steps))
    pose6 = jnp.concatenate([so3_log(final.R), final.t], axis=-1)
    return pose6, done & jnp.all(jnp.isfinite(pose6), axis=-1)
