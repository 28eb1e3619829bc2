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

from .geometry import back_project, hat, project, so3_exp, so3_log

# Points with z below this fraction of their distance are "behind the camera": their projection
# uses this floor instead, so residuals stay finite (large) and never inf/NaN.
_MIN_Z_FRAC = 1e-3
# Cauchy termination of Gauss-Newton: steps in rad / depth units, cost in px^2 (float32-safe).
_GN_RTOL = 1e-5
_GN_ATOL = 1e-6


def _masked(weight, X, uv):
    """Zero the coordinates of masked points so garbage padding never reaches the arithmetic."""
    valid = weight > 0
    X = jnp.where(valid[:, None], X, jnp.array([0.0, 0.0, 1.0], X.dtype))
    uv = jnp.where(valid[:, None], uv, 0.0)
    return valid, X, uv


def _in_front(Y):
    """(..., 3) camera-frame points -> (bool (...), guarded z (...)): z floored at 1e-3 * |Y|."""
    norm = jnp.sqrt(jnp.sum(Y * Y, axis=-1) + 1e-30)
    z_min = _MIN_Z_FRAC * norm
    in_front = Y[..., 2] > z_min
    return in_front, jnp.where(in_front, Y[..., 2], z_min)


def project_guarded(K, Y):
    """Camera-frame points Y (..., 3) -> (pixels (..., 2), in_front (...)), finite for any finite Y."""
    in_front, z = _in_front(Y)
    return project(K, jnp.concatenate([Y[..., :2], z[..., None]], axis=-1)), in_front


def _residuals_Rt(R, t, X, uv, K, weight):
    """(N, 2) residuals sqrt(weight) * (project(K, R X + t) - uv) in px; exactly 0 where weight == 0."""
    valid, X, uv = _masked(weight, X, uv)
    uv_hat, _ = project_guarded(K, X @ R.T + t)
    scale = jnp.sqrt(jnp.where(valid, weight, 1.0))
    return jnp.where(valid[:, None], scale[:, None] * (uv_hat - uv), 0.0)


def reprojection_residuals(pose6, X, uv, K, weight):
    """Residuals (N, 2) [px] of pose6 (6,) on points X (N, 3), pixels uv (N, 2), K (3, 3).

    Scaled by sqrt(weight) (cost = sum weight * |error|^2); exactly 0 where weight == 0.
    """
    return _residuals_Rt(so3_exp(pose6[:3]), pose6[3:], X, uv, K, weight)


def initial_pose(X, uv, weight, K, n_iter=3):
    """Data-driven pose6 (6,) without a prior: iterated linearised algebraic solve.

    With unit bearings b = K^-1 [u, v, 1] / |.|, each step solves the weighted 6x6 normal
    equations of b x (exp([w]) R X + t) = 0 linearised in (w, t), then R <- exp(w) R. Rows are
    divided by the current point distance, so the error is roughly angular. Converges from the
    identity for rotations up to ~30 deg; needs >= 3 points with weight > 0 (4 for uniqueness).
    """
    valid, X, uv = _masked(weight, X, uv)
    w = jnp.where(valid, weight, 0.0)
    b = back_project(K, uv, jnp.ones_like(uv[:, 0]))
    b = b / jnp.linalg.norm(b, axis=-1, keepdims=True)
    B = hat(b)  # (N, 3, 3): B @ x = b x x
    eye6 = jnp.eye(6, dtype=X.dtype)

    def step(_, Rt):
        R, t = Rt
        Y = X @ R.T
        dist_sq = jnp.sum((Y + t) ** 2, axis=-1)
        s = w / jnp.maximum(dist_sq, 1e-12)
        A = jnp.concatenate([-B @ hat(Y), B], axis=-1)  # (N, 3, 6) acting on (w, t)
        rhs = -jnp.cross(b, Y)  # (N, 3)
        H = jnp.einsum("n,nij,nik->jk", s, A, A)
        g = jnp.einsum("n,nij,ni->j", s, A, rhs)
        H = H + (1e-9 * jnp.trace(H) + 1e-30) * eye6
        x = jnp.linalg.solve(H, g)
        return so3_exp(x[:3]) @ R, x[3:]

    R0 = jnp.eye(3, dtype=X.dtype)
    R, t = jax.lax.fori_loop(0, n_iter, step, (R0, jnp.zeros(3, X.dtype)))
    return jnp.concatenate([so3_log(R), t])


def _gauss_newton():
    """Gauss-Newton with normal-equation Cholesky solves (6x6); see ``solve_pnp``."""
    return optx.GaussNewton(rtol=_GN_RTOL, atol=_GN_ATOL, linear_solver=lx.Normal(lx.Cholesky()))


def solve_pnp(X, uv, weight, K, *, steps, pose0=None):
    """Minimise sum weight * |project(K, R X + t) - uv|^2 -> (pose6 (6,), ok () bool).

    Starts from ``pose0`` when given, else from ``initial_pose``. Gauss-Newton
    (``optimistix.GaussNewton``, at most ``steps`` steps) on a local rotation increment
    R = exp([w]) R0, so the parametrisation is never near its pi singularity. Plain Gauss-Newton
    is enough here: the algebraic start lands inside its basin, and a diverging minimal sample
    just scores no inliers in RANSAC. ``ok``: finite and converged before ``steps``.
    Jittable and vmappable; needs >= 3 weighted points.
    """
    if pose0 is None:
        pose0 = initial_pose(X, uv, weight, K)
    R0 = so3_exp(pose0[:3])

    def residuals(y, args):
        return _residuals_Rt(so3_exp(y[:3]) @ R0, y[3:], X, uv, K, weight)

    y0 = jnp.concatenate([jnp.zeros(3, pose0.dtype), pose0[3:]])
    sol = optx.least_squares(residuals, _gauss_newton(), y0, max_steps=steps, throw=False)
    R = so3_exp(sol.value[:3]) @ R0
    pose6 = jnp.concatenate([so3_log(R), sol.value[3:]])
    ok = (sol.result == optx.RESULTS.successful) & jnp.all(jnp.isfinite(pose6))
    return pose6, ok
