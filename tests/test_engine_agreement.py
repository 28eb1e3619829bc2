"""The JAX engine against the NumPy/OpenCV reference on a 30-clip synthetic corpus.

Both engines see the same points and regions (label maps match pixel for pixel); they differ in
the PnP-RANSAC. Where they differ, the scene's known geometry says which one is wrong:

- noise-free rigid clips: both recover the exact motion, so every component must agree within
  ``ATOL`` (with masked moving objects one clip, moving1, has a small region whose tracks cross
  the mask margin: both engines give ~40 deg^2 there, JAX 39 vs OpenCV 48);
- noisy / outlier / perturbed clips: the variances are driven by per-region pose errors, and the
  two estimators make different errors. There the test checks that the JAX engine is not the
  wrong one: its poses are closer to the true camera motion on rigid scenes, and on every clip
  they explain the region's tracks at least as well as OpenCV's (MSAC cost: squared reprojection
  error truncated at inlier_px, summed over the region's points) in nearly every region.

So the engines agree on the rigid and masked moving clips (20/20 each) but on few of the 1 px +
30% outlier clips (4/20; figures per variant: bench/RESULTS.md): cv2.solvePnPRansac (100
iterations, adaptive stop, inlier-count scoring) returns poses several degrees off on small,
weakly conditioned regions where the JAX engine's MSAC scoring and least-squares refinement land
at the least-squares optimum. On such regions ``ransac.refine_poses`` re-admits points its
uncertainty explains and drops points of extreme leverage, so that the final fit neither slides
along the rotation-translation valley onto one gross outlier nor leaves out the few clean points
that pin it (see the last test).
"""

import cv2
import numpy as np
import pytest

from sgc_jax import COMPONENTS, SGCConfig, score_batch
from sgc_jax.engines import reference, stages
from sgc_jax.research.perturb import perturb_clip
from sgc_jax.research.synth import synth_clip

BASE = dict(n_layers=1, static_spheres=5, n_frames=4)
SIZES = (dict(height=120, width=160, n_tracks=2048), dict(height=96, width=128, n_tracks=1024))
CONFIG = SGCConfig()


def _corpus():
    specs = []
    for family, seed0, extra in (
        ("rigid", 10, {}),
        ("moving", 20, dict(moving_objects=2)),
        ("noisy", 30, None),
        ("outliers", 40, dict(noise_px=1.0, outlier_frac=0.3)),
        ("unmasked", 60, dict(moving_objects=2, with_mask=False)),
    ):
        for i in range(4):
            kw = extra if extra is not None else dict(noise_px=0.5 + 0.25 * i)
            specs.append((f"{family}{i}", family, dict(seed=seed0 + i, **kw, **SIZES[i % 2])))
    for i in range(2):
        specs.append((f"lowconf{i}", "lowconf", dict(seed=70 + i, low_conf_frac=0.3, noise_px=0.5, **SIZES[i])))
    clips = [synth_clip(clip_id=name, group=family, **BASE, **kw) for name, family, kw in specs]
    ladder = [("warp", 0.25), ("warp", 0.75), ("squeeze", 0.25), ("squeeze", 0.75),
              ("depth_warp", 0.25), ("depth_warp", 0.75), ("warp", 0.5), ("squeeze", 0.5)]
    for i, (kind, severity) in enumerate(ladder):
        clips.append(perturb_clip(clips[i % 4], kind, severity, seed=i))
    return clips


@pytest.fixture(scope="module")
def scored():
    clips = _corpus()
    assert len(clips) >= 30
    ref = score_batch(clips, engine="reference", progress=False)
    jx = score_batch(clips, engine="jax", progress=False)
    return clips, ref, jx


# The agreement bar in the scale-free units of docs/semantics.md §4: rotation variances 0.05
# deg^2; translation variances (1% of the median depth)^2 = 1 (% of D)^2 and the depth error 0.1%
# (1e-4 md^2 and 1e-3 md in depth units); or 5% of the value.
ATOL = {"local_rot_var": 0.05, "global_rot_var": 0.05, "local_trans_var": 1.0, "global_trans_var": 1.0,
        "depth_error": 0.1}


def _within_tolerance(clip, ref_value, jax_value, component):
    return abs(jax_value - ref_value) <= max(ATOL[component], 0.05 * abs(ref_value))


def _angle_deg(R_a, R_b):
    return reference.rotation_angle_deg(R_a, R_b)


def test_noise_free_rigid_clips_agree_on_every_component(scored):
    clips, ref, jx = scored
    checked = 0
    for clip, r, j in zip(clips, ref.clips, jx.clips):
        if clip.group != "rigid" or "~" in clip.clip_id:
            continue
        for k in COMPONENTS:
            assert _within_tolerance(clip, r.components[k], j.components[k], k), (clip.clip_id, k)
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
        assert _within_tolerance(clip, r.components["depth_error"], j.components["depth_error"], "depth_error"), (
            clip.clip_id, r.components["depth_error"], j.components["depth_error"])


def test_on_rigid_scenes_jax_local_poses_are_closer_to_the_truth(scored):
    """Where the engines disagree on a rigid scene, the reference is the one away from the truth."""
    clips, ref, jx = scored
    jax_errors, ref_errors = [], []
    for clip, r, j in zip(clips, ref.clips, jx.clips):
        if clip.group not in ("rigid", "moving", "noisy", "outliers", "lowconf") or "~" in clip.clip_id:
            continue
        for p in range(clip.n_pairs):
            R_g, _ = reference.global_relative_pose(clip, p + 1, CONFIG)
            both = (j.pairs.region_status[p] == 0) & (r.pairs.region_status[p] == 0)
            for slot in np.flatnonzero(both):
                jax_errors.append(_angle_deg(j.pairs.R_local[p, slot], R_g))
                ref_errors.append(_angle_deg(r.pairs.R_local[p, slot], R_g))
        assert j.components["local_rot_var"] <= r.components["local_rot_var"] * 1.05 + 0.05, clip.clip_id
    jax_errors, ref_errors = np.array(jax_errors), np.array(ref_errors)
    differ = np.abs(jax_errors - ref_errors) > 0.1
    assert differ.sum() > 0  # the corpus does exercise the disagreement
    assert np.mean(jax_errors[differ] < ref_errors[differ]) >= 0.75
    assert np.percentile(jax_errors, 95) < np.percentile(ref_errors, 95)


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


def _truth_errors(clips, result):
    """Rotation error [deg] against the true motion and sigma_clean [deg] (``_clean_fit_rot_std``) of every
    accepted region with >= 50 points on the 1 px + 30% outlier clips."""
    errors, limits = [], []
    for clip, scored_clip in zip(clips, result.clips):
        if clip.group != "outliers" or "~" in clip.clip_id:
            continue
        pairs = scored_clip.pairs
        for p in range(clip.n_pairs):
            pair = p + 1
            R_g, t_g = reference.global_relative_pose(clip, pair, CONFIG)
            X, uv, _ = reference.usable_points(clip, pair, CONFIG)
            member_of = reference.point_regions(reference.partition_regions(clip, pair, CONFIG), uv)
            for slot in np.flatnonzero((pairs.region_status[p] == 0) & (pairs.region_points[p] >= 50)):
                in_region = member_of == slot + 1
                assert in_region.sum() == pairs.region_points[p, slot]  # the same region in both engines
                sigma_clean = _clean_fit_rot_std(clip, pair, X[in_region], uv[in_region], R_g, t_g)
                errors.append(_angle_deg(pairs.R_local[p, slot], R_g))
                limits.append(sigma_clean)
    return np.array(errors), np.array(limits)


def test_on_outlier_clips_jax_local_poses_are_near_the_information_limit(scored):
    """Local poses against the true motion, 1 px noise and 30% outlier tracks, accepted regions
    with >= 50 points.

    A depth layer is a narrow band of nearly one depth, so its rotation trades against its
    translation: the least-squares pose of its truly clean points, started at the truth, has a
    predicted std sigma_clean of 0.1-0.5 deg on these 120 x 160 / 96 x 128 clips (fx 139 / 111
    px, where 1 px is 0.4-0.5 deg), so a flat 0.2 deg is below what the data hold for every
    region here. The bar is max(0.2 deg, 3 sigma_clean). Of the JAX engine's few misses, one is a
    region the data hardly pin (sigma_clean 1.7 deg); at 288 x 512 (seeds 40-43, 4096 tracks) it
    meets the bar on every accepted region of the same scenes. Figures per engine and variant:
    bench/RESULTS.md.
    """
    clips, ref, jx = scored
    jax_errors, jax_limits = _truth_errors(clips, jx)
    ref_errors, ref_limits = _truth_errors(clips, ref)
    assert len(jax_errors) >= 20
    jax_within = np.mean(jax_errors <= np.maximum(0.2, 3.0 * jax_limits))
    ref_within = np.mean(ref_errors <= np.maximum(0.2, 3.0 * ref_limits))
    assert jax_within >= 0.85, (jax_within, ref_within)
    assert jax_within > ref_within + 0.3
    assert np.median(jax_errors) < 0.5 * np.median(ref_errors)


def test_both_engines_back_project_and_project_through_the_whole_K_skew_included():
    """docs/semantics.md §3.2 step 3: X = Z K^-1 (u, v, 1), K's skew K[0, 1] included."""
    rng = np.random.default_rng(0)
    K = np.array([[300.0, 4.0, 160.0], [0.0, 280.0, 120.0], [0.0, 0.0, 1.0]])
    uv, Z = rng.uniform([0.0, 0.0], [320.0, 240.0], (50, 2)), rng.uniform(1.0, 5.0, 50)
    X = reference.back_project(K, uv, Z)
    np.testing.assert_allclose(X, Z[:, None] * np.linalg.solve(K, np.c_[uv, np.ones(50)].T).T, rtol=1e-12)
    X_jax, _ = stages.points_prev(*(np.asarray(a, np.float32) for a in (Z, K, uv)), np.ones(50, bool))
    np.testing.assert_allclose(np.asarray(X_jax), X, rtol=1e-5)  # float32
    assert reference.reprojection_errors(X, uv, K, np.eye(3), np.zeros(3)).max() < 1e-9
