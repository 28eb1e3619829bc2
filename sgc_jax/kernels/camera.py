"""The pinhole camera, written once: pixels <-> camera-frame points.

Pixels are (u, v) = (column, row) with centres at integer coordinates; K = [[fx, s, cx], [0, fy,
cy], [0, 0, 1]]; depth z is along the optical axis. A pose (R, t) maps camera i-1 coordinates to
camera i: Y = R X + t.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp

# A point with z at most this fraction of its distance is behind the camera; ``project_floored``
# projects it at that depth floor instead, so its pixel stays finite (and far off).
MIN_Z_FRAC = 1e-3


def back_project_xyz(K, u, v, z):
    """Pixels (u, v) at depth z (broadcasting) -> camera-frame coordinates (X, Y, Z)."""
    y = (v - K[1, 2]) / K[1, 1]
    x = (u - K[0, 2] - K[0, 1] * y) / K[0, 0]
    return x * z, y * z, z


def back_project(K, uv, z):
    """Pixels uv (..., 2) at depth z (...) -> camera-frame points (..., 3)."""
    return jnp.stack(back_project_xyz(K, uv[..., 0], uv[..., 1], z), -1)


def pixel_of(K, xn, yn):
    """Normalised image coordinates (x / z, y / z) -> pixels (u, v)."""
    return K[0, 0] * xn + K[0, 1] * yn + K[0, 2], K[1, 1] * yn + K[1, 2]


def project_xyz(K, X, Y, Z):
    """Camera-frame coordinates -> pixels (u, v), no depth guard (the caller drops z <= 0)."""
    return pixel_of(K, X / Z, Y / Z)


def transform_xyz(R, t, x, y, z):
    """R X + t on coordinate columns: R (..., 3, 3), t (..., 3) against columns (N,) -> Y (..., N) x3."""
    return tuple(R[..., i, 0, None] * x + R[..., i, 1, None] * y + R[..., i, 2, None] * z + t[..., i, None]
                 for i in range(3))


def transform_pointwise(R, t, x, y, z):
    """R X + t with one pose per point: R (N, 3, 3), t (N, 3), columns (N,) -> (R X (N,) x3, Y (N,) x3)."""
    RX = tuple(R[:, i, 0] * x + R[:, i, 1] * y + R[:, i, 2] * z for i in range(3))
    return RX, tuple(RX[i] + t[:, i] for i in range(3))


class Projection(NamedTuple):
    """Pixels of camera-frame points with the depth floor, and what their Jacobian needs."""

    u: object
    v: object
    in_front: object  # z > MIN_Z_FRAC |Y|
    xn: object  # x / z (z floored)
    yn: object
    inv_z: object  # 1 / z (z floored)
    norm: object  # |Y|


def project_floored(K, Yx, Yy, Yz) -> Projection:
    """Camera-frame coordinates -> Projection; behind the camera z is MIN_Z_FRAC |Y| instead."""
    norm = jnp.sqrt(Yx * Yx + Yy * Yy + Yz * Yz)
    in_front = (Yz > 0) & (Yz > MIN_Z_FRAC * norm)
    inv_z = 1.0 / jnp.where(in_front, Yz, MIN_Z_FRAC * norm + 1e-30)
    xn, yn = Yx * inv_z, Yy * inv_z
    u, v = pixel_of(K, xn, yn)
    return Projection(u, v, in_front, xn, yn, inv_z, norm)


def homogeneous_pixels(K, R, t, x, y, z):
    """K (R X + t) unnormalised, (pu, pv, pz) each (..., N) for poses R (..., 3, 3), t (..., 3):
    the pixel is (pu / pz, pv / pz). RANSAC's inlier test compares without dividing."""
    P = K @ jnp.concatenate([R, t[..., None]], axis=-1)  # (..., 3, 4)
    return tuple(P[..., i, 0, None] * x + P[..., i, 1, None] * y + P[..., i, 2, None] * z + P[..., i, 3, None]
                 for i in range(3))
