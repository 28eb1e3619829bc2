"""A frame's depth regions (docs/semantics.md §3.2 steps 1-4, §6.1): 1-D k-means layers, grid and depth+spatial partitions."""

from __future__ import annotations

import cv2
import numpy as np

from ...config import SGCConfig
from ...io.clip import Clip
from .tracks import point_regions


def valid_depth(depth: np.ndarray) -> np.ndarray:
    return np.isfinite(depth) & (depth > 0)


def kmeans_1d(values: np.ndarray, k: int, bins: int) -> np.ndarray:
    """Exact 1-D k-means on a ``bins``-bin histogram by dynamic programming.

    values (N,) -> labels (N,) in 0..k-1, clusters in increasing value order. Clusters are
    unions of whole bins; among those the within-cluster sum of squares is minimal.
    """
    values = np.asarray(values, np.float64)
    if values.size == 0:
        return np.zeros(0, np.int64)
    lo, hi = values.min(), values.max()
    if hi - lo <= 0:
        return np.zeros(values.size, np.int64)
    u = (values - lo) / (hi - lo)
    bin_of = np.clip(np.floor(u * bins), 0, bins - 1).astype(np.int64)
    N = np.concatenate([[0.0], np.cumsum(np.bincount(bin_of, minlength=bins))])
    S = np.concatenate([[0.0], np.cumsum(np.bincount(bin_of, weights=u, minlength=bins))])
    Q = np.concatenate([[0.0], np.cumsum(np.bincount(bin_of, weights=u * u, minlength=bins))])
    a = np.arange(bins + 1)[:, None]  # first bin of the last cluster (a == b + 1: empty cluster)
    b = np.arange(bins)[None, :]  # last bin
    n, s, q = N[b + 1] - N[a], S[b + 1] - S[a], Q[b + 1] - Q[a]
    cost = np.maximum(q - s * s / np.maximum(n, 1.0), 0.0)
    cost = np.where(a <= b + 1, np.where(a == b + 1, 0.0, cost), np.inf)
    prev = np.concatenate([[0.0], np.full(bins, np.inf)])  # D_0(a - 1) for a = 0..bins
    choices = []
    for _ in range(k):
        total = prev[:, None] + cost
        choice = np.argmin(total, axis=0)
        choices.append(choice)
        prev = np.concatenate([[0.0], total[choice, np.arange(bins)]])
    cluster_of_bin = np.zeros(bins, np.int64)
    last = bins - 1
    for j in range(k - 1, -1, -1):
        if last < 0:
            break
        first = choices[j][last]
        cluster_of_bin[first: last + 1] = j
        last = first - 1
    return cluster_of_bin[bin_of]


def depth_regions(depth: np.ndarray, region_mask: np.ndarray, config: SGCConfig,
                  layers: int | None = None) -> np.ndarray:
    """Label map (H, W): 1..N_s depth clusters (``layers`` of them, default k_seg) of the masked
    pixels, 0 = no region (docs/semantics.md §3.2)."""
    labels = np.zeros(depth.shape, np.int32)
    cluster = kmeans_1d(depth[region_mask], config.k_seg if layers is None else layers, config.kmeans_bins)
    counts = np.bincount(cluster, minlength=config.k_seg)
    kept = np.flatnonzero(counts >= max(config.min_region_pixels, 1))  # never an empty cluster, as the JAX engine
    renumber = np.zeros(config.k_seg, np.int32)
    renumber[kept] = np.arange(1, kept.size + 1)
    labels[region_mask] = renumber[cluster]
    return labels


def pair_region_mask(clip: Clip, frame: int, config: SGCConfig) -> np.ndarray:
    """S_i: static and valid depth in frame ``frame`` (the pair's region frame; authors: invalid
    static depth too)."""
    static = clip.static_mask[frame] if config.use_mos else np.ones(clip.image_size, bool)
    if config.compat == "authors":
        return static
    return static & valid_depth(clip.depth[frame])


def layer_count(region_mask: np.ndarray, uv: np.ndarray, config: SGCConfig) -> int:
    """Depth layers of a frame whose background (H, W) holds the points uv (n, 2) at their pixels
    (``track_pixel``): one per ``tracks_per_layer`` of them and two from that many on, 1..k_seg; k_seg unless
    ``layers_follow_tracks`` (docs/semantics.md §3.2)."""
    if not config.layers_follow_tracks:
        return config.k_seg
    on_mask = int((point_regions(region_mask.astype(np.int32), uv, config.track_pixel_offset) > 0).sum())
    per_layer = config.tracks_per_layer
    return int(np.clip(max(on_mask // per_layer, 2 * (on_mask >= per_layer)), 1, config.k_seg))


def partition_regions(clip: Clip, frame: int, config: SGCConfig, layers: int | None = None) -> np.ndarray:
    """Region label map (H, W) of frame ``frame`` for the configured partition; ``layers``: depth
    layers (partition ``depth``; default k_seg)."""
    region_mask = pair_region_mask(clip, frame, config)
    depth = np.where(valid_depth(clip.depth[frame]), clip.depth[frame], 0.0)
    if config.partition == "grid":
        return grid_regions(region_mask, config)
    if config.partition == "depth+spatial":
        return spatial_regions(depth, region_mask, config)
    return depth_regions(depth, region_mask, config, layers)


def grid_regions(region_mask: np.ndarray, config: SGCConfig) -> np.ndarray:
    """Label map (H, W): a rows x cols = k_seg grid over the mask's bounding box (h x w pixels),
    the factorisation with the squarest cells (ties: fewer rows); cells numbered row-major,
    cells under min_region_pixels dropped (the paper's "Grid depth" ablation)."""
    labels = np.zeros(region_mask.shape, np.int32)
    if not region_mask.any():
        return labels
    rows_any, cols_any = np.flatnonzero(region_mask.any(1)), np.flatnonzero(region_mask.any(0))
    y0, x0 = rows_any[0], cols_any[0]
    h, w = rows_any[-1] - y0 + 1, cols_any[-1] - x0 + 1
    shapes = [(r, config.k_seg // r) for r in range(1, config.k_seg + 1) if config.k_seg % r == 0]
    rows, cols = min(shapes, key=lambda s: max(s[1] * h, s[0] * w) / min(s[1] * h, s[0] * w))
    y, x = np.mgrid[: region_mask.shape[0], : region_mask.shape[1]]
    cell = np.clip((y - y0) * rows // h, 0, rows - 1) * cols + np.clip((x - x0) * cols // w, 0, cols - 1)
    counts = np.bincount(cell[region_mask], minlength=config.k_seg)
    kept = np.flatnonzero(counts >= max(config.min_region_pixels, 1))
    renumber = np.zeros(config.k_seg, np.int32)
    renumber[kept] = np.arange(1, kept.size + 1)
    labels[region_mask] = renumber[cell[region_mask]]
    return labels


def spatial_regions(depth: np.ndarray, region_mask: np.ndarray, config: SGCConfig) -> np.ndarray:
    """Label map (H, W): depth clusters split into 4-connected components; components under
    min_region_pixels dropped; the k_seg largest kept, numbered by decreasing size (ties: first
    pixel in raster order)."""
    labels = np.zeros(depth.shape, np.int32)
    if not region_mask.any():
        return labels
    cluster = np.full(depth.shape, -1, np.int64)
    cluster[region_mask] = kmeans_1d(depth[region_mask], config.k_seg, config.kmeans_bins)
    components = []  # (size, first raster index, pixel mask)
    for c in np.unique(cluster[region_mask]):
        n, comp = cv2.connectedComponents((cluster == c).astype(np.uint8), connectivity=4)
        for i in range(1, n):
            pixels = comp == i
            components.append((int(pixels.sum()), int(np.flatnonzero(pixels.ravel())[0]), pixels))
    components = [c for c in components if c[0] >= max(config.min_region_pixels, 1)]
    components.sort(key=lambda c: (-c[0], c[1]))
    for new_id, (_, _, pixels) in enumerate(components[: config.k_seg], start=1):
        labels[pixels] = new_id
    return labels
