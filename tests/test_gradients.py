"""The differentiable score (docs/semantics.md §10): sgc_smooth equals sgc where no smooth bound is
active, and its gradients agree with central finite differences in float64."""

import dataclasses
import logging

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scenes import DEMO_SCENE

from sgc_jax.calibration import COMPONENTS, Calibration, default_calibration, normalise, sgc_score
from sgc_jax.calibration.formula import SMOOTH_FLOOR_WIDTH, scored_values, sgc_smooth_score, smooth_floor
from sgc_jax.engines.jax_engine.smooth_stage import smooth_components, smooth_stage
from sgc_jax.io.tables import FLOOR_COLUMNS
from sgc_jax.kernels.implicit_pose import least_squares_pose
from sgc_jax.kernels.so3 import so3_exp
from sgc_jax.research.noise import NoiseModel, add_noise
from sgc_jax.research.perturb import perturb_clip
from sgc_jax.research.synth import synth_clip
from sgc_jax.scoring.scorer import Scorer, batch_of

SHAPE = (2, DEMO_SCENE["n_frames"], DEMO_SCENE["height"], DEMO_SCENE["width"], DEMO_SCENE["n_tracks"])
FLOATS = ("depth", "track_prev", "track_curr", "R_wc", "t_wc", "K")

# sgc_smooth's components against the forward pass's, in float32: the same poses, D to one
# rounding, the camera's rotation by a polar iteration instead of an SVD (measured: <= 4e-6).
FORWARD_RTOL = 1e-4
# Finite differences in float64: each input moved by at most 2.5e-8 of itself, below half a float32
# ulp, so every choice (made on float32 values) stays as it was; the step's truncation and
# rounding errors are ~1e-7 of the derivative (measured), so 1e-3 leaves a margin.
FD_STEP = 1e-8
FD_RTOL = 1e-3


def gradient_clip(seed: int):
    """A consistent scene with 0.5 px track noise and 1 % depth noise (so that no pixel's depth
    error sits at the kink of |e|), tracks off the pixel grid (so that no track sits on the edge
    of the pixel its depth is read at)."""
    clip = synth_clip(seed=seed, noise_px=0.5, **DEMO_SCENE)
    rng = np.random.default_rng(seed)
    depth = (clip.depth * (1.0 + 0.01 * rng.standard_normal(clip.depth.shape))).astype(np.float32)
    return dataclasses.replace(clip, depth=np.where(clip.depth > 0, depth, 0.0).astype(np.float32),
                               track_prev=(clip.track_prev + 0.25).astype(np.float32))


@pytest.fixture(scope="module")
def scorer():
    return Scorer(SHAPE, differentiable=True)


@pytest.fixture(scope="module")
def batch():
    """A clip whose cameras err (0.3 deg per frame), so that its depth checks warp with the camera's
    refit to the tracks (§3.6 step 6), and a depth_warp of it with exact cameras."""
    clean = gradient_clip(3)
    return batch_of([add_noise(clean, NoiseModel(camera_rot_deg=0.3), seed=3), perturb_clip(clean, "depth_warp", 0.5)])


def test_the_batch_warps_depth_with_the_camera_and_with_its_refit(scorer, batch):
    by_refit = np.asarray(scorer.choices(batch).depth_by_refit)
    assert by_refit[0].any() and not by_refit[1].any()


def smooth_and_forward_components(scorer, batch):
    out = scorer(batch)
    per_clip = jax.vmap(lambda c, f: smooth_components(c, f, scorer.bucket, scorer.config)[0])
    components = jax.jit(per_clip)(scorer.clip_arrays(batch), scorer.choices(batch))
    return components, out


def test_sgc_smooth_components_are_the_forward_ones(scorer, batch):
    components, out = smooth_and_forward_components(scorer, batch)
    for k in COMPONENTS:
        np.testing.assert_allclose(np.asarray(components[k]), np.asarray(out[k]), rtol=FORWARD_RTOL, err_msg=k)
    forward = {k: np.asarray(out[k], np.float64) for k in COMPONENTS}
    present = {k: ~np.isnan(forward[k]) for k in COMPONENTS}
    floors = {name: np.asarray(out[name], np.float64) for name in FLOOR_COLUMNS}
    np.testing.assert_allclose(np.asarray(out["sgc_smooth"]),
                               sgc_smooth_score(forward, present, scorer.calibration, floors=floors), rtol=FORWARD_RTOL)


def test_sgc_smooth_reads_the_depth_at_each_points_own_position_as_the_forward_does(batch):
    from sgc_jax.config import SGCConfig

    at_point = Scorer(SHAPE, SGCConfig(depth_check_at="point"), differentiable=True)
    components, out = smooth_and_forward_components(at_point, batch)
    np.testing.assert_allclose(np.asarray(components["depth_error"]), np.asarray(out["depth_error"]),
                               rtol=FORWARD_RTOL)


def test_cameras_that_run_backward_keep_the_forward_scale_of_zero(scorer):
    clean = gradient_clip(3)
    batch = batch_of([dataclasses.replace(clean, t_wc=-clean.t_wc), clean])  # every translation negated
    assert np.asarray(scorer.choices(batch).scale)[0] == 0.0  # s held at 0 (§3.4)
    components, out = smooth_and_forward_components(scorer, batch)
    for k in COMPONENTS:
        np.testing.assert_allclose(np.asarray(components[k]), np.asarray(out[k]), rtol=FORWARD_RTOL, err_msg=k)


def test_smooth_score_equals_sgc_where_no_bound_is_active():
    calibration = Calibration.load(default_calibration("spec"))
    rng = np.random.default_rng(0)
    # components spread over the calibration's range, from far below its zero to far above
    components = {k: np.exp(rng.uniform(-4, 4, 2000)) for k in COMPONENTS}
    present = {k: rng.uniform(size=2000) > 0.1 for k in COMPONENTS}
    components = {k: np.where(present[k], components[k], np.nan) for k in COMPONENTS}
    floors = {f"{k}_floor": np.exp(rng.uniform(-4, 4, 2000)) for k in COMPONENTS[:4]}
    scaled = normalise(scored_values(components, calibration, floors), calibration, floor_at_zero=False)
    sgc = sgc_score(components, calibration, floors=floors)
    smooth = sgc_smooth_score(components, present, calibration, floors=floors)
    unbounded = np.all([~present[k] | (scaled[k] >= SMOOTH_FLOOR_WIDTH) for k in COMPONENTS], axis=0)
    any_present = np.any([present[k] for k in COMPONENTS], axis=0)
    assert 0 < unbounded.sum() < len(sgc)
    np.testing.assert_allclose(smooth[unbounded & any_present], sgc[unbounded & any_present], rtol=1e-12)
    assert np.all(smooth[any_present] >= sgc[any_present] - 1e-12) and np.all(smooth[any_present] > 0)
    assert np.all(np.isnan(smooth[~any_present]))


def test_smooth_floor_is_continuous_with_a_continuous_slope():
    x = np.linspace(-2, 2, 400001)
    y = smooth_floor(x)
    slope = np.gradient(y, x)
    assert np.max(np.abs(np.diff(y))) < 1e-4 and np.max(np.abs(np.diff(slope))) < 1e-2
    assert np.all(y > 0) and np.all(slope > 0)


def smooth_score_gradients(scorer, batch):
    """d sum(sgc_smooth) / d every float input of the batch, as a user writes it: jax.grad through
    the Scorer's call, all inputs at once (one backward program for this file; one per input would
    compile six). Clips are independent, so clip b's slices are d sgc_smooth[b]."""
    floats = {name: batch[name] for name in FLOATS}
    return jax.grad(lambda x: scorer({**batch, **x})["sgc_smooth"].sum())(floats)


@pytest.fixture(scope="module")
def gradients(scorer, batch):
    return smooth_score_gradients(scorer, batch)


def test_jax_grad_reaches_every_input_kind(batch, gradients):
    for name in FLOATS:
        grad = np.asarray(gradients[name])
        assert grad.shape == batch[name].shape and np.all(np.isfinite(grad)), name
        assert np.any(grad[0] != 0) and np.any(grad[1] != 0), f"{name}: each clip has a gradient"


def test_inputs_made_from_the_scorers_outputs_run_the_programs_plain_arrays_compiled(scorer, batch, gradients,
                                                                                      caplog):
    """A descent step feeds the Scorer arrays made from its outputs, which carry its mesh's
    sharding: they are placed as plain arrays are, so no step compiles again."""
    stepped = {**batch, "depth": batch["depth"] - 1e-3 * gradients["depth"]}
    with jax.log_compiles(True), caplog.at_level(logging.WARNING):
        smooth_score_gradients(scorer, stepped)
    assert not [r for r in caplog.records if "compilation of jit(<lambda>)" in r.getMessage()]


def test_a_clip_scoring_zero_still_has_a_depth_gradient(scorer):
    batch = batch_of([synth_clip(seed=seed, noise_px=0.5, **DEMO_SCENE) for seed in (3, 4)])
    out = scorer(batch)
    assert float(out["sgc"][0]) == 0.0  # a consistent scene below the calibration's zero
    grad = np.asarray(smooth_score_gradients(scorer, batch)["depth"])
    assert np.all(np.isfinite(grad)) and np.any(grad[0] != 0)


def test_gradients_agree_with_finite_differences_in_float64(scorer, batch):
    frozen = scorer.choices(batch)
    arrays = scorer.clip_arrays(batch)
    rng = np.random.default_rng(0)
    with jax.enable_x64(True):
        base = {n: jnp.asarray(getattr(arrays, n), jnp.float64) for n in FLOATS}
        score = jax.jit(lambda x: smooth_stage(arrays._replace(**x), frozen, scorer.bucket, scorer.config,
                                               scorer.calibration).sum())
        grad = jax.jit(jax.grad(score))(base)
        for name in FLOATS:
            x = np.asarray(base[name])
            direction = np.abs(x) * np.clip(rng.standard_normal(x.shape), -2.5, 2.5)  # relative moves
            step = {**base, name: base[name] + FD_STEP * direction}
            back = {**base, name: base[name] - FD_STEP * direction}
            finite = float(score(step) - score(back)) / (2 * FD_STEP)
            analytic = float(np.sum(np.asarray(grad[name]) * direction))
            assert abs(finite - analytic) <= FD_RTOL * abs(analytic), (name, finite, analytic)


def test_least_squares_pose_gradient_is_the_implicit_one():
    """The pose's derivative with respect to a pixel, against finite differences of a float64
    Gauss-Newton solve from scratch."""
    rng = np.random.default_rng(1)
    with jax.enable_x64(True):
        X = jnp.asarray(rng.uniform([-1, -1, 3], [1, 1, 6], (40, 3)))
        K = jnp.asarray([[300.0, 0, 64], [0, 300.0, 48], [0, 0, 1]])
        pose = jnp.asarray([0.02, -0.01, 0.03, 0.1, -0.05, 0.2])
        Y = X @ so3_exp(pose[:3]).T + pose[3:]
        uv = jnp.stack([K[0, 0] * Y[:, 0] / Y[:, 2] + K[0, 2], K[1, 1] * Y[:, 1] / Y[:, 2] + K[1, 2]], -1)
        uv = uv + jnp.asarray(rng.normal(0, 0.5, uv.shape))
        weight = jnp.ones(40)

        @jax.jit
        def solved(uv, start):  # many Newton steps from a start away from the optimum
            return least_squares_pose(start, X, uv, K, weight, jnp.bool_(True), steps=20)

        optimum = solved(uv, pose)
        jacobian = jax.jit(jax.jacobian(lambda u: solved(u, optimum)))(uv)
        direction = jnp.asarray(rng.normal(0, 1, uv.shape))
        h = 1e-6
        finite = (solved(uv + h * direction, pose) - solved(uv - h * direction, pose)) / (2 * h)
        analytic = jnp.tensordot(jacobian, direction, axes=2)
        np.testing.assert_allclose(np.asarray(finite), np.asarray(analytic), rtol=FD_RTOL, atol=1e-9)


def test_differentiable_needs_the_default_semantics():
    from sgc_jax.config import SGCConfig

    with pytest.raises(ValueError, match="compat='spec'"):
        Scorer((1, 4, 16, 16, 8), SGCConfig(compat="authors"), differentiable=True)
