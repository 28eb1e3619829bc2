"""The partitions of docs/semantics.md §3.2 and §6.1: ``grid`` and ``depth+spatial`` region
structure, identical in both engines, and scored end to end; the frame whose partition a pair's
regions are (``region_frame``)."""

import dataclasses
import functools

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from sgc_jax import COMPONENTS, SGCConfig, score_clip
from sgc_jax.engines import reference
from sgc_jax.kernels import partitions
from sgc_jax.research.agreement import within_tolerance

# The kernels are traced inside the engine's program; called alone here, each is jitted once.
grid_regions = jax.jit(partitions.grid_regions, static_argnames=("k",))
connected_components = jax.jit(partitions.connected_components)
spatial_regions = jax.jit(partitions.spatial_regions, static_argnames=("k",))

CONFIG = SGCConfig(k_seg=3, min_region_pixels=4)


def two_depth_map():
    """24 x 32 frame: near blobs A (8x8) and B (6x6, same depth as A but not touching it), a far
    band C (the rest of the mask), and a 1-pixel near speck D (below min_region_pixels)."""
    depth = np.full((24, 32), 9.0, np.float32)
    depth[2:10, 2:10] = 2.0  # A: 64 px
    depth[14:20, 20:26] = 2.0  # B: 36 px
    depth[22, 0] = 2.0  # D: 1 px
    mask = np.ones_like(depth, bool)
    mask[:, 30:] = False
    return depth, mask


def test_depth_spatial_splits_a_depth_cluster_into_its_connected_parts():
    depth, mask = two_depth_map()
    labels = reference.spatial_regions(depth, mask, CONFIG)
    # Two depth levels: near splits into A, B and the speck D (dropped, < 4 px); far is one
    # component C. Numbered by decreasing size: C, A, B.
    c_size = int(mask.sum() - 64 - 36 - 1)
    assert [(labels == i).sum() for i in range(1, labels.max() + 1)] == [c_size, 64, 36]
    assert (labels[2:10, 2:10] == 2).all() and (labels[14:20, 20:26] == 3).all() and labels[22, 0] == 0


def test_depth_spatial_keeps_the_largest_k_components_above_the_size_floor():
    depth, mask = two_depth_map()
    labels = reference.spatial_regions(depth, mask, CONFIG.replace(k_seg=2))
    assert labels.max() == 2 and (labels[14:20, 20:26] == 0).all()  # B is the third largest
    labels = reference.spatial_regions(depth, mask, CONFIG.replace(min_region_pixels=70))
    assert labels.max() == 1 and (labels[2:10, 2:10] == 0).all()  # A (64 px) under the floor


def test_jax_depth_spatial_matches_the_reference_on_the_hand_built_map():
    from sgc_jax.kernels.kmeans import kmeans_1d
    depth, mask = two_depth_map()

    @functools.partial(jax.jit, static_argnames=("k", "bins"))
    def depth_spatial(depth, mask, min_region_pixels, *, k, bins):
        cluster = kmeans_1d(depth.reshape(-1), mask.reshape(-1), k=k, bins=bins)
        return spatial_regions(cluster.reshape(depth.shape), k=k, min_region_pixels=min_region_pixels)

    for config in (CONFIG, CONFIG.replace(k_seg=2), CONFIG.replace(min_region_pixels=70)):
        jx, n = depth_spatial(depth, mask, config.min_region_pixels, k=config.k_seg, bins=config.kmeans_bins)
        ref = reference.spatial_regions(depth, mask, config)
        np.testing.assert_array_equal(np.asarray(jx), ref)
        assert int(n) == ref.max()


def test_jax_connected_components_match_opencv():
    rng = np.random.default_rng(0)
    cluster = rng.integers(-1, 3, size=(40, 56)).astype(np.int32)
    root = np.asarray(connected_components(cluster))
    for c in range(3):
        n, comp = cv2.connectedComponents((cluster == c).astype(np.uint8), connectivity=4)
        for i in range(1, n):
            pixels = comp == i
            assert np.unique(root[pixels]).size == 1
            assert root[pixels][0] == np.flatnonzero(pixels.ravel())[0]
    assert (root[cluster < 0] == np.iinfo(np.int32).max).all()


def serpentine(H=41, W=56):
    """Cluster 0: one path a pixel wide winding down the rows (ends joined alternately at the right
    and left edge); cluster 1: the rows between, each its own component."""
    cluster = np.zeros((H, W), np.int32)
    cluster[1::2] = 1
    cluster[1::4, -1] = 0
    cluster[3::4, 0] = 0
    return cluster


@pytest.mark.parametrize("turn", [0, 1, 2])
def test_jax_connected_components_match_opencv_on_a_winding_path(turn):
    # the path's first pixel (in raster order) lies at one of its ends, or mid-path after a
    # quarter turn: its root reaches every pixel only along the path, through the whole frame
    cluster = np.ascontiguousarray(np.rot90(serpentine(), turn))
    root = np.asarray(connected_components(cluster))
    for c in range(2):
        n, comp = cv2.connectedComponents((cluster == c).astype(np.uint8), connectivity=4)
        for i in range(1, n):
            pixels = comp == i
            assert (root[pixels] == np.flatnonzero(pixels.ravel())[0]).all()


@pytest.mark.parametrize("partition", ["grid", "depth+spatial"])
def test_both_engines_build_the_same_label_map_on_a_synthetic_frame(rigid_clip, partition):
    config = SGCConfig(partition=partition)
    frame = 2
    ref = reference.partition_regions(rigid_clip, frame, config)
    mask = reference.pair_region_mask(rigid_clip, frame, config)
    depth = np.where(mask, rigid_clip.depth[frame], 0.0).astype(np.float32)
    if partition == "grid":
        jx, n = grid_regions(mask, k=config.k_seg, min_region_pixels=config.min_region_pixels)
    else:
        from sgc_jax.kernels.kmeans import kmeans_1d
        cluster = kmeans_1d(depth.reshape(-1), mask.reshape(-1), k=config.k_seg, bins=config.kmeans_bins)
        jx, n = spatial_regions(cluster.reshape(depth.shape), k=config.k_seg,
                                min_region_pixels=config.min_region_pixels)
    np.testing.assert_array_equal(np.asarray(jx), ref)
    assert int(n) == ref.max() >= 2


def test_a_depth_partition_read_in_place_is_the_sliced_frames_and_counts_their_masks_finite_pixels():
    depth, mask = two_depth_map()
    far = np.where(mask, depth * 1.5, 0.0).astype(np.float32)
    far[5, 5] = np.nan  # on the mask, without a depth: no pixel of the partition
    frames = np.stack([np.zeros_like(depth), depth, far])  # frame 0 is not partitioned
    masks = np.stack([mask, mask, mask])
    regions = dict(k=CONFIG.k_seg, bins=CONFIG.kmeans_bins, min_region_pixels=CONFIG.min_region_pixels)
    sliced = jax.jit(lambda d, m: partitions.depth_partition(d, m, **regions))(frames[1:], masks[1:])
    pick = jnp.array([1, 2])
    in_place = jax.jit(lambda d, m: partitions.depth_partition_of(lambda i: (d[pick[i]], m[pick[i]]), 2, **regions))(
        frames, masks)
    for got, want in zip(in_place, sliced):
        np.testing.assert_array_equal(np.asarray(got), np.asarray(want))
    np.testing.assert_array_equal(np.asarray(in_place.n_pixels), [mask.sum(), mask.sum() - 1])


def test_grid_cells_are_row_major_squarest_cells():
    mask = np.zeros((60, 90), bool)
    mask[10:50, 5:85] = True  # 40 x 80 bounding box: k=10 -> 2 rows x 5 cols (cells 20 x 16)
    labels = reference.grid_regions(mask, SGCConfig(k_seg=10, min_region_pixels=1))
    assert labels.max() == 10
    assert labels[10, 5] == 1 and labels[10, 84] == 5 and labels[49, 5] == 6 and labels[49, 84] == 10
    assert (labels[~mask] == 0).all()


def test_depth_spatial_scores_a_rigid_clip_near_zero_in_both_engines(rigid_clip):
    result = score_clip(rigid_clip, engine="jax", partition="depth+spatial")
    ref = score_clip(rigid_clip, engine="reference", partition="depth+spatial")
    for scored in (result, ref):
        assert scored.status == "ok"
        assert scored.components["local_rot_var"] < 1e-3 and scored.components["global_rot_var"] < 1e-3
    plain = score_clip(rigid_clip, engine="reference")
    assert (result.pairs.n_regions >= plain.pairs.n_regions).all()  # splitting never merges
    np.testing.assert_array_equal(ref.pairs.n_regions, result.pairs.n_regions)  # the same regions


PREVIOUS, CURRENT = SGCConfig(region_frame="previous"), SGCConfig(region_frame="current")


def test_previous_region_frame_keeps_the_trackers_frame_i_error_out_of_membership(rigid_clip):
    rng = np.random.default_rng(0)
    noisy = dataclasses.replace(rigid_clip, track_curr=rigid_clip.track_curr + rng.normal(
        0.0, 2.0, rigid_clip.track_curr.shape).astype(np.float32))
    moved_under_current = 0
    for pair in range(1, rigid_clip.n_frames):
        exact, tracked = reference.pair_points(rigid_clip, pair, PREVIOUS), reference.pair_points(noisy, pair, PREVIOUS)
        np.testing.assert_array_equal(exact.labels, reference.partition_regions(rigid_clip, pair - 1, PREVIOUS))
        np.testing.assert_array_equal(exact.region, tracked.region)
        moved_under_current += int(np.sum(reference.pair_points(rigid_clip, pair, CURRENT).region
                                          != reference.pair_points(noisy, pair, CURRENT).region))
    assert moved_under_current > 0  # read at frame i, the same noise moves points across borders


def test_both_engines_pose_the_same_regions_of_the_previous_frame(rigid_clip):
    jx = score_clip(rigid_clip, engine="jax", region_frame="previous")
    ref = score_clip(rigid_clip, engine="reference", region_frame="previous")
    for field in ("n_regions", "region_points", "region_status"):
        np.testing.assert_array_equal(getattr(jx.pairs, field), getattr(ref.pairs, field), err_msg=field)
    for k in COMPONENTS:
        assert within_tolerance(ref.components[k], jx.components[k], k), (k, ref.components[k], jx.components[k])
    current = score_clip(rigid_clip, engine="reference", config=CURRENT)
    assert not np.array_equal(current.pairs.region_points, ref.pairs.region_points)


def test_depth_layers_follow_the_tracks_in_both_engines(rigid_clip):
    # ~1,900 of the clip's 2,048 tracks lie on the background: one layer per 400 of them is 4
    config = SGCConfig(tracks_per_layer=400)
    jx = score_clip(rigid_clip, engine="jax", config=config)
    ref = score_clip(rigid_clip, engine="reference", config=config)
    for field in ("n_regions", "region_points", "region_status"):
        np.testing.assert_array_equal(getattr(jx.pairs, field), getattr(ref.pairs, field), err_msg=field)
    for k in COMPONENTS:
        assert within_tolerance(ref.components[k], jx.components[k], k), (k, ref.components[k], jx.components[k])
    points = [reference.pair_points(rigid_clip, pair, config) for pair in range(1, rigid_clip.n_frames)]
    assert all(1 <= n <= len(p.X) // 400 for n, p in zip(ref.pairs.n_regions, points))
    assert (ref.pairs.n_regions < score_clip(rigid_clip, engine="jax").pairs.n_regions).all()
