"""warp.py: forward depth warp with a z-buffer and the depth error (docs/semantics.md §3.6)."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from sgc_jax.config import DEPTH_SCALE_MIN_PIXELS, DEPTH_SCALE_STRIDE, SGCConfig
from sgc_jax.engines import reference
from sgc_jax.engines.jax_engine.finish_stage import FinishStage, pair_depth_errors
from sgc_jax.io.clip import Clip
from sgc_jax.kernels import depth_map, warp
from sgc_jax.kernels.medians import masked_median
from sgc_jax.kernels.so3 import so3_exp
from sgc_jax.research import diagnostics

# The kernels are traced inside the engine's program; called alone here, each is jitted once.
warp_depth = jax.jit(warp.warp_depth, static_argnames=("nearest", "mask_holes", "magnified"))
depth_error = jax.jit(warp.depth_error, static_argnames=("relative",))

H, W = 24, 32
K = np.array([[30.0, 0.0, 15.5], [0.0, 30.0, 11.5], [0.0, 0.0, 1.0]], np.float32)
I3 = np.eye(3, dtype=np.float32)
ZERO = np.zeros(3, np.float32)
# float32 vs the float64 loop: warped z differs by a few ulps of depths ~ 1..10.
Z_RTOL = 1e-5


def loop_warp(depth, K_prev, K_curr, R, t, nearest=True):
    """Per-pixel float64 loop of the SPEC semantics: (warped, hit)."""
    depth = np.asarray(depth, np.float64)
    Hh, Ww = depth.shape
    best = np.full((Hh, Ww), np.nan)
    Kinv = np.linalg.inv(np.asarray(K_prev, np.float64))
    for v in range(Hh):
        for u in range(Ww):
            d = depth[v, u]
            if not (np.isfinite(d) and d > 0):
                continue
            X = R @ (Kinv @ np.array([u, v, 1.0]) * d) + t
            if X[2] <= 1e-5:
                continue
            p = np.asarray(K_curr, np.float64) @ (X / X[2])
            iu, iv = int(np.floor(p[0] + 0.5)), int(np.floor(p[1] + 0.5))
            if 0 <= iu < Ww and 0 <= iv < Hh:
                old = best[iv, iu]
                if np.isnan(old) or (X[2] < old if nearest else X[2] > old):
                    best[iv, iu] = X[2]
    hit = ~np.isnan(best)
    return np.where(hit, best, 0.0), hit


def test_identity_pose_reproduces_depth():
    rng = np.random.default_rng(0)
    depth = rng.uniform(1.0, 10.0, (H, W)).astype(np.float32)
    depth[3, 4] = 0.0
    depth[5, 6] = np.nan
    valid = np.isfinite(depth) & (depth > 0)
    valid[7, 8] = False
    warped, hit = warp_depth(depth, valid, K, K, I3, ZERO)
    np.testing.assert_array_equal(np.asarray(hit), valid)
    np.testing.assert_array_equal(np.asarray(warped), np.where(valid, depth, 0.0))


def test_translation_along_z_of_a_fronto_parallel_plane():
    depth = np.full((H, W), 4.0, np.float32)
    warped, hit = warp_depth(depth, np.ones((H, W), bool), K, K, I3, np.array([0, 0, 1.0], np.float32))
    warped, hit = np.asarray(warped), np.asarray(hit)
    assert hit[11:13, 15:17].all() and not hit[0, 0]  # the image shrinks by 4/5 about the centre
    np.testing.assert_allclose(warped[hit], 5.0, rtol=1e-6)
    np.testing.assert_array_equal(warped[~hit], 0.0)


@pytest.mark.parametrize("nearest, expected", [(True, 1.0), (False, 2.0)])
def test_collisions_keep_the_nearest_or_the_farthest(nearest, expected):
    # Shifting by t_x moves a pixel by fx * t_x / z: (u=2, z=1) and (u=3, z=2) both land on u=4.
    depth = np.zeros((H, W), np.float32)
    depth[11, 2], depth[11, 3] = 1.0, 2.0
    t = np.array([2.0 / K[0, 0], 0.0, 0.0], np.float32)
    warped, hit = warp_depth(depth, depth > 0, K, K, I3, t, nearest=nearest)
    assert np.asarray(hit).sum() == 1 and bool(hit[11, 4])
    assert float(warped[11, 4]) == pytest.approx(expected)


def plane_depth(K, normal, offset):
    """(H, W) depth of the plane normal . X = offset seen through K."""
    v, u = np.mgrid[:H, :W].astype(np.float64)
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1)
    return offset / (rays @ normal)


def test_rigid_plane_scene_with_small_rotation_has_tiny_depth_error():
    normal0 = np.array([0.1, -0.3, 1.0]) / np.linalg.norm([0.1, -0.3, 1.0])
    offset0 = 5.0
    R = np.asarray(so3_exp(np.radians(np.array([0.5, -1.0, 0.3], np.float32))), np.float64)
    t = np.array([0.05, -0.02, 0.1])
    normal1 = R @ normal0  # plane in camera 1: (R n) . X' = offset + (R n) . t
    depth0 = plane_depth(K, normal0, offset0).astype(np.float32)
    depth1 = plane_depth(K, normal1, offset0 + normal1 @ t).astype(np.float32)
    warped, hit = warp_depth(depth0, np.ones((H, W), bool), K, K, R.astype(np.float32), t.astype(np.float32))
    err, n = depth_error(warped, hit, depth1, np.ones((H, W), bool), np.ones((H, W), bool))
    assert int(n) > 0.8 * H * W
    # Rounding to the nearest pixel moves a sample by <= 0.5 px along a gentle depth gradient.
    assert float(err) < 1e-2 * float(depth1.mean())


# Frame i's inverse depth interpolated bilinearly is exact on a plane; float32 leaves ~5e-6 %.
EXACT_PLANE_PERCENT = 1e-3


def slanting_plane_clip():
    """A plane slanting from depth 0.9 at the top to 1.5 at the bottom of 24x32 px (1-2 % a pixel
    row, as a floor seen from close by), seen from two exact cameras -> (two-frame Clip, R, t)."""
    R = np.asarray(so3_exp(np.radians(np.array([0.4, -0.7, 0.2], np.float32))), np.float64)
    t = np.array([0.07, 0.03, 0.25])
    normal0 = np.array([0.1, 0.5, 1.0]) / np.linalg.norm([0.1, 0.5, 1.0])
    normal1 = R @ normal0
    depth = np.stack([plane_depth(K, normal0, 1.0), plane_depth(K, normal1, 1.0 + normal1 @ t)]).astype(np.float32)
    no_tracks = np.zeros((1, 1, 2), np.float32)
    clip = Clip(clip_id="plane", depth=depth, K=np.stack([K, K]).astype(np.float64), R_wc=np.stack([np.eye(3), R]),
                t_wc=np.stack([np.zeros(3), t]), static_mask=np.ones((2, H, W), bool), track_prev=no_tracks,
                track_curr=no_tracks, track_vis=np.ones((1, 1), bool), track_conf=np.ones((1, 1), np.float32))
    return clip, R, t


def slanting_plane_depth_error(engine: str, config: SGCConfig) -> float:
    """The depth error [%] of ``slanting_plane_clip``'s pair, warped with its exact cameras."""
    clip, R, t = slanting_plane_clip()
    if engine == "reference":
        return reference.pair_depth_error(clip, 1, R, t, config)[1]
    as_pairs = (clip.depth, clip.static_mask, np.array([0], np.int32), clip.K[:1].astype(np.float32),
                clip.K[1:].astype(np.float32), R[None].astype(np.float32), t[None].astype(np.float32),
                np.array([clip.image_size], np.int32), np.array([True]))
    stage = FinishStage.of(config, vectorized=False)
    return float(jax.jit(pair_depth_errors, static_argnames="stage")(*as_pairs, stage=stage)[0])


@pytest.mark.parametrize("engine", ["jax", "reference"])
def test_a_slanting_plane_reads_no_depth_error_at_each_points_own_position(engine):
    assert slanting_plane_depth_error(engine, SGCConfig(depth_check_at="point")) < EXACT_PLANE_PERCENT


@pytest.mark.parametrize("engine", ["jax", "reference"])
def test_at_the_pixel_it_rounds_to_a_slanting_plane_reads_the_rounding(engine):
    # the rounding moves a point by up to half a pixel along a depth gradient of 1-2 % a pixel
    assert 0.1 < slanting_plane_depth_error(engine, SGCConfig()) < 1.0


def plane_depth_at(normal, offset, u, v):
    """The depth of the plane normal . X = offset at the (sub-pixel) positions (u, v) through K."""
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1)
    return offset / (rays @ normal)


@pytest.mark.parametrize("engine", ["jax", "reference"])
def test_a_point_is_read_at_its_own_position_only_where_its_four_pixels_lie_on_one_compared_surface(engine):
    normal = np.array([0.1, 0.5, 1.0]) / np.linalg.norm([0.1, 0.5, 1.0])
    depth = plane_depth(K, normal, 1.0)  # 0.9-1.5, 1-2 % a pixel row
    depth[10:14, 12:16] = 0.5  # a nearer surface: its edge spans far more than DEPTH_EDGE_RATIO
    depth[3, 5] = 0.0  # no reading
    comparable = depth > 0
    comparable[18, 20] = False  # masked as moving
    # (u, v): on the plane, across the nearer surface's edge, beside the pixel with no reading, beside
    # the masked one, and past the last column (no four pixels around it)
    u = np.array([25.3, 11.5, 4.6, 19.8, W - 0.7])
    v = np.array([5.7, 11.2, 2.4, 17.9, 6.0])
    z = np.full(5, 1.25)  # as float32 too
    if engine == "jax":
        read = np.asarray(warp.at_pixel_centre(*(a.astype(np.float32) for a in (u, v, z)), np.ones(5, bool),
                                               depth.astype(np.float32), comparable), np.float64)
    else:
        read = reference.at_pixel_centre(u, v, z, depth, comparable)
    on_plane = z[0] * depth[6, 25] / plane_depth_at(normal, 1.0, u[0], v[0])  # carried to pixel (25, 6)'s centre
    np.testing.assert_allclose(read[0], on_plane, rtol=Z_RTOL)
    assert abs(read[0] - z[0]) > 100 * Z_RTOL * z[0]  # the carry is no rounding: 0.4 px along 1-2 % a pixel
    np.testing.assert_array_equal(read[1:], z[1:])


@pytest.mark.parametrize("nearest", [True, False])
def test_matches_a_numpy_loop_on_a_random_case(nearest):
    rng = np.random.default_rng(1)
    depth = rng.uniform(1.0, 4.0, (H, W)).astype(np.float32)
    depth[rng.random((H, W)) < 0.1] = 0.0
    K_curr = (K * np.array([[1.1], [0.9], [1.0]])).astype(np.float32)
    R = np.asarray(so3_exp(np.array([0.05, -0.1, 0.08], np.float32)), np.float64)
    t = np.array([0.3, -0.2, 0.4])
    expected, expected_hit = loop_warp(depth, K, K_curr, R, t, nearest)
    warped, hit = warp_depth(depth, depth > 0, K, K_curr, R.astype(np.float32), t.astype(np.float32),
                             nearest=nearest)
    warped, hit = np.asarray(warped), np.asarray(hit)
    assert 0.3 * H * W < expected_hit.sum() < H * W  # partial overlap with collisions and holes
    np.testing.assert_array_equal(hit, expected_hit)
    np.testing.assert_allclose(warped, expected, rtol=Z_RTOL)


def test_points_behind_the_camera_are_dropped():
    depth = np.full((H, W), 2.0, np.float32)
    warped, hit = warp_depth(depth, depth > 0, K, K, I3, np.array([0, 0, -3.0], np.float32))
    assert not np.asarray(hit).any() and not np.asarray(warped).any()


def test_depth_error_is_masked_and_nan_without_overlap():
    warped = np.array([[2.0, 3.0], [0.0, 5.0]], np.float32)
    hit = warped > 0
    curr = np.array([[2.5, 1.0], [4.0, np.nan]], np.float32)
    static = np.array([[True, True], [True, True]])
    err, n = depth_error(warped, hit, curr, np.isfinite(curr) & (curr > 0), static)
    assert int(n) == 2 and float(err) == pytest.approx((0.5 + 2.0) / 2)
    err, n = depth_error(warped, hit, curr, np.isfinite(curr), static & np.array([[False, True], [True, True]]))
    assert int(n) == 1 and float(err) == pytest.approx(2.0)
    err, n = depth_error(warped, hit, curr, np.isfinite(curr), np.zeros((2, 2), bool))
    assert int(n) == 0 and np.isnan(float(err))


@pytest.mark.parametrize("n", [0, 1, 2, 7, 1000])
def test_masked_median_is_the_middle_of_the_selected_values(n):
    rng = np.random.default_rng(n)
    values = rng.lognormal(size=1000).astype(np.float32)
    values[:300] = values[-1]  # ties across the middle
    mask = np.zeros(1000, bool)
    mask[rng.permutation(1000)[:n]] = True
    expected = np.median(values[mask]) if n else np.nan
    np.testing.assert_array_equal(float(masked_median(values, mask)), expected)


pair_depth_map = jax.jit(depth_map.pair_depth_map)
# The engines run the same reweighted least squares, in float32 and float64: their maps agree to
# float32 rounding of the sums. Against the exact map, β is shrunk by about DEPTH_MAP_DAMPING x z̄² /
# Var(z) (1.0e-3 on these depths, 1-3 apart, weighted towards the near ones).
ENGINES_RTOL = 1e-5
EXACT_MAP_RTOL = 2e-3


def test_the_pairs_depth_map_is_the_least_absolute_relative_error_where_it_fits_far_better():
    rng = np.random.default_rng(3)
    warped = rng.uniform(1.0, 3.0, (40, 48)).astype(np.float32)
    depth = (1.03 * warped + 0.05).astype(np.float32)
    depth[rng.random(depth.shape) < 0.2] *= 2.0  # a fifth of the pixels disagree: the map keeps 1.03, 0.05
    both = rng.random(depth.shape) < 0.8
    jax_map, reference_map = np.asarray(pair_depth_map(warped, depth, both)), np.array(reference.pair_depth_map(warped, depth, both))
    np.testing.assert_allclose(jax_map, reference_map, rtol=ENGINES_RTOL)
    np.testing.assert_allclose(reference_map, [1.03, 0.05], rtol=EXACT_MAP_RTOL)
    few = np.zeros_like(both)
    rows, cols = np.nonzero(np.ones_like(few[::DEPTH_SCALE_STRIDE, ::DEPTH_SCALE_STRIDE]))
    few[rows[:DEPTH_SCALE_MIN_PIXELS - 1] * DEPTH_SCALE_STRIDE, cols[:DEPTH_SCALE_MIN_PIXELS - 1] * DEPTH_SCALE_STRIDE] = True
    assert few[::DEPTH_SCALE_STRIDE, ::DEPTH_SCALE_STRIDE].sum() == DEPTH_SCALE_MIN_PIXELS - 1
    assert tuple(np.asarray(pair_depth_map(warped, depth, few))) == reference.pair_depth_map(warped, depth, few) == (1.0, 0.0)


def test_a_shift_of_the_whole_frame_is_read_up_to_but_a_part_moved_in_depth_is_not():
    warped = np.broadcast_to(np.linspace(2.0, 10.0, 48, dtype=np.float32), (40, 48))  # a floor running away
    shifted = (warped + 0.3).astype(np.float32)
    near_farther = np.where(warped < 3.6, 1.1 * warped, warped).astype(np.float32)  # the nearest fifth
    both = np.ones((40, 48), bool)
    for depth, expected in ((shifted, (1.0, 0.3)), (near_farther, (1.0, 0.0))):
        jax_map, reference_map = np.asarray(pair_depth_map(warped, depth, both)), reference.pair_depth_map(warped, depth, both)
        np.testing.assert_allclose(jax_map, reference_map, rtol=ENGINES_RTOL, atol=ENGINES_RTOL)
        np.testing.assert_allclose(reference_map, expected, rtol=EXACT_MAP_RTOL, atol=EXACT_MAP_RTOL)


def test_a_pair_whose_compared_depths_do_not_vary_keeps_the_scale_alone():
    warped = np.full((40, 48), 2.0, np.float32)
    depth = np.full((40, 48), 2.06, np.float32)
    both = np.ones((40, 48), bool)
    for scale, offset in (np.asarray(pair_depth_map(warped, depth, both)), reference.pair_depth_map(warped, depth, both)):
        assert scale * 2.0 + offset == pytest.approx(2.06, rel=1e-6)
        assert abs(offset) < 1e-2 * abs(scale * 2.0)  # a scale, not a shift, carries the fit


def test_batch_of_pairs_equals_loop():
    rng = np.random.default_rng(2)
    depth = rng.uniform(1.0, 4.0, (3, H, W)).astype(np.float32)
    rot = np.asarray(so3_exp(rng.normal(0, 0.05, (3, 3)).astype(np.float32)))
    t = rng.normal(0, 0.1, (3, 3)).astype(np.float32)
    Ks = np.broadcast_to(K, (3, 3, 3))
    batch = jax.vmap(warp_depth)(depth, depth > 0, Ks, Ks, rot, t)
    for i in range(3):
        single = warp_depth(depth[i], depth[i] > 0, K, K, rot[i], t[i])
        np.testing.assert_array_equal(np.asarray(batch[0][i]), np.asarray(single[0]))
        np.testing.assert_array_equal(np.asarray(batch[1][i]), np.asarray(single[1]))


def near_square_over_background():
    """A fronto-parallel square at depth 2 in front of a wall at depth 8, and a forward motion of
    1 (the square is magnified 2x, the wall 8/7x) -> (depth0, t, square_interior, wall): the last
    two are frame-1 masks at least 1.5 px from the square's edge there (half-width 9 px)."""
    v, u = np.mgrid[:H, :W]
    square = lambda half: (np.abs(u - K[0, 2]) <= half) & (np.abs(v - K[1, 2]) <= half)  # noqa: E731
    depth0 = np.where(square(4.5), 2.0, 8.0).astype(np.float32)
    return depth0, np.array([0.0, 0.0, -1.0], np.float32), square(7.5), ~square(10.5)


def test_a_magnified_surface_leaves_holes_through_which_the_background_shows():
    depth0, t, interior, _ = near_square_over_background()
    warped, hit = map(np.asarray, warp_depth(depth0, depth0 > 0, K, K, I3, t))
    assert np.any(warped[interior & hit] == 7.0)  # wall points in the square's holes: errors of 600%


@pytest.mark.parametrize("engine", ["jax", "reference"])
def test_hole_rule_discards_what_is_seen_through_a_nearer_surface(engine):
    depth0, t, interior, wall = near_square_over_background()
    if engine == "jax":
        warped, hit = map(np.asarray, warp_depth(depth0, depth0 > 0, K, K, I3, t, mask_holes=True))
    else:
        warped = reference.warp_depth(depth0, K, K, np.eye(3), t.astype(np.float64), mask_holes=True)
        hit = warped > 0
    assert hit[interior].any() and hit[wall].any()
    np.testing.assert_allclose(warped[interior & hit], 1.0, rtol=Z_RTOL)
    np.testing.assert_allclose(warped[wall & hit], 7.0, rtol=Z_RTOL)


def test_hole_rule_keeps_every_pixel_of_a_smooth_surface():
    normal = np.array([0.1, -0.3, 1.0]) / np.linalg.norm([0.1, -0.3, 1.0])
    depth0 = plane_depth(K, normal, 5.0).astype(np.float32)
    R = np.asarray(so3_exp(np.radians(np.array([0.5, -1.0, 0.3], np.float32))))
    t = np.array([0.05, -0.02, -0.4], np.float32)
    plain = np.asarray(warp_depth(depth0, depth0 > 0, K, K, R, t)[1])
    masked = np.asarray(warp_depth(depth0, depth0 > 0, K, K, R, t, mask_holes=True)[1])
    np.testing.assert_array_equal(masked, plain)


def random_points(rng, n, Hc, Wc, magnifications):
    """n random front (90 %) points around and beyond an (Hc, Wc) image, magnified as drawn."""
    u = rng.uniform(-40.0, Wc + 40.0, n).astype(np.float32)
    v = rng.uniform(-40.0, Hc + 40.0, n).astype(np.float32)
    u[:4], v[:4] = [-1.0, Wc - 1e-3, np.nan, -2.5], [-0.5, Hc - 0.5, 1.0, 2.0]  # edges, NaN, out by a little
    z = rng.uniform(0.1, 5.0, n).astype(np.float32)
    front = (rng.uniform(size=n) > 0.1) & np.isfinite(u)
    return warp.Splat(np.zeros(n, np.int32), z, u, v, front, magnifications.astype(np.float32))


def reference_cover(points, Hc, Wc):
    on = points.front
    return reference.depth_check._hole_cover(np.stack([points.u, points.v])[:, on].astype(np.float64),
                                             points.z[on].astype(np.float64), points.magnification[on].astype(np.float64), Hc, Wc)


@pytest.mark.parametrize("largest_level", [0, warp.HOLE_LEVELS + 1])
def test_hole_cover_matches_the_reference(largest_level):
    rng = np.random.default_rng(11 + largest_level)
    Hc, Wc, n = 40, 56, 600
    points = random_points(rng, n, Hc, Wc, np.exp2(rng.uniform(-1.0, largest_level + 1.0, n)))
    cover = jax.jit(warp._hole_cover, static_argnums=(1, 2))(points, Hc, Wc)
    np.testing.assert_array_equal(np.asarray(cover).reshape(Hc, Wc), reference_cover(points, Hc, Wc).astype(np.float32))


def documented_reach(magnification):
    """docs/semantics.md §3.6 step 3: the magnification, at least 1 and at most the largest reach."""
    return min(max(magnification, 1.0), warp.MAX_HOLE_REACH_PX)


@pytest.mark.parametrize("engine", ["jax", "reference"])
def test_a_point_covers_the_pixels_within_its_reach(engine):
    rng = np.random.default_rng(8)
    Hc = Wc = 160
    rows, cols = np.mgrid[:Hc, :Wc]
    for magnification in np.exp2(rng.uniform(-1.0, 5.0, 24)):
        u, v = rng.uniform(60.0, 100.0, 2)
        points = warp.Splat(np.zeros(1, np.int32), np.ones(1, np.float32), np.float32([u]), np.float32([v]),
                            np.ones(1, bool), np.float32([magnification]))
        if engine == "jax":
            cover = np.asarray(jax.jit(warp._hole_cover, static_argnums=(1, 2))(points, Hc, Wc)).reshape(Hc, Wc)
        else:
            cover = reference_cover(points, Hc, Wc)
        r = documented_reach(magnification)
        within = (cols > u - r) & (cols <= u + r) & (rows > v - r) & (rows <= v + r)
        np.testing.assert_array_equal(np.isfinite(cover), within, err_msg=f"m = {magnification}")


def approach_to_a_square(magnification):
    """A fronto-parallel square at depth 2 before a wall at depth 8 on a 48x64 image, and the
    forward motion that magnifies the square ``magnification`` times to about 34 px a side ->
    (depth0, K, t, square, wall): frame-1 masks of the square 1 px within its edge and of the wall
    2 px beyond it there."""
    K2 = np.array([[60.0, 0.0, 31.5], [0.0, 60.0, 23.5], [0.0, 0.0, 1.0]], np.float32)
    v, u = np.mgrid[:48, :64]
    square = lambda half: (np.abs(u - K2[0, 2]) <= half) & (np.abs(v - K2[1, 2]) <= half)  # noqa: E731
    half = np.floor(16.0 / magnification) + 0.5
    depth0 = np.where(square(half), 2.0, 8.0).astype(np.float32)
    t = np.array([0.0, 0.0, -(2.0 - 2.0 / magnification)], np.float32)
    half *= magnification
    return depth0, K2, t, square(half - 1.0), ~square(half + 2.0)


@pytest.mark.parametrize("engine", ["jax", "reference"])
@pytest.mark.parametrize("magnification", [3.0, 5.0, 12.0])
def test_no_background_shows_through_a_surface_magnified_many_times(engine, magnification):
    depth0, K2, t, square, wall = approach_to_a_square(magnification)
    if engine == "jax":
        warped, hit = map(np.asarray, warp_depth(depth0, depth0 > 0, K2, K2, I3, t, mask_holes=True))
    else:
        warped = reference.warp_depth(depth0, K2, K2, np.eye(3), t.astype(np.float64), mask_holes=True)
        hit = warped > 0
    near = 2.0 / magnification
    assert hit[square].any() and hit[wall].any()
    np.testing.assert_allclose(warped[square & hit], near, rtol=Z_RTOL)  # the square's own splats only
    np.testing.assert_allclose(warped[wall & hit], 8.0 + t[2], rtol=Z_RTOL)


def approach_to_a_square_edge(magnification):
    """A fronto-parallel square at depth 2 before a wall at depth 8 on a 48x64 image, its true edge
    0.95 px beyond its last pixel centres (the next centres lie on the wall), and the forward motion
    that magnifies it ``magnification`` times -> (depth0, K, t, frame-1 mask of the true square)."""
    K2 = np.array([[60.0, 0.0, 31.5], [0.0, 60.0, 23.5], [0.0, 0.0, 1.0]], np.float32)
    v, u = np.mgrid[:48, :64]
    square = lambda half: (np.abs(u - K2[0, 2]) <= half) & (np.abs(v - K2[1, 2]) <= half)  # noqa: E731
    half = np.floor(14.0 / magnification) + 0.5 + 0.95
    depth0 = np.where(square(half), 2.0, 8.0).astype(np.float32)
    t = np.array([0.0, 0.0, -(2.0 - 2.0 / magnification)], np.float32)
    return depth0, K2, t, square(half * magnification)


@pytest.mark.parametrize("engine", ["jax", "reference"])
@pytest.mark.parametrize("magnification", [1.5, 2.2, 5.0])
def test_the_wall_does_not_show_where_a_magnified_square_grows_beyond_its_splats(engine, magnification):
    depth0, K2, t, square = approach_to_a_square_edge(magnification)
    plain, plain_hit = map(np.asarray, warp_depth(depth0, depth0 > 0, K2, K2, I3, t))
    assert np.any(plain[square & plain_hit] > 2.0)  # without the rule the wall lands inside the square's edge
    if engine == "jax":
        warped, hit = map(np.asarray, warp_depth(depth0, depth0 > 0, K2, K2, I3, t, mask_holes=True))
    else:
        warped = reference.warp_depth(depth0, K2, K2, np.eye(3), t.astype(np.float64), mask_holes=True)
        hit = warped > 0
    assert hit[square].any() and hit[~square].any()
    np.testing.assert_allclose(warped[square & hit], 2.0 / magnification, rtol=Z_RTOL)


def test_the_larger_squares_change_nothing_where_no_point_comes_2x_nearer():
    has_magnified = jax.jit(warp.has_magnified)
    for magnification, t in ((1.5, None), (3.0, None), (1.0, np.array([0.2, -0.1, -0.3], np.float32))):
        depth0, K2, t_square, _ = approach_to_a_square_edge(magnification)
        t = t_square if t is None else t
        full, small = (np.asarray(warp_depth(depth0, depth0 > 0, K2, K2, I3, t, mask_holes=True, magnified=m)[1])
                       for m in (True, False))
        assert bool(has_magnified(depth0, depth0 > 0, K2, K2, I3, t)) == (magnification >= 2.0)
        if magnification < 2.0:
            np.testing.assert_array_equal(small, full)
        else:
            assert (small & ~full).any()  # without them the wall shows beyond the square's splats


def entering_square():
    """A wall at depth 8 and, in frame 1 only, a square at depth 2 in the last 6 columns that frame 0
    could not see: the camera moved 0.4 to the right, shifting the square 6 px and the wall 1.5 px
    -> (depth0, depth1, t, square)."""
    depth0 = np.full((H, W), 8.0, np.float32)
    square = np.zeros((H, W), bool)
    square[8:16, W - 6:] = True
    depth1 = np.where(square, 2.0, 8.0).astype(np.float32)
    return depth0, depth1, np.array([-0.4, 0.0, 0.0], np.float32), square


@pytest.mark.parametrize("engine", ["jax", "reference"])
def test_a_surface_entering_the_view_is_not_compared_with_what_it_covers(engine):
    depth0, depth1, t, square = entering_square()
    if engine == "jax":
        warped, hit = map(np.asarray, warp_depth(depth0, depth0 > 0, K, K, I3, t, mask_holes=True))
        seen = np.asarray(warp.previous_view(depth1, depth1 > 0, K, K, I3, t).seen)
    else:
        warped = reference.warp_depth(depth0, K, K, np.eye(3), t.astype(np.float64), mask_holes=True)
        hit, seen = warped > 0, reference.seen_from_previous(depth1, K, K, np.eye(3), t.astype(np.float64))
    assert np.any(hit & square)  # the wall frame 0 saw lands where the square now is: 300 % errors
    np.testing.assert_array_equal(seen[square], False)
    assert seen[:, : W - 2][~square[:, : W - 2]].all()  # the wall frame 0 saw, but for its last 1.5 px
    compared = hit & seen
    np.testing.assert_allclose(warped[compared], depth1[compared], rtol=Z_RTOL)


def square_frame_i_minus_1_did_not_warp(gap: str):
    """A wall at depth 8 and a square at depth 2 in both frames, the camera moved 0.4 to the right
    (the square shifts 12 px, the wall 3 px); frame 0 does not warp the square: its depth there is
    invalid (``gap`` "invalid_depth", a sensor's dropout) or masked as a moving object ("mask")
    -> a two-frame Clip."""
    f = 60.0
    Kc = np.array([[f, 0.0, 15.5], [0.0, f, 11.5], [0.0, 0.0, 1.0]])
    depth = np.full((2, H, W), 8.0, np.float32)
    static = np.ones((2, H, W), bool)
    depth[:, 8:16, 14:22] = 2.0
    depth[1] = np.full((H, W), 8.0, np.float32)
    depth[1, 8:16, 2:10] = 2.0
    if gap == "invalid_depth":
        depth[0, 8:16, 14:22] = 0.0
    else:
        static[0, 8:16, 14:22] = False
    no_tracks = np.zeros((1, 1, 2), np.float32)
    return Clip(clip_id="gap", depth=depth, K=np.stack([Kc, Kc]), R_wc=np.stack([np.eye(3)] * 2),
                t_wc=np.array([[0.0, 0.0, 0.0], [-0.4, 0.0, 0.0]]), static_mask=static, track_prev=no_tracks,
                track_curr=no_tracks, track_vis=np.ones((1, 1), bool), track_conf=np.ones((1, 1), np.float32))


@pytest.mark.parametrize("vectorized", [False, True])
@pytest.mark.parametrize("gap", ["invalid_depth", "mask"])
def test_a_surface_frame_i_minus_1_did_not_warp_is_not_compared_with_what_lands_on_it(gap, vectorized):
    clip = square_frame_i_minus_1_did_not_warp(gap)
    R, t = np.eye(3), clip.t_wc[1]
    warped = reference.warp_depth(reference.warp_source(clip, 1, SGCConfig()), clip.K[0], clip.K[1], R, t,
                                  mask_holes=True)
    square = clip.depth[1] == 2.0
    assert (warped[square] == 8.0).sum() >= 8  # the wall frame 0 saw beside the gap lands on the square: 300 %
    expected = reference.pair_depth_error(clip, 1, R, t, SGCConfig())[1]
    assert expected < 1e-4  # only the wall, compared with itself
    as_pairs = (clip.depth, clip.static_mask, np.array([0], np.int32), clip.K[:1].astype(np.float32),
                clip.K[1:].astype(np.float32), R[None].astype(np.float32), t[None].astype(np.float32),
                np.array([clip.image_size], np.int32), np.array([True]))
    stage = FinishStage.of(SGCConfig(), vectorized=vectorized)
    got = float(jax.jit(pair_depth_errors, static_argnames="stage")(*as_pairs, stage=stage)[0])
    assert got < 1e-4


def card_behind_a_post(card_factor: float = 1.0):
    """A wall at depth 8, a card at depth 2 (frame 0's columns 22-49) and a post at depth 1 (columns
    20-27) in front of the card's left edge; the camera moved 0.38 to the right (the post shifts
    11.4 px, the card 5.7, the wall 1.4: no splat on a half pixel). In frame 1 the post has left the
    card's edge, and the wall frame 0 saw beside the post lands on card pixels frame 0 saw only as
    the post. ``card_factor``: frame 0's card that many times its true depth (a depth
    inconsistency) -> a two-frame Clip."""
    Hc, Wc, f = 24, 64, 30.0
    Kc = np.array([[f, 0.0, 31.5], [0.0, f, 11.5], [0.0, 0.0, 1.0]])
    depth = np.full((2, Hc, Wc), 8.0, np.float32)
    depth[0, 6:18, 22:50] = 2.0 * card_factor
    depth[0, 4:20, 20:28] = 1.0
    depth[1, :, :] = 8.0
    depth[1, 6:18, 16:44] = 2.0
    depth[1, 4:20, 9:17] = 1.0
    no_tracks = np.zeros((1, 1, 2), np.float32)
    return Clip(clip_id="post", depth=depth, K=np.stack([Kc, Kc]), R_wc=np.stack([np.eye(3)] * 2),
                t_wc=np.array([[0.0, 0.0, 0.0], [-0.38, 0.0, 0.0]]), static_mask=np.ones((2, Hc, Wc), bool),
                track_prev=no_tracks, track_curr=no_tracks, track_vis=np.ones((1, 1), bool),
                track_conf=np.ones((1, 1), np.float32))


def jax_pair_depth_error(clip, vectorized: bool) -> float:
    """The JAX engine's depth error [%] of a two-frame clip's pair, warped with its cameras."""
    R, t = np.eye(3, dtype=np.float32), clip.t_wc[1].astype(np.float32)
    as_pairs = (clip.depth, clip.static_mask, np.array([0], np.int32), clip.K[:1].astype(np.float32),
                clip.K[1:].astype(np.float32), R[None], t[None], np.array([clip.image_size], np.int32),
                np.array([True]))
    stage = FinishStage.of(SGCConfig(), vectorized=vectorized)
    return float(jax.jit(pair_depth_errors, static_argnames="stage")(*as_pairs, stage=stage)[0])


@pytest.mark.parametrize("vectorized", [False, True])
def test_a_surface_frame_i_minus_1_saw_behind_a_nearer_one_is_not_compared_with_what_lands_on_it(vectorized):
    clip = card_behind_a_post()
    R, t = np.eye(3), clip.t_wc[1]
    warped = reference.warp_depth(clip.depth[0], clip.K[0], clip.K[1], R, t, mask_holes=True)
    card = clip.depth[1] == 2.0
    assert (warped[card] == 8.0).sum() >= 12  # the wall frame 0 saw beside the post lands on the card: 300 %
    assert forward_only_depth_error(clip) > 2.0
    expected = reference.pair_depth_error(clip, 1, R, t, SGCConfig())[1]
    assert expected < 1e-4  # what frame 0 saw, compared with itself
    assert jax_pair_depth_error(clip, vectorized) < 1e-4


@pytest.mark.parametrize("card_factor", [0.8, 1.25])
def test_a_surface_too_near_or_too_far_in_frame_i_minus_1_keeps_its_error_beside_a_post(card_factor):
    clip, consistent = card_behind_a_post(card_factor), card_behind_a_post()
    R, t = np.eye(3), clip.t_wc[1]
    expected = reference.pair_depth_error(clip, 1, R, t, SGCConfig())[1]
    assert expected > 1.0
    # what the rule leaves out of the pair's mean is the consistent clip's wall-on-card error, no more
    left_out = forward_only_depth_error(clip) - expected
    assert left_out <= forward_only_depth_error(consistent) - reference.pair_depth_error(consistent, 1, R, t, SGCConfig())[1]
    np.testing.assert_allclose(jax_pair_depth_error(clip, vectorized=False), expected, rtol=Z_RTOL)


# pixels that float32 rounds to the other side of a half-pixel than float64 does
SEEN_ROUNDING_PIXELS = 2


def tilted_plane_seen(depth1):
    """(R, t) of a camera move that leaves part of the plane depth1 (H, W) outside frame i-1, and
    the reference engine's ``seen_from_previous`` of it (H, W)."""
    R = np.asarray(so3_exp(np.radians(np.array([2.0, -6.0, 1.0], np.float32))))
    t = np.array([0.6, -0.3, 0.5], np.float32)
    expected = reference.seen_from_previous(depth1, K.astype(np.float64), K.astype(np.float64), R.astype(np.float64),
                                            t.astype(np.float64))
    return R, t, expected


def tilted_plane():
    normal = np.array([0.2, -0.1, 1.0]) / np.linalg.norm([0.2, -0.1, 1.0])
    return plane_depth(K, normal, 3.0).astype(np.float32)


def test_seen_from_previous_agrees_between_the_engines():
    depth1 = tilted_plane()
    depth1[:3, :5] = 0.0  # invalid pixels are never seen
    R, t, expected = tilted_plane_seen(depth1)
    seen = np.asarray(warp.previous_view(depth1, depth1 > 0, K, K, R, t).seen)
    assert 0.2 < expected.mean() < 0.95 and not expected[:3, :5].any()
    assert np.sum(seen != expected) <= SEEN_ROUNDING_PIXELS


def test_padding_is_no_part_of_what_frame_i_minus_1_saw():
    """A clip padded to its shape bucket: a point that frame i-1 would see only in the padding
    rows or columns was not seen (the reference engine works on the true size)."""
    depth1 = tilted_plane()
    H, W = depth1.shape
    R, t, expected = tilted_plane_seen(depth1)
    padded = np.zeros((H + 8, W + 8), np.float32)
    padded[:H, :W] = depth1
    seen = np.asarray(warp.previous_view(padded, padded > 0, K, K, R, t, np.array([H, W], np.int32)).seen)
    assert not seen[H:].any() and not seen[:, W:].any()
    assert np.sum(seen[:H, :W] != expected) <= SEEN_ROUNDING_PIXELS
    unbounded = np.asarray(warp.previous_view(padded, padded > 0, K, K, R, t).seen)
    assert np.sum(unbounded[:H, :W] & ~expected) > 20  # what the padding would have let through


def card_whose_depth_errs_in_frame_i_minus_1(card_depth: float):
    """A wall at depth 10 and a card (rows 6-17) at ``card_depth``, the camera moved 0.4 to the right
    (the card shifts 0.4 f / card_depth px): frame i exact, frame i-1's card 30 % too far, so its
    warp falls short and the wall's splats land on the card's leading columns in frame i -> a
    two-frame Clip with R_wc, t_wc of the move."""
    Hc, Wc, f = 24, 64, 30.0
    Kc = np.array([[f, 0.0, 31.5], [0.0, f, 11.5], [0.0, 0.0, 1.0]])
    shift = int(round(f * 0.4 / card_depth))
    depth = np.full((2, Hc, Wc), 10.0, np.float32)
    depth[0, 6:18, 40:56] = 1.3 * card_depth
    depth[1, 6:18, 40 - shift:56 - shift] = card_depth
    no_tracks = np.zeros((1, 1, 2), np.float32)
    return Clip(clip_id="card", depth=depth, K=np.stack([Kc, Kc]), R_wc=np.stack([np.eye(3)] * 2),
                          t_wc=np.array([[0.0, 0.0, 0.0], [-0.4, 0.0, 0.0]]), static_mask=np.ones((2, Hc, Wc), bool),
                          track_prev=no_tracks, track_curr=no_tracks, track_vis=np.ones((1, 1), bool),
                          track_conf=np.ones((1, 1), np.float32))


def forward_only_depth_error(clip) -> float:
    """The pair's depth error [%] with no look back into frame i-1 (§3.6 steps 1-4 alone)."""
    R, t = np.eye(3), clip.t_wc[1]
    warped = reference.warp_depth(clip.depth[0], clip.K[0], clip.K[1], R, t, mask_holes=True)
    warped = np.where(reference.seen_from_previous(clip.depth[1], clip.K[0], clip.K[1], R, t), warped, 0.0)
    return 100.0 * reference.depth_error(warped, clip.depth[1], clip.static_mask[1], relative=True)


@pytest.mark.parametrize("vectorized", [False, True])
@pytest.mark.parametrize("card_depth", [0.5, 2.0])
def test_frame_i_minus_1_is_looked_up_only_where_the_warp_put_a_surface_10x_farther(card_depth, vectorized):
    clip = card_whose_depth_errs_in_frame_i_minus_1(card_depth)
    R, t = np.eye(3), clip.t_wc[1]
    expected = reference.pair_depth_error(clip, 1, R, t, SGCConfig())[1]
    as_pairs = (clip.depth[:2], clip.static_mask[:2], np.array([0], np.int32), clip.K[:1].astype(np.float32),
                clip.K[1:2].astype(np.float32), R[None].astype(np.float32), t[None].astype(np.float32),
                np.array([clip.image_size], np.int32), np.array([True]))
    stage = FinishStage.of(SGCConfig(), vectorized=vectorized)
    got = float(jax.jit(pair_depth_errors, static_argnames="stage")(*as_pairs, stage=stage)[0])
    np.testing.assert_allclose(got, expected, rtol=Z_RTOL)
    forward = forward_only_depth_error(clip)
    if card_depth == 0.5:  # the wall 20x farther: 60 pixels at 1,900 % (96 % for the pair) read 30 % instead
        assert forward > 50.0 and expected < 0.2 * forward
    else:  # the wall 5x farther: its bounded error (400 %) stands
        assert expected == pytest.approx(forward, rel=1e-12)


def test_the_depth_warp_error_map_reads_frame_i_minus_1_where_the_score_does():
    """``research.diagnostics.depth_warp_error``'s map holds each pixel's error as the pair's mean
    counts it: the wall's splats on the card read 30 %, not 1,900 % (§3.6 step 5)."""
    clip = card_whose_depth_errs_in_frame_i_minus_1(0.5)
    check = diagnostics.depth_warp_error(clip, 1)
    assert np.nanmean(check.error) == pytest.approx(check.mean, rel=1e-9)
    assert np.nanmax(check.error) < 100.0  # forward only, 60 of its pixels at 1,900 %
