"""How a frame's static background splits into regions (docs/semantics.md §3.2 step 2, §6.1):
depth layers (1-D k-means of the depth), a grid over the background's bounding box, or depth
layers split into 4-connected components. Regions are numbered 1..N_s, 0 is none.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import lax

from .kmeans import bin_of, cluster_of_bins, histogram, kmeans_1d, normalise, unit_values

# Copies of the bins the histograms of ``frames_at_once`` add into (``kmeans.segment_sums``): on a
# GPU neighbouring pixels share a bin, and one copy serialises their atomic adds (an H200's pixel
# stage at B = 64: 48 ms with 1, 23.5 with 32 or 128; bench/history/issue-61.md).
ACCELERATOR_HISTOGRAM_COPIES = 32

NO_LABEL = jnp.iinfo(jnp.int32).max  # connected components: outside every cluster


def cluster_counts(labels, *, k: int):
    """(N,) int labels (-1 = none) -> (k,) int32 entries per cluster 0..k-1."""
    return jax.ops.segment_sum((labels >= 0).astype(jnp.int32), jnp.where(labels >= 0, labels, k), num_segments=k + 1)[:k]


def renumber_kept(cluster, counts, min_region_pixels):
    """Clusters (..., N) with fewer than min_region_pixels (or no) entries dropped, the kept ones
    numbered 1..N_s in index order -> (regions (..., N) int32, N_s (...)); counts (..., k)."""
    kept = (counts >= min_region_pixels) & (counts > 0)
    new_id = jnp.where(kept, jnp.cumsum(kept.astype(jnp.int32), axis=-1), 0)
    region = jnp.where(cluster >= 0, jnp.take_along_axis(new_id, jnp.maximum(cluster, 0), axis=-1), 0)
    return region.astype(jnp.int32), jnp.sum(kept, axis=-1).astype(jnp.int32)


class DepthPartition(NamedTuple):
    """Depth regions of frames (leading axis F) as a function of depth: each histogram bin's region."""

    lo: jax.Array  # (F,) depth at the histogram's start
    span: jax.Array  # (F,) depth range the bins cover
    region_of_bin: jax.Array  # (F, bins) int32, 0 = none
    n_regions: jax.Array  # (F,) int32
    n_pixels: jax.Array  # (F,) int32 pixels the layers split: the mask's, of finite depth


def depth_partition(depth, region_mask, *, k: int, bins: int, min_region_pixels, layers=None,
                    frames_at_once: bool = False) -> DepthPartition:
    """Depth layers of frames (F, H, W) over their masks (F, H, W), ``layers`` (F,) int32 in 1..k
    per frame (default k); ``region_of_depth`` labels pixels. ``depth_partition_of`` with the frames
    given as arrays."""
    return depth_partition_of(lambda i: (depth[i], region_mask[i]), depth.shape[0], k=k, bins=bins,
                              min_region_pixels=min_region_pixels, layers=layers, frames_at_once=frames_at_once)


def depth_partition_of(read_frame, n_frames: int, *, k: int, bins: int, min_region_pixels, layers=None,
                       frames_at_once: bool = False) -> DepthPartition:
    """Depth layers of the frames ``read_frame(i)`` -> (depth (H, W), region mask (H, W)), i in
    0..n_frames-1 (traced), ``layers`` (F,) as ``depth_partition``'s. The histograms are built frame
    by frame, each frame read where it lies (unbatched scatters are several times faster on a CPU;
    ``histogram``'s CPU form) or, ``frames_at_once``, all in one batched step (an
    accelerator would otherwise run F loop iterations of tiny kernels)."""
    F = n_frames

    def frame_histogram(i):
        depth, region_mask = read_frame(i)
        u, valid, has_span, (lo, span) = normalise(depth.reshape(-1), region_mask.reshape(-1))
        sums, n_bin = histogram(u * bins, bin_of(u, bins), valid, bins, cpu_form=not frames_at_once,
                                copies=ACCELERATOR_HISTOGRAM_COPIES)  # the CPU form has no copies
        return sums, n_bin, has_span, lo, span

    over_frames = jax.vmap(frame_histogram) if frames_at_once else lambda frames: lax.map(frame_histogram, frames)
    sums, n_bin, has_span, lo, span = over_frames(jnp.arange(F))
    layers = jnp.full(F, k, jnp.int32) if layers is None else layers
    # the DP gains from batching
    cluster = jax.vmap(lambda s, h, n: cluster_of_bins(s, h, k, bins, n))(sums, has_span, layers)
    counts = jax.vmap(lambda n, c: jax.ops.segment_sum(n, c, num_segments=k))(n_bin, cluster)
    region_of_bin, n_regions = renumber_kept(cluster, counts, min_region_pixels)
    return DepthPartition(lo, span, region_of_bin, n_regions, sums.count[:, -1])  # int32 counts: exact


def region_of_depth(partition: DepthPartition, depth, region_mask):
    """Region (...) int32 of depths (...) in one frame's partition (no F axis); 0 off the mask or
    for a non-finite depth."""
    u, valid = unit_values(depth, region_mask, (partition.lo, partition.span))
    bins = partition.region_of_bin.shape[-1]
    return jnp.where(valid, partition.region_of_bin[bin_of(u, bins)], 0).astype(jnp.int32)


def depth_regions(depth, region_mask, *, k: int, bins: int, min_region_pixels):
    """One frame (H, W) -> (regions (H, W) int32 by increasing depth, N_s)."""
    partition = depth_partition(depth[None], region_mask[None], k=k, bins=bins, min_region_pixels=min_region_pixels)
    frame = jax.tree.map(lambda x: x[0], partition)
    return region_of_depth(frame, depth, region_mask), frame.n_regions


def grid_shape(k: int) -> tuple[tuple[int, int], ...]:
    """Every (rows, cols) with rows * cols = k, by increasing rows (grid_regions' tie-break order)."""
    return tuple((r, k // r) for r in range(1, k + 1) if k % r == 0)


def grid_regions(region_mask, *, k: int, min_region_pixels):
    """(H, W) mask -> (cells (H, W) int32 in row-major order, N_s): rows x cols = k cells over the
    mask's bounding box (h x w), the factorisation whose cells are closest to square
    (min max(cols h, rows w) / min(...), ties to fewer rows); pixel (y, x) is in cell row
    (y - y0) rows // h, column (x - x0) cols // w."""
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
    region, n_regions = renumber_kept(cell, cluster_counts(cell, k=k), min_region_pixels)
    return region.reshape(H, W), n_regions


NEIGHBOURS = ((-1, 0), (1, 0), (0, -1), (0, 1))  # 4-connectivity: (dy, dx) of each neighbour


def _shifted(a, fill, dy, dx):
    """a (H, W) read at (y + dy, x + dx), ``fill`` beyond the edges."""
    H, W = a.shape
    return jnp.pad(a, ((1, 1), (1, 1)), constant_values=fill)[1 + dy: 1 + dy + H, 1 + dx: 1 + dx + W]


def _same_cluster(cluster):
    """(4, H, W) bool: whether each pixel's neighbour (``NEIGHBOURS``) lies in its cluster (>= 0)."""
    return jnp.stack([(_shifted(cluster, -1, dy, dx) == cluster) & (cluster >= 0) for dy, dx in NEIGHBOURS])


def _neighbour_min(label, same):
    """Each pixel's label lowered to the smallest label of its 4-neighbours in the same cluster
    (``same`` from ``_same_cluster``)."""
    out = label
    for near, (dy, dx) in zip(same, NEIGHBOURS):  # four static shifts
        out = jnp.minimum(out, jnp.where(near, _shifted(label, NO_LABEL, dy, dx), NO_LABEL))
    return out


class Propagation(NamedTuple):
    label: jax.Array  # (H, W) each pixel's root so far: a pixel of its component, raster index <= its own
    changed: jax.Array  # () bool


def _to_roots(parent):
    """Flat parents (n,) (each <= its own index, NO_LABEL outside every cluster) -> each pixel's
    root, by pointer jumping until every pixel points at a pixel that points at itself."""
    n = parent.shape[0]

    def jump(state):
        pointer, _ = state
        further = jnp.where(pointer < n, pointer[jnp.minimum(pointer, n - 1)], pointer)
        return further, jnp.any(further != pointer)

    return jax.lax.while_loop(lambda state: state[1], jump, (parent, jnp.bool_(True)))[0]


def connected_components(cluster):
    """(H, W) int32 cluster ids (-1 = none) -> (H, W) int32 component root: the raster index of the
    component's first pixel, NO_LABEL outside every cluster. Min-label hooking with pointer
    jumping (as Shiloach-Vishkin's): each step, every root takes the smallest root next to any of
    its pixels in the same cluster, then every pixel jumps to its root; it ends when no root
    changes, which leaves each component rooted at its smallest raster index."""
    H, W = cluster.shape
    valid = cluster >= 0
    start = jnp.where(valid, jnp.arange(H * W, dtype=jnp.int32).reshape(H, W), NO_LABEL)
    same = _same_cluster(cluster)

    def step(state: Propagation) -> Propagation:
        root = state.label.reshape(-1)
        lowest = _neighbour_min(state.label, same).reshape(-1)  # the smallest root beside each pixel
        # out of bounds, and dropped, outside every cluster
        hooked = jnp.minimum(root.at[root].min(lowest, mode="drop"), lowest)
        new = _to_roots(hooked)
        return Propagation(new.reshape(H, W), jnp.any(new != root))

    return jax.lax.while_loop(lambda s: s.changed, step, Propagation(start, jnp.bool_(True))).label


def spatial_regions(cluster, *, k: int, min_region_pixels):
    """(H, W) int32 depth clusters (-1 = none) -> (regions (H, W) int32, N_s): 4-connected
    components of one cluster, those under min_region_pixels dropped, the k largest numbered
    1..N_s by decreasing size, ties to the first pixel in raster order."""
    H, W = cluster.shape
    root = connected_components(cluster).reshape(-1)
    valid = root != NO_LABEL
    sizes = jax.ops.segment_sum(valid.astype(jnp.int32), jnp.where(valid, root, 0), num_segments=H * W)
    eligible = jnp.where(sizes >= jnp.maximum(min_region_pixels, 1), sizes, 0).astype(jnp.float32)
    top_size, top_root = jax.lax.top_k(eligible, k)  # equal sizes: lower raster index first
    kept = top_size > 0
    new_id = jnp.zeros(H * W, jnp.int32).at[top_root].set(jnp.where(kept, jnp.arange(1, k + 1), 0))
    region = jnp.where(valid, new_id[jnp.where(valid, root, 0)], 0)
    return region.reshape(H, W).astype(jnp.int32), jnp.sum(kept).astype(jnp.int32)


def depth_spatial_regions(depth, region_mask, *, k: int, bins: int, min_region_pixels, cpu_form: bool = False):
    """One frame (H, W) -> (regions (H, W) int32, N_s) of the ``depth+spatial`` partition: depth
    clusters (``kmeans_1d``, ``cpu_form`` as there) split into connected components."""
    cluster = kmeans_1d(depth.reshape(-1), region_mask.reshape(-1), k=k, bins=bins, cpu_form=cpu_form)
    return spatial_regions(cluster.reshape(depth.shape), k=k, min_region_pixels=min_region_pixels)
