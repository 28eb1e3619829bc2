"""Where a track's depth and region are read (docs/semantics.md §1.1, ``track_pixel``): the floor
pixel (the paper's code, the default) or the pixel whose centre is nearest, the same pixel in both
engines."""

import numpy as np
import pytest
from scenes import SMALL_SCENE

from sgc_jax import SGCConfig, score_batch
from sgc_jax.engines import reference
from sgc_jax.engines.jax_engine.pixel_stage import track_pixels
from sgc_jax.research.agreement import within_tolerance
from sgc_jax.research.noise import NOISE_MODELS, add_noise
from sgc_jax.research.synth import synth_clip

NEAREST = SGCConfig(track_pixel="nearest")
# x (and y) of points about pixel centres: just short of half way, past it, left of the first
# pixel's centre, on a centre
POSITIONS = np.array([2.49, 2.51, -0.4, 3.0], np.float32)
FLOOR_PIXELS = [2, 2, -1, 3]
NEAREST_PIXELS = [2, 3, 0, 3]


@pytest.mark.parametrize("config, expected", [(SGCConfig(), FLOOR_PIXELS), (NEAREST, NEAREST_PIXELS)],
                         ids=["floor", "nearest"])
def test_both_engines_read_the_floor_or_the_nearest_pixel(config, expected):
    points = np.stack([POSITIONS, POSITIONS[::-1]], axis=-1)
    col, row = track_pixels(points, np.float32(config.track_pixel_offset))
    assert np.asarray(col).tolist() == expected and np.asarray(row).tolist() == expected[::-1]
    col, row = reference.track_pixels(points.astype(np.float64), config.track_pixel_offset)
    assert col.tolist() == expected and row.tolist() == expected[::-1]


def test_authors_always_reads_the_floor_pixel():
    assert SGCConfig(compat="authors", track_pixel="nearest").track_pixel_offset == 0.0
    assert NEAREST.track_pixel_offset == 0.5


@pytest.fixture(scope="module")
def clean_and_noisy():
    clip = synth_clip(seed=3, clip_id="small", **SMALL_SCENE)
    return clip, add_noise(clip, NOISE_MODELS["iid-both"].replace(px=1.0), seed=3)


def test_tracks_at_pixel_centres_score_the_same_under_either_read(clean_and_noisy):
    # the generator's frame i-1 positions are integers (per-pair queries): floor and nearest coincide
    clip, _ = clean_and_noisy
    floor, nearest = (score_batch([clip], config=c, progress=False).clips[0].pairs for c in (SGCConfig(), NEAREST))
    for name in ("local_rot_var", "local_trans_var", "global_rot_var", "global_trans_var", "depth_error",
                 "region_points"):
        np.testing.assert_array_equal(getattr(floor, name), getattr(nearest, name), err_msg=name)


def test_with_errors_at_frame_i_minus_1_the_engines_read_the_same_points_under_nearest(clean_and_noisy):
    _, noisy = clean_and_noisy
    floor = score_batch([noisy], config=SGCConfig(), progress=False).clips[0].pairs
    jx = score_batch([noisy], config=NEAREST, progress=False).clips[0]
    ref = score_batch([noisy], config=NEAREST, engine="reference", progress=False).clips[0]
    # the same usable tracks with depth, in the same regions: the read is the engines' one shared step
    np.testing.assert_array_equal(jx.pairs.region_points, ref.pairs.region_points)
    np.testing.assert_array_equal(jx.pairs.n_tracks, ref.pairs.n_tracks)
    assert within_tolerance(ref.components["depth_error"], jx.components["depth_error"], "depth_error")
    assert not np.array_equal(floor.region_points, jx.pairs.region_points)  # the read moved members
