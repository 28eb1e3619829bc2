"""Padding and bucketing: padded frames, tracks and pixels are marked invalid and never
change a clip's numbers; clips of one bucket share its compiled stages, and the pose stage is
shared by every image size."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from sgc_jax import COMPONENTS, SGCConfig
from sgc_jax.config import STATIC_FIELDS
from sgc_jax.engines.jax_engine import buckets, dispatch, pose_stage, programs
from sgc_jax.research.synth import synth_clip


def assert_same_pairs(padded, as_is):
    assert list(padded.reason) == list(as_is.reason)
    np.testing.assert_array_equal(padded.n_tracks, as_is.n_tracks)
    np.testing.assert_array_equal(padded.n_regions, as_is.n_regions)
    np.testing.assert_array_equal(padded.region_status, as_is.region_status)
    for k in COMPONENTS:  # float32 reductions over longer padded axes reorder sums
        np.testing.assert_allclose(getattr(padded, k), getattr(as_is, k), rtol=1e-4, atol=1e-7, err_msg=k)


# A noisy clip (30% outlier tracks: RANSAC's sampling must not depend on the padded track count)
# of the suite's 4 x 128 x 128 x 1024 bucket, padded to buckets other tests score anyway: more
# frames (the demo corpus's) and more tracks and columns (conftest.SCENE's); and more tracks alone,
# which shares the finish stage's program (keyed on T, H, W) with the clip's own bucket.
SMALL_NOISY = dict(n_layers=2, static_spheres=4, height=100, width=120, n_tracks=1000, n_frames=3, noise_px=1.0,
                   outlier_frac=0.3)
# Each static field (docs/semantics.md §2) altered, and the stages whose programs it shapes.
ALTERED_STATIC = {"k_seg": 8, "ransac_hypotheses": 50, "kmeans_bins": 32, "lm_steps": 5, "partition": "grid",
                  "region_frame": "current", "compat": "authors", "global_pose": False, "align_scale": False,
                  "borrow_region_poses": False, "depth_check_at": "point"}
READ_BY = {"k_seg": ("pixel", "pose", "finish"), "ransac_hypotheses": ("pose",), "kmeans_bins": ("pixel",),
           "lm_steps": ("pose",), "partition": ("pixel",), "region_frame": ("pixel",),
           "compat": ("pixel", "pose", "finish"), "global_pose": ("pose", "finish"), "align_scale": ("pose",),
           "borrow_region_poses": ("pose",), "depth_check_at": ("finish",)}
LARGER = {"frames": buckets.Bucket(T=8, H=128, W=128, P=1024),
          "tracks_and_columns": buckets.Bucket(T=4, H=128, W=192, P=2048),
          "tracks": buckets.Bucket(T=4, H=128, W=128, P=2048)}


@pytest.mark.parametrize("larger", sorted(LARGER))
def test_padding_to_a_larger_bucket_does_not_change_the_score(larger, monkeypatch):
    clip = synth_clip(seed=3, clip_id="small-noisy", **SMALL_NOISY)
    config = SGCConfig()
    assert buckets.bucket_for(clip) == buckets.Bucket(T=4, H=128, W=128, P=1024)
    [as_is] = dispatch.score_pairs_batch([clip], config)
    before = len(programs.compile_log())
    monkeypatch.setattr(dispatch, "bucket_for", lambda clip: LARGER[larger])
    [padded] = dispatch.score_pairs_batch([clip], config)
    assert_same_pairs(padded, as_is)
    if larger == "tracks":
        assert "finish" not in [key.name for key, _ in programs.compile_log()[before:]]


def test_clips_of_another_image_size_share_the_pose_stage(noisy_clip, monkeypatch, capsys):
    """docs/semantics.md §7.1: the pose stage (most of the compile) depends on T and P only."""
    config = SGCConfig()
    natural = buckets.bucket_for(noisy_clip)
    [as_is] = dispatch.score_pairs_batch([noisy_clip], config)
    before = len(programs.compile_log())
    taller = dataclasses.replace(natural, H=natural.H + 64)
    monkeypatch.setattr(dispatch, "bucket_for", lambda clip: taller)
    capsys.readouterr()
    [padded] = dispatch.score_pairs_batch([noisy_clip], config)
    assert [key.name for key, _ in programs.compile_log()[before:]] == ["pixel", "finish"]
    # a bucket no other test uses: its compile is announced on stderr, once, naming the bucket and stages
    assert capsys.readouterr().err.count(f"compiling the JAX program for clips of up to {taller.T} frames, "
                                         f"{taller.H}x{taller.W} px, {taller.P} tracks per pair (pixel, finish;") == 1
    assert_same_pairs(padded, as_is)


def program_keys(config: SGCConfig, bucket) -> dict:
    return {stage.name: programs.ProgramKey(programs.split(stage)[1], stage.sizes(bucket))
            for stage in programs.stages_of(config)}


@pytest.mark.parametrize("field, value", [(f, v) for f, v in ALTERED_STATIC.items()])
def test_a_static_field_keys_the_programs_of_the_stages_that_read_it_and_no_other(field, value):
    bucket = buckets.Bucket(T=4, H=128, W=192, P=2048)
    default, altered = program_keys(SGCConfig(), bucket), program_keys(SGCConfig(**{field: value}), bucket)
    assert {name for name in default if default[name] != altered[name]} == set(READ_BY[field])


def test_every_static_field_names_the_stages_it_shapes():
    assert set(ALTERED_STATIC) == set(READ_BY) == set(STATIC_FIELDS)


def test_value_fields_key_no_program():
    bucket = buckets.Bucket(T=4, H=128, W=192, P=2048)
    values = {"inlier_px": 4.0, "min_region_pixels": 50, "quality_rule": False, "tracks_per_layer": 0,
              "max_rot_std_deg": 2.0, "seed": 3}
    assert program_keys(SGCConfig(**values), bucket) == program_keys(SGCConfig(), bucket)


def test_one_program_per_bucket_and_program_shaping_options(rigid_clip, drift_clip, moving_clip):
    """docs/semantics.md §7.1: a second corpus of the bucket, other thresholds or seed, use_mos=False,
    other track filtering and perturbed clips reuse the program: XLA compiles nothing."""
    from jax import monitoring

    from sgc_jax import perturb_clip, score_batch

    config = SGCConfig()
    dispatch.score_pairs_batch([rigid_clip], config)  # the program of this bucket, compiled here or earlier
    held = programs.compile_count()
    compiles = []
    listener = lambda event, duration, **kw: compiles.append(kw.get("fun_name")) if "backend_compile" in event else None  # noqa: E731
    monitoring.register_event_duration_secs_listener(listener)
    try:
        other = dataclasses.replace(drift_clip, clip_id="other")
        assert buckets.bucket_for(other) == buckets.bucket_for(moving_clip) == buckets.bucket_for(rigid_clip)
        dispatch.score_pairs_batch([other, moving_clip], config)
        for changes in (dict(inlier_px=6.0, min_inlier_frac=0.4, confidence=0.95), dict(seed=7), dict(use_mos=False),
                        dict(min_track_conf=0.9, max_rot_std_deg=2.0, min_region_pixels=50, ambiguous_rot_deg=5.0)):
            dispatch.score_pairs_batch([moving_clip], config.replace(**changes))
        score_batch([perturb_clip(rigid_clip, kind, 0.5, seed=0) for kind in ("warp", "depth_warp")], progress=False)
    finally:
        monitoring.unregister_event_duration_listener(listener)
    assert compiles == [] and programs.compile_count() == held


def test_pairs_posed_in_groups_give_what_all_pairs_at_once_give():
    # a loop whose length depends on the lane, as RANSAC's and the least squares' do
    def steps(args):
        x, n = args
        return jax.lax.while_loop(lambda c: c[1] < n, lambda c: (c[0] * 1.5 + 1.0, c[1] + 1), (x, 0))[0], None

    for n_pairs in (1, 4, 5, 6, 7, 15, 16):
        x = jnp.arange(n_pairs * 3, dtype=jnp.float32).reshape(n_pairs, 3)
        n = jnp.arange(n_pairs) % 4
        for vectorized in (False, True):
            grouped, _ = pose_stage.pair_groups(steps, (x, n), n_pairs, vectorized)
            assert grouped.shape == (n_pairs, 3)
            np.testing.assert_array_equal(np.asarray(grouped), np.asarray(jax.vmap(steps)((x, n))[0]))


def test_a_padded_pair_never_switches_a_clips_warps_to_their_costlier_form():
    """The last frame warped by the first padded frame's camera (identity, at the origin) may bring
    a surface 2x nearer; the larger squares (docs/semantics.md §3.6 step 3) are then chosen for a
    clip's real pairs only."""
    from sgc_jax.engines.jax_engine.finish_stage import has_magnified_surface

    H = W = 16
    depth = np.stack([np.full((H, W), 4.0), np.full((H, W), 4.0), np.zeros((H, W))]).astype(np.float32)
    static = depth > 0
    K = np.array([[16.0, 0, 8], [0, 16.0, 8], [0, 0, 1]], np.float32)
    R_g = np.stack([np.eye(3)] * 2).astype(np.float32)
    t_g = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, -2.5]], np.float32)  # the padded camera: the wall 4 -> 1.5
    pairs = (np.arange(2, dtype=np.int32), np.stack([K] * 2), np.stack([K] * 2), R_g, t_g,
             np.array([[H, W]] * 2, np.int32))
    choose = jax.jit(has_magnified_surface, static_argnums=4)
    assert bool(choose(depth, static, pairs, np.array([True, True]), False))  # it would ask for the squares
    for vectorized in (False, True):
        assert not bool(choose(depth, static, pairs, np.array([True, False]), vectorized))


# frame counts video generators make (4n + 1: SVD, Wan, CogVideoX, HunyuanVideo, LTX-Video)
GENERATOR_FRAME_COUNTS = (17, 25, 33, 49, 65, 81, 97, 129, 161, 257)


def test_video_generators_frame_counts_are_buckets_of_their_own():
    for T in GENERATOR_FRAME_COUNTS:
        assert buckets.bucket_for_shape(T, 480, 832, 4096).T == T


def test_beyond_16_frames_padding_adds_under_a_quarter_of_a_clips_pairs_and_short_clips_keep_their_buckets():
    for T in range(17, 2050):
        padded = buckets.bucket_for_shape(T, 64, 64, 64).T
        assert T <= padded and padded - 1 < 1.25 * (T - 1), T
    assert [buckets.bucket_for_shape(T, 64, 64, 64).T for T in range(1, 17)] == [
        2, 2, 4, 4, 8, 8, 8, 8, 12, 12, 12, 12, 16, 16, 16, 16]


def test_padded_host_arrays_are_aligned_for_device_put_to_keep_them():
    clip = synth_clip(seed=3, clip_id="small-noisy", **SMALL_NOISY)
    batch = buckets.pad_clip(clip, LARGER["frames"], SGCConfig())
    for name in ("depth", "static", "K", "R_wc", "t_wc", "track_prev", "track_curr", "usable"):
        array = getattr(batch, name)
        assert array.ctypes.data % buckets.HOST_ALIGN == 0, name
    on_device = jax.device_put(batch.depth)
    np.testing.assert_array_equal(np.asarray(on_device), batch.depth)
    if jax.default_backend() == "cpu":  # taken as it is, not copied
        assert on_device.unsafe_buffer_pointer() == batch.depth.ctypes.data
