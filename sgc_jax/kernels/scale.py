"""The per-clip translation scale s of docs/semantics.md §3.4: each pair's equations, and their
weighted median over the clip (an L1 fit, so outlier tracks do not drag it)."""

from __future__ import annotations

import jax.numpy as jnp

from .bisection import ordered_keys, smallest_reaching, value_of_key
from .camera import back_project


def scale_equations(X, use, K_curr, track_curr, R_g, t_g):
    """One pair's equations a_k s = b_k for the scale: a point X (P, 3) of camera i-1 (``use`` (P,))
    seen at normalised n in frame i gives, per image axis k, a_k = n_k t_3 - t_k and b_k = Y_k -
    n_k Y_3 (Y = R_g X) -> (ratios b / a, weights |a| f_k / Y_3), each (P, 2): the weight is the
    reprojection change in pixels per unit of s, 0 for an unused point."""
    Y = X @ R_g.T
    n = back_project(K_curr, track_curr, jnp.ones_like(track_curr[:, 0]))  # (P, 3), n_3 = 1
    a = n[:, :2] * t_g[2] - t_g[:2]
    b = Y[:, :2] - n[:, :2] * Y[:, 2:3]
    focal = jnp.stack([K_curr[0, 0], K_curr[1, 1]])
    ok = use[:, None] & (Y[:, 2:3] > 0) & (a != 0)
    weight = jnp.where(ok, jnp.abs(a) * focal / jnp.where(ok, Y[:, 2:3], 1.0), 0.0)
    return jnp.where(ok, b / jnp.where(ok, a, 1.0), 0.0), weight


def weighted_median(values, weights, fallback):
    """The smallest value whose cumulative weight reaches half the total (any shape, flattened;
    weight 0: unused); ``fallback`` when the total is 0."""
    # bisection over the values' order-keeping uint32 keys: 32 masked sums, a tenth of a sort's cost on CPU
    keys, weights = ordered_keys(values.reshape(-1)), weights.reshape(-1)
    total = jnp.sum(weights)
    key = smallest_reaching(lambda mid: jnp.sum(jnp.where(keys <= mid, weights, 0.0)) >= 0.5 * total,
                            jnp.uint32(0), jnp.uint32(0xFFFFFFFF), 32)
    return jnp.where(total > 0, value_of_key(key), fallback)
