"""An opt-in step before scoring: the ramps of points on no surface that a depth network's enlarged
output puts at depth edges made invalid (docs/semantics.md §3.6, "Smooth depth edges"; the ramps
are :func:`sgc_jax.io.depth_edges.edges_and_ramps`)."""

from __future__ import annotations

import dataclasses

from ..io.clip import Clip
from ..io.depth_edges import DEPTH_EDGE_RATIO, without_ramps


def leave_out_depth_ramps(clip: Clip, ratio: float = DEPTH_EDGE_RATIO) -> Clip:
    """``clip`` with the depth on ramps (at an edge, whose 3 x 3 neighbourhood's valid depths span more
    than ``ratio``, and over 5 % from both its least and its greatest) set to 0, invalid; the share of
    the valid depth so left out in ``meta["depth_ramps"]``. Edges that are steps keep their depth."""
    depth, share = without_ramps(clip.depth, ratio)
    record = {"ratio": float(ratio), "invalid_frac": round(share, 4)}
    return dataclasses.replace(clip, depth=depth, meta={**clip.meta, "depth_ramps": record})
