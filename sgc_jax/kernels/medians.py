"""The median of the entries a mask selects, at a fixed shape."""

from __future__ import annotations

import jax.numpy as jnp


def masked_median(values, mask):
    """Median of the (n,) ``values`` where ``mask`` (n,) bool (the mean of the two middle ones for an
    even count); NaN where none is selected. One sort of all n."""
    count = jnp.sum(mask)
    ranked = jnp.sort(jnp.where(mask, values, jnp.inf))
    middle = 0.5 * (ranked[jnp.maximum(count - 1, 0) // 2] + ranked[count // 2])
    return jnp.where(count > 0, middle, jnp.nan)
