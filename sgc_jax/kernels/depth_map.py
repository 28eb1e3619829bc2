"""A pair's depth map (docs/semantics.md §3.6 step 7): frame i−1's depth read as α ẑ + β against
frame i's, on a sub-grid of the compared pixels: the scale alone (α the median ratio, β = 0), or the
affine map of least absolute relative error where it fits far better. A depth estimator aligned frame
by frame leaves each frame its own scale and shift; the inconsistencies of §6.4 move depth across the
image, and a part of the world moved in depth moves only its own pixels, which no such map undoes."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ..config import (
    DEPTH_MAP_DAMPING,
    DEPTH_MAP_GATE,
    DEPTH_MAP_STEPS,
    DEPTH_MAP_WEIGHT_FLOOR,
    DEPTH_SCALE_MIN_PIXELS,
    DEPTH_SCALE_STRIDE,
)
from .medians import masked_median


def weighted_fit(z, d, weight):
    """(α, β) minimising Σ w (α z + β − d)² / d² + λ β² Σ w / d² over (n,) warped depths z, frame i's d
    and weights w (``weight``), λ = DEPTH_MAP_DAMPING: the weighted regression of d on z, centred
    (float32 keeps its digits where the depths vary little), β shrunk so that depths that do not
    vary give the scale alone, d̄ / z̄."""
    u = weight / (d * d)
    total = jnp.maximum(jnp.sum(u), jnp.finfo(z.dtype).tiny)
    z_mean, d_mean = jnp.sum(u * z) / total, jnp.sum(u * d) / total
    dz, dd = z - z_mean, d - d_mean
    var, cov = jnp.sum(u * dz * dz) / total, jnp.sum(u * dz * dd) / total
    kappa = DEPTH_MAP_DAMPING / (1.0 + DEPTH_MAP_DAMPING)
    alpha = (cov + kappa * z_mean * d_mean) / (var + kappa * z_mean * z_mean)
    return jnp.stack([alpha, (d_mean - alpha * z_mean) / (1.0 + DEPTH_MAP_DAMPING)])


def pair_depth_map(warped, depth_curr, both, median=masked_median):
    """(α, β) float32 of the pair (docs/semantics.md §3.6 step 7) on the ``both`` (H, W) pixels of every
    DEPTH_SCALE_STRIDE-th row and column, warped depth ẑ and frame i's d (H, W): the affine map of least
    Σ |α ẑ + β − d| / d where its median relative error there is below DEPTH_MAP_GATE times the scale's,
    else the scale (median d / ẑ, 0); (1, 0) with fewer than DEPTH_SCALE_MIN_PIXELS. The affine map:
    iteratively reweighted least squares, DEPTH_MAP_STEPS steps from the scale, then one more whose
    weights are held. ``median(values, mask)``: one whose gradient reaches the middle values, for
    ``sgc_smooth``, which differentiates through the chosen map (the choice held)."""
    s = DEPTH_SCALE_STRIDE
    sub = both[::s, ::s].reshape(-1)
    z = jnp.where(sub, warped[::s, ::s].reshape(-1), 1.0)
    d = jnp.where(sub, depth_curr[::s, ::s].reshape(-1), 1.0)
    held_z, held_d = jax.lax.stop_gradient(z), jax.lax.stop_gradient(d)

    def relative_errors(coef):
        return jnp.abs((coef[0] * held_z + coef[1] - held_d) / held_d)

    def weights(coef):
        return jnp.where(sub, 1.0 / jnp.maximum(relative_errors(coef), DEPTH_MAP_WEIGHT_FLOOR), 0.0)

    scale = jnp.stack([median(d / z, sub), jnp.zeros((), z.dtype)])
    coef = jax.lax.fori_loop(0, DEPTH_MAP_STEPS, lambda _, c: weighted_fit(held_z, held_d, weights(c)),
                             jax.lax.stop_gradient(scale))
    affine = weighted_fit(z, d, weights(coef))
    held_affine, held_scale = jax.lax.stop_gradient(affine), jax.lax.stop_gradient(scale)
    fits_better = (masked_median(relative_errors(held_affine), sub)
                   < DEPTH_MAP_GATE * masked_median(relative_errors(held_scale), sub))
    chosen = jnp.where(fits_better, affine, scale)
    return jnp.where(jnp.sum(sub) >= DEPTH_SCALE_MIN_PIXELS, chosen, jnp.array([1.0, 0.0], z.dtype))
