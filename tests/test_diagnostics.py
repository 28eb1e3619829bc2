"""sgc_jax.research.diagnostics: per-pair quantities behind the diagnostic figures, checked against the
scored PairArrays and against known geometry (true poses of synthetic scenes)."""

import dataclasses

import numpy as np
import pytest

from sgc_jax import SGCConfig
from sgc_jax.codes import REGION_STATUS
from sgc_jax.engines import reference
from sgc_jax.io.clip import relative_poses
from sgc_jax.research import diagnostics

PAIR = 2
ACCEPTED = REGION_STATUS["ok"]


@pytest.fixture(scope="module")
def rigid_pairs(rigid_clip):
    return reference.score_pairs(rigid_clip)


@pytest.fixture(scope="module")
def drift_pairs(drift_clip):
    return reference.score_pairs(drift_clip)


def _with_true_poses(clip, pairs):
    """The scored pairs with every accepted region's pose replaced by the camera's true relative
    pose (its translation in the engines' units of D)."""
    R_rel, t_rel = relative_poses(clip)
    t_rel = t_rel / pairs.depth_unit
    accepted = pairs.region_status == ACCEPTED
    R = np.where(accepted[..., None, None], R_rel[:, None], np.nan)
    t = np.where(accepted[..., None], t_rel[:, None], np.nan)
    return dataclasses.replace(pairs, R_local=R, t_local=t)


def test_region_labels_have_the_scored_number_of_regions(rigid_clip, rigid_pairs):
    labels = diagnostics.region_labels(rigid_clip, PAIR)
    assert labels.shape == rigid_clip.image_size
    assert labels.max() == rigid_pairs.n_regions[PAIR - 1]
    assert not labels[~rigid_clip.static_mask[PAIR]].any()


def test_region_tracks_count_the_scored_points_per_region(drift_clip, drift_pairs):
    tracks = diagnostics.region_tracks(drift_clip, PAIR)
    counts = np.bincount(tracks.region, minlength=drift_pairs.region_points.shape[1] + 1)[1:]
    np.testing.assert_array_equal(counts, drift_pairs.region_points[PAIR - 1])
    # uv_prev: the frame pair-1 positions of the usable tracks with depth, back-projected from
    usable = drift_clip.usable_tracks(SGCConfig().min_track_conf)[PAIR - 1]
    prev = drift_clip.track_prev[PAIR - 1][usable]
    depth = drift_clip.depth[PAIR - 1][np.floor(prev[:, 1]).astype(int), np.floor(prev[:, 0]).astype(int)]
    np.testing.assert_allclose(tracks.uv_prev, prev[depth > 0], atol=1e-3)


def test_true_poses_predict_the_global_motion_in_every_region(rigid_clip, rigid_pairs):
    flow = diagnostics.pose_flow(rigid_clip, _with_true_poses(rigid_clip, rigid_pairs), PAIR)
    ok = flow.accepted
    assert ok.sum() >= 3
    np.testing.assert_allclose(flow.local_px[ok], flow.global_px[ok], atol=1e-4)
    assert np.isnan(flow.local_px[~ok]).all()
    # a moving camera: the arrows are not all zero
    assert np.nanmax(np.linalg.norm(flow.global_px, axis=1)) > 0.5


def test_a_shifted_local_translation_moves_its_arrow_by_fx_dx_over_z(rigid_clip, rigid_pairs):
    pairs = _with_true_poses(rigid_clip, rigid_pairs)
    j = int(np.flatnonzero(pairs.region_status[PAIR - 1] == ACCEPTED)[0])
    dx = 0.05  # units of D along the camera x axis
    shifted = pairs.t_local.copy()
    shifted[PAIR - 1, j, 0] += dx
    before = diagnostics.pose_flow(rigid_clip, pairs, PAIR)
    after = diagnostics.pose_flow(rigid_clip, dataclasses.replace(pairs, t_local=shifted), PAIR)
    R_rel, t_rel = relative_poses(rigid_clip)
    z_new = (R_rel[PAIR - 1] @ before.anchor[j] + t_rel[PAIR - 1] / pairs.depth_unit)[2]  # anchor in units of D
    fx = rigid_clip.K[PAIR, 0, 0]
    np.testing.assert_allclose(after.local_px[j] - before.local_px[j], [fx * dx / z_new, 0.0], atol=1e-6)
    assert after.disagreement_px[j] == pytest.approx(fx * dx / z_new, rel=1e-6)
    others = np.arange(len(after.status)) != j
    np.testing.assert_array_equal(after.local_px[others], before.local_px[others])


def test_a_drifting_layer_parts_from_the_global_motion(drift_clip, drift_pairs):
    flow = diagnostics.pose_flow(drift_clip, drift_pairs, PAIR)
    gaps = flow.disagreement_px[flow.accepted]
    assert np.nanmax(gaps) > 1.0  # the drifting layer's regions move on their own
    assert np.nanmin(gaps) < 1e-2  # the rigid rest agrees with the camera


def test_depth_warp_error_mean_is_the_pairs_depth_error(drift_clip, drift_pairs):
    for pair in range(1, drift_clip.n_frames):
        warp = diagnostics.depth_warp_error(drift_clip, pair)
        # rel 1e-6: the result stores s in depth units per pose unit, so t_g comes back to 1 ulp,
        # which can move one pixel's rounding in the warp
        assert warp.mean == pytest.approx(drift_pairs.depth_error[pair - 1], rel=1e-6)
        assert np.nanmean(warp.error) == pytest.approx(warp.mean, rel=1e-9)
        assert not warp.compared[~drift_clip.static_mask[pair]].any()


def test_rigid_depth_warp_errs_only_at_occlusion_edges(rigid_clip):
    warp = diagnostics.depth_warp_error(rigid_clip, PAIR)
    assert warp.compared.sum() > 0.5 * rigid_clip.static_mask[PAIR].sum()
    relative = warp.error[warp.compared] / 100  # percent of depth (docs/semantics.md §3.6)
    assert np.median(relative) < 1e-3  # rounding to the nearest pixel on slanted surfaces
    assert np.mean(relative > 1e-2) < 0.05  # the rest: occlusion edges
    assert warp.error_unit == "% of depth"
    # the warped depth is in the clip's own depth units, as its depth maps are shown beside it
    ratio = warp.warped[warp.compared] / rigid_clip.depth[PAIR][warp.compared]
    assert np.median(ratio) == pytest.approx(1.0, abs=1e-3)


def test_region_reprojection_means_are_the_scored_ones(drift_clip, drift_pairs):
    reproj = diagnostics.region_reprojection(drift_clip, drift_pairs, PAIR)
    for j, status in enumerate(reproj.status):
        assert len(reproj.global_px[j]) == drift_pairs.region_points[PAIR - 1, j]
        if status == ACCEPTED:
            assert reproj.local_px[j].mean() == pytest.approx(drift_pairs.region_reproj[PAIR - 1, j], rel=1e-9)
        else:
            assert reproj.local_px[j].size == 0
    assert reproj.inlier_px == SGCConfig().inlier_px


def test_true_global_pose_reprojects_a_rigid_scene_exactly(rigid_clip, rigid_pairs):
    reproj = diagnostics.region_reprojection(rigid_clip, rigid_pairs, PAIR)
    errors = np.concatenate([g for g in reproj.global_px if len(g)])
    assert np.median(errors) < 1e-3


def test_global_pose_scale_multiplies_the_translation(rigid_clip):
    R1, t1 = diagnostics.global_pose(rigid_clip, PAIR)
    R2, t2 = diagnostics.global_pose(rigid_clip, PAIR, scale=2.5)
    np.testing.assert_array_equal(R1, R2)
    np.testing.assert_allclose(t2, 2.5 * t1)


@pytest.mark.parametrize("pair", [0, 4])
def test_a_pair_outside_the_clip_is_refused(rigid_clip, pair):
    with pytest.raises(ValueError, match="pair must be in 1..3"):
        diagnostics.depth_warp_error(rigid_clip, pair)


def test_a_label_map_that_does_not_match_the_result_warns(rigid_clip, rigid_pairs):
    n_regions = rigid_pairs.n_regions.copy()
    n_regions[PAIR - 1] -= 1
    with pytest.warns(RuntimeWarning, match="region slots may not line up"):
        diagnostics.pose_flow(rigid_clip, dataclasses.replace(rigid_pairs, n_regions=n_regions), PAIR)


def test_a_failed_clip_has_nothing_to_diagnose(rigid_clip):
    from sgc_jax.scoring.result import failed_clip

    with pytest.raises(ValueError, match="no per-pair arrays"):
        diagnostics.pose_flow(rigid_clip, failed_clip("rigid", "broken"), PAIR)
