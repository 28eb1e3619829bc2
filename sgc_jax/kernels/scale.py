"""The per-clip translation scale s of docs/semantics.md §3.4: each pair's equations, and their
weighted median over the equations near the best of a few starts (an L1 fit with the far equations
cut, so neither outlier tracks nor near ones with large weights drag it)."""

from __future__ import annotations

import jax
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
    return weighted_medians(values.reshape(-1), weights.reshape(-1), fallback)


def weighted_medians(values, weights, fallback):
    """``weighted_median`` along the last axis of values and weights (broadcast against each other),
    all in one bisection: (..., N) -> (...)."""
    # bisection over the values' order-keeping uint32 keys: 32 masked sums, a tenth of a sort's cost on CPU
    keys = ordered_keys(values)
    total = jnp.sum(weights, axis=-1)
    key = smallest_reaching(
        lambda mid: jnp.sum(jnp.where(keys <= mid[..., None], weights, 0.0), axis=-1) >= 0.5 * total,
        jnp.zeros(total.shape, jnp.uint32), jnp.full(total.shape, 0xFFFFFFFF, jnp.uint32), 32)
    return jnp.where(total > 0, value_of_key(key), fallback)


def truncated_cost(scale, ratios, weights, cut_px):
    """Sum over the used equations of min(w |s - r|, cut_px): each one's linearised reprojection
    residual in pixels, cut where a RANSAC inlier would end."""
    return jnp.sum(jnp.where(weights > 0, jnp.minimum(weights * jnp.abs(scale - ratios), cut_px), 0.0))


def robust_scale(ratios, weights, cut_px, fallback):
    """s from every pair's equations (T-1, P, 2) (``scale_equations``): the start of lowest
    truncated cost among the weighted and the plain median (each equation counted once) of every
    pair's equations together and of each pair's own (the first of equal ones), then the weighted
    median of the equations whose residual there is below ``cut_px``, or 0 where that is negative
    (a camera translation that runs against the tracks is no rescaling of it); ``fallback`` when
    no equation has a weight. The plain medians are starts where a few near tracks hold most of
    the weight in every pair."""
    by_pair, pair_weights = ratios.reshape(ratios.shape[0], -1), weights.reshape(weights.shape[0], -1)
    weight_sets = jnp.stack([pair_weights, (pair_weights > 0).astype(weights.dtype)])  # (2, T-1, 2P): weighted, plain
    overall = weighted_medians(by_pair.reshape(-1), weight_sets.reshape(2, -1), fallback)  # (2,)
    per_pair = weighted_medians(by_pair, weight_sets, overall[0])  # (2, T-1)
    starts = jnp.concatenate([overall, per_pair.reshape(-1)])
    costs = jax.vmap(truncated_cost, in_axes=(0, None, None, None))(starts, ratios, weights, cut_px)
    start = starts[jnp.argmin(costs)]
    near = weights * jnp.abs(start - ratios) < cut_px
    return jnp.maximum(weighted_median(ratios, jnp.where(near, weights, 0.0), start), 0.0)
