"""Rotations: SO(3) exp and log, the angle between two rotations, the nearest rotation.

Rotation vectors are axis * angle in radians; matrices act on column vectors (x' = R x). Small
angles take Taylor branches behind a "double where", so values and gradients stay finite at the
identity.
"""

from __future__ import annotations

import jax.numpy as jnp

# Below this (the squared angle [rad^2] in so3_exp, sin^2(angle / 2) in so3_log) the Taylor branches
# err by at most ~2e-13 relative: far below float32's round-off (6e-8) and the float64 checks' tolerances.
SMALL_ANGLE_SQ = 1e-6


def hat(v):
    """(..., 3) -> (..., 3, 3) skew-symmetric matrix: hat(v) @ x = cross(v, x)."""
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    zero = jnp.zeros_like(x)
    return jnp.stack([jnp.stack([zero, -z, y], -1), jnp.stack([z, zero, -x], -1), jnp.stack([-y, x, zero], -1)], -2)


def _vee_asym(M):
    """(..., 3, 3) -> (..., 3): vee(M - M^T), 2 sin(angle) axis for a rotation."""
    return jnp.stack([M[..., 2, 1] - M[..., 1, 2], M[..., 0, 2] - M[..., 2, 0], M[..., 1, 0] - M[..., 0, 1]], -1)


def so3_exp(rotvec):
    """Rotation vector (..., 3) [rad] -> rotation matrix (..., 3, 3) (Rodrigues)."""
    theta_sq = jnp.sum(rotvec * rotvec, axis=-1)
    small = theta_sq < SMALL_ANGLE_SQ
    theta_sq_safe = jnp.where(small, 1.0, theta_sq)
    theta = jnp.sqrt(theta_sq_safe)
    half_sin = jnp.sin(0.5 * theta)
    a = jnp.where(small, 1.0 - theta_sq / 6.0 + theta_sq**2 / 120.0, jnp.sin(theta) / theta)
    # (1 - cos t) / t^2 as 2 sin^2(t/2) / t^2: no cancellation in float32
    b = jnp.where(small, 0.5 - theta_sq / 24.0 + theta_sq**2 / 720.0, 2.0 * half_sin**2 / theta_sq_safe)
    # hat(w)^2 = w w^T - |w|^2 I, so R = (1 - b |w|^2) I + a hat(w) + b w w^T
    eye = jnp.eye(3, dtype=rotvec.dtype)
    outer = rotvec[..., :, None] * rotvec[..., None, :]
    return (1.0 - b * theta_sq)[..., None, None] * eye + a[..., None, None] * hat(rotvec) + b[..., None, None] * outer


def _quaternion_wxyz(R):
    """(..., 3, 3) -> (..., 4) unit quaternion (w, x, y, z), w >= 0 (Shepperd's method)."""
    r00, r11, r22 = R[..., 0, 0], R[..., 1, 1], R[..., 2, 2]
    trace = r00 + r11 + r22
    # four candidates of 4 q_k^2; the largest gives a well-conditioned square root
    cands = jnp.stack([1.0 + trace, 1.0 + r00 - r11 - r22, 1.0 - r00 + r11 - r22, 1.0 - r00 - r11 + r22], -1)
    choice = jnp.argmax(cands, axis=-1)
    s = 2.0 * jnp.sqrt(jnp.maximum(cands, 1e-12))  # 4 |q_k|; clamped so the unused branches stay finite
    d21 = R[..., 2, 1] - R[..., 1, 2]
    d02 = R[..., 0, 2] - R[..., 2, 0]
    d10 = R[..., 1, 0] - R[..., 0, 1]
    p01 = R[..., 0, 1] + R[..., 1, 0]
    p02 = R[..., 0, 2] + R[..., 2, 0]
    p12 = R[..., 1, 2] + R[..., 2, 1]
    s0, s1, s2, s3 = s[..., 0], s[..., 1], s[..., 2], s[..., 3]
    q_w = jnp.stack([0.25 * s0, d21 / s0, d02 / s0, d10 / s0], -1)
    q_x = jnp.stack([d21 / s1, 0.25 * s1, p01 / s1, p02 / s1], -1)
    q_y = jnp.stack([d02 / s2, p01 / s2, 0.25 * s2, p12 / s2], -1)
    q_z = jnp.stack([d10 / s3, p02 / s3, p12 / s3, 0.25 * s3], -1)
    q = jnp.choose(choice[..., None], [q_w, q_x, q_y, q_z], mode="clip")
    q = q * jnp.where(q[..., :1] < 0, -1.0, 1.0)
    return q / jnp.linalg.norm(q, axis=-1, keepdims=True)


def so3_log(R):
    """Rotation matrix (..., 3, 3) -> rotation vector (..., 3) [rad], angle in [0, pi]; through the
    quaternion, accurate near the identity and near pi."""
    q = _quaternion_wxyz(R)
    w, v = q[..., 0], q[..., 1:]
    n_sq = jnp.sum(v * v, axis=-1)
    small = n_sq < SMALL_ANGLE_SQ
    n = jnp.sqrt(jnp.where(small, 1.0, n_sq))
    w_safe = jnp.where(small, w, 1.0)
    # angle / sin(angle / 2) = 2 atan2(n, w) / n; Taylor in n for small n (w ~ 1 there)
    scale = jnp.where(small, 2.0 / w_safe - (2.0 / 3.0) * n_sq / w_safe**3, 2.0 * jnp.arctan2(n, w) / n)
    return scale[..., None] * v


def rotation_angle_deg(R_a, R_b):
    """Angle of R_a^T R_b [deg], (..., 3, 3) x2 -> (...); accurate from ~1e-5 deg to 180 deg."""
    # E = R_a^T R_b - I has O(angle) entries with relative float32 error; then atan2(sin, cos)
    E = jnp.swapaxes(R_a, -1, -2) @ (R_b - R_a)
    a = _vee_asym(E)
    a_sq = jnp.sum(a * a, axis=-1)
    sin_angle = 0.5 * jnp.where(a_sq > 0, jnp.sqrt(jnp.where(a_sq > 0, a_sq, 1.0)), 0.0)
    cos_angle = 1.0 + 0.5 * jnp.trace(E, axis1=-2, axis2=-1)
    return jnp.degrees(jnp.arctan2(sin_angle, cos_angle))


def nearest_rotation(M):
    """(..., 3, 3) -> the closest rotation in Frobenius norm (SVD, det forced to +1)."""
    U, _, Vt = jnp.linalg.svd(M)
    d = jnp.sign(jnp.linalg.det(U @ Vt))
    d = jnp.where(d == 0, 1.0, d)
    D = jnp.ones(M.shape[:-1], M.dtype).at[..., 2].set(d)
    return (U * D[..., None, :]) @ Vt


def polar_rotation(M, steps: int = 6):
    """(..., 3, 3) near a rotation -> its nearest rotation by Higham's polar iteration (M + M^-T) / 2,
    unrolled ``steps`` times (quadratic convergence). ``nearest_rotation``'s value without its SVD,
    whose gradient is undefined where singular values repeat (every rotation)."""
    for _ in range(steps):  # static and small
        M = 0.5 * (M + jnp.swapaxes(jnp.linalg.inv(M), -1, -2))
    return M
