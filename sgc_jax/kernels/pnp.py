"""Perspective-n-point for one point set: reprojection residuals and their Jacobians, an algebraic
start, and an optimistix Gauss-Newton solve (docs/semantics.md §7.1).

A pose is ``pose6 = (rotvec [rad], t)``, mapping camera i-1 coordinates X to camera i
coordinates R X + t; pixels as ``camera``. Point sets have a static size N and a weight (N,)
(0: padded or ignored).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import optimistix as optx

from .camera import MIN_Z_FRAC, back_project, project_floored, transform_pointwise, transform_xyz
from .linalg import NormalCholesky, small_matmul, solve_spd
from .regions import HIGHEST, region_onehot
from .so3 import hat, so3_exp, so3_log

# Gauss-Newton stops when both the step and the residual change are below ~1e-4 px (float32
# resolves ~3e-5 px at 500 px), so where a solve started leaves no trace.
GN_RTOL = 1e-6
GN_ATOL = 1e-4


def point_columns(X, uv, weight):
    """Masked points as columns (x, y, z, u, v, sqrt_w), each (*points,); masked ones at (0, 0, 1)."""
    valid = weight > 0
    x = jnp.where(valid, X[..., 0], 0.0)
    y = jnp.where(valid, X[..., 1], 0.0)
    z = jnp.where(valid, X[..., 2], 1.0)
    u = jnp.where(valid, uv[..., 0], 0.0)
    v = jnp.where(valid, uv[..., 1], 0.0)
    return x, y, z, u, v, jnp.sqrt(jnp.where(valid, weight, 0.0))


def projected_columns(R, t, K, x, y, z):
    """Pixels (u, v) and in_front, each (..., N), of column points under poses R (..., 3, 3), t (..., 3)."""
    p = project_floored(K, *transform_xyz(R, t, x, y, z))
    return p.u, p.v, p.in_front


def projected_pointwise(R, t, K, x, y, z):
    """``projected_columns`` with one pose per point: R (N, 3, 3), t (N, 3), columns (N,)."""
    p = project_floored(K, *transform_pointwise(R, t, x, y, z)[1])
    return p.u, p.v, p.in_front


def reprojection_residuals(pose6, X, uv, K, weight):
    """sqrt(weight) (projection - uv) (N, 2) [px] of pose6 (6,); exactly 0 where weight == 0."""
    x, y, z, u, v, sqrt_w = point_columns(X, uv, weight)
    u_hat, v_hat, _ = projected_columns(so3_exp(pose6[:3]), pose6[3:], K, x, y, z)
    return jnp.stack([sqrt_w * (u_hat - u), sqrt_w * (v_hat - v)], axis=-1)


def pointwise_residuals(R_pt, t_pt, K, cols):
    """Residuals of each point under its own pose, and what their Jacobian needs.

    R_pt (*points, 3, 3), t_pt (*points, 3), point axes first (or broadcastable: (n_chunks, 3, 3,
    1) per chunk of slots) -> ((du, dv), (R X, d du / dY, d dv / dY)), the last three triples of
    per-point coordinates, Y = R X + t."""
    x, y, z, u, v, sqrt_w = cols
    RX, Y = transform_pointwise(R_pt, t_pt, x, y, z)
    p = project_floored(K, *Y)
    # d depth / dY: e_z in front of the camera, the floor's MIN_Z_FRAC Y / |Y| behind it
    floor = MIN_Z_FRAC / jnp.maximum(p.norm, 1e-30)
    d_depth = tuple(jnp.where(p.in_front, e, floor * c) for e, c in zip((0.0, 0.0, 1.0), Y))
    d_xn = tuple((float(i == 0) - p.xn * d_depth[i]) * p.inv_z for i in range(3))
    d_yn = tuple((float(i == 1) - p.yn * d_depth[i]) * p.inv_z for i in range(3))
    grad_u = tuple(sqrt_w * (K[0, 0] * d_xn[i] + K[0, 1] * d_yn[i]) for i in range(3))
    grad_v = tuple(sqrt_w * K[1, 1] * d_yn[i] for i in range(3))
    return (sqrt_w * (p.u - u), sqrt_w * (p.v - v)), (RX, grad_u, grad_v)


def pose_jacobian_rows(RX, grad):
    """d residual / d (w, dt) of the left-perturbed pose exp([w]) R, t + dt: (RX x grad, grad),
    stacked (6, *points), from ``pointwise_residuals``' R X and one axis's d residual / dY."""
    return jnp.stack([RX[1] * grad[2] - RX[2] * grad[1], RX[2] * grad[0] - RX[0] * grad[2],
                      RX[0] * grad[1] - RX[1] * grad[0], grad[0], grad[1], grad[2]])


def initial_pose(X, uv, weight, K, n_iter=3):
    """A pose6 (6,) without a prior: iterated linearised algebraic solve of b x (R X + t) = 0
    (b the unit bearing of each pixel), each row divided by the point's current distance so the
    error is roughly angular. Converges from the identity for rotations up to ~30 deg; needs >= 3
    weighted points (4 for uniqueness)."""
    x, y, z, u, v, sqrt_w = point_columns(X, uv, weight)
    X, uv, w = jnp.stack([x, y, z], -1), jnp.stack([u, v], -1), sqrt_w**2
    b = back_project(K, uv, jnp.ones_like(uv[:, 0]))
    b = b / jnp.linalg.norm(b, axis=-1, keepdims=True)
    B = hat(b)  # (N, 3, 3): B @ x = b x x

    def step(_, pose):
        R, t = pose
        Y = jnp.sum(R[None] * X[:, None, :], axis=-1)  # (N, 3) = X @ R^T
        s = w / jnp.maximum(jnp.sum((Y + t) ** 2, axis=-1), 1e-12)
        # b x (w x Y) = ((b . Y) I - Y b^T) w
        A_w = jnp.sum(b * Y, -1)[:, None, None] * jnp.eye(3, dtype=X.dtype) - Y[:, :, None] * b[:, None, :]
        A = jnp.concatenate([A_w, B], axis=-1)  # (N, 3, 6) acting on (w, t)
        rhs = -jnp.cross(b, Y)  # (N, 3)
        sA = s[:, None, None] * A
        H = jnp.sum(sA[:, :, :, None] * A[:, :, None, :], axis=(0, 1))
        g = jnp.sum(sA * rhs[:, :, None], axis=(0, 1))
        delta = solve_spd(H, g)
        return small_matmul(so3_exp(delta[:3]), R), delta[3:]

    R, t = jax.lax.fori_loop(0, n_iter, step, (jnp.eye(3, dtype=X.dtype), jnp.zeros(3, X.dtype)))
    return jnp.concatenate([so3_log(R), t])


def pixel_scaling(K, cols):
    """(rotation, translation) units per pixel of image motion for points ``cols`` (as
    ``point_columns``): fx, and fx / the weighted points' mean distance."""
    x, y, z, _, _, sqrt_w = cols
    valid = sqrt_w > 0
    mean_dist = jnp.sum(jnp.where(valid, jnp.sqrt(x * x + y * y + z * z), 0.0)) / jnp.maximum(jnp.sum(valid), 1)
    return K[0, 0], K[0, 0] / jnp.maximum(mean_dist, 1e-12)


def gauss_newton_updates(X, uv, weight, K, pose0, *, updates: int):
    """pose6 (6,) after ``updates`` undamped Gauss-Newton updates from pose0 (6,), each
    re-linearised at its pose on the left perturbation exp([w]) R, t + dt, scaled as in
    ``solve_pnp``; no stopping test. For the minimal samples, where a few points make the
    least-squares solve's machinery cost more than its arithmetic (``solve_pnp`` with ``steps``
    takes ``steps - 1`` updates: its first step only linearises)."""
    cols = point_columns(X, uv, weight)
    scale_rot, scale_t = pixel_scaling(K, cols)
    scale = jnp.stack([scale_rot] * 3 + [scale_t] * 3)[:, None]  # (6, 1)
    n = X.shape[0]

    def update(_, pose):
        R, t = pose
        (du, dv), (RX, grad_u, grad_v) = pointwise_residuals(jnp.broadcast_to(R, (n, 3, 3)),
                                                             jnp.broadcast_to(t, (n, 3)), K, cols)
        J_u, J_v = pose_jacobian_rows(RX, grad_u) / scale, pose_jacobian_rows(RX, grad_v) / scale  # (6, n)
        normal = jnp.sum(J_u[:, None] * J_u[None, :] + J_v[:, None] * J_v[None, :], axis=-1)
        delta = -solve_spd(normal, jnp.sum(J_u * du + J_v * dv, axis=-1)) / scale[:, 0]
        return small_matmul(so3_exp(delta[:3]), R), t + delta[3:]

    R, t = jax.lax.fori_loop(0, updates, update, (so3_exp(pose0[:3]), pose0[3:]))
    return jnp.concatenate([so3_log(R), t])


def solve_pnp(X, uv, weight, K, *, steps, pose0=None):
    """Minimise sum weight |project(R X + t) - uv|^2 -> (pose6 (6,), converged () bool).

    Gauss-Newton (``optimistix``, at most ``steps`` steps) from ``pose0`` (default:
    ``initial_pose``) on the increment exp([w]) R0, t0 + dt, both scaled to ~px of image motion
    (w by fx, dt by fx / mean point distance) so one tolerance fits and the 6x6 normal equations
    are well conditioned in float32. Undamped: the algebraic start lies in the basin, and a
    diverging minimal sample merely scores no inliers. Needs >= 3 weighted points."""
    if pose0 is None:
        pose0 = initial_pose(X, uv, weight, K)
    R0, t0 = so3_exp(pose0[:3]), pose0[3:]
    x, y, z, u, v, sqrt_w = point_columns(X, uv, weight)
    scale_rot, scale_t = pixel_scaling(K, (x, y, z, u, v, sqrt_w))

    def pose_of(increment):
        return small_matmul(so3_exp(increment[:3] / scale_rot), R0), t0 + increment[3:] / scale_t

    def residuals(increment, args):
        u_hat, v_hat, _ = projected_columns(*pose_of(increment), K, x, y, z)
        return sqrt_w * (u_hat - u), sqrt_w * (v_hat - v)

    solver = optx.GaussNewton(rtol=GN_RTOL, atol=GN_ATOL, linear_solver=NormalCholesky())
    sol = optx.least_squares(residuals, solver, jnp.zeros(6, pose0.dtype), max_steps=steps, throw=False)
    R, t = pose_of(sol.value)
    pose6 = jnp.concatenate([so3_log(R), t])
    return pose6, (sol.result == optx.RESULTS.successful) & jnp.all(jnp.isfinite(pose6))


def translation_for_rotation(X, uv, weight, region, K, R, k: int):
    """Per region, the translation (k, 3) that best explains pixels uv (N, 2) of points X (N, 3)
    (weight > 0, region in 1..k) under one rotation R (3, 3): linear least squares of t_a - r_a t_3
    = r_a Y_3 - Y_a on both image axes (r = K^-1 (u, v, 1), Y = R X), each row divided by Y_3 so
    it weighs as a pixel error over f; points with Y_3 <= 0 left out. Fewer than two points: a
    meaningless finite translation."""
    rays = back_project(K, uv, jnp.ones_like(uv[:, 0]))  # (N, 3), z = 1
    Y = X @ R.T
    use = (weight > 0) & (Y[:, 2] > 0)
    inv_z = jnp.where(use, 1.0 / jnp.where(use, Y[:, 2], 1.0), 0.0)
    zero, one = jnp.zeros_like(inv_z), jnp.ones_like(inv_z)
    rows = [jnp.stack([one, zero, -rays[:, 0]], -1) * inv_z[:, None],  # (N, 3) per image axis
            jnp.stack([zero, one, -rays[:, 1]], -1) * inv_z[:, None]]
    rhs = [rays[:, a] - Y[:, a] * inv_z for a in (0, 1)]  # 0 for unused points
    normal = sum(r[:, :, None] * r[:, None, :] for r in rows).reshape(-1, 9)
    moment = sum(r * b[:, None] for r, b in zip(rows, rhs))
    onehot = region_onehot(region, k, X.dtype)
    A = jnp.dot(onehot, normal, precision=HIGHEST).reshape(k, 3, 3)
    b = jnp.dot(onehot, moment, precision=HIGHEST)
    return jax.vmap(solve_spd)(A, b)
