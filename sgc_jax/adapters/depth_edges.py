"""An opt-in step before scoring: the depth at edges made invalid, where a depth network's enlarged
output puts ramps of points that lie on no surface (docs/semantics.md §3.6, "Smooth depth edges";
the edges are :func:`sgc_jax.io.depth_edges.depth_edges`)."""

from __future__ import annotations

import dataclasses

import numpy as np

from ..io.clip import Clip
from ..io.depth_edges import DEPTH_EDGE_RATIO, depth_edges, valid_depth


def leave_out_depth_edges(clip: Clip, ratio: float = DEPTH_EDGE_RATIO) -> Clip:
    """``clip`` with the depth at edges (a 3 x 3 neighbourhood whose valid depths span more than
    ``ratio``) set to 0, invalid; the share of the valid depth so left out in ``meta["depth_edges"]``."""
    if not (np.isfinite(ratio) and ratio > 1):
        raise ValueError(f"the depth edge ratio must be > 1 (largest / smallest depth of a 3 x 3 neighbourhood), "
                         f"got {ratio!r}")
    edges = depth_edges(clip.depth, ratio)
    share = int(edges.sum()) / max(int(valid_depth(clip.depth).sum()), 1)
    record = {"ratio": float(ratio), "invalid_frac": round(share, 4)}
    depth = np.where(edges, 0, clip.depth).astype(clip.depth.dtype)
    return dataclasses.replace(clip, depth=depth, meta={**clip.meta, "depth_edges": record})
