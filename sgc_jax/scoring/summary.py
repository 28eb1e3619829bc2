"""A clip's summary from its per-pair arrays (docs/semantics.md §3.8, §3.10, §3.11, §5, §9.3),
written once for NumPy (float64: the tables, ``result.summarize_clip``) and ``jax.numpy``
(float32: the Scorer's device program): the components' means over pairs, the noise floors, the
score and its interval, the evidence, the camera's motion and the status."""

from __future__ import annotations

from typing import Any, Mapping

import jax.numpy as jnp
import numpy as np

from ..calibration import COMPONENTS, Calibration, sgc_score
from ..calibration.interval import score_interval
from ..codes import PAIR_REASON_CODE, SCORER_STATUS_CODE
from ..engines.evidence import (
    LOW_EVIDENCE,
    EvidenceLevels,
    cameras_outrun_tracks,
    clip_evidence,
    fits_no_rigid_motion,
    pair_evidence,
    parallax_px,
    pose_tracks,
    tracks_lost,
    upper_with_unseen,
)
from ..engines.noise_floors import floor_score, pair_floors
from ..stats import camera_dynamics, nanmean

# The per-clip columns ``summarize_pairs`` gives, besides the components and floors.
MEANS = ("reproj_error", "parallax_px", "static_frac")


def _float(xp):
    return np.float64 if xp is np else xp.float32


def summarize_pairs(pairs: Mapping[str, Any], pair_valid: Any, calibration: Calibration, compat: str,
                    levels: EvidenceLevels, xp=np) -> dict[str, Any]:
    """Per-pair arrays (..., n_pairs) (per-region ones (..., n_pairs, k); ``reason`` as
    PAIR_REASON_CODE; ``PairArrays.columns()`` names them) and the pairs each clip has (...,
    n_pairs) -> per-clip arrays (...,): sgc, sgc_lo, sgc_hi, the components, the floors, sgc_floor,
    evidence, pose_tracks, reproj_error, parallax_px, static_frac, ecd_trans, ecd_rot, status
    (SCORER_STATUS_CODE), n_pairs, n_pairs_scored, n_ill_conditioned; and per pair (..., n_pairs)
    ``pair_floors`` (a dict), ``pair_evidence`` and ``pair_breaks`` (a dict)."""
    mean = lambda values: nanmean(values, pair_valid, xp)  # noqa: E731
    components = {k: mean(pairs[k]) for k in COMPONENTS}
    per_pair_floors = pair_floors(pairs, compat, xp)
    floors = {name: mean(value) for name, value in per_pair_floors.items()}
    sgc = sgc_score(components, calibration, xp=xp, floors=floors)
    sgc_lo, sgc_hi = score_interval({k: pairs[k] for k in COMPONENTS}, sgc, calibration, pair_valid, xp=xp,
                                    pair_floors=per_pair_floors)
    per_pair_evidence, tracks = evidence_per_pair(pairs, levels, xp)
    evidence = xp.asarray(clip_evidence(per_pair_evidence, pair_valid, xp=xp), _float(xp))
    breaks = pair_breaks(pairs, pair_valid, compat, levels, xp)  # the clip is not measured as one world (§3.11)
    evidence = xp.where(xp.any(breaks["tracks_lost"] | breaks["no_rigid_motion"], axis=-1), 0.0, evidence)
    scored = xp.sum(pair_valid & (pairs["reason"] == PAIR_REASON_CODE["ok"]), axis=-1)
    return dict(
        sgc=sgc, sgc_lo=sgc_lo, sgc_hi=upper_with_unseen(sgc, sgc_hi, evidence, xp=xp), **components, **floors,
        sgc_floor=floor_score(floors, calibration, xp=xp), evidence=evidence, pose_tracks=mean(tracks),
        **{name: mean(pairs[name]) for name in MEANS},
        ecd_trans=mean(pairs["t_g_norm"]), ecd_rot=mean(pairs["R_g_angle_deg"]),
        status=clip_status(pairs["reason"], pair_valid, sgc, evidence, xp),
        n_pairs=xp.sum(pair_valid, axis=-1), n_pairs_scored=scored,
        n_ill_conditioned=xp.sum(xp.where(pair_valid, pairs["n_ill_conditioned"], 0), axis=-1),
        pair_floors=per_pair_floors, pair_evidence=per_pair_evidence, pair_breaks=breaks)


def pair_breaks(pairs: Mapping[str, Any], pair_valid: Any, compat: str, levels: EvidenceLevels,
                xp=np) -> dict[str, Any]:
    """Where the world breaks between a pair's two frames (docs/semantics.md §3.11), (..., n_pairs)
    bool each: ``tracks_lost``, and among the other pairs ``no_rigid_motion`` (their tracks fit no
    pose the score can read); none under compat="authors"."""
    if compat == "authors":
        none = xp.zeros(xp.shape(pair_valid), bool)
        return {"tracks_lost": none, "no_rigid_motion": none}
    lost = tracks_lost(pairs["n_tracks"], pair_valid, levels, xp)
    return {"tracks_lost": lost, "no_rigid_motion": fits_no_rigid_motion(pairs["reason"], lost) & pair_valid}


def evidence_per_pair(pairs: Mapping[str, Any], levels: EvidenceLevels, xp=np) -> tuple[Any, Any]:
    """(each pair's evidence (..., n_pairs) (docs/semantics.md §3.11), the tracks in its accepted
    local poses) from ``summarize_pairs``' per-pair arrays."""
    tracks = xp.asarray(pose_tracks(pairs["region_status"], pairs["region_points"], xp=xp), _float(xp))
    measured = pairs["reason"] == PAIR_REASON_CODE["ok"]
    outrun = cameras_outrun_tracks(pairs["t_g_norm"], pairs["R_g_angle_deg"], pairs["tracks_trans"],
                                   pairs["tracks_rot_deg"], levels, xp=xp)
    return pair_evidence(measured, tracks, pairs["t_g_norm"], pairs["R_g_angle_deg"], pairs["static_frac"], levels,
                         outrun, xp=xp), tracks


def clip_status(reason: Any, pair_valid: Any, sgc: Any, evidence: Any, xp=np) -> Any:
    """(...,) SCORER_STATUS codes from the pairs' reasons (..., n_pairs) and the clips' score and
    evidence (...,): why no pair was scored when every pair says the same (no usable tracks, no
    static depth), else low_evidence, ok, partial or error (docs/semantics.md §3.7, §9.3)."""
    n_pairs = xp.sum(pair_valid, axis=-1)
    every = lambda code: xp.all(xp.where(pair_valid, reason == code, True), axis=-1) & (n_pairs > 0)  # noqa: E731
    scored = xp.sum(pair_valid & (reason == PAIR_REASON_CODE["ok"]), axis=-1)
    return xp.select(
        [every(PAIR_REASON_CODE["too_few_tracks"]), every(PAIR_REASON_CODE["no_static"]),
         ~xp.isnan(sgc) & (evidence < LOW_EVIDENCE), ~xp.isnan(sgc) & (scored == n_pairs), ~xp.isnan(sgc)],
        [SCORER_STATUS_CODE[s] for s in ("no_tracks", "no_static", "low_evidence", "ok", "partial")],
        SCORER_STATUS_CODE["error"]).astype(np.int32)


def table_status(code: int, sgc: float) -> str:
    """The tables' status (docs/semantics.md §3.7) of a clip with SCORER_STATUS ``code``: a clip
    whose every pair lacks tracks or static depth is an error, or low_evidence when its depth
    error alone gives a score."""
    status = next(name for name, value in SCORER_STATUS_CODE.items() if value == code)
    if status in ("no_tracks", "no_static"):
        return "error" if np.isnan(sgc) else "low_evidence"
    return status


def summarize_on_device(out: Mapping[str, Any], pair_valid, depth_unit, K, image_hw, calibration: Calibration,
                        compat: str, levels: EvidenceLevels) -> dict[str, Any]:
    """The finish stage's output (leading axes B, T-1), the pairs each clip has (B, T-1), its D
    (B,), intrinsics (B, T, 3, 3) and true image size (B, 2) -> ``summarize_pairs``' per-clip
    arrays (B,) in float32, with ecd (over the B clips) and depth_unit."""
    image_pixels = (image_hw[:, 0] * image_hw[:, 1]).astype(jnp.float32)
    pairs = dict(out, static_frac=out["region_pixels"] / image_pixels[:, None],
                 parallax_px=parallax_px(K[:, 1:], out["t_g_norm"], compat != "authors", xp=jnp))
    summary = summarize_pairs(pairs, pair_valid, calibration, compat, levels, xp=jnp)
    del summary["pair_floors"], summary["pair_evidence"], summary["pair_breaks"]
    return dict(summary, ecd=camera_dynamics(summary["ecd_trans"], summary["ecd_rot"], xp=jnp), depth_unit=depth_unit)
