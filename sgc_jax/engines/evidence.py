"""Evidence (docs/semantics.md §3.11): how much of each pair's geometry the score measured, and so
how large an inconsistency it could have missed. Written once for NumPy (the tables, float64) and
``jax.numpy`` (the Scorer, float32)."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from ..codes import PAIR_REASON_CODE, REGION_OK
from .units import PERCENT


@dataclasses.dataclass(frozen=True)
class EvidenceLevels:
    """Where a pair counts as fully measured (docs/semantics.md §3.11): each level is a floor, more
    than it adds nothing. ``full_tracks`` and ``full_static_frac`` fitted on the FIT split
    (bench/evidence_levels.py); the full-motion levels are the reward's design (§9.4)."""

    full_tracks: float = 360.0  # tracks in the pair's accepted local poses
    full_motion_trans: float = 1.0  # camera translation of the pair [% of D] ...
    full_motion_rot_deg: float = 0.5  # ... or its rotation [deg]
    full_static_frac: float = 0.2  # share of the frame that is static with valid depth
    # a pair whose cameras move more than this many times what its tracks show counts nothing: the
    # cameras claim a motion the video does not show (a video held still under the cameras it was
    # asked to follow); chosen on FIT's battery: every other clip's pairs at most 4.4, still videos 15 up
    cameras_outrun_tracks: float = 5.0
    # a clip with a pair whose usable tracks fall below this share of its pairs' median counts no
    # evidence: the tracker lost the world between two frames (a cut), and the two sides are not
    # measured as one world (nor where the tracks are there but fit no readable pose,
    # ``fits_no_rigid_motion``);
    # not fitted: a cut leaves 0-0.007, the real clips' least pair 0.65
    tracks_lost_share: float = 0.25

    def __post_init__(self) -> None:
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            if not value > 0:  # 0 would divide by zero into a NaN evidence
                raise ValueError(f"EvidenceLevels.{field.name} must be > 0, got {value!r}")


# A clip whose evidence (the mean over its pairs) is below this has status low_evidence: less than
# half of its pairs' worth of geometry was measured as the score needs.
LOW_EVIDENCE = 0.5
# The score the calibrations give a fully perturbed clip (their fit rule puts full severity at 1,
# docs/semantics.md §5.4): what an unmeasured part of a clip could hide, for ``sgc_hi``.
FULL_SEVERITY_SGC = 1.0


def pose_tracks(region_status: Any, region_points: Any, xp=np) -> Any:
    """(..., k) region statuses and members -> (...,) the tracks in the pair's accepted local poses."""
    return xp.sum(xp.where(region_status == REGION_OK, region_points, 0), axis=-1)


def parallax_px(K_curr: Any, t_g_norm: Any, scale_free: bool, xp=np) -> Any:
    """(..., 3, 3) intrinsics of frame i and ``t_g_norm`` (...,) [% of D] -> (...,) the image motion
    [px] of a point at depth D, seen square-on, from the camera's translation: f ‖s t_g‖ / D, f the
    mean of fx and fy. NaN under compat="authors" (t_g in pose units)."""
    if not scale_free:
        return xp.full(xp.shape(t_g_norm), np.nan)
    focal = 0.5 * (K_curr[..., 0, 0] + K_curr[..., 1, 1])
    return focal * t_g_norm / PERCENT


def camera_motion(trans: Any, rot_deg: Any, levels: EvidenceLevels, xp=np) -> Any:
    """The camera's motion against the full-motion level, max(trans / full_motion_trans, rot /
    full_motion_rot_deg): per pair from ``t_g_norm`` and ``R_g_angle_deg``, per clip from
    ``ecd_trans`` and ``ecd_rot``; NaN counts 0."""
    motion = xp.fmax(trans / levels.full_motion_trans, rot_deg / levels.full_motion_rot_deg)
    return xp.where(xp.isnan(motion), 0.0, motion)


def cameras_outrun_tracks(trans: Any, rot_deg: Any, tracks_trans: Any, tracks_rot_deg: Any, levels: EvidenceLevels,
                          xp=np) -> Any:
    """(...,) bool: the camera's motion (``trans``, ``rot_deg``) exceeds ``levels.cameras_outrun_tracks``
    times the tracks' (``tracks_trans``, ``tracks_rot_deg``: the pose that fits them best; NaN: not
    known, never outrun), both against the full-motion levels."""
    tracks = camera_motion(tracks_trans, tracks_rot_deg, levels, xp)
    known = ~xp.isnan(tracks_rot_deg) & ~xp.isnan(tracks_trans)
    return known & (camera_motion(trans, rot_deg, levels, xp) > levels.cameras_outrun_tracks * tracks)


def pair_evidence(measured: Any, tracks: Any, trans: Any, rot_deg: Any, static_frac: Any, levels: EvidenceLevels,
                  outrun: Any = False, xp=np) -> Any:
    """(...,) in [0, 1]: 0 for a pair that lacks a component (``measured`` False) or whose cameras
    outrun its tracks (``outrun``, ``cameras_outrun_tracks``), else the product of its tracks,
    camera motion and static share, each against its full level and capped at 1."""
    def share(value, full):
        return xp.clip(xp.asarray(value) / full, 0.0, 1.0)

    value = (share(tracks, levels.full_tracks) * xp.clip(camera_motion(trans, rot_deg, levels, xp), 0.0, 1.0)
             * share(static_frac, levels.full_static_frac))
    return xp.where(measured & ~xp.asarray(outrun), value, 0.0)


def tracks_lost(n_tracks: Any, pair_valid: Any, levels: EvidenceLevels, xp=np) -> Any:
    """(..., T-1) usable tracks per pair and the pairs each clip has -> (..., T-1) bool: a pair whose
    usable tracks fall below ``levels.tracks_lost_share`` of the median over the clip's pairs."""
    counts = xp.where(pair_valid, xp.asarray(n_tracks) * 1.0, np.nan)
    median = xp.nanmedian(counts, axis=-1, keepdims=True)
    return pair_valid & (counts < levels.tracks_lost_share * median)


def fits_no_rigid_motion(reason: Any, lost: Any) -> Any:
    """(..., T-1) pair reasons (PAIR_REASON_CODE) and ``tracks_lost`` -> (..., T-1) bool: a pair whose
    tracks are there but fit no pose the score can read (reason ``no_pose``, or ``ill_conditioned``:
    every fitted pose left out by the region-quality rule): the world breaks there too."""
    unread = (reason == PAIR_REASON_CODE["no_pose"]) | (reason == PAIR_REASON_CODE["ill_conditioned"])
    return unread & ~lost


def clip_evidence(per_pair: Any, pair_valid: Any, xp=np) -> Any:
    """(..., T-1) pair evidence and the pairs each clip has -> (...,) the mean over its pairs (0 with none)."""
    count = xp.sum(pair_valid, axis=-1)
    return xp.sum(xp.where(pair_valid, per_pair, 0.0), axis=-1) / xp.maximum(count, 1)


def upper_with_unseen(sgc: Any, sgc_hi: Any, evidence: Any, xp=np) -> Any:
    """``sgc_hi`` raised to what the unmeasured share 1 − e of a clip could hide: the score were that
    share fully perturbed, sgc + (1 − e) max(0, 1 − sgc) (``FULL_SEVERITY_SGC`` = 1); a NaN
    ``sgc_hi`` (fewer than 2 scored pairs) takes this bound too."""
    hidden = sgc + (1.0 - evidence) * xp.maximum(FULL_SEVERITY_SGC - sgc, 0.0)
    return xp.where(xp.isnan(sgc), sgc_hi, xp.fmax(sgc_hi, xp.where(evidence < 1.0, hidden, sgc_hi)))


def shortfall(tracks: np.ndarray, trans: np.ndarray, rot_deg: np.ndarray, static_frac: np.ndarray,
              measured: np.ndarray, levels: EvidenceLevels, outrun: np.ndarray | bool = False,
              lost: np.ndarray | bool = False, no_rigid_motion: np.ndarray | bool = False) -> str:
    """Text for a clip's reason: how many of its measured pairs fall short of each full level,
    e.g. ``"below full: tracks x3, motion x2"``, whose cameras outrun their tracks, and how many
    pairs lost the clip's tracks (``tracks_lost``) or hold tracks that fit no readable pose
    (``fits_no_rigid_motion``; "" when none of these)."""
    short = {"tracks": tracks < levels.full_tracks, "motion": camera_motion(trans, rot_deg, levels) < 1.0,
             "static": static_frac < levels.full_static_frac}
    counts = {name: int(np.sum(below & measured)) for name, below in short.items()}
    listed = ", ".join(f"{name} x{n}" for name, n in counts.items() if n)
    outruns = int(np.sum(np.asarray(outrun) & measured))
    breaks = {"tracks_lost": int(np.sum(lost)), "no_rigid_motion": int(np.sum(no_rigid_motion))}
    parts = ([f"{name} x{n}" for name, n in breaks.items() if n] + ([f"below full: {listed}"] if listed else [])
             + ([f"cameras_outrun_tracks x{outruns}"] if outruns else []))
    return "; ".join(parts)
