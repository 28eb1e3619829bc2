"""Shared fixtures: small synthetic scenes reused across test files (built once per session)."""

import os

import pytest

os.environ.setdefault("XLA_FLAGS", "--xla_cpu_multi_thread_eigen=true")

from sgc_jax.synth import synth_clip  # noqa: E402

# Well-conditioned scenes: two planar layers (one slanted) plus four static spheres, so every
# depth region is a curved 3D point set. Small planar patches are the ill-posed case where any
# PnP-RANSAC (OpenCV's included) may return the planar-ambiguity twin pose (see issue 7).
SCENE = dict(n_layers=2, static_spheres=4, height=120, width=160, n_tracks=2048, n_frames=4)


@pytest.fixture(scope="session")
def rigid_clip():
    return synth_clip(seed=1, clip_id="rigid", group="rigid", **SCENE)


@pytest.fixture(scope="session")
def moving_clip():
    return synth_clip(seed=2, clip_id="moving", group="moving", moving_objects=2, **SCENE)


@pytest.fixture(scope="session")
def noisy_clip():
    return synth_clip(seed=3, clip_id="noisy", group="noisy", noise_px=1.0, outlier_frac=0.3, **SCENE)


@pytest.fixture(scope="session")
def drift_clip():
    return synth_clip(seed=1, clip_id="drift", group="drift", layer_drift=0.15, **SCENE)
