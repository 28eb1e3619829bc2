"""Depth partitions (docs/semantics.md §3.2 step 2, §6.1): exact 1-D k-means on a histogram, and
the grid ablation.

``kmeans_1d`` is an exact dynamic programme over ``bins`` equal-width histogram bins: clusters
are unions of whole bins, and among those partitions the within-cluster sum of squares is
minimal (exact k-means whenever distinct values fall in distinct bins). Deterministic; ties go
to the smallest first bin of the last cluster (``jnp.argmin`` semantics). Each of the k DP layers
is a row-minima search that divide and conquer solves in O(bins log bins) cost evaluations (the
SSE cost is Monge), with costs from double-float prefix sums: same partition as the dense
O(bins^2) layer in float64 (``reference.kmeans_1d``), up to float rounding at exact ties.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from .fence import materialise


def _normalise(values, valid):
    """(N,) values, (N,) valid -> (u in [0, 1], bin-ready mask, has_span, (lo, span));
    u = (v - lo) / span (lo = 0, span = 1 when the values span no range)."""
    v = values.astype(jnp.float32)
    valid = valid & jnp.isfinite(v)
    lo = jnp.min(jnp.where(valid, v, jnp.inf))
    hi = jnp.max(jnp.where(valid, v, -jnp.inf))
    span = hi - lo
    has_span = span > 0  # False with no valid value (-inf) and with a single distinct value
    scale = (jnp.where(has_span, lo, 0.0), jnp.where(has_span, span, 1.0))
    u, valid = _unit_values(values, valid, scale)
    return u, valid, has_span, scale


def _unit_values(values, valid, scale):
    """Values mapped to [0, 1] with a frame's (lo, span), and the mask of finite valid ones."""
    v = values.astype(jnp.float32)
    valid = valid & jnp.isfinite(v)
    lo, span = scale
    return (jnp.where(valid, v, lo) - lo) / span, valid


def _bin_of(u, bins):
    return jnp.clip(jnp.floor(u * bins), 0, bins - 1).astype(jnp.int32)


# The DP's cluster cost (within-cluster SSE of bins a..b) comes from prefix sums over bins held
# as float32 pairs (hi, lo): "double-float" arithmetic with error-free transformations (Dekker,
# Knuth) carries ~44 significant bits, so Q - S^2/n keeps the spread of a tight cluster far from
# the origin, where plain float32 prefix sums would cancel it away. Positions are in bin units
# about the histogram's middle.


def _two_sum(a, b):
    """a + b = s + e exactly (Knuth)."""
    s = a + b
    v = s - a
    return s, (a - (s - v)) + (b - v)


def _split(a):
    """a = hi + lo exactly, each with at most 12 significant bits. Masking the low mantissa bits,
    unlike Veltkamp's 4097 * a trick, is immune to the compiler forming multiply-adds (FMA)."""
    hi = jax.lax.bitcast_convert_type(
        jax.lax.bitcast_convert_type(a, jnp.int32) & jnp.int32(-4096), jnp.float32)
    return hi, a - hi


def _two_prod(a, b):
    """a * b as a double-float (p, e), to ~2^-48 relative. Built only from the exact products of
    12-bit halves: the usual e = fma-like(a * b - p) form breaks when the compiler recomputes
    p = a * b inside an FMA, which XLA CPU does."""
    a_hi, a_lo = _split(a)
    b_hi, b_lo = _split(b)
    cross, cross_err = _two_sum(a_hi * b_lo, a_lo * b_hi)
    p, e = _two_sum(a_hi * b_hi, cross)
    return _quick_two_sum(p, e + cross_err + a_lo * b_lo)


def _quick_two_sum(s, e):
    t = s + e
    return t, e - (t - s)


def _df_add(x, y):
    s, e = _two_sum(x[0], y[0])
    return _quick_two_sum(s, e + x[1] + y[1])


def _df_sub(x, y):
    return _df_add(x, (-y[0], -y[1]))


def _df_mul(x, y):
    p, e = _two_prod(x[0], y[0])
    return _quick_two_sum(p, e + x[0] * y[1] + x[1] * y[0])


def _df_div(x, n):
    """Double-float x divided by a float32 n > 0."""
    q = x[0] / n
    p, e = _two_prod(q, n)
    return _quick_two_sum(q, ((x[0] - p) - e + x[1]) / n)


def _prefix_sums(y, bin_of, valid, bins):
    """Prefix sums over bins 0..c-1, c = 0..bins: counts (bins + 1,) int32, and double-float
    sums of positions and squared positions ((bins + 1,) hi, (bins + 1,) lo) each.

    y (N,) positions in bin units [0, bins]; each bin's sums are split into an exact part at the
    bin centre and float32 sums of the offsets d (|d| <= 0.5) from it.
    """
    d = jnp.where(valid, y - (bin_of.astype(jnp.float32) + 0.5), 0.0)
    # Three 1-D segment sums: faster on CPU than one over stacked (N, 3) rows.
    n_c, d_c, e_c = (jax.ops.segment_sum(x, bin_of, num_segments=bins) for x in (valid.astype(jnp.float32), d, d * d))
    centre = jnp.arange(bins, dtype=jnp.float32) + (0.5 - 0.5 * bins)
    zero = jnp.zeros(bins, jnp.float32)
    s_c = _df_add(_two_prod(n_c, centre), (d_c, zero))  # sum of (centre + d)
    q_c = _df_add(_df_add(_two_prod(n_c, centre * centre), _two_prod(2.0 * centre, d_c)), (e_c, zero))

    def prefix(x):
        hi, lo = jax.lax.associative_scan(_df_add, x)
        return jnp.concatenate([jnp.zeros(1, jnp.float32), hi]), jnp.concatenate([jnp.zeros(1, jnp.float32), lo])

    n_bin = jnp.round(n_c).astype(jnp.int32)
    return (jnp.concatenate([jnp.zeros(1, jnp.int32), jnp.cumsum(n_bin)]), prefix(s_c), prefix(q_c)), n_bin


def _range_cost(first, last):
    """SSE of the values in bins first..last - 1 (first <= last) from the prefix entries
    (count, s, q) at the boundaries ``first`` and ``last`` (tuples of arrays); 0 when empty."""
    n = (last[0] - first[0]).astype(jnp.float32)
    s_ab = _df_sub(last[1], first[1])
    q_ab = _df_sub(last[2], first[2])
    sse = _df_sub(q_ab, _df_div(_df_mul(s_ab, s_ab), jnp.maximum(n, 1.0)))
    return jnp.where(n > 0, jnp.maximum(sse[0] + sse[1], 0.0), 0.0)


def _search_plan(bins: int) -> tuple[np.ndarray, ...]:
    """Static plan of the divide-and-conquer row-minima search over the DP's columns 0..bins-1,
    padded so that every level has the same width M (a loop traces one level).

    Per level (arrays (levels, M)): the columns solved there (ascending; ``bins`` pads); for each,
    the already solved columns whose optima bound its search from below / above (-1: none); and
    (levels, M, 2) the indices of its left / right child in the next level (-1: none). Optimal
    first bins are nondecreasing in the last bin (the SSE cost is Monge), so a column's search
    lies between its neighbours' optima.
    """
    levels, frontier = [], [(0, bins - 1, -1, -1)]
    while frontier:
        mids, lefts, rights, children, nxt = [], [], [], [], []
        for lo, hi, left, right in frontier:
            m = (lo + hi) // 2
            mids.append(m), lefts.append(left), rights.append(right)
            kids = [-1, -1]
            if lo <= m - 1:
                kids[0] = len(nxt)
                nxt.append((lo, m - 1, left, m))
            if m + 1 <= hi:
                kids[1] = len(nxt)
                nxt.append((m + 1, hi, m, right))
            children.append(kids)
        levels.append((mids, lefts, rights, children))
        frontier = nxt
    width = max(len(level[0]) for level in levels)
    pad = lambda rows, fill: np.array([r + [fill] * (width - len(r)) for r in rows], np.int32)  # noqa: E731
    return (pad([level[0] for level in levels], bins), pad([level[1] for level in levels], -1),
            pad([level[2] for level in levels], -1), pad([level[3] for level in levels], [-1, -1]))


def _segment_min_nonnegative(values, segment, num_segments):
    """``jax.ops.segment_min`` of float32 values >= 0 (or +inf; -0.0 counts as 0; no subnormals,
    which XLA CPU's float min flushes to 0), as a minimum of their bit patterns, which order as
    the values do: batched over the frames, XLA CPU's integer scatter-min is several times
    faster than its float one."""
    bits = jax.lax.bitcast_convert_type(values, jnp.int32) & jnp.int32(0x7FFFFFFF)  # -0.0 -> 0.0
    low = jax.ops.segment_min(bits, segment, num_segments=num_segments)
    # an empty segment's int32 maximum reads back as a NaN: +inf, as segment_min of floats gives
    return jnp.where(low == jnp.iinfo(jnp.int32).max, jnp.inf, jax.lax.bitcast_convert_type(low, jnp.float32))


def _dp_step(prev, sums, plan, bins):
    """One k-means DP layer: for every last bin b, min over a of prev[a] + cost(a, b).

    prev (bins + 1,) = D_{j-1}(a - 1) for a = 0..bins; cost(a, b) = SSE of bins a..b, 0 when
    a == b + 1 (empty cluster), +inf when a > b + 1. -> (best (bins,), first (bins,) int32), ties
    to the smallest a. Divide and conquer over b: a level solves its columns over the rows of
    their search ranges, which tile the rows (neighbours share at most an end point, evaluated
    separately), so every level costs O(bins + M) and the step O((bins + M) log bins), not bins^2.
    """
    rows = jnp.arange(bins + 1, dtype=jnp.int32)
    take = lambda idx: jax.tree.map(lambda x: x[idx], sums)  # noqa: E731  prefix entries at idx
    width = plan[0].shape[1]

    def level(carry, columns):
        first, best, seg = carry
        mids, lefts, rights, children = columns
        lo = jnp.where(lefts >= 0, first[jnp.maximum(lefts, 0)], 0)
        hi = jnp.minimum(jnp.where(rights >= 0, first[jnp.maximum(rights, 0)], bins), mids + 1)
        last = take(jnp.minimum(mids + 1, bins))  # prefix entries after each column's last bin
        seg_c = jnp.maximum(seg, 0)
        inside = (seg >= 0) & (rows >= lo[seg_c]) & (rows <= hi[seg_c])
        tot = jnp.where(inside, prev + _range_cost(sums, jax.tree.map(lambda x: x[seg_c], last)), jnp.inf)
        seg_id = jnp.where(inside, seg_c, width)
        # A range's last row may lie in the next range too (which then owns it): evaluate it here.
        end = prev[hi] + _range_cost(take(hi), last)
        low = jnp.minimum(_segment_min_nonnegative(tot, seg_id, width + 1)[:width], end)
        arg = jax.ops.segment_min(jnp.where(tot == low[seg_c], rows, bins + 1), seg_id, num_segments=width + 1)[:width]
        arg = jnp.minimum(jnp.minimum(arg, jnp.where(end == low, hi, bins + 1)), hi).astype(jnp.int32)
        # per column, then gathered per row below: fused there, XLA would redo the columns' costs per row
        arg, low = materialise((arg, low))
        first = first.at[mids].set(arg, mode="drop")  # padding columns (mids = bins) write nothing
        best = best.at[mids].set(low, mode="drop")
        # Rows before a column's optimum are searched for its left child, the others for its right.
        kids = children[seg_c]
        seg = jnp.where(seg >= 0, jnp.where(rows < arg[seg_c], kids[:, 0], kids[:, 1]), -1)
        return (first, best, seg), None

    # seg: index of the column whose range a row lies in (-1: none)
    init = (jnp.zeros(bins, jnp.int32), jnp.zeros(bins, jnp.float32), jnp.zeros(bins + 1, jnp.int32))
    (first, best, _), _ = lax.scan(level, init, tuple(jnp.asarray(a) for a in plan))
    return best, first


def kmeans_1d(values, valid, *, k: int, bins: int):
    """(N,) float values, (N,) bool valid -> (N,) int32 cluster 0..k-1 by increasing value, -1 invalid."""
    bin_of, valid, cluster_of_bin, _ = _kmeans_bins(values, valid, k, bins)
    return jnp.where(valid, cluster_of_bin[bin_of], -1).astype(jnp.int32)


def _kmeans_bins(values, valid, k, bins):
    """The DP of ``kmeans_1d`` -> (bin (N,), valid (N,), cluster of each bin (bins,), valid entries
    per bin (bins,) int32); every bin is in cluster 0 when the values span no range."""
    u, valid, has_span, _ = _normalise(values, valid)
    bin_of = _bin_of(u, bins)
    sums, n_bin = _prefix_sums(u * bins, bin_of, valid, bins)
    return bin_of, valid, _cluster_of_bins(sums, has_span, k, bins), n_bin


def _cluster_of_bins(sums, has_span, k, bins):
    """The k-layer DP over prefix sums, then the backtrack -> cluster 0..k-1 of each bin (bins,)."""
    plan = _search_plan(bins)

    def forward(prev, _):
        # prev[a] = D_{j-1}(a - 1) for a = 0..bins, with D(-1) = 0.
        best, first = _dp_step(prev, sums, plan, bins)
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
    return jnp.where(has_span, cluster_of_bin, 0)


def cluster_counts(labels, *, k: int):
    """(N,) int labels (-1 = none) -> (k,) int32 number of entries per cluster 0..k-1."""
    return jax.ops.segment_sum(
        (labels >= 0).astype(jnp.int32), jnp.where(labels >= 0, labels, k), num_segments=k + 1
    )[:k]


def _renumber_kept(cluster, counts, min_region_pixels):
    """Drop clusters with < min_region_pixels (or 0) entries; kept ones -> 1..N_s in index order.
    cluster (..., N), counts (..., k): leading axes are frames."""
    kept = (counts >= min_region_pixels) & (counts > 0)
    new_id = jnp.where(kept, jnp.cumsum(kept.astype(jnp.int32), axis=-1), 0)
    region = jnp.where(cluster >= 0, jnp.take_along_axis(new_id, jnp.maximum(cluster, 0), axis=-1), 0)
    return region.astype(jnp.int32), jnp.sum(kept, axis=-1).astype(jnp.int32)


def depth_regions(depth, region_mask, *, k: int, bins: int, min_region_pixels):
    """(H, W) depth, (H, W) bool mask -> ((H, W) int32 region 1..N_s by increasing depth, 0 = none; N_s)."""
    partition = depth_partition(depth[None], region_mask[None], k=k, bins=bins, min_region_pixels=min_region_pixels)
    frame = jax.tree.map(lambda x: x[0], partition)
    return region_of_depth(frame, depth, region_mask), frame.n_regions


class DepthPartition(NamedTuple):
    """Depth regions of frames (leading axis F): region 1..N_s of each histogram bin, 0 = none."""

    lo: jax.Array  # (F,) depth at the histogram's start
    span: jax.Array  # (F,) depth range the bins cover
    region_of_bin: jax.Array  # (F, bins) int32
    n_regions: jax.Array  # (F,) int32


def depth_partition(depth, region_mask, *, k: int, bins: int, min_region_pixels):
    """docs/semantics.md §3.2 step 2 for frames (F, H, W) -> DepthPartition; ``region_of_depth``
    labels pixels.

    Histograms frame by frame (``lax.map``: unbatched scatters are several times faster on CPU);
    the DP, whose many small steps gain from batching, vmapped over the frames.
    """
    F = depth.shape[0]

    def histogram(frame):
        u, valid, has_span, (lo, span) = _normalise(*frame)
        sums, n_bin = _prefix_sums(u * bins, _bin_of(u, bins), valid, bins)
        return sums, n_bin, has_span, lo, span

    sums, n_bin, has_span, lo, span = lax.map(histogram, (depth.reshape(F, -1), region_mask.reshape(F, -1)))
    cluster_of_bin = jax.vmap(lambda s, h: _cluster_of_bins(s, h, k, bins))(sums, has_span)
    counts = jax.vmap(lambda n, c: jax.ops.segment_sum(n, c, num_segments=k))(n_bin, cluster_of_bin)
    region_of_bin, n_regions = _renumber_kept(cluster_of_bin, counts, min_region_pixels)
    return DepthPartition(lo, span, region_of_bin, n_regions)


def region_of_depth(partition: DepthPartition, depth, region_mask):
    """Region (...) int32 of depths (...) in one frame's partition (no leading F axis); 0 where
    ``region_mask`` is False or the depth is not finite."""
    u, valid = _unit_values(depth, region_mask, (partition.lo, partition.span))
    bins = partition.region_of_bin.shape[-1]
    return jnp.where(valid, partition.region_of_bin[_bin_of(u, bins)], 0).astype(jnp.int32)


def grid_shape(k: int) -> tuple[tuple[int, int], ...]:
    """All (rows, cols) with rows * cols = k, by increasing rows (the tie-break order of grid_regions)."""
    return tuple((r, k // r) for r in range(1, k + 1) if k % r == 0)


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
