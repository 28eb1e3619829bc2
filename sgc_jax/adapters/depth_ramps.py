"""An opt-in step before scoring: the ramps of points on no surface that a depth network's enlarged
output puts at depth edges made invalid (docs/semantics.md §3.6, "Smooth depth edges"; the ramps
are :func:`sgc_jax.io.depth_edges.edges_and_ramps`)."""

from __future__ import annotations

import dataclasses

import numpy as np

from ..io.clip import Clip
from ..io.depth_edges import DEPTH_EDGE_RATIO, edges_and_ramps, valid_depth


def leave_out_depth_ramps(clip: Clip, ratio: float = DEPTH_EDGE_RATIO) -> Clip:
    """``clip`` with the depth on ramps (at an edge, whose 3 x 3 neighbourhood's valid depths span more
    than ``ratio``, and over 5 % from both its least and its greatest) set to 0, invalid; the share of
    the valid depth so left out in ``meta["depth_ramps"]``. Edges that are steps keep their depth."""
    if not (np.isfinite(ratio) and ratio > 1):
        raise ValueError(f"the depth edge ratio must be > 1 (largest / smallest depth of a 3 x 3 neighbourhood), "
                         f"got {ratio!r}")
    _, ramps = edges_and_ramps(clip.depth, ratio)
    share = int(ramps.sum()) / max(int(valid_depth(clip.depth).sum()), 1)
    record = {"ratio": float(ratio), "invalid_frac": round(share, 4)}
    depth = np.where(ramps, 0, clip.depth).astype(clip.depth.dtype)
    return dataclasses.replace(clip, depth=depth, meta={**clip.meta, "depth_ramps": record})
