"""Evidence (docs/semantics.md §3.11): a component a pair could not measure is missing, never 0; a
pair counts in proportion to what it measured; a clip measured on little says so in its status,
reason and ``sgc_hi``."""

import dataclasses

import numpy as np
import pytest
from scenes import TINY

from sgc_jax import EvidenceLevels, score_batch
from sgc_jax.codes import PAIR_REASON_CODE
from sgc_jax.engines.evidence import (
    FULL_SEVERITY_SGC,
    LOW_EVIDENCE,
    camera_motion,
    cameras_outrun_tracks,
    fits_no_rigid_motion,
    pair_evidence,
    tracks_lost,
    upper_with_unseen,
)
from sgc_jax.research.adversaries import with_frames
from sgc_jax.research.synth import synth_clip

LEVELS = EvidenceLevels()


def test_a_pair_counts_in_proportion_to_what_it_measured():
    full = dict(tracks=LEVELS.full_tracks, trans=LEVELS.full_motion_trans, rot_deg=0.0, static_frac=1.0)
    evidence = lambda **changes: float(pair_evidence(True, **{**full, **changes}, levels=LEVELS))  # noqa: E731
    assert evidence() == 1.0 and evidence(tracks=10 * LEVELS.full_tracks, static_frac=1.0) == 1.0
    assert evidence(tracks=LEVELS.full_tracks / 2) == pytest.approx(0.5)
    assert evidence(trans=0.0, rot_deg=LEVELS.full_motion_rot_deg / 4) == pytest.approx(0.25)
    assert evidence(static_frac=LEVELS.full_static_frac / 2) == pytest.approx(0.5)
    assert float(pair_evidence(False, **full, levels=LEVELS)) == 0.0  # a component missing: nothing measured
    assert camera_motion(np.nan, np.nan, LEVELS) == 0.0


def test_a_pair_whose_cameras_outrun_its_tracks_counts_nothing():
    full = dict(tracks=LEVELS.full_tracks, trans=LEVELS.full_motion_trans, rot_deg=0.0, static_frac=1.0)
    outrun = lambda tracks_trans: cameras_outrun_tracks(  # noqa: E731
        full["trans"], full["rot_deg"], tracks_trans, 0.0, LEVELS)
    assert outrun(LEVELS.full_motion_trans / (LEVELS.cameras_outrun_tracks * 1.01))
    assert not outrun(LEVELS.full_motion_trans / (LEVELS.cameras_outrun_tracks * 0.99))
    assert not outrun(np.nan)  # the tracks' motion unknown: no test
    assert float(pair_evidence(True, **full, levels=LEVELS, outrun=True)) == 0.0


def test_a_pair_below_a_share_of_the_clips_median_tracks_has_lost_them():
    share = LEVELS.tracks_lost_share
    counts = np.array([1000, 1000, 1000 * share - 1, 1000 * share, 1000])
    assert tracks_lost(counts, np.ones(5, bool), LEVELS).tolist() == [False, False, True, False, False]
    assert not tracks_lost(counts, np.array([True, True, False, True, True]), LEVELS).any()  # not a pair of the clip
    assert not tracks_lost(np.zeros(4), np.ones(4, bool), LEVELS).any()  # no tracks anywhere: nothing was lost


def test_a_pair_whose_tracks_fit_no_readable_pose_breaks_the_clip_unless_they_were_lost():
    reasons = ("ok", "no_pose", "no_pose", "one_pose", "ill_conditioned", "ill_conditioned")
    reason = np.array([PAIR_REASON_CODE[r] for r in reasons])
    lost = np.array([False, False, True, False, False, True])
    assert fits_no_rigid_motion(reason, lost).tolist() == [False, True, False, False, True, False]


@pytest.mark.parametrize("engine", ["jax", "reference"])
def test_a_clip_whose_tracks_are_lost_between_two_frames_counts_no_evidence(engine):
    whole = synth_clip(seed=3, **TINY, noise_px=0.5)
    vis = whole.track_vis.copy()
    vis[whole.n_pairs // 2] = False  # a cut: the tracker loses every track between two frames
    cut = dataclasses.replace(whole, clip_id="cut", track_vis=vis)
    honest, broken = score_batch([whole, cut], engine=engine, progress=False).clips
    assert honest.evidence > 0.5 and "tracks_lost" not in honest.reason
    assert broken.evidence == 0.0 and broken.status == "low_evidence" and "tracks_lost x1" in broken.reason
    assert broken.sgc_hi >= broken.sgc + (FULL_SEVERITY_SGC - broken.sgc) - 1e-6


@pytest.mark.parametrize("engine", ["jax", "reference"])
def test_a_clip_whose_tracks_fit_no_rigid_motion_between_two_frames_counts_no_evidence(engine):
    whole = synth_clip(seed=3, **TINY, noise_px=0.5)
    curr = whole.track_curr.copy()
    pair = whole.n_pairs // 2
    curr[pair] = curr[pair][np.random.default_rng(0).permutation(whole.n_tracks)]  # every track matched at random
    broken = score_batch([dataclasses.replace(whole, clip_id="scrambled", track_curr=curr)], engine=engine,
                         progress=False).clips[0]
    assert broken.pairs.reason[pair] == "no_pose"
    assert broken.evidence == 0.0 and broken.status == "low_evidence" and "no_rigid_motion x1" in broken.reason


def test_under_the_authors_semantics_lost_tracks_leave_the_status_as_it_was():
    vis = (clip := synth_clip(seed=3, **TINY, noise_px=0.5)).track_vis.copy()
    vis[clip.n_pairs // 2] = False
    cut = score_batch([dataclasses.replace(clip, track_vis=vis)], engine="reference", compat="authors",
                      progress=False).clips[0]
    assert "tracks_lost" not in cut.reason and cut.evidence > 0.0


# The tracks' pose in float32 (JAX) and float64 (reference): the same Gauss-Newton updates from the
# same starts, so their rotations agree to rounding; 1e-3 deg is a thousandth of the motions compared.
TRACKS_MOTION_DEG = 1e-3


@pytest.mark.parametrize("engine", ["jax", "reference"])
def test_a_video_that_holds_still_under_moving_cameras_counts_no_evidence(engine):
    moving = synth_clip(seed=3, **TINY, noise_px=0.5)
    still = with_frames(moving, [0] * moving.n_frames)
    still = dataclasses.replace(still, clip_id="still", K=moving.K, R_wc=moving.R_wc, t_wc=moving.t_wc)
    honest, held = score_batch([moving, still], engine=engine, progress=False).clips
    assert honest.evidence > 0.5 and "cameras_outrun_tracks" not in honest.reason
    assert held.evidence == 0.0 and held.status == "low_evidence" and "cameras_outrun_tracks" in held.reason
    np.testing.assert_allclose(honest.pairs.tracks_rot_deg, honest.pairs.R_g_angle_deg, rtol=0.2)


def test_the_engines_agree_on_the_motion_the_tracks_show():
    clip = synth_clip(seed=3, **TINY, noise_px=0.5)
    by_jax, by_reference = (score_batch([clip], engine=e, progress=False).clips[0].pairs for e in ("jax", "reference"))
    np.testing.assert_allclose(by_jax.tracks_rot_deg, by_reference.tracks_rot_deg, atol=TRACKS_MOTION_DEG)
    np.testing.assert_allclose(by_jax.tracks_trans, by_reference.tracks_trans, rtol=1e-3)


def test_the_upper_bound_holds_what_an_unmeasured_share_could_hide():
    assert upper_with_unseen(0.1, 0.2, 1.0) == 0.2  # fully measured: the bootstrap's bound
    assert upper_with_unseen(0.0, 0.05, 0.0) == FULL_SEVERITY_SGC
    assert upper_with_unseen(0.2, np.nan, 0.5) == pytest.approx(0.2 + 0.5 * 0.8)
    assert np.isnan(upper_with_unseen(np.nan, np.nan, 0.0))


@pytest.fixture(scope="module")
def thin():
    """A TINY scene (reference engine) at 24 tracks per pair: one layer per pair."""
    return score_batch([synth_clip(seed=3, **{**TINY, "n_tracks": 24}, noise_px=0.5)], engine="reference",
                       progress=False).clips[0]


def test_a_clip_measured_on_little_is_never_a_plain_ok_with_score_zero(thin):
    assert thin.status == "low_evidence" and thin.evidence < LOW_EVIDENCE
    assert thin.reason.startswith(f"evidence {thin.evidence:.2f} < {LOW_EVIDENCE}") and "one_pose" in thin.reason
    assert np.isnan(thin.components["local_rot_var"]) and np.isnan(thin.components["local_trans_var"])
    assert thin.sgc_hi >= thin.sgc + (1 - thin.evidence) * (FULL_SEVERITY_SGC - thin.sgc) - 1e-12
    pairs = thin.pair_records()
    assert {p["reason"] for p in pairs} == {"one_pose"} and {p["evidence"] for p in pairs} == {0.0}
