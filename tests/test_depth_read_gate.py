"""The depth-read gate (docs/semantics.md §3.2 step 5b): which tracks leave their region, and the
same ones in both engines."""

import jax.numpy as jnp
import numpy as np
import pytest
from scenes import DEMO_SCENE

from sgc_jax import SGCConfig, score_batch
from sgc_jax.kernels.depth_read_gate import gate_depth_reads
from sgc_jax.research.noise import NoiseModel, add_noise
from sgc_jax.research.synth import synth_clip

GATE = 0.05
MIN_KEPT = 10
K_SEG = 3


def gated(region, X, Z_curr, R=np.eye(3), t=np.zeros(3), gate=GATE, min_kept=MIN_KEPT):
    return np.asarray(gate_depth_reads(jnp.asarray(region, jnp.int32), jnp.asarray(X, jnp.float32),
                                       jnp.asarray(Z_curr, jnp.float32), jnp.asarray(R, jnp.float32),
                                       jnp.asarray(t, jnp.float32), jnp.float32(gate), jnp.int32(min_kept), K_SEG))


def two_regions(n=12):
    """Region 1 and 2 with n points each at depth 2 and 4, one track with no region; frame i reads
    the depths a camera moving 0.5 forward (t_z = -0.5) gives them."""
    region = np.r_[np.full(n, 1), np.full(n, 2), 0]
    X = np.c_[np.zeros((2 * n + 1, 2)), np.r_[np.full(n, 2.0), np.full(n, 4.0), 3.0]]
    return region, X, X[:, 2] - 0.5, np.array([0.0, 0.0, -0.5])


def test_a_track_whose_frame_i_read_crosses_a_depth_edge_leaves_its_region():
    region, X, Z_curr, t = two_regions()
    Z_curr[0] = 3.5  # read on the far surface: 2.33 times the depth the camera gives it
    Z_curr[13] = 3.5 * 1.04  # within 5 % of the read: stays
    out = gated(region, X, Z_curr, t=t)
    assert out[0] == 0 and out[13] == 2
    assert np.array_equal(np.delete(out, 0), np.delete(region, 0))


def test_a_track_without_depth_at_frame_i_leaves_its_region():
    region, X, Z_curr, t = two_regions()
    Z_curr[5] = 0.0
    assert gated(region, X, Z_curr, t=t)[5] == 0


def test_a_region_the_gate_would_thin_below_min_region_points_keeps_all_its_tracks():
    region, X, Z_curr, t = two_regions(n=MIN_KEPT)
    Z_curr[0] = 3.5  # region 1 would keep MIN_KEPT - 1
    Z_curr[MIN_KEPT] = 9.0
    out = gated(region, X, Z_curr, t=t, min_kept=MIN_KEPT - 1)
    assert out[0] == 0 and out[MIN_KEPT] == 0
    assert np.array_equal(gated(region, X, Z_curr, t=t), region)


@pytest.mark.parametrize("case", ["gate 0", "camera pose not finite"])
def test_no_gate_or_no_finite_camera_pose_keeps_every_track(case):
    region, X, Z_curr, t = two_regions()
    Z_curr[:] = 100.0
    if case == "gate 0":
        out = gated(region, X, Z_curr, t=t, gate=0.0)
    else:
        out = gated(region, X, Z_curr, R=np.full((3, 3), np.nan), t=np.full(3, np.nan))
    assert np.array_equal(out, region)


def test_both_engines_take_the_same_tracks_out_of_the_same_regions():
    # both ends at 2 px: some frame-(i-1) reads cross depth edges (bucket of the demo scenes)
    clip = add_noise(synth_clip(seed=1, **DEMO_SCENE), NoiseModel(px=2.0, ends="both"), seed=1)
    config = SGCConfig(depth_read_gate=GATE)
    counts = {engine: score_batch([clip], engine=engine, config=config, progress=False).clips[0].pairs.region_points
              for engine in ("jax", "reference")}
    ungated = score_batch([clip], config=config.replace(depth_read_gate=0.0), progress=False).clips[0].pairs.region_points
    assert np.array_equal(counts["jax"], counts["reference"])
    assert counts["jax"].sum() < ungated.sum()


def test_authors_compat_never_gates():
    clip = add_noise(synth_clip(seed=1, **DEMO_SCENE), NoiseModel(px=2.0, ends="both"), seed=1)
    counts = [score_batch([clip], engine="reference", compat="authors", depth_read_gate=gate, progress=False).clips[0].pairs.region_points
              for gate in (0.0, GATE)]
    assert np.array_equal(*counts)


def test_a_negative_gate_is_refused():
    with pytest.raises(ValueError, match="depth_read_gate"):
        SGCConfig(depth_read_gate=-0.01)
