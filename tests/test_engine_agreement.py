"""The JAX engine against the spec reference (NumPy + OpenCV, docs/semantics.md §7.2) on a
30-clip synthetic corpus.

Both engines see the same points and regions (label maps match pixel for pixel) and state the
same local pose (docs/semantics.md §3.2 step 6): from the coarse optimum (the local optimum of
lowest truncated cost at inlier_px), the local optimum at its noise-level cut, or the rival where
that costs less. They search for the coarse optimum differently, the reference harder (many
more minimal samples, no early stop, every neighbour's optimum and the camera's pose as starts).
Where the engines' poses differ, the one of higher cost on the region's points is the wrong
one. Both judge a pose against the same rival (docs/semantics.md §3.3), so they agree on the
region statuses. The bars below are what the engines must keep.
"""

import cv2
import numpy as np
import pytest

from sgc_jax import COMPONENTS, SGCConfig, score_batch
from sgc_jax.engines import reference
from sgc_jax.engines.jax_engine import pose_stage
from sgc_jax.research.agreement import agreement_corpus, compare, within_by_family, within_tolerance

CONFIG = SGCConfig()


@pytest.fixture(scope="module")
def scored():
    clips = agreement_corpus()
    assert len(clips) >= 30
    ref = score_batch(clips, engine="reference", progress=False)
    jx = score_batch(clips, engine="jax", progress=False)
    return clips, ref, jx


def _angle_deg(R_a, R_b):
    return reference.rotation_angle_deg(R_a, R_b)


def test_noise_free_rigid_clips_agree_on_every_component(scored):
    clips, ref, jx = scored
    checked = 0
    for clip, r, j in zip(clips, ref.clips, jx.clips):
        if clip.group != "rigid" or "~" in clip.clip_id:
            continue
        for k in COMPONENTS:
            assert within_tolerance(r.components[k], j.components[k], k), (clip.clip_id, k)
            checked += 1
    assert checked == 4 * len(COMPONENTS)


# The translation scale is a weighted median of ~10^4 per-track roots (docs/semantics.md §3.4):
# float32 (JAX) against float64 (reference) roots move it by far less than this.
SCALE_REL_TOL = 1e-3


def test_translation_scale_and_depth_error_agree_on_every_clip(scored):
    # Neither involves a local pose (docs/semantics.md §3.4, §3.6): the engines see the same
    # tracks and depth, so they agree on every clip, noisy, outlier and perturbed ones included.
    clips, ref, jx = scored
    for clip, r, j in zip(clips, ref.clips, jx.clips):
        assert abs(r.scale - j.scale) <= SCALE_REL_TOL * abs(r.scale), (clip.clip_id, r.scale, j.scale)
        assert within_tolerance(r.components["depth_error"], j.components["depth_error"], "depth_error"), (
            clip.clip_id, r.components["depth_error"], j.components["depth_error"])


# The bars: 0.95 of (clip, component) cases within tolerance, rho 0.98, 0.98
# of statuses and JAX wrong on at most 0.02 of regions. At seed 0: 150 of 150 cases, rho 1.000,
# 668 of 669 statuses, JAX the worse pose in 2 regions (bench/history/issue-39.md, "The reference engine's
# Levenberg-Marquardt step"; other seeds and GPUs: bench/engine_agreement.py). Misses, where a
# seed has them, are on the 1 px + 30% outlier and unmasked clips, whose small regions have coarse
# optima of nearly equal cost, where the JAX engine's adaptive stop can miss the lowest basin.
AGREEMENT_SHARE = 0.95
# Families whose every (clip, component) case agrees: one pose per region, found alike. With frame
# i-1's regions (the default) the 0.75 squeeze has two regions of near-equal optima where the
# reference settles in the higher-cost one (11.82 vs 11.69 and 422.5 vs 419.3 px^2; bench/history/issue-41.md,
# "The excess score, the default").
AGREEING_FAMILIES = ("rigid", "moving", "noisy", "lowconf")
SPEARMAN_MIN = 0.98
STATUS_AGREEMENT = 0.98
JAX_WRONG_MAX = 0.02


def test_every_component_agrees_on_all_but_the_outlier_and_unmasked_clips_and_most_of_those(scored):
    within = within_by_family(*scored)
    for family in AGREEING_FAMILIES:
        assert all(within[family]), family
    share = np.mean(np.concatenate(list(within.values())))
    assert share >= AGREEMENT_SHARE, share


@pytest.fixture(scope="module")
def agreement(scored):
    """bench/engine_agreement.py's figures of the reference (the base) against the JAX engine."""
    return compare(*scored, CONFIG)


def test_the_engines_rank_the_clips_alike(agreement):
    assert agreement.spearman >= SPEARMAN_MIN, agreement.spearman


def test_the_engines_agree_on_nearly_every_region_status(agreement):
    assert agreement.regions > 500
    assert agreement.status_share >= STATUS_AGREEMENT, agreement.status_share


def test_a_scoring_compared_with_itself_agrees_in_every_figure(scored, agreement):
    # the comparison's fixed point
    clips, _, jx = scored
    same = compare(clips, jx, jx, CONFIG)
    assert same.components_within == same.components == len(clips) * len(COMPONENTS)
    assert same.same_status == same.regions > 500
    # a float64 Pearson r of identical average ranks: tied ranks (clips at SGC 0) round it to 1 - 2e-16
    assert same.spearman == pytest.approx(1.0, abs=1e-12)
    assert same.posed > 500 and same.differ == same.a_worse == same.b_worse == 0
    assert agreement.differ > 0  # across engines some regions do differ: a perfect self-comparison is not a given


def test_where_the_local_poses_differ_the_jax_engine_is_seldom_the_wrong_one(agreement):
    # a: the reference, b: the JAX engine; the worse pose is the wrong one
    assert agreement.posed > 500 and agreement.differ > 0
    assert agreement.b_worse <= JAX_WRONG_MAX * agreement.posed, agreement


@pytest.fixture(scope="module")
def opencv_rotations(scored):
    """(clip_id, pair) -> rotations (k_seg, 3, 3) of cv2.solvePnPRansac with the authors' settings
    on the spec regions of the pair (NaN where it gives none), on the rigid-scene families."""
    out = {}
    for clip in scored[0]:
        if clip.group not in ("rigid", "moving", "noisy", "outliers", "lowconf") or "~" in clip.clip_id:
            continue
        for pair in range(1, clip.n_frames):
            points = reference.pair_points(clip, pair, CONFIG)
            out[clip.clip_id, pair] = np.full((CONFIG.k_seg, 3, 3), np.nan)
            for slot, pose in enumerate(reference.authors_region_poses(points, clip.K[pair], CONFIG, pair)):
                out[clip.clip_id, pair][slot] = pose.R
    return out


def test_on_rigid_scenes_the_spec_local_worst_poses_are_no_further_from_the_truth_than_opencv_ransac(
        scored, opencv_rotations):
    """The authors' PnP (OpenCV's adaptive RANSAC, inlier counting) on the same regions, against
    both spec engines: the spec engines' worst poses are no further from the true motion, to within
    one region of the corpus; on the default's regions the two tails meet (bench/history/issue-58.md,
    "Larger depth layers shipped")."""
    clips, ref, jx = scored
    errors = {"jax": [], "reference": [], "opencv": []}
    for clip, r, j in zip(clips, ref.clips, jx.clips):
        if clip.group not in ("rigid", "moving", "noisy", "outliers", "lowconf") or "~" in clip.clip_id:
            continue
        for p in range(clip.n_pairs):
            R_g, _ = reference.global_relative_pose(clip, p + 1, CONFIG)
            opencv = opencv_rotations[clip.clip_id, p + 1]
            posed = ((j.pairs.region_status[p] == 0) & (r.pairs.region_status[p] == 0)
                     & np.isfinite(opencv).all((1, 2)))
            for slot in np.flatnonzero(posed):
                for name, R in (("jax", j.pairs.R_local[p, slot]), ("reference", r.pairs.R_local[p, slot]),
                                ("opencv", opencv[slot])):
                    errors[name].append(_angle_deg(R, R_g))
    errors = {name: np.array(e) for name, e in errors.items()}
    # a percentile of n regions resolves no finer than one region's rank: OpenCV's 95th percentile
    # one rank up is the bar, so that one region's coin toss between two searches does not decide it
    opencv_one_rank_up = np.percentile(errors["opencv"], 95 + 100 / len(errors["opencv"]))
    for engine in ("jax", "reference"):
        differ = np.abs(errors[engine] - errors["opencv"]) > 0.1
        assert differ.sum() > 0  # the corpus does exercise the disagreement
        assert np.percentile(errors[engine], 95) <= opencv_one_rank_up, (engine, opencv_one_rank_up)


def _clean_fit_rot_std(clip, pair, X, uv, R_g, t_g):
    """The best any estimator can do on a region's points X (n, 3), uv (n, 2): the predicted
    rotation std [deg] of the least-squares pose of its truly clean members (error < 4 px = 4 sigma
    under the true motion), started at the truth."""
    K = clip.K[pair].astype(np.float64)
    clean = reference.reprojection_errors(X, uv, K, R_g, t_g) < 4.0
    _, rvec, tvec = cv2.solvePnP(X[clean], uv[clean], K, None, cv2.Rodrigues(R_g)[0], t_g.reshape(3, 1).copy(),
                                 True, cv2.SOLVEPNP_ITERATIVE)
    R = cv2.Rodrigues(rvec)[0]
    rot_std, _, _ = reference.pose_uncertainty(X[clean], uv[clean], K, R, tvec.ravel())
    return rot_std


def _truth_errors(clips, rotations):
    """Rotation error [deg] against the true motion and sigma_clean [deg] (``_clean_fit_rot_std``)
    of every posed region with >= 50 points on the 1 px + 30% outlier clips; ``rotations(i, clip,
    pair)`` gives (statuses (k,), rotations (k, 3, 3)) of clip i's pair."""
    errors, limits = [], []
    for i, clip in enumerate(clips):
        if clip.group != "outliers" or "~" in clip.clip_id:
            continue
        for pair in range(1, clip.n_frames):
            R_g, t_g = reference.global_relative_pose(clip, pair, CONFIG)
            points = reference.pair_points(clip, pair, CONFIG)
            status, R = rotations(i, clip, pair)
            counts = np.bincount(points.region, minlength=CONFIG.k_seg + 1)[1:]
            for slot in np.flatnonzero((status == 0) & (counts >= 50)):
                member = points.region == slot + 1
                errors.append(_angle_deg(R[slot], R_g))
                limits.append(_clean_fit_rot_std(clip, pair, points.X[member], points.uv[member], R_g, t_g))
    return np.array(errors), np.array(limits)


def test_on_outlier_clips_the_spec_local_poses_are_near_the_information_limit(scored, opencv_rotations):
    """Local poses against the true motion, 1 px noise and 30% outlier tracks, posed regions
    with >= 50 points.

    A depth layer is a narrow band of nearly one depth, so its rotation trades against its
    translation: the least-squares pose of its truly clean points, started at the truth, has a
    predicted std sigma_clean of 0.1-0.5 deg on these 120 x 160 / 96 x 128 clips (fx 139 / 111
    px, where 1 px is 0.4-0.5 deg), so a flat 0.2 deg is below what the data hold for every
    region here. The bar is max(0.2 deg, 3 sigma_clean); OpenCV's RANSAC with the authors'
    settings on the same regions stands for the authors' pipeline.
    """
    clips, ref, jx = scored
    within = {}
    engine = lambda result: lambda i, clip, pair: (result.clips[i].pairs.region_status[pair - 1],  # noqa: E731
                                                    result.clips[i].pairs.R_local[pair - 1])
    opencv = lambda i, clip, pair: (np.where(np.isfinite(opencv_rotations[clip.clip_id, pair]).all((1, 2)), 0, 2),  # noqa: E731
                                    opencv_rotations[clip.clip_id, pair])
    for name, rotations in (("jax", engine(jx)), ("reference", engine(ref)), ("opencv", opencv)):
        errors, limits = _truth_errors(clips, rotations)
        assert len(errors) >= 20, name
        within[name] = np.mean(errors <= np.maximum(0.2, 3.0 * limits))
    assert within["jax"] >= 0.85 and within["reference"] >= 0.85, within
    # measured 0.98 for OpenCV, 1.0 for the spec engines (bench/history/issue-20.md, "One semantics, two independent searches")
    assert min(within["jax"], within["reference"]) >= within["opencv"], within


def test_both_engines_back_project_and_project_through_the_whole_K_skew_included():
    """docs/semantics.md §3.2 step 3: X = Z K^-1 (u, v, 1), K's skew K[0, 1] included."""
    rng = np.random.default_rng(0)
    K = np.array([[300.0, 4.0, 160.0], [0.0, 280.0, 120.0], [0.0, 0.0, 1.0]])
    uv, Z = rng.uniform([0.0, 0.0], [320.0, 240.0], (50, 2)), rng.uniform(1.0, 5.0, 50)
    X = reference.back_project(K, uv, Z)
    np.testing.assert_allclose(X, Z[:, None] * np.linalg.solve(K, np.c_[uv, np.ones(50)].T).T, rtol=1e-12)
    X_jax, _ = pose_stage.points_prev(*(np.asarray(a, np.float32) for a in (Z, K, uv)), np.ones(50, bool))
    np.testing.assert_allclose(np.asarray(X_jax), X, rtol=1e-5)  # float32
    assert reference.reprojection_errors(X, uv, K, np.eye(3), np.zeros(3)).max() < 1e-9
