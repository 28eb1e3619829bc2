"""The validation protocol (docs/semantics.md §7.4): its noise models deal the errors they name, and
its TEST split shares nothing with what the default score's constants were fitted on."""

from __future__ import annotations

import json
from importlib import resources

import numpy as np
import pytest
from scenes import DEMO_SCENE, SYNTH_SCENE
from tolerances import FLOOR_RATIO_RANGE

from sgc_jax import score_batch
from sgc_jax.research.corridor import CORRIDOR_SEEDS, Corridor, CorridorSpec
from sgc_jax.research.noise import (
    NOISE_MODELS,
    NoiseModel,
    add_noise,
    letterboxed,
    overlaid,
    radially_distorted,
    smooth_field,
)
from sgc_jax.research.perturb import PERTURBATIONS, perturb_clip
from sgc_jax.research.protocol import (
    FIT_POOL_SEEDS,
    FIT_SCENES,
    FIT_SEEDS,
    HELD_OUT_SEEDS,
    TEST_SCENES,
    TEST_SEEDS,
    UNSEEN_SEEDS,
    Cell,
    cell_clips,
    cells,
    detection_table,
    random_scene,
    rows_scored_or_read,
    tracks_on_mover,
)
from sgc_jax.research.synth import synth_clip

# Sampling tolerances: RMS over 2 x (T-1) x P = 1,536 draws (SYNTH_SCENE) is within 10 % of its
# value with probability > 0.999; correlation shares over >= 1,000 pairs of tracks within 0.1.
RMS_RTOL = 0.1
SHARE_ATOL = 0.1


@pytest.fixture(scope="module")
def exact_clip():
    return synth_clip(seed=3, clip_id="exact", n_layers=2, static_spheres=2, with_frames=False, **SYNTH_SCENE)


def rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(values.astype(np.float64) ** 2)))


def test_the_zero_model_changes_no_array(exact_clip):
    noisy = add_noise(exact_clip, NoiseModel(), seed=1)
    for name in ("track_prev", "track_curr", "track_vis", "depth", "R_wc", "t_wc"):
        np.testing.assert_array_equal(getattr(noisy, name), getattr(exact_clip, name))


def test_per_pair_queries_err_at_frame_i_only(exact_clip):
    noisy = add_noise(exact_clip, NOISE_MODELS["iid-curr"].replace(px=1.5), seed=1)
    np.testing.assert_array_equal(noisy.track_prev, exact_clip.track_prev)
    assert rms(noisy.track_curr - exact_clip.track_curr) == pytest.approx(1.5, rel=RMS_RTOL)


def test_long_range_tracks_err_at_both_ends_independently(exact_clip):
    noisy = add_noise(exact_clip, NOISE_MODELS["iid-both"].replace(px=1.5), seed=1)
    prev_error = noisy.track_prev - exact_clip.track_prev
    curr_error = noisy.track_curr - exact_clip.track_curr
    assert rms(prev_error) == pytest.approx(1.5, rel=RMS_RTOL)
    assert rms(curr_error) == pytest.approx(1.5, rel=RMS_RTOL)
    assert abs(np.corrcoef(prev_error.ravel(), curr_error.ravel())[0, 1]) < SHARE_ATOL


def shared_share(errors: np.ndarray, positions: np.ndarray, lo: float, hi: float) -> float:
    """Mean product of the errors of two tracks of one pair lo..hi px apart, over the mean square
    error; errors and positions (pairs, P, 2)."""
    products = []
    for e, p in zip(errors, positions):
        d = np.linalg.norm(p[:, None] - p[None], axis=-1)
        i, j = np.nonzero((d >= lo) & (d < hi) & np.triu(np.ones_like(d, bool), 1))
        products.append(np.sum(e[i] * e[j], -1))
    return float(np.mean(np.concatenate(products)) / np.mean(np.sum(errors ** 2, -1)))


def test_correlated_errors_are_shared_by_nearby_tracks_and_not_by_far_ones():
    clip = synth_clip(seed=4, clip_id="wide", n_layers=2, static_spheres=2, with_frames=False, n_frames=9,
                      height=144, width=192, n_tracks=800)
    noisy = add_noise(clip, NOISE_MODELS["correlated"], seed=2)  # px = 0: no error at all
    assert np.array_equal(noisy.track_curr, clip.track_curr)
    model = NOISE_MODELS["correlated"].replace(px=1.0)
    noisy = add_noise(clip, model, seed=2)
    errors, positions = noisy.track_curr - clip.track_curr, clip.track_curr
    # share x exp(-d^2 / 2 l^2) at l = 16 px, share 0.85: 0.82 at 0-4 px, 0.00 at 64-96 px (8 fields)
    assert shared_share(errors, positions, 0, 4) == pytest.approx(0.82, abs=SHARE_ATOL)
    assert shared_share(errors, positions, 64, 96) == pytest.approx(0.0, abs=SHARE_ATOL)


def test_smooth_fields_have_unit_rms_and_their_correlation_length():
    field = smooth_field(np.random.default_rng(0), (8,), 128, 128, 16.0)
    assert rms(field) == pytest.approx(1.0, rel=1e-6)
    lag = 16  # exp(-1/2) = 0.61 at one correlation length
    corr = np.mean(field[:, :, lag:] * field[:, :, :-lag]) / np.mean(field ** 2)
    assert corr == pytest.approx(np.exp(-0.5), abs=SHARE_ATOL)


def test_depth_errors_are_largest_at_depth_edges(exact_clip):
    noisy = add_noise(exact_clip, NOISE_MODELS["depth"], seed=3)
    ratio = np.abs(np.log(noisy.depth / exact_clip.depth))
    log_depth = np.log(exact_clip.depth)
    edge = np.zeros_like(ratio, bool)
    edge[:, :, 1:] |= np.abs(np.diff(log_depth, axis=2)) > 0.05
    edge[:, 1:, :] |= np.abs(np.diff(log_depth, axis=1)) > 0.05
    assert np.median(ratio[~edge]) < 0.02  # the smooth field's 1 % RMS
    assert np.mean(ratio[edge]) > 5 * np.mean(ratio[~edge])


def test_outliers_land_anywhere_and_stay_visible(exact_clip):
    noisy = add_noise(exact_clip, NOISE_MODELS["outliers"].replace(px=0.5), seed=4)
    far = np.linalg.norm(noisy.track_curr - exact_clip.track_curr, axis=-1) > 5.0  # 10 sigma of the noise
    assert np.mean(far) == pytest.approx(0.1, abs=0.03)
    assert noisy.track_vis[far].all()


def test_a_draw_depends_on_its_seed_only(exact_clip):
    model = NOISE_MODELS["correlated"].replace(px=1.0)
    a, b, c = (add_noise(exact_clip, model, seed=s) for s in (7, 7, 8))
    np.testing.assert_array_equal(a.track_curr, b.track_curr)
    assert not np.array_equal(a.track_curr, c.track_curr)


def test_a_depth_scale_error_scales_each_frame_by_one_factor(exact_clip):
    noisy = add_noise(exact_clip, NoiseModel(depth_scale_rel=0.02), seed=4)
    valid = exact_clip.depth > 0
    ratio = np.where(valid, noisy.depth / np.where(valid, exact_clip.depth, 1.0), np.nan)
    per_frame = np.nanmedian(ratio, axis=(1, 2))
    np.testing.assert_allclose(ratio[valid], np.broadcast_to(per_frame[:, None, None], ratio.shape)[valid],
                               rtol=1e-6)  # float32 depth
    assert np.ptp(per_frame) > 0.005 and np.all(np.abs(np.log(per_frame)) < 0.1)
    np.testing.assert_array_equal(noisy.track_curr, exact_clip.track_curr)


def test_a_depth_offset_error_shifts_each_frame_by_one_offset(exact_clip):
    noisy = add_noise(exact_clip, NoiseModel(depth_offset_rel=0.02), seed=4)
    valid = exact_clip.depth > 0
    shift = np.where(valid, noisy.depth.astype(np.float64) - exact_clip.depth, np.nan)
    per_frame = np.nanmedian(shift, axis=(1, 2))
    np.testing.assert_allclose(shift[valid], np.broadcast_to(per_frame[:, None, None], shift.shape)[valid],
                               atol=1e-5 * exact_clip.depth.max())  # float32 depth
    median = np.median(exact_clip.depth[valid])
    assert np.ptp(per_frame) > 0.005 * median and np.all(np.abs(per_frame) < 0.1 * median)
    np.testing.assert_array_equal(noisy.track_curr, exact_clip.track_curr)


def camera_centres(clip) -> np.ndarray:
    return -np.einsum("tji,tj->ti", clip.R_wc, clip.t_wc)


def test_a_camera_rotation_error_turns_each_camera_about_its_centre(exact_clip):
    noisy = add_noise(exact_clip, NoiseModel(camera_rot_deg=0.5), seed=5)
    np.testing.assert_allclose(camera_centres(noisy), camera_centres(exact_clip), atol=1e-9)
    turns = np.einsum("tij,tkj->tik", noisy.R_wc, exact_clip.R_wc)  # R_noisy R_exactᵀ
    angles = np.degrees(np.arccos(np.clip((np.trace(turns, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    # |rotation vector| of RMS 0.5 deg per axis: a chi distribution with 3 degrees of freedom times 0.5
    assert np.all(angles > 0) and np.all(angles < 0.5 * 5)
    orthonormal = np.einsum("tij,tkj->tik", noisy.R_wc, noisy.R_wc)
    np.testing.assert_allclose(orthonormal, np.broadcast_to(np.eye(3), turns.shape), atol=1e-12)
    np.testing.assert_array_equal(noisy.track_curr, exact_clip.track_curr)
    np.testing.assert_array_equal(noisy.depth, exact_clip.depth)


def test_a_camera_centre_error_is_in_median_camera_steps(exact_clip):
    noisy = add_noise(exact_clip, NoiseModel(camera_step_rel=0.5), seed=6)
    np.testing.assert_allclose(noisy.R_wc, exact_clip.R_wc, atol=0)
    centres = camera_centres(exact_clip)
    step = np.median(np.linalg.norm(np.diff(centres, axis=0), axis=1))
    moved = np.linalg.norm(camera_centres(noisy) - centres, axis=1) / step
    # 3 axes of RMS 0.5 steps: each centre moves 0.87 steps RMS; four frames' RMS lies within a factor 2
    assert 0.5 * 0.87 < rms(moved) < 2 * 0.87


def test_a_lens_bends_each_track_by_k1_r_squared_and_shows_the_depth_it_bent_there(exact_clip):
    k1 = -0.3  # tracks move 1 px (median) to 5 px on this 48 x 64 scene
    seen = radially_distorted(exact_clip, k1)
    K = exact_clip.K[0] if exact_clip.K.ndim == 3 else exact_clip.K
    normalised = (exact_clip.track_prev[0].astype(np.float64) - K[:2, 2]) / np.diag(K)[:2]
    bent = (seen.track_prev[0].astype(np.float64) - K[:2, 2]) / np.diag(K)[:2]
    np.testing.assert_allclose(bent, normalised * (1 + k1 * np.sum(normalised**2, -1, keepdims=True)), atol=1e-5)
    H, W = exact_clip.image_size
    inside = np.all((seen.track_prev[0] > 1) & (seen.track_prev[0] < [W - 2, H - 2]), axis=-1)

    def depth_at(clip, xy):  # frame 0 at the nearest pixel
        col, row = np.rint(xy[inside]).astype(int).T
        return clip.depth[0][row, col]

    # nearest pixels on both sides: a track keeps its depth but where rounding crosses a depth edge
    # (94 % of them keep it within 0.1 %; 74 % with the depth left unbent, 64 % with the tracks)
    kept = np.abs(depth_at(seen, seen.track_prev[0]) / depth_at(exact_clip, exact_clip.track_prev[0]) - 1) < 1e-3
    assert kept.mean() > 0.9
    np.testing.assert_array_equal(seen.R_wc, exact_clip.R_wc)
    np.testing.assert_array_equal(radially_distorted(exact_clip, 0.0).depth, exact_clip.depth)


def test_letterbox_bars_hold_one_static_depth_and_no_visible_track(exact_clip):
    boxed = letterboxed(exact_clip, 0.25)
    H = exact_clip.image_size[0]
    bars = np.r_[0:H // 4, H - H // 4:H]
    assert np.unique(boxed.depth[:, bars]).size == 1 and boxed.static_mask[:, bars].all()
    rows = lambda track: np.rint(track[..., 1])  # noqa: E731
    in_bars = (rows(boxed.track_prev) < H // 4) | (rows(boxed.track_curr) >= H - H // 4)
    assert in_bars.any() and not (boxed.track_vis & in_bars).any()
    middle = slice(H // 4, H - H // 4)
    np.testing.assert_array_equal(boxed.depth[:, middle], exact_clip.depth[:, middle])


def test_an_overlay_holds_its_tracks_in_place_at_one_depth_static_unless_masked(exact_clip):
    over = overlaid(exact_clip, 0.5, 0.5)
    moved = np.any(over.track_curr != exact_clip.track_curr, axis=-1)
    assert moved.any() and np.array_equal(over.track_curr[moved], over.track_prev[moved])
    assert over.track_vis[moved].all()
    H, W = exact_clip.image_size
    corner = (slice(None), slice(H // 2 - 4, H - 4), slice(W // 2 - 4, W - 4))
    assert np.unique(over.depth[corner]).size == 1 and over.static_mask[corner].all()
    assert not overlaid(exact_clip, 0.5, 0.5, masked=True).static_mask[corner].any()
    np.testing.assert_array_equal(over.depth[:, : H // 2 - 4], exact_clip.depth[:, : H // 2 - 4])


def test_test_split_shares_no_seed_with_the_fit_split():
    assert {s.seed for s in TEST_SCENES} <= set(TEST_SEEDS)
    assert {s.seed for s in FIT_SCENES} <= set(FIT_SEEDS)
    assert not set(FIT_SEEDS) & set(TEST_SEEDS)


def test_unseen_scenes_share_no_seed_with_either_split():
    assert not set(UNSEEN_SEEDS) & (set(FIT_SEEDS) | set(TEST_SEEDS))
    assert not set(HELD_OUT_SEEDS) & (set(FIT_SEEDS) | set(TEST_SEEDS) | set(UNSEEN_SEEDS))
    assert random_scene(3).spec == random_scene(3).spec and random_scene(3).seed == UNSEEN_SEEDS[3]


def test_fit_pool_lies_in_fit_and_shares_no_seed_with_other_fit_scenes():
    assert set(FIT_POOL_SEEDS) <= set(FIT_SEEDS)
    text = resources.files("sgc_jax.calibration").joinpath("sgc-spec-2026.json").read_text()
    bench_scenes = {10, 11, 12}  # bench/excess_score.py, intervals.py, noise_floors.py: seed 10 + s
    taken = {s.seed for s in FIT_SCENES} | set(json.loads(text)["corpus"]["seeds"]) | bench_scenes
    assert not set(FIT_POOL_SEEDS) & taken
    scene = random_scene(5, pool="fit")
    assert scene.seed == FIT_POOL_SEEDS[5] and scene.name == "fit-pool-5"


def test_shipped_calibration_corpus_shares_no_seed_with_the_test_split():
    text = resources.files("sgc_jax.calibration").joinpath("sgc-spec-2026.json").read_text()
    seeds = set(json.loads(text)["corpus"]["seeds"])
    assert seeds <= set(FIT_SEEDS)
    assert not seeds & set(TEST_SEEDS)


def test_test_split_holds_sizes_frame_counts_motions_and_layouts_the_fit_split_lacks():
    def values(scenes, *keys):
        return {tuple(s.spec[k] for k in keys) for s in scenes}

    for keys in [("height", "width"), ("n_frames",), ("camera_motion",), ("rot_deg_per_frame", "trans_per_frame"),
                 ("n_layers", "static_spheres")]:
        assert values(TEST_SCENES, *keys) - values(FIT_SCENES, *keys), keys


def test_cell_clips_share_the_noise_draw_of_their_cell():
    scene = TEST_SCENES[1]
    cell = Cell(scene, "iid-curr", 1.0, 200)
    clips = cell_clips(cell, inconsistencies=("squeeze", "mover"), severities=(0.25,))
    kinds = [kind for _, kind, _ in clips]
    assert kinds == ["", "squeeze", "mover-masked", "mover"]
    clean, squeezed = clips[0][0], clips[1][0]
    exact = scene.clip(200)
    # squeeze moves only y: the x errors of the clean and the squeezed clip are the same draw
    np.testing.assert_allclose(clean.track_curr[..., 0] - exact.track_curr[..., 0],
                               squeezed.track_curr[..., 0] - exact.track_curr[..., 0], atol=1e-4)


def test_every_cell_and_draw_has_its_own_noise_seed():
    seeds = [cell.noise_seed for split in ("fit", "test") for draw in (0, 1, 2) for cell in cells(split, draw=draw)]
    assert len(set(seeds)) == len(seeds)


def test_detection_counts_a_cell_when_the_inconsistency_scores_above_its_twin():
    rows = [dict(cell=1, kind="", severity=0.0, sgc=0.1), dict(cell=1, kind="warp", severity=0.25, sgc=0.2),
            dict(cell=2, kind="", severity=0.0, sgc=0.3), dict(cell=2, kind="warp", severity=0.25, sgc=0.3),
            dict(cell=1, kind="mover-masked", severity=0.0, sgc=0.0), dict(cell=1, kind="mover", severity=1.0,
                                                                            sgc=float("nan"))]
    assert detection_table(rows) == {("mover", 1.0): 0.0, ("warp", 0.25): 0.5}


# The claims under long-range tracks' errors (both ends, 0.5 px), on the demo scene's bucket: a
# consistent scene scores at most 0.10 (the protocol's bar for one clip; measured 0.000-0.022 on
# seeds 7-9) and sits near its floors; each perturbation at severity 0.25 scores above it (by
# 0.027-0.39 on those seeds). TEST-split figures: bench/history/issue-58.md, "The validation protocol".
CONSISTENT_MAX = 0.10
BOTH_ENDS = NOISE_MODELS["iid-both"].replace(px=0.5)


def scores_at_both_ends(clean_clips) -> dict:
    """{(seed, kind): ClipResult} of each (seed, consistent clip) and its perturbations at 0.25 ("" the
    clip itself), every one under BOTH_ENDS's errors, one draw a seed."""
    clips, kinds = [], []
    for seed, clean in clean_clips:
        for kind in ("", *PERTURBATIONS):
            base = perturb_clip(clean, kind, 0.25, seed=seed) if kind else clean
            clips.append(add_noise(base, BOTH_ENDS, seed=seed))
            kinds.append((seed, kind))
    return dict(zip(kinds, score_batch(clips, progress=False).clips))


@pytest.fixture(scope="module")
def both_ends_scores():
    return scores_at_both_ends((seed, synth_clip(seed=seed, clip_id=f"demo-{seed}", **DEMO_SCENE)) for seed in (7, 8))


def test_with_errors_at_both_track_ends_a_consistent_scene_stays_near_zero_and_near_its_floors(both_ends_scores):
    for (seed, kind), clip in both_ends_scores.items():
        if kind:
            continue
        assert clip.sgc <= CONSISTENT_MAX, (seed, clip.sgc)
        ratios = [clip.components[name.removesuffix("_floor")] / floor for name, floor in clip.floors.items()]
        assert FLOOR_RATIO_RANGE[0] <= np.median(ratios) <= FLOOR_RATIO_RANGE[1], (seed, ratios)


def test_with_errors_at_both_track_ends_each_perturbation_scores_above_its_consistent_scene(both_ends_scores):
    for (seed, kind), clip in both_ends_scores.items():
        if kind:
            assert clip.sgc > both_ends_scores[(seed, "")].sgc, (seed, kind, clip.sgc)


# The same claims on a scene family written apart from the synthesis (research.corridor: oblique
# walls, floor and ceiling), on the demo scene's bucket: its consistent scenes score 0.048-0.050 at
# this size (the depth check's rounding on surfaces that slant away, docs/semantics.md §3.6 step 2),
# each perturbation at 0.25 above them by 0.020-0.068 (bench/history/issue-58.md "A corridor").
@pytest.fixture(scope="module")
def corridor_scores():
    spec = CorridorSpec(**{key: DEMO_SCENE[key] for key in ("n_frames", "height", "width", "n_tracks")})
    return scores_at_both_ends((seed, Corridor(seed, spec, moving=False).clip(masked=False, clip_id=f"corridor-{seed}"))
                               for seed in CORRIDOR_SEEDS[:2])


def test_on_a_corridor_a_consistent_scene_stays_below_the_bar_and_each_perturbation_scores_above_it(corridor_scores):
    for (seed, kind), clip in corridor_scores.items():
        consistent = corridor_scores[(seed, "")]
        assert clip.status == "ok" and consistent.sgc <= CONSISTENT_MAX, (seed, kind, clip.status, consistent.sgc)
        if kind:
            assert clip.sgc > consistent.sgc, (seed, kind, clip.sgc, consistent.sgc)


def test_benchmark_rows_are_written_when_scored_and_read_back_unscored(tmp_path):
    rows = [dict(scene="fit-0", kind="", tracks=200, sgc=0.5), dict(scene="fit-0", kind="warp", tracks=200, sgc=np.nan)]
    path = tmp_path / "rows.csv"
    scored = rows_scored_or_read(None, path, lambda: rows, ("scene", "kind"), ("tracks",))
    read = rows_scored_or_read(path, None, lambda: pytest.fail("read rows are not scored again"), ("scene", "kind"),
                               ("tracks",))
    assert scored == rows
    assert [r["scene"] for r in read] == ["fit-0", "fit-0"] and [r["tracks"] for r in read] == [200, 200]
    assert read[0]["sgc"] == 0.5 and np.isnan(read[1]["sgc"]) and [r["kind"] for r in read] == ["", "warp"]


@pytest.mark.parametrize("seed", [3, 4])
def test_a_movers_tracks_are_those_on_the_object_not_on_its_masks_margin(seed):
    scene = dict(n_layers=2, moving_objects=1, with_frames=False, **SYNTH_SCENE)
    masked = synth_clip(seed=seed, **scene)
    exact_mask = synth_clip(seed=seed, mask_margin_px=0, **scene)  # the same tracks, the mask the object alone
    H, W = exact_mask.image_size
    column = np.clip(np.rint(exact_mask.track_prev[..., 0]).astype(int), 0, W - 1)
    row = np.clip(np.rint(exact_mask.track_prev[..., 1]).astype(int), 0, H - 1)
    on_object = ~exact_mask.static_mask[np.arange(exact_mask.n_pairs)[:, None], row, column]
    expected = np.mean(np.sum(on_object & exact_mask.usable_tracks(0.0), axis=1))
    assert expected > 0
    assert tracks_on_mover(masked, 0.0) == expected
    assert tracks_on_mover(synth_clip(seed=seed, n_layers=2, with_frames=False, **SYNTH_SCENE), 0.0) == 0.0
