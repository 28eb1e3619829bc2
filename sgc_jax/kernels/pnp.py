"""Perspective-n-point: reprojection residuals, an optimistix Gauss-Newton pose solve (one point
set) and a Levenberg-Marquardt solve of many regions' poses at once (docs/semantics.md §7.1).

A pose is a 6-vector ``pose6 = (rotvec [rad], t)`` mapping camera i-1 coordinates X to camera i
coordinates ``R X + t`` with ``R = so3_exp(rotvec)``; pixels follow ``geometry.project``.
Point sets have a static size N; ``weight`` (N,) masks them (0 = padded / ignored point).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import lineax as lx
import optimistix as optx

from .fence import materialise
from .geometry import back_project, hat, small_matmul, so3_exp, so3_log

# Points with z below this fraction of their distance are "behind the camera": their projection
# uses this floor instead, so residuals stay finite (large) and never inf/NaN.
_MIN_Z_FRAC = 1e-3
# Gauss-Newton stops when both the step and the residual change are below ~1e-4 px (float32
# resolves ~3e-5 px at 500 px), so where a solve started (padding, batching) leaves no trace.
_GN_RTOL = 1e-6
_GN_ATOL = 1e-4


def point_columns(X, uv, weight):
    """Masked points (X (*points, 3), uv (*points, 2), weight (*points,)) as columns: (x, y, z, u,
    v, sqrt_w), each (*points,); masked points sit at (0, 0, 1)."""
    valid = weight > 0
    x = jnp.where(valid, X[..., 0], 0.0)
    y = jnp.where(valid, X[..., 1], 0.0)
    z = jnp.where(valid, X[..., 2], 1.0)
    u = jnp.where(valid, uv[..., 0], 0.0)
    v = jnp.where(valid, uv[..., 1], 0.0)
    sqrt_w = jnp.sqrt(jnp.where(valid, weight, 0.0))
    return x, y, z, u, v, sqrt_w


def project_columns(R, t, K, x, y, z):
    """Pose (R, t) and K applied to points given as columns -> (u, v, in_front), each (..., N).

    Points with z <= 1e-3 * |R X + t| are behind the camera; they are projected with that depth
    floor instead, so the pixels stay finite for any finite input. R (..., 3, 3), t (..., 3).
    """
    def row(i):
        return (
            R[..., i, 0, None] * x + R[..., i, 1, None] * y + R[..., i, 2, None] * z + t[..., i, None]
        )

    return _pinhole(K, row(0), row(1), row(2))


def project_pointwise(R, t, K, x, y, z):
    """``project_columns`` with one pose per point: R (N, 3, 3), t (N, 3), columns (N,)."""
    def row(i):
        return R[:, i, 0] * x + R[:, i, 1] * y + R[:, i, 2] * z + t[:, i]

    return _pinhole(K, row(0), row(1), row(2))


def _pinhole(K, Yx, Yy, Yz):
    """Camera-frame columns -> (u, v, in_front) with the depth floor of ``project_columns``."""
    norm_sq = Yx * Yx + Yy * Yy + Yz * Yz
    in_front = (Yz > 0) & (Yz * Yz > _MIN_Z_FRAC**2 * norm_sq)
    inv_z = 1.0 / jnp.where(in_front, Yz, _MIN_Z_FRAC * jnp.sqrt(norm_sq) + 1e-30)
    xn, yn = Yx * inv_z, Yy * inv_z
    return K[0, 0] * xn + K[0, 1] * yn + K[0, 2], K[1, 1] * yn + K[1, 2], in_front


def _residual_columns(R, t, K, cols):
    """(du, dv) each (N,): sqrt(weight) * (projection - uv) [px], exactly 0 for masked points."""
    x, y, z, u, v, sqrt_w = cols
    u_hat, v_hat, _ = project_columns(R, t, K, x, y, z)
    return sqrt_w * (u_hat - u), sqrt_w * (v_hat - v)


def reprojection_residuals(pose6, X, uv, K, weight):
    """Residuals (N, 2) [px] of pose6 (6,) on points X (N, 3), pixels uv (N, 2), K (3, 3).

    Scaled by sqrt(weight) (cost = sum weight * |error|^2); exactly 0 where weight == 0.
    """
    du, dv = _residual_columns(so3_exp(pose6[:3]), pose6[3:], K, point_columns(X, uv, weight))
    return jnp.stack([du, dv], axis=-1)


def initial_pose(X, uv, weight, K, n_iter=3):
    """Data-driven pose6 (6,) without a prior: iterated linearised algebraic solve.

    With unit bearings b = K^-1 [u, v, 1] / |.|, each step solves the weighted 6x6 normal
    equations of b x (exp([w]) R X + t) = 0 linearised in (w, t), then R <- exp(w) R. Rows are
    divided by the current point distance, so the error is roughly angular. Converges from the
    identity for rotations up to ~30 deg; needs >= 3 points with weight > 0 (4 for uniqueness).
    """
    x, y, z, u, v, sqrt_w = point_columns(X, uv, weight)
    X, uv, w = jnp.stack([x, y, z], -1), jnp.stack([u, v], -1), sqrt_w**2
    b = back_project(K, uv, jnp.ones_like(uv[:, 0]))
    b = b / jnp.linalg.norm(b, axis=-1, keepdims=True)
    B = hat(b)  # (N, 3, 3): B @ x = b x x

    def step(_, Rt):
        R, t = Rt
        Y = jnp.sum(R[None] * X[:, None, :], axis=-1)  # (N, 3) = X @ R^T
        dist_sq = jnp.sum((Y + t) ** 2, axis=-1)
        s = w / jnp.maximum(dist_sq, 1e-12)
        # b x (w x Y) = ((b . Y) I - Y b^T) w
        A_w = jnp.sum(b * Y, -1)[:, None, None] * jnp.eye(3, dtype=X.dtype) - Y[:, :, None] * b[:, None, :]
        A = jnp.concatenate([A_w, B], axis=-1)  # (N, 3, 6) acting on (w, t)
        rhs = -jnp.cross(b, Y)  # (N, 3)
        sA = s[:, None, None] * A
        H = jnp.sum(sA[:, :, :, None] * A[:, :, None, :], axis=(0, 1))
        g = jnp.sum(sA * rhs[:, :, None], axis=(0, 1))
        x = solve_spd(H, g)
        return small_matmul(so3_exp(x[:3]), R), x[3:]

    R0 = jnp.eye(3, dtype=X.dtype)
    R, t = jax.lax.fori_loop(0, n_iter, step, (R0, jnp.zeros(3, X.dtype)))
    return jnp.concatenate([so3_log(R), t])


def solve_spd(A, b):
    """Solve A x = b for a small symmetric positive (semi)definite A (n, n), b (n,) -> x (n,).

    Unrolled Cholesky (n static): plain elementwise ops, so it vectorises across ``vmap``
    (LAPACK's batched 6x6 calls cost more than the arithmetic). Pivots are floored at
    1e-7 * trace(A), which turns a singular direction into a zero step instead of NaN.
    """
    n = A.shape[-1]
    floor = 1e-7 * jnp.trace(A) / n + jnp.finfo(A.dtype).tiny
    L = [[None] * n for _ in range(n)]
    for j in range(n):
        d = jnp.sqrt(jnp.maximum(A[j, j] - sum(L[j][k] ** 2 for k in range(j)), floor))
        L[j][j] = d
        for i in range(j + 1, n):
            L[i][j] = (A[i, j] - sum(L[i][k] * L[j][k] for k in range(j))) / d
    y = [None] * n
    for i in range(n):
        y[i] = (b[i] - sum(L[i][k] * y[k] for k in range(i))) / L[i][i]
    x = [None] * n
    for i in reversed(range(n)):
        x[i] = (y[i] - sum(L[k][i] * x[k] for k in range(i + 1, n))) / L[i][i]
    return jnp.stack(x)


_DOT_MIN_ROWS = 64  # Jacobian rows from which NormalCholesky forms J^T J with a matmul


class NormalCholesky(lx.AbstractLinearSolver):
    """Least-squares solve of a tall real operator J via J^T J x = J^T b with ``solve_spd``.

    For small parameter vectors (here 6) inside ``vmap``; the operator's input must be one array.
    The transposed solve (pinv(J)^T = pinv(J^T), a minimum-norm solve J (J^T J)^-1 b) is
    provided so lineax can differentiate through it; real operators are their own conjugate.
    """

    def init(self, operator, options):
        del options
        return operator.as_matrix(), operator.in_structure(), operator.out_structure(), False

    def compute(self, state, vector, options):
        del options
        J, in_structure, out_structure, transposed = state
        b = jnp.concatenate([leaf.reshape(-1) for leaf in jax.tree_util.tree_leaves(vector)])
        if J.shape[0] > _DOT_MIN_ROWS:  # one (batched) matmul; XLA CPU's reduce of J_i J_i^T is slow
            normal = jnp.einsum("ni,nj->ij", J, J, precision=jax.lax.Precision.HIGHEST)
        else:  # a few rows (minimal samples): fused elementwise sums beat a tiny-matmul call
            normal = jnp.sum(J[:, :, None] * J[:, None, :], axis=0)
        # J^T b by elementwise sums at any size: XLA CPU's (batched) matrix-vector dot costs more
        J_t_b = lambda v: jnp.sum(J * v[:, None], axis=0)  # noqa: E731
        if transposed:
            x, structure = J @ solve_spd(normal, b), out_structure
        else:
            x, structure = solve_spd(normal, J_t_b(b)), in_structure
        return x.reshape(structure.shape).astype(structure.dtype), lx.RESULTS.successful, {}

    def transpose(self, state, options):
        J, in_structure, out_structure, transposed = state
        return (J, in_structure, out_structure, not transposed), options

    def conj(self, state, options):
        return state, options

    def assume_full_rank(self):
        return True


def _gauss_newton():
    """Gauss-Newton with 6x6 normal equations solved by ``NormalCholesky``; see ``solve_pnp``."""
    return optx.GaussNewton(rtol=_GN_RTOL, atol=_GN_ATOL, linear_solver=NormalCholesky())


def solve_pnp(X, uv, weight, K, *, steps, pose0=None):
    """Minimise sum weight * |project(K, R X + t) - uv|^2 -> (pose6 (6,), ok () bool).

    Starts from ``pose0`` when given, else from ``initial_pose``. Gauss-Newton
    (``optimistix.GaussNewton``, at most ``steps`` steps) on an increment y = (w, dt) with
    R = exp([w]) R0, t = t0 + dt, both scaled to ~px of image motion (w by fx, dt by fx / mean
    point distance) so one tolerance fits parameters and residuals and the 6x6 normal equations
    are well conditioned in float32. Plain Gauss-Newton (no damping) is enough: the algebraic
    start lands inside its basin, and a diverging minimal sample just scores no inliers in RANSAC.
    ``ok``: finite and converged (steps < 1e-4 px) within ``steps``. Jittable and vmappable;
    needs >= 3 weighted points.
    """
    if pose0 is None:
        pose0 = initial_pose(X, uv, weight, K)
    R0, t0 = so3_exp(pose0[:3]), pose0[3:]
    cols = point_columns(X, uv, weight)
    x, y, z, _, _, sqrt_w = cols
    valid = sqrt_w > 0
    dist = jnp.sqrt(x * x + y * y + z * z)
    mean_dist = jnp.sum(jnp.where(valid, dist, 0.0)) / jnp.maximum(jnp.sum(valid), 1)
    scale_rot = K[0, 0]
    scale_t = K[0, 0] / jnp.maximum(mean_dist, 1e-12)

    def pose_of(y):
        return small_matmul(so3_exp(y[:3] / scale_rot), R0), t0 + y[3:] / scale_t

    def residuals(y, args):
        R, t = pose_of(y)
        return _residual_columns(R, t, K, cols)

    y0 = jnp.zeros(6, pose0.dtype)
    sol = optx.least_squares(residuals, _gauss_newton(), y0, max_steps=steps, throw=False)
    R, t = pose_of(sol.value)
    pose6 = jnp.concatenate([so3_log(R), t])
    ok = (sol.result == optx.RESULTS.successful) & jnp.all(jnp.isfinite(pose6))
    return pose6, ok


def block_normals(onehot, J_u, J_v):
    """Normal matrices (k, 6, 6) J^T J of each block from Jacobian rows J_u, J_v (6, *points)
    (d residual / d parameter, parameter axis first), summed over the block's points (``onehot``
    as in ``_block_sums``). Every product of two rows comes from one broadcast, summed within a
    chunk of slots where it is made: one pass over J, which on CPU beats 21 passes for the
    distinct entries alone (and a gather of their index pairs, which copies J 21 times)."""
    products = J_u[:, None] * J_u[None, :] + J_v[:, None] * J_v[None, :]  # (6, 6, *points)
    if products.ndim == 4:  # slot layout: sum each chunk
        products = jnp.sum(products, axis=-1)
    return jnp.einsum("kn,ijn->kij", onehot, products, precision=jax.lax.Precision.HIGHEST)


def _block_sums(onehot, values):
    """(k, N) block membership, (m, N) per-point values -> (k, m) sums over each block's points.

    Slot layout: onehot (k, n_chunks) over chunks and values (m, n_chunks, SLOT_CHUNK): each
    chunk is summed first, so the product is over chunks, not points.
    """
    if values.ndim == 3:
        values = jnp.sum(values, axis=-1)
    return jnp.einsum("kn,mn->km", onehot, values, precision=jax.lax.Precision.HIGHEST)


# Joint solves lay the points out region by region in chunks of SLOT_CHUNK slots, every chunk
# holding one region's points (padded with empty slots): a per-region sum is then a sum within
# chunks plus a small (k, n_chunks) product, and a point's pose is its chunk's, broadcast, where
# the point-by-region layout costs O(k N) per sum and a gather per point.
SLOT_CHUNK = 32


class RegionSlots(NamedTuple):
    """Points grouped by region into chunks of SLOT_CHUNK slots (S slots, S / SLOT_CHUNK chunks).

    point (S,) int32: the point index in each slot, N (one past the last point) for an empty
    slot; chunk_region (n_chunks,) int32: the region index 0..k-1 of each chunk (0 for chunks of
    empty slots only); chunk_onehot (k, n_chunks): 1 where a chunk holds that region's points.
    """

    point: jax.Array
    chunk_region: jax.Array
    chunk_onehot: jax.Array


def region_onehot(region, k: int, dtype):
    """(N,) int region 1..k (0: none) -> (k, N) indicator of each region's points, as dtype."""
    return (region[None, :] == jnp.arange(1, k + 1, dtype=region.dtype)[:, None]).astype(dtype)


def label_ranks(label, n_labels: int):
    """Counting sort's ranks, without a sort: label (N,) int in 0..n_labels-1 (others: none) ->
    (rank (N,) int32, each point's position among the points of its label in index order (0 for
    points of no label); count (n_labels,) int32).

    Prefix counts by blocks of 64 points: a product with a triangular matrix within blocks, and
    one across the block totals. Several times faster on CPU than ``argsort`` (XLA's sort), and
    exact (counts < 2^24 in float32).
    """
    N = label.shape[0]
    B = 64
    n_blocks = -(-N // B)
    label = jnp.concatenate([label, jnp.full(n_blocks * B - N, -1, label.dtype)])
    onehot = (label[None, :] == jnp.arange(n_labels, dtype=label.dtype)[:, None]).astype(jnp.float32)
    onehot = onehot.reshape(n_labels, n_blocks, B)
    inclusive = jnp.triu(jnp.ones((B, B), jnp.float32))
    within = jnp.einsum("lbi,ij->lbj", onehot, inclusive, precision=jax.lax.Precision.HIGHEST)
    block_count = jnp.sum(onehot, axis=-1)  # (n_labels, n_blocks)
    before = jnp.einsum("lb,bc->lc", block_count, jnp.triu(jnp.ones((n_blocks, n_blocks), jnp.float32), 1),
                        precision=jax.lax.Precision.HIGHEST)
    rank = jnp.sum((within + before[..., None] - 1.0) * onehot, axis=0).reshape(-1)[:N]
    return jnp.maximum(rank, 0.0).astype(jnp.int32), jnp.sum(block_count, axis=-1).astype(jnp.int32)


def region_slots(region, k: int, dtype=jnp.float32) -> RegionSlots:
    """The slot layout of N points with region (N,) int in 1..k (0 or > k: none, left out).

    S = N + k (SLOT_CHUNK - 1) rounded up to a multiple of SLOT_CHUNK, enough for any split of
    the N points into k regions. Within a region, points keep their index order.
    """
    N = region.shape[0]
    C = SLOT_CHUNK
    S = -(-(N + k * (C - 1)) // C) * C
    member = (region >= 1) & (region <= k)
    rank, count = label_ranks(jnp.where(member, region - 1, -1), k)
    padded = -(-count // C) * C
    slot_start = jnp.cumsum(padded) - padded
    slot = jnp.where(member, slot_start[jnp.clip(region - 1, 0, k - 1)] + rank, S)
    point = jnp.full(S, N, jnp.int32).at[slot].set(jnp.arange(N, dtype=jnp.int32), mode="drop")
    chunk_first = jnp.arange(S // C, dtype=jnp.int32) * C
    holds = (chunk_first[None, :] >= slot_start[:, None]) & (chunk_first[None, :] < (slot_start + count)[:, None])
    return RegionSlots(point, jnp.argmax(holds, axis=0).astype(jnp.int32), holds.astype(dtype))


def to_slots(slots: RegionSlots, values, fill):
    """Per-point values (N, ...) -> (n_chunks, SLOT_CHUNK, ...) in the slot layout; empty slots
    hold ``fill``."""
    padded = jnp.concatenate([values, jnp.broadcast_to(jnp.asarray(fill, values.dtype), (1,) + values.shape[1:])])
    return padded[slots.point].reshape((-1, SLOT_CHUNK) + values.shape[1:])


def pointwise_residuals(R_pt, t_pt, K, cols):
    """Residuals of each point under its own pose (R_pt (*points, 3, 3) and t_pt (*points, 3)
    with the point axes first, or broadcastable to them: (n_chunks, 3, 3, 1) per chunk of slots)
    -> ((du, dv), (R X, d du / dY, d dv / dY)), each of the last three a triple of per-point
    coordinates, Y = R X + t, with the behind-camera depth floor of ``project_columns``."""
    x, y, z, u, v, sqrt_w = cols
    RX = tuple(R_pt[:, i, 0] * x + R_pt[:, i, 1] * y + R_pt[:, i, 2] * z for i in range(3))
    Yx, Yy, Yz = (RX[i] + t_pt[:, i] for i in range(3))
    norm = jnp.sqrt(Yx * Yx + Yy * Yy + Yz * Yz)
    in_front = (Yz > 0) & (Yz > _MIN_Z_FRAC * norm)
    inv_z = 1.0 / jnp.where(in_front, Yz, _MIN_Z_FRAC * norm + 1e-30)
    xn, yn = Yx * inv_z, Yy * inv_z
    u_hat = K[0, 0] * xn + K[0, 1] * yn + K[0, 2]
    v_hat = K[1, 1] * yn + K[1, 2]
    # d depth / dY: e_z in front of the camera, else the floor's _MIN_Z_FRAC * Y / |Y|.
    floor = _MIN_Z_FRAC / jnp.maximum(norm, 1e-30)
    d_depth = tuple(jnp.where(in_front, e, floor * c) for e, c in ((0.0, Yx), (0.0, Yy), (1.0, Yz)))
    d_xn = tuple((float(i == 0) - xn * d_depth[i]) * inv_z for i in range(3))
    d_yn = tuple((float(i == 1) - yn * d_depth[i]) * inv_z for i in range(3))
    grad_u = tuple(sqrt_w * (K[0, 0] * d_xn[i] + K[0, 1] * d_yn[i]) for i in range(3))
    grad_v = tuple(sqrt_w * K[1, 1] * d_yn[i] for i in range(3))
    return (sqrt_w * (u_hat - u), sqrt_w * (v_hat - v)), (RX, grad_u, grad_v)


# Levenberg-Marquardt of the joint region solve: a region stops once a step would lower its squared
# error by less than _LM_RTOL of it (float32 resolves ~1e-7), or its damping passes
# _LM_MAX_DAMPING (no step lowers it), or its step is below _LM_ATOL_PX in pixel-scaled units.
_LM_RTOL = 1e-6
_LM_ATOL_PX = 1e-4
_LM_MAX_DAMPING = 1e8


def solve_pnp_regions(X, uv, weight, region, K, pose0, *, steps, slots: RegionSlots | None = None):
    """Minimise each region's sum weight * |project(K, R X + t) - uv|^2, all k regions at once
    -> (pose6 (k, 6), converged (k,) bool).

    X (N, 3), uv (N, 2), weight (N,), region (N,) int in 1..k (0: none), pose0 (k, 6) starts.
    Levenberg-Marquardt with a damping of its own per region (Nielsen's update), on the left
    perturbation (exp([w]) R, t + dt) in pixel-scaled parameters (w by fx, dt by fx / the
    region's mean point distance): a step is taken only where it lowers that region's error, so
    a start far from the optimum (a few points, a rotation tens of degrees off) descends to it
    instead of diverging. One pass over the N points per step, laid out in ``RegionSlots``
    (``slots``: ``region_slots(region, k)``, computed here when not given); at most ``steps``
    steps, fewer once every region has stopped. Needs >= 3 weighted points per region.
    """
    k = pose0.shape[0]
    dtype = X.dtype
    if slots is None:
        slots = region_slots(region, k, dtype)
    onehot = slots.chunk_onehot
    weight = jnp.where((region >= 1) & (region <= k), weight, 0.0)
    cols = point_columns(to_slots(slots, X, jnp.array([0.0, 0.0, 1.0], dtype)), to_slots(slots, uv, 0.0),
                          to_slots(slots, weight, 0.0))  # (n_chunks, SLOT_CHUNK) each
    x, y, z, _, _, sqrt_w = cols
    valid = (sqrt_w > 0).astype(dtype)
    sums = _block_sums(onehot, jnp.stack([valid * jnp.sqrt(x * x + y * y + z * z), valid]))
    mean_dist = sums[:, 0] / jnp.maximum(sums[:, 1], 1.0)
    scale = jnp.concatenate([jnp.broadcast_to(K[0, 0], (k, 3)),
                             jnp.broadcast_to((K[0, 0] / jnp.maximum(mean_dist, 1e-12))[:, None], (k, 3))],
                            axis=-1)  # (k, 6): pixel-scaled units per parameter unit (finite for an empty region)
    per_chunk = lambda table: table[slots.chunk_region][..., None]  # noqa: E731  (k, ...) -> (n_chunks, ..., 1)
    chunk_scale = scale[slots.chunk_region].T[..., None]  # (6, n_chunks, 1)

    def linearise(R, t):
        """Squared error (k,), J^T J (k, 6, 6) and J^T r (k, 6) in the scaled parameters."""
        (du, dv), (RX, grad_u, grad_v) = pointwise_residuals(per_chunk(R), per_chunk(t), K, cols)

        def rows(g):  # d residual / d (w, dt): w . (RX x g) + dt . g, then scaled
            return jnp.stack([RX[1] * g[2] - RX[2] * g[1], RX[2] * g[0] - RX[0] * g[2], RX[0] * g[1] - RX[1] * g[0],
                              g[0], g[1], g[2]]) / chunk_scale

        J_u, J_v = materialise((rows(grad_u), rows(grad_v)))  # (6, n_chunks, SLOT_CHUNK) each
        cost = _block_sums(onehot, (du * du + dv * dv)[None])[:, 0]
        return cost, block_normals(onehot, J_u, J_v), _block_sums(onehot, J_u * du + J_v * dv)

    def step(state):
        R, t, cost, normal, grad, damping, growth, done, i = state
        diag = jnp.diagonal(normal, axis1=1, axis2=2)
        damped = normal + (damping[:, None] * diag + 1e-12)[:, :, None] * jnp.eye(6, dtype=dtype)
        delta = -jax.vmap(solve_spd)(damped, grad) / scale  # (k, 6) in (w [rad], dt)
        R_new, t_new = small_matmul(so3_exp(delta[:, :3]), R), t + delta[:, 3:]
        cost_new, normal_new, grad_new = linearise(R_new, t_new)
        scaled = delta * scale
        predicted = -(2.0 * jnp.sum(grad * scaled, -1) + jnp.einsum("ki,kij,kj->k", scaled, normal, scaled))
        rho = (cost - cost_new) / jnp.maximum(predicted, 1e-30)
        # A step is taken only where it lowers the error by more than float32's rounding of the sum
        # (so that differently fused programs, one device or several, take the same steps).
        # Settled: the step lowers it by less, the linear model expects no more, or the step is
        # below float32's resolution of a pixel; it is not taken, and nothing is left to gain.
        lower = jnp.isfinite(cost_new) & (cost_new < cost)
        significant = lower & (cost - cost_new > _LM_RTOL * cost + _LM_ATOL_PX**2)
        settled = ~done & ((lower & ~significant) | (predicted <= _LM_RTOL * cost + _LM_ATOL_PX**2)
                           | (jnp.max(jnp.abs(scaled), -1) < _LM_ATOL_PX))
        accept = ~done & ~settled & significant
        damping = jnp.where(accept, jnp.maximum(damping * jnp.maximum(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3), 1e-12),
                            jnp.where(done, damping, damping * growth))
        growth = jnp.where(accept, 2.0, jnp.where(done, growth, growth * 2.0))
        pick = lambda new, old: jnp.where(accept.reshape((k,) + (1,) * (new.ndim - 1)), new, old)  # noqa: E731
        done = done | settled | (damping > _LM_MAX_DAMPING)
        return (pick(R_new, R), pick(t_new, t), pick(cost_new, cost), pick(normal_new, normal), pick(grad_new, grad),
                damping, growth, done, i + 1)

    R0, t0 = so3_exp(pose0[:, :3]), pose0[:, 3:]
    cost0, normal0, grad0 = linearise(R0, t0)
    done0 = ~jnp.isfinite(cost0) | ~jnp.all(jnp.isfinite(pose0), axis=-1)
    state = (R0, t0, cost0, normal0, grad0, jnp.full(k, 1e-3, dtype), jnp.full(k, 2.0, dtype), done0, 0)
    R, t, _, _, _, _, _, done, _ = jax.lax.while_loop(lambda s: (s[-1] < steps) & jnp.any(~s[-2]), step, state)
    pose6 = jnp.concatenate([so3_log(R), t], axis=-1)
    return pose6, done & jnp.all(jnp.isfinite(pose6), axis=-1)


def translation_for_rotation(X, uv, weight, region, K, R, k: int):
    """Per region, the translation (k, 3) that best explains pixels uv (N, 2) of points X (N, 3)
    (weight (N,) > 0, region (N,) in 1..k) under one rotation R (3, 3): linear least squares of
    t_a - r_a t_3 = r_a Y_3 - Y_a on both image axes a (r = K^-1 (u, v, 1), Y = R X), each divided
    by Y_3 so that it weighs as a pixel error over f; points with Y_3 <= 0 are left out. A region
    with fewer than two such points gets a meaningless (finite) translation."""
    dtype = X.dtype
    rays = back_project(K, uv, jnp.ones_like(uv[:, 0]))  # (N, 3), z = 1
    Y = X @ R.T
    use = (weight > 0) & (Y[:, 2] > 0)
    inv_z = jnp.where(use, 1.0 / jnp.where(use, Y[:, 2], 1.0), 0.0)
    zero, one = jnp.zeros_like(inv_z), jnp.ones_like(inv_z)
    rows = [jnp.stack([one, zero, -rays[:, 0]], -1) * inv_z[:, None],  # (N, 3) per image axis
            jnp.stack([zero, one, -rays[:, 1]], -1) * inv_z[:, None]]
    rhs = [rays[:, a] - Y[:, a] * inv_z for a in (0, 1)]  # rows of unused points are 0
    normal = sum(r[:, :, None] * r[:, None, :] for r in rows).reshape(-1, 9)
    moment = sum(r * b[:, None] for r, b in zip(rows, rhs))
    onehot = region_onehot(region, k, dtype)
    A = jnp.dot(onehot, normal, precision=jax.lax.Precision.HIGHEST).reshape(k, 3, 3)
    b = jnp.dot(onehot, moment, precision=jax.lax.Precision.HIGHEST)
    return jax.vmap(solve_spd)(A, b)
