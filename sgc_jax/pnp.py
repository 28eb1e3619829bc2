"""Perspective-n-point: reprojection residuals and an optimistix Gauss-Newton pose solve (SPEC §3.6).

A pose is a 6-vector ``pose6 = (rotvec [rad], t)`` mapping camera i-1 coordinates X to camera i
coordinates ``R X + t`` with ``R = so3_exp(rotvec)``; pixels follow ``geometry.project``.
Point sets have a static size N; ``weight`` (N,) masks them (0 = padded / ignored point).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import lineax as lx
import optimistix as optx

from .geometry import back_project, hat, small_matmul, so3_exp, so3_log

# Points with z below this fraction of their distance are "behind the camera": their projection
# uses this floor instead, so residuals stay finite (large) and never inf/NaN.
_MIN_Z_FRAC = 1e-3
# Gauss-Newton stops when both the step and the residual change are below ~1e-4 px (float32
# resolves ~3e-5 px at 500 px), so where a solve started (padding, batching) leaves no trace.
_GN_RTOL = 1e-6
_GN_ATOL = 1e-4


def _point_columns(X, uv, weight):
    """Masked points as columns: (x, y, z, u, v, sqrt_w), each (N,); masked points sit at (0, 0, 1)."""
    valid = weight > 0
    x = jnp.where(valid, X[:, 0], 0.0)
    y = jnp.where(valid, X[:, 1], 0.0)
    z = jnp.where(valid, X[:, 2], 1.0)
    u = jnp.where(valid, uv[:, 0], 0.0)
    v = jnp.where(valid, uv[:, 1], 0.0)
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

    Yx, Yy, Yz = row(0), row(1), row(2)
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
    du, dv = _residual_columns(so3_exp(pose6[:3]), pose6[3:], K, _point_columns(X, uv, weight))
    return jnp.stack([du, dv], axis=-1)


def initial_pose(X, uv, weight, K, n_iter=3):
    """Data-driven pose6 (6,) without a prior: iterated linearised algebraic solve.

    With unit bearings b = K^-1 [u, v, 1] / |.|, each step solves the weighted 6x6 normal
    equations of b x (exp([w]) R X + t) = 0 linearised in (w, t), then R <- exp(w) R. Rows are
    divided by the current point distance, so the error is roughly angular. Converges from the
    identity for rotations up to ~30 deg; needs >= 3 points with weight > 0 (4 for uniqueness).
    """
    x, y, z, u, v, sqrt_w = _point_columns(X, uv, weight)
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
        normal = jnp.sum(J[:, :, None] * J[:, None, :], axis=0)  # J^T J without a tiny-matmul call
        if transposed:
            x, structure = J @ solve_spd(normal, b), out_structure
        else:
            x, structure = solve_spd(normal, jnp.sum(J * b[:, None], axis=0)), in_structure
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
    cols = _point_columns(X, uv, weight)
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
