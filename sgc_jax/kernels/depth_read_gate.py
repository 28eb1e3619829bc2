"""The depth-read gate (docs/semantics.md §3.2 step 5b): a track whose depth read at frame i
disagrees with the depth the camera's pose gives its frame-(i-1) point leaves its region before
the pose search. Such a track's depth read at frame i-1 (or i) has most likely crossed a depth
edge, which moves its 3D point off its surface by more than any pixel error does."""

from __future__ import annotations

import jax.numpy as jnp

from .regions import region_onehot


def gate_depth_reads(point_region, X, Z_curr, R_g, t_g, gate, min_kept, k: int):
    """Regions (P,) int32 1..k (0: none) of a pair's tracks after the gate.

    ``X`` (P, 3) the tracks' frame-(i-1) points in camera i-1, ``Z_curr`` (P,) frame i's depth at
    their frame-i pixels, (``R_g``, ``t_g``) the camera's pose from i-1 to i in X's units. A track
    is kept where Z_curr > 0 and |z - Z_curr| <= ``gate`` Z_curr, z the depth of R_g X + t_g.
    ``gate`` 0 (or a pose that is not finite) keeps every track; a region the gate would leave
    with fewer than ``min_kept`` tracks keeps all of its own."""
    z = X @ R_g[2] + t_g[2]
    agrees = (Z_curr > 0) & (jnp.abs(z - Z_curr) <= gate * Z_curr)
    onehot = region_onehot(point_region, k, jnp.int32)  # (k, P)
    kept = jnp.sum(onehot * agrees[None, :], axis=1)  # (k,)
    region_too_thin = jnp.sum(onehot * (kept < min_kept)[:, None], axis=0) > 0  # (P,)
    applies = (gate > 0) & jnp.all(jnp.isfinite(R_g)) & jnp.all(jnp.isfinite(t_g))
    keep = ~applies | agrees | region_too_thin
    return jnp.where(keep, point_region, 0).astype(point_region.dtype)
