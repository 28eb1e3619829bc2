"""The ``depth+spatial`` partition of docs/semantics.md §6.1 in JAX: depth clusters split into 4-connected
components, the largest ``k`` kept.

Rule (shared with ``sgc_jax.engines.reference.spatial_regions``): pixels of the same depth cluster that
touch horizontally or vertically form one component; components with fewer than
``min_region_pixels`` pixels are dropped; of the rest the ``k`` largest are kept and numbered
1..N_s by decreasing size, ties broken by the component's first pixel in raster order.
"""

from __future__ import annotations


import jax
import jax.numpy as jnp

_NONE = jnp.iinfo(jnp.int32).max


def _neighbour_min(label, cluster):
    """Each pixel's label lowered to the smallest label of its 4-neighbours in the same cluster."""
    def shifted(a, fill, dy, dx):
        pad = jnp.pad(a, ((1, 1), (1, 1)), constant_values=fill)
        H, W = a.shape
        return pad[1 + dy: 1 + dy + H, 1 + dx: 1 + dx + W]

    out = label
    for dy, dx in ((-1, 0), (1, 0), (0, -1), (0, 1)):  # four static shifts, not a loop over pixels
        same = shifted(cluster, -1, dy, dx) == cluster
        out = jnp.minimum(out, jnp.where(same & (cluster >= 0), shifted(label, _NONE, dy, dx), _NONE))
    return out


def connected_components(cluster):
    """(H, W) int32 cluster ids (-1 = none) -> (H, W) int32 component root: the raster index of
    the component's first pixel, ``_NONE`` outside every cluster. Min-label propagation with
    pointer jumping, iterated until nothing changes."""
    H, W = cluster.shape
    valid = cluster >= 0
    start = jnp.where(valid, jnp.arange(H * W, dtype=jnp.int32).reshape(H, W), _NONE)

    def step(state):
        label, _ = state
        new = _neighbour_min(label, cluster)
        flat = new.reshape(-1)
        jumped = jnp.where(valid, flat[jnp.minimum(new, H * W - 1)].reshape(H, W), _NONE)
        new = jnp.minimum(new, jumped)
        return new, jnp.any(new != label)

    label, _ = jax.lax.while_loop(lambda s: s[1], step, (start, jnp.bool_(True)))
    return label


def spatial_regions(cluster, *, k: int, min_region_pixels):
    """(H, W) int32 depth cluster ids (-1 = none) -> ((H, W) int32 region 1..N_s, 0 = none; N_s)."""
    H, W = cluster.shape
    root = connected_components(cluster).reshape(-1)
    valid = root != _NONE
    sizes = jax.ops.segment_sum(valid.astype(jnp.int32), jnp.where(valid, root, 0), num_segments=H * W)
    eligible = jnp.where(sizes >= jnp.maximum(min_region_pixels, 1), sizes, 0).astype(jnp.float32)
    top_size, top_root = jax.lax.top_k(eligible, k)  # equal sizes: lower raster index first
    kept = top_size > 0
    new_id = jnp.zeros(H * W, jnp.int32).at[top_root].set(jnp.where(kept, jnp.arange(1, k + 1), 0))
    region = jnp.where(valid, new_id[jnp.where(valid, root, 0)], 0)
    return region.reshape(H, W).astype(jnp.int32), jnp.sum(kept).astype(jnp.int32)
