"""Pose jitter (sgc_jax.research.pose_jitter, docs/semantics.md §3.10): how much each layer's pose
changes between pairs against what the floors' pose noise gives that change. Per-pair arrays built
by hand, so the ratio's law is known."""

from __future__ import annotations

import numpy as np
import pytest

from sgc_jax.codes import REGION_OK
from sgc_jax.engines.pairs import empty_pair_arrays
from sgc_jax.engines.reference import so3_exp
from sgc_jax.research.pose_jitter import pose_jitter, rotation_log_deg

N_PAIRS, SLOTS = 200, 8
# 200 pairs of 8 layers: the ratio's spread over 20 seeds is 3.7 % (relative); four of it.
RATIO_TOL = 0.15


def hand_made_pairs(offsets_deg: float, offsets_pct: float, noise_scale: float, seed: int = 0):
    """Every pair with SLOTS accepted poses of unequal weights and noises; each pose = its slot's
    fixed offset (the same in every pair) + an independent error noise_scale times the noise the
    floors count (region_rot_noise, region_trans_noise)."""
    rng = np.random.default_rng(seed)
    pairs = empty_pair_arrays(N_PAIRS, SLOTS)
    pairs.region_status[:] = REGION_OK
    pairs.region_rot_per_px[:] = rng.uniform(0.5, 2.0, (N_PAIRS, SLOTS))
    pairs.region_trans_per_px[:] = rng.uniform(0.5, 2.0, (N_PAIRS, SLOTS))
    pairs.region_rot_noise[:] = rng.uniform(0.2, 1.0, (N_PAIRS, SLOTS))  # deg
    pairs.region_trans_noise[:] = rng.uniform(0.002, 0.01, (N_PAIRS, SLOTS))  # units of D
    slot_rot = rng.normal(0.0, offsets_deg, (SLOTS, 3))
    slot_trans = rng.normal(0.0, offsets_pct / 100.0, (SLOTS, 3))
    error = lambda noise: rng.normal(size=(N_PAIRS, SLOTS, 3)) * noise[..., None] / np.sqrt(3)  # noqa: E731
    rotvecs = 2.0 + slot_rot + noise_scale * error(pairs.region_rot_noise)  # the camera turns by ~3.5 deg
    pairs.R_local[:] = np.array([[so3_exp(np.radians(v)) for v in row] for row in rotvecs])
    pairs.t_local[:] = 0.01 + slot_trans + noise_scale * error(pairs.region_trans_noise)
    return pairs


def test_rotation_vectors_hold_from_tiny_to_large_angles():
    for angle in (1e-6, 1e-3, 3.0, 90.0, 170.0):
        v = angle * np.array([0.6, -0.48, 0.64])
        assert np.allclose(rotation_log_deg(so3_exp(np.radians(v))), v, rtol=1e-6, atol=0.0)


def test_jitter_is_one_when_the_poses_carry_the_noise_the_floors_count():
    jitter = pose_jitter(hand_made_pairs(offsets_deg=0.0, offsets_pct=0.0, noise_scale=1.0))
    assert jitter.compared == (N_PAIRS - 1) * SLOTS * (SLOTS - 1) // 2
    assert jitter.rot == pytest.approx(1.0, abs=RATIO_TOL)
    assert jitter.trans == pytest.approx(1.0, abs=RATIO_TOL)


def test_errors_larger_than_the_floors_count_raise_it_by_their_variance():
    jitter = pose_jitter(hand_made_pairs(offsets_deg=0.0, offsets_pct=0.0, noise_scale=3.0))
    assert jitter.rot == pytest.approx(9.0, rel=RATIO_TOL)
    assert jitter.trans == pytest.approx(9.0, rel=RATIO_TOL)


def test_a_disagreement_that_persists_across_pairs_leaves_it_at_one():
    # layers 3 deg and 5 % of D apart, several times their noise, the same in every pair
    jitter = pose_jitter(hand_made_pairs(offsets_deg=3.0, offsets_pct=5.0, noise_scale=1.0))
    assert jitter.rot == pytest.approx(1.0, abs=RATIO_TOL)
    assert jitter.trans == pytest.approx(1.0, abs=RATIO_TOL)


def test_pairs_with_fewer_than_two_poses_compare_nothing():
    pairs = hand_made_pairs(offsets_deg=0.0, offsets_pct=0.0, noise_scale=1.0)
    pairs.region_status[:, 1:] = REGION_OK + 1  # one accepted pose a pair
    jitter = pose_jitter(pairs)
    assert jitter.compared == 0 and np.isnan(jitter.rot) and np.isnan(jitter.trans)
