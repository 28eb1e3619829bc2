"""Tracks and poses against a clip's own geometry (sgc_jax.research.ground_truth, bench/realdata.py):
on a rigid clip every accepted pose is the camera's and every track sits on its exact position; a
layer that drifts shows as poses off the camera's whose tracks are off theirs."""

from __future__ import annotations

from sgc_jax import score_batch
from sgc_jax.research.ground_truth import region_motion_errors

# Exact synthetic tracks against their positions recomputed from float32 depth and cameras: 4e-6
# px and 2e-5 deg measured on the rigid scene; a thousand times that is still float32's rounding.
EXACT_PX, EXACT_DEG = 1e-3, 1e-2


def test_a_rigid_clips_poses_are_the_cameras_and_its_tracks_sit_on_their_exact_positions(rigid_clip):
    records = region_motion_errors(rigid_clip, score_batch([rigid_clip], progress=False).clips[0].pairs)
    assert len(records) >= rigid_clip.n_pairs  # every pair has accepted poses to judge
    assert max(r["median_px"] for r in records) < EXACT_PX
    assert max(r["deg_off"] for r in records) < EXACT_DEG
    assert all(r["share_off"] == 0.0 for r in records)


def test_a_drifting_layers_poses_and_tracks_are_off_the_cameras_motion(drift_clip):
    records = region_motion_errors(drift_clip, score_batch([drift_clip], progress=False).clips[0].pairs)
    drifting = [r for r in records if r["share_off"] > 0.5]
    assert drifting, "the drifting layer's tracks are > 3 px off the camera's motion in some region"
    assert all(r["median_px"] > 3.0 for r in drifting)
    assert max(r["deg_off"] for r in drifting) > 1.0
    # and the layers that do not drift stay on it
    assert min(r["median_px"] for r in records) < EXACT_PX
