"""Depth partitions of SPEC §3 step 2: exact 1-D k-means on a histogram, and the grid ablation.

``kmeans_1d`` is an exact dynamic programme over ``bins`` equal-width histogram bins: clusters
are unions of whole bins, and among those partitions the within-cluster sum of squares is
minimal (exact k-means whenever distinct values fall in distinct bins). Deterministic; ties go
to the smallest first bin of the last cluster (``jnp.argmin`` semantics).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
from jax import lax


def _normalise(values, valid):
    """(N,) values, (N,) valid -> (u in [0, 1], bin-ready mask, has_span); u = (v - lo) / span."""
    v = values.astype(jnp.float32)
    valid = valid & jnp.isfinite(v)
    lo = jnp.min(jnp.where(valid, v, jnp.inf))
    hi = jnp.max(jnp.where(valid, v, -jnp.inf))
    span = hi - lo
    has_span = span > 0  # False with no valid value (-inf) and with a single distinct value
    lo_safe = jnp.where(has_span, lo, 0.0)
    span_safe = jnp.where(has_span, span, 1.0)
    u = (jnp.where(valid, v, lo_safe) - lo_safe) / span_safe
    return u, valid, has_span


def _cost_matrix(u, bin_of, valid, bins):
    """Cost C[a, b] (bins + 1, bins): SSE of bins a..b (a <= b), 0 if a == b + 1, +inf if a > b + 1.

    Sums are taken about the centre of bin a rather than 0, so the Q - S^2/N cancellation only
    costs relative float32 precision of the cluster's own spread (not of its absolute position).
    """
    w = valid.astype(jnp.float32)
    centre = (bin_of.astype(jnp.float32) + 0.5) / bins
    d = jnp.where(valid, u - centre, 0.0)  # offset from the bin centre, |d| <= 0.5 / bins
    n_b = jax.ops.segment_sum(w, bin_of, num_segments=bins)
    s_b = jax.ops.segment_sum(d, bin_of, num_segments=bins)
    q_b = jax.ops.segment_sum(d * d, bin_of, num_segments=bins)
    a = jnp.arange(bins + 1)[:, None]
    b = jnp.arange(bins)[None, :]
    upper = b >= a
    off = (b - a).astype(jnp.float32) / bins  # centre of bin b minus centre of bin a
    n_ab = jnp.cumsum(jnp.where(upper, n_b, 0.0), axis=1)
    s_ab = jnp.cumsum(jnp.where(upper, s_b + n_b * off, 0.0), axis=1)
    q_ab = jnp.cumsum(jnp.where(upper, q_b + 2.0 * off * s_b + n_b * off * off, 0.0), axis=1)
    sse = jnp.maximum(q_ab - s_ab * s_ab / jnp.maximum(n_ab, 1.0), 0.0)
    return jnp.where(upper, sse, jnp.where(a == b + 1, 0.0, jnp.inf))


@functools.partial(jax.jit, static_argnames=("k", "bins"))
def kmeans_1d(values, valid, *, k: int, bins: int):
    """(N,) float values, (N,) bool valid -> (N,) int32 cluster 0..k-1 by increasing value, -1 invalid."""
    u, valid, has_span = _normalise(values, valid)
    bin_of = jnp.clip(jnp.floor(u * bins), 0, bins - 1).astype(jnp.int32)
    cost = _cost_matrix(u, bin_of, valid, bins)

    def forward(prev, _):
        # prev[a] = D_{j-1}(a - 1) for a = 0..bins, with D(-1) = 0.
        total = prev[:, None] + cost
        first = jnp.argmin(total, axis=0).astype(jnp.int32)
        best = jnp.min(total, axis=0)
        return jnp.concatenate([jnp.zeros(1, jnp.float32), best]), first

    prev0 = jnp.concatenate([jnp.zeros(1, jnp.float32), jnp.full(bins, jnp.inf, jnp.float32)])
    _, first_bin = lax.scan(forward, prev0, None, length=k)  # (k, bins): A_j(b) at row j - 1

    bin_ids = jnp.arange(bins, dtype=jnp.int32)

    def backward(carry, j):
        last, cluster_of_bin = carry
        first = jnp.where(last >= 0, first_bin[j, jnp.maximum(last, 0)], last + 1)
        cluster_of_bin = jnp.where((bin_ids >= first) & (bin_ids <= last), j, cluster_of_bin)
        return (first - 1, cluster_of_bin), None

    init = (jnp.int32(bins - 1), jnp.zeros(bins, jnp.int32))
    (_, cluster_of_bin), _ = lax.scan(backward, init, jnp.arange(k - 1, -1, -1, dtype=jnp.int32))
    labels = jnp.where(has_span, cluster_of_bin[bin_of], 0)
    return jnp.where(valid, labels, -1).astype(jnp.int32)


def cluster_counts(labels, *, k: int):
    """(N,) int labels (-1 = none) -> (k,) int32 number of entries per cluster 0..k-1."""
    return jax.ops.segment_sum(
        (labels >= 0).astype(jnp.int32), jnp.where(labels >= 0, labels, k), num_segments=k + 1
    )[:k]


def _renumber_kept(cluster, counts, min_region_pixels):
    """Drop clusters with < min_region_pixels (or 0) entries; kept ones -> 1..N_s in index order."""
    kept = (counts >= min_region_pixels) & (counts > 0)
    new_id = jnp.where(kept, jnp.cumsum(kept.astype(jnp.int32)), 0)
    region = jnp.where(cluster >= 0, new_id[jnp.maximum(cluster, 0)], 0)
    return region.astype(jnp.int32), jnp.sum(kept).astype(jnp.int32)


@functools.partial(jax.jit, static_argnames=("k", "bins"))
def depth_regions(depth, region_mask, *, k: int, bins: int, min_region_pixels):
    """(H, W) depth, (H, W) bool mask -> ((H, W) int32 region 1..N_s by increasing depth, 0 = none; N_s)."""
    cluster = kmeans_1d(depth.reshape(-1), region_mask.reshape(-1), k=k, bins=bins)
    region, n_regions = _renumber_kept(cluster, cluster_counts(cluster, k=k), min_region_pixels)
    return region.reshape(depth.shape), n_regions


def grid_shape(k: int) -> tuple[tuple[int, int], ...]:
    """All (rows, cols) with rows * cols = k, by increasing rows (the tie-break order of grid_regions)."""
    return tuple((r, k // r) for r in range(1, k + 1) if k % r == 0)


@functools.partial(jax.jit, static_argnames=("k",))
def grid_regions(region_mask, *, k: int, min_region_pixels):
    """(H, W) bool mask -> ((H, W) int32 grid cell 1..N_s in row-major cell order, 0 = none; N_s).

    The grid covers the bounding box (h x w pixels) of the mask with rows x cols = k cells, the
    factorisation minimising max(cols*h, rows*w) / min(cols*h, rows*w) (cells closest to square;
    ties -> fewer rows). Pixel (y, x) is in cell row (y - y0) * rows // h, column (x - x0) * cols // w.
    """
    H, W = region_mask.shape
    any_row = jnp.any(region_mask, axis=1)
    any_col = jnp.any(region_mask, axis=0)
    y0 = jnp.argmax(any_row).astype(jnp.int32)
    x0 = jnp.argmax(any_col).astype(jnp.int32)
    h = jnp.maximum(H - jnp.argmax(any_row[::-1]).astype(jnp.int32) - y0, 1)
    w = jnp.maximum(W - jnp.argmax(any_col[::-1]).astype(jnp.int32) - x0, 1)
    shapes = jnp.array(grid_shape(k), jnp.int32)  # (n_shapes, 2)
    cols_h = (shapes[:, 1] * h).astype(jnp.float32)
    rows_w = (shapes[:, 0] * w).astype(jnp.float32)
    choice = jnp.argmin(jnp.maximum(cols_h, rows_w) / jnp.minimum(cols_h, rows_w))
    rows, cols = shapes[choice, 0], shapes[choice, 1]
    y = jnp.arange(H, dtype=jnp.int32)[:, None]
    x = jnp.arange(W, dtype=jnp.int32)[None, :]
    cell_row = jnp.clip((y - y0) * rows // h, 0, rows - 1)
    cell_col = jnp.clip((x - x0) * cols // w, 0, cols - 1)
    cell = jnp.where(region_mask, cell_row * cols + cell_col, -1).reshape(-1)
    region, n_regions = _renumber_kept(cell, cluster_counts(cell, k=k), min_region_pixels)
    return region.reshape(H, W), n_regions
