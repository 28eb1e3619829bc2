"""Exact 1-D k-means on a histogram (docs/semantics.md §3.2 step 2).

Values fall into ``bins`` equal-width bins; clusters are unions of whole bins, and among those the
within-cluster sum of squares is minimal (exact k-means whenever distinct values fall in distinct
bins). A dynamic programme over k layers, each a row-minima search that divide and conquer solves
in O(bins log bins) (the SSE cost is Monge), on prefix sums of ~44 significant bits or more
(double-float pairs, or float64 where a CPU has it natively). Deterministic; ties go to the
smallest first bin of the last cluster.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from .double_float import df_add, df_div, df_mul, df_sub, two_prod
from .fence import materialise


class Histogram(NamedTuple):
    """Prefix sums over bins 0..c-1, c = 0..bins: counts (bins + 1,) int32 and the sums of
    positions and of squared positions [bin units about the histogram's middle], each a
    double-float pair of (bins + 1,) float32 or, in the CPU form (``histogram``), one (bins + 1,)
    float64 array."""

    count: jax.Array
    sum: tuple | jax.Array
    sum_sq: tuple | jax.Array


def normalise(values, valid):
    """(N,) values and valid -> (u in [0, 1] (N,), finite valid (N,), has_span (), (lo, span));
    u = (v - lo) / span, with lo = 0, span = 1 when the values span no range."""
    v = values.astype(jnp.float32)
    valid = valid & jnp.isfinite(v)
    lo = jnp.min(jnp.where(valid, v, jnp.inf))
    hi = jnp.max(jnp.where(valid, v, -jnp.inf))
    has_span = hi - lo > 0  # False with no valid value (-inf) and with a single distinct value
    scale = (jnp.where(has_span, lo, 0.0), jnp.where(has_span, hi - lo, 1.0))
    u, valid = unit_values(values, valid, scale)
    return u, valid, has_span, scale


def unit_values(values, valid, scale):
    """Values mapped to [0, 1] by a frame's (lo, span), and the mask of the finite valid ones."""
    v = values.astype(jnp.float32)
    valid = valid & jnp.isfinite(v)
    lo, span = scale
    return (jnp.where(valid, v, lo) - lo) / span, valid


def bin_of(u, bins):
    """Bin index (int32) of unit values u."""
    return jnp.clip(jnp.floor(u * bins), 0, bins - 1).astype(jnp.int32)


def histogram(y, bins_of, valid, bins, cpu_form: bool = False, copies: int = 1) -> tuple[Histogram, jax.Array]:
    """Prefix sums of positions y (N,) [bin units, 0..bins] -> (Histogram, entries per bin (bins,)).

    Each bin's sums are an exact part at the bin centre plus float32 sums of the offsets from it
    (|d| <= 0.5), so Q - S^2 / n keeps the spread of a tight cluster far from the origin.
    ``cpu_form``: the offsets and their squares summed as one complex segment sum (the same sums,
    complex addition is per part, in half the time of two), and the prefix sums in float64, which
    a CPU does natively, instead of double-float pairs (several times the arithmetic).
    ``copies`` > 1 (the other form only): entry i added into copy i mod ``copies`` of the bins and
    the copies summed after (``segment_sums``); 1 is the plain segment sum."""
    d = jnp.where(valid, y - (bins_of.astype(jnp.float32) + 0.5), 0.0)
    # 1-D segment sums: faster on CPU than one over stacked (N, 3) rows
    # counted in int32: a float32 count stops at 2^24 entries in one bin (an 8K frame's flat wall)
    if cpu_form:
        n_bin = jax.ops.segment_sum(valid.astype(jnp.int32), bins_of, num_segments=bins)
        sums = jax.ops.segment_sum(jax.lax.complex(d, d * d), bins_of, num_segments=bins)
        return _wide_prefix_sums(n_bin, jnp.real(sums), jnp.imag(sums), bins), n_bin
    n_bin = segment_sums(valid.astype(jnp.int32), bins_of, bins, copies)
    d_c, e_c = (segment_sums(x, bins_of, bins, copies) for x in (d, d * d))
    n_c = n_bin.astype(jnp.float32)
    centre = jnp.arange(bins, dtype=jnp.float32) + (0.5 - 0.5 * bins)
    zero = jnp.zeros(bins, jnp.float32)
    s_c = df_add(two_prod(n_c, centre), (d_c, zero))
    q_c = df_add(df_add(two_prod(n_c, centre * centre), two_prod(2.0 * centre, d_c)), (e_c, zero))

    def prefix(x):
        hi, lo = jax.lax.associative_scan(df_add, x)
        return jnp.concatenate([jnp.zeros(1, jnp.float32), hi]), jnp.concatenate([jnp.zeros(1, jnp.float32), lo])

    return Histogram(jnp.concatenate([jnp.zeros(1, jnp.int32), jnp.cumsum(n_bin)]), prefix(s_c), prefix(q_c)), n_bin


def segment_sums(values, segment, num_segments: int, copies: int = 1):
    """``jax.ops.segment_sum`` of values (N,) by segment (N,), entry i added into copy i mod
    ``copies`` of the segments and the copies summed after: on a GPU, neighbouring entries of one
    segment (a depth histogram's pixels) wait on each other's atomic adds to one address
    (bench/history/issue-61.md "The least-squares step on an H200"). Integer sums are the same for
    any ``copies``, float sums up to their order."""
    if copies == 1:
        return jax.ops.segment_sum(values, segment, num_segments=num_segments)
    copy = jnp.arange(values.shape[0], dtype=segment.dtype) % copies
    spread = jax.ops.segment_sum(values, copy * num_segments + segment, num_segments=copies * num_segments)
    return jnp.sum(spread.reshape(copies, num_segments), axis=0)


def _wide_prefix_sums(n_bin, d_c, e_c, bins) -> Histogram:
    """The CPU form's Histogram from each bin's count n_bin (bins,) int32 and float32 sums of the
    offsets d_c and of their squares e_c (bins,): float64 made and used only in a 64-bit scope, so
    the rest of the program keeps JAX's default types."""
    with jax.enable_x64(True):
        n_c, d_c, e_c = (x.astype(jnp.float64) for x in (n_bin, d_c, e_c))
        centre = jnp.arange(bins, dtype=jnp.float64) + (0.5 - 0.5 * bins)
        zero = jnp.zeros(1, jnp.float64)
        prefix = lambda x: jnp.concatenate([zero, jnp.cumsum(x)])  # noqa: E731
        return Histogram(jnp.concatenate([jnp.zeros(1, jnp.int32), jnp.cumsum(n_bin, dtype=jnp.int32)]),
                         prefix(n_c * centre + d_c), prefix(n_c * centre * centre + 2.0 * centre * d_c + e_c))


def range_cost(first: Histogram, last: Histogram):
    """SSE (float32) of the values in bins first..last - 1 from the prefix entries at both
    boundaries; 0 when empty."""
    if not isinstance(first.sum, tuple):  # the CPU form: float64
        with jax.enable_x64(True):
            n = (last.count - first.count).astype(jnp.float64)
            s_ab = last.sum - first.sum
            sse = (last.sum_sq - first.sum_sq) - s_ab * s_ab / jnp.maximum(n, 1.0)
            return jnp.where(n > 0, jnp.maximum(sse, 0.0), 0.0).astype(jnp.float32)
    n = (last.count - first.count).astype(jnp.float32)
    s_ab = df_sub(last.sum, first.sum)
    q_ab = df_sub(last.sum_sq, first.sum_sq)
    sse = df_sub(q_ab, df_div(df_mul(s_ab, s_ab), jnp.maximum(n, 1.0)))
    return jnp.where(n > 0, jnp.maximum(sse[0] + sse[1], 0.0), 0.0)


class SearchPlan(NamedTuple):
    """The divide-and-conquer row-minima search over the DP's columns, per level (levels, M), every
    level padded to the same width M: the columns solved there (``bins`` pads), the solved columns
    whose optima bound each search from below and above (-1: none), and (levels, M, 2) each
    column's left and right child in the next level (-1: none)."""

    mids: np.ndarray
    lefts: np.ndarray
    rights: np.ndarray
    children: np.ndarray


def search_plan(bins: int) -> SearchPlan:
    """The static SearchPlan over columns 0..bins-1: optimal first bins are nondecreasing in the
    last bin (Monge), so a column's search lies between its neighbours' optima."""
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
    return SearchPlan(*(pad([level[i] for level in levels], fill) for i, fill in enumerate((bins, -1, -1, [-1, -1]))))


def segment_min_nonnegative(values, segment, num_segments):
    """``jax.ops.segment_min`` of float32 values >= 0 or +inf (no subnormals), as a minimum of
    their bit patterns: batched over frames, XLA CPU's integer scatter-min is several times faster
    than its float one."""
    bits = jax.lax.bitcast_convert_type(values, jnp.int32) & jnp.int32(0x7FFFFFFF)  # -0.0 -> 0.0
    low = jax.ops.segment_min(bits, segment, num_segments=num_segments)
    # an empty segment's int32 maximum would read back as a NaN: +inf, as segment_min of floats gives
    return jnp.where(low == jnp.iinfo(jnp.int32).max, jnp.inf, jax.lax.bitcast_convert_type(low, jnp.float32))


class LevelState(NamedTuple):
    """The search after some levels: each column's optimal first bin and cost (bins,), and the
    column whose search range each row lies in (bins + 1,) (-1: none)."""

    first: jax.Array
    best: jax.Array
    segment: jax.Array


def dp_step(prev, sums: Histogram, plan: SearchPlan, bins):
    """One DP layer: for every last bin b, min over a of prev[a] + cost(a, b) -> (best (bins,),
    first (bins,) int32), ties to the smallest a. prev (bins + 1,) = D_{j-1}(a - 1); cost(a, b)
    is the SSE of bins a..b, 0 for a == b + 1, +inf for a > b + 1. A level solves its columns
    over rows that tile (neighbours share at most an end point, evaluated apart), so a layer
    costs O((bins + M) log bins)."""
    rows = jnp.arange(bins + 1, dtype=jnp.int32)
    take = lambda idx: jax.tree.map(lambda x: x[idx], sums)  # noqa: E731  prefix entries at idx
    width = plan.mids.shape[1]

    def level(state: LevelState, columns):
        mids, lefts, rights, children = columns
        lo = jnp.where(lefts >= 0, state.first[jnp.maximum(lefts, 0)], 0)
        hi = jnp.minimum(jnp.where(rights >= 0, state.first[jnp.maximum(rights, 0)], bins), mids + 1)
        last = take(jnp.minimum(mids + 1, bins))  # prefix entries after each column's last bin
        seg = state.segment
        seg_c = jnp.maximum(seg, 0)
        inside = (seg >= 0) & (rows >= lo[seg_c]) & (rows <= hi[seg_c])
        tot = jnp.where(inside, prev + range_cost(sums, jax.tree.map(lambda x: x[seg_c], last)), jnp.inf)
        seg_id = jnp.where(inside, seg_c, width)
        # a range's last row may lie in the next range too (which owns it): evaluated here
        end = prev[hi] + range_cost(take(hi), last)
        low = jnp.minimum(segment_min_nonnegative(tot, seg_id, width + 1)[:width], end)
        arg = jax.ops.segment_min(jnp.where(tot == low[seg_c], rows, bins + 1), seg_id, num_segments=width + 1)[:width]
        arg = jnp.minimum(jnp.minimum(arg, jnp.where(end == low, hi, bins + 1)), hi).astype(jnp.int32)
        # per column, then gathered per row: fused, XLA would redo the columns' costs per row
        arg, low = materialise((arg, low))
        first = state.first.at[mids].set(arg, mode="drop")  # padding columns (mids = bins) write nothing
        best = state.best.at[mids].set(low, mode="drop")
        # rows before a column's optimum are searched for its left child, the others for its right
        kids = children[seg_c]
        seg = jnp.where(seg >= 0, jnp.where(rows < arg[seg_c], kids[:, 0], kids[:, 1]), -1)
        return LevelState(first, best, seg), None

    init = LevelState(jnp.zeros(bins, jnp.int32), jnp.zeros(bins, jnp.float32), jnp.zeros(bins + 1, jnp.int32))
    final, _ = lax.scan(level, init, SearchPlan(*(jnp.asarray(a) for a in plan)))
    return final.best, final.first


class Backtrack(NamedTuple):
    """The backward pass's state: the last bin of the cluster being placed, each bin's cluster so far."""

    last_bin: jax.Array  # int32; -1 once every bin is placed
    cluster: jax.Array  # (bins,) int32


def first_layer(sums: Histogram, bins):
    """The DP's first layer: one cluster of bins 0..b for every last bin b -> (best (bins,), first
    (bins,) int32, all 0), as ``dp_step`` gives it from D(-1) = 0 and +inf before."""
    start = jax.tree.map(lambda x: jnp.broadcast_to(x[0], (bins,)), sums)
    best = 0.0 + range_cost(start, jax.tree.map(lambda x: x[1:], sums))  # 0.0 +: prev[0] + cost, as dp_step
    return best, jnp.zeros(bins, jnp.int32)


def last_bin_step(prev, sums: Histogram, bins):
    """One DP layer at the last bin only (the layer no later one reads, whose backtrack starts
    there): min over a of prev[a] + cost(a, bins - 1) -> (best (), first () int32), ties to the
    smallest a; prev as ``dp_step``'s."""
    end = jax.tree.map(lambda x: jnp.broadcast_to(x[bins], x.shape), sums)
    total = prev + range_cost(sums, end)  # rows a = 0..bins; a = bins: an empty last cluster
    return jnp.min(total), jnp.argmin(total).astype(jnp.int32)


def cluster_of_bins(sums: Histogram, has_span, k, bins, k_used=None):
    """The k-layer DP, then the backtrack -> cluster 0..k_used-1 of each bin (bins,), by increasing
    value; every bin in cluster 0 when the values span no range. ``k_used`` (traced, 1..k; default
    k): the DP's row j holds the optimum for j + 1 clusters, so fewer clusters is a backtrack from
    an earlier row, the same program. The first layer is closed-form and the last is needed at the
    last bin only (its backtrack's start); the layers between search every column."""
    plan = search_plan(bins)
    k_used = k if k_used is None else k_used

    def forward(prev, _):  # prev[a] = D_{j-1}(a - 1) for a = 0..bins, D(-1) = 0
        best, first = dp_step(prev, sums, plan, bins)
        return jnp.concatenate([jnp.zeros(1, jnp.float32), best]), first

    best, first = first_layer(sums, bins)
    rows = [first[None]]
    prev = jnp.concatenate([jnp.zeros(1, jnp.float32), best])
    if k > 2:
        prev, middle = lax.scan(forward, prev, None, length=k - 2)
        rows.append(middle)
    if k > 1:
        rows.append(jnp.broadcast_to(last_bin_step(prev, sums, bins)[1], (1, bins)))
    first_bin = jnp.concatenate(rows)  # (k, bins): A_j(b) at row j - 1; the last row valid at bins - 1
    bin_ids = jnp.arange(bins, dtype=jnp.int32)

    def backward(state: Backtrack, step) -> tuple[Backtrack, None]:
        last = state.last_bin
        j = k_used - 1 - step  # rows k_used-1 .. 0; steps past row 0 change nothing
        row = jnp.maximum(j, 0)
        first = jnp.where(last >= 0, first_bin[row, jnp.maximum(last, 0)], last + 1)
        spanned = (bin_ids >= first) & (bin_ids <= last) & (j >= 0)
        return Backtrack(jnp.where(j >= 0, first - 1, last), jnp.where(spanned, row, state.cluster)), None

    done, _ = lax.scan(backward, Backtrack(jnp.int32(bins - 1), jnp.zeros(bins, jnp.int32)),
                       jnp.arange(k, dtype=jnp.int32))
    return jnp.where(has_span, done.cluster, 0)


def kmeans_1d(values, valid, *, k: int, bins: int, k_used=None, cpu_form: bool = False):
    """(N,) values, (N,) bool valid -> (N,) int32 cluster 0..k_used-1 by increasing value, -1
    invalid; ``k_used`` (traced, 1..k) defaults to k; ``cpu_form`` as ``histogram``'s (the same
    clusters)."""
    u, valid, has_span, _ = normalise(values, valid)
    bins_of = bin_of(u, bins)
    sums, _ = histogram(u * bins, bins_of, valid, bins, cpu_form=cpu_form)
    return jnp.where(valid, cluster_of_bins(sums, has_span, k, bins, k_used)[bins_of], -1).astype(jnp.int32)
