"""Per-clip summaries on the device (docs/semantics.md §9.3): the finish stage's per-pair arrays
-> the columns ``scoring.result.summarize_clip`` and ``camera_dynamics`` give, in float32."""

from __future__ import annotations

import jax.numpy as jnp

from ...calibration import COMPONENTS, Calibration, sgc_score
from ...calibration.interval import score_interval
from ...codes import PAIR_REASON_CODE, SCORER_STATUS_CODE
from ...io.tables import FLOOR_COLUMNS
from ...stats import camera_dynamics
from ..evidence import (
    LOW_EVIDENCE,
    EvidenceLevels,
    clip_evidence,
    pair_evidence,
    parallax_px,
    pose_tracks,
    upper_with_unseen,
)
from ..noise_floors import floor_score, floors_of
from ..units import PERCENT


def nanmean(values, mask):
    """Mean over the last axis of the non-NaN values where ``mask`` (NaN when there are none)."""
    keep = mask & ~jnp.isnan(values)
    count = jnp.sum(keep, axis=-1)
    total = jnp.sum(jnp.where(keep, values, 0.0), axis=-1)
    return jnp.where(count > 0, total / jnp.maximum(count, 1), jnp.nan)


def clip_status(reason, pair_valid, sgc, evidence):
    """(B,) SCORER_STATUS codes from the pairs' reasons (B, T-1) and the clips' evidence (B,): why
    no pair was scored when every pair says the same (no usable tracks, no static depth; the tables
    call such a clip partial when its depth error alone gives a score), else low_evidence, ok,
    partial or error as the tables."""
    n_pairs = jnp.sum(pair_valid, axis=-1)
    every = lambda code: jnp.all(jnp.where(pair_valid, reason == code, True), axis=-1) & (n_pairs > 0)  # noqa: E731
    scored = jnp.sum(pair_valid & (reason == PAIR_REASON_CODE["ok"]), axis=-1)
    return jnp.select(
        [every(PAIR_REASON_CODE["too_few_tracks"]), every(PAIR_REASON_CODE["no_static"]),
         ~jnp.isnan(sgc) & (evidence < LOW_EVIDENCE), ~jnp.isnan(sgc) & (scored == n_pairs), ~jnp.isnan(sgc)],
        [SCORER_STATUS_CODE[s] for s in ("no_tracks", "no_static", "low_evidence", "ok", "partial")],
        SCORER_STATUS_CODE["error"]).astype(jnp.int32)


def pair_floors(out: dict, pair_valid, compat: str) -> dict:
    """The noise floors (docs/semantics.md §3.10) of each pair (B, T-1); NaN under compat="authors"."""
    if compat == "authors":
        return {name: jnp.full(pair_valid.shape, jnp.nan) for name in FLOOR_COLUMNS}
    return floors_of(out["region_status"], out["region_rot_noise"], PERCENT * out["region_trans_noise"],
                     {k: out[k] for k in COMPONENTS}, xp=jnp)


def evidence_on_device(out: dict, pair_valid, K, image_hw, levels: EvidenceLevels, compat: str) -> dict:
    """The evidence of docs/semantics.md §3.11: per clip (B,) ``evidence`` and the means over its
    pairs of ``pose_tracks``, ``parallax_px``, ``static_frac``; ``K`` (B, T, 3, 3), ``image_hw`` (B, 2)."""
    tracks = pose_tracks(out["region_status"], out["region_points"], xp=jnp).astype(jnp.float32)
    image_pixels = (image_hw[:, 0] * image_hw[:, 1]).astype(jnp.float32)
    static_frac = out["region_pixels"] / image_pixels[:, None]
    parallax = parallax_px(K[:, 1:], out["t_g_norm"], compat != "authors", xp=jnp)
    measured = out["reason"] == PAIR_REASON_CODE["ok"]
    per_pair = pair_evidence(measured, tracks, out["t_g_norm"], out["R_g_angle_deg"], static_frac, levels, xp=jnp)
    return dict(evidence=clip_evidence(per_pair, pair_valid, xp=jnp).astype(jnp.float32),
                pose_tracks=nanmean(tracks, pair_valid), parallax_px=nanmean(parallax, pair_valid),
                static_frac=nanmean(static_frac, pair_valid))


def summarize_on_device(out: dict, pair_valid, depth_unit, K, image_hw, calibration: Calibration, compat: str,
                        levels: EvidenceLevels) -> dict:
    """The finish stage's output (leading axes B, T-1), the pairs each clip has (B, T-1), its D
    (B,), intrinsics (B, T, 3, 3) and true image size (B, 2) -> per-clip arrays (B,): the
    components, sgc and its interval, the noise floors, the evidence, ecd_trans, ecd_rot, ecd,
    status and counts."""
    mean = lambda name: nanmean(out[name], pair_valid)  # noqa: E731
    components = {k: mean(k) for k in COMPONENTS}
    per_pair_floors = pair_floors(out, pair_valid, compat)
    floors = {name: nanmean(value, pair_valid) for name, value in per_pair_floors.items()}
    sgc = sgc_score(components, calibration, xp=jnp, floors=floors)
    sgc_lo, sgc_hi = score_interval(out, sgc, calibration, pair_valid, xp=jnp, pair_floors=per_pair_floors)
    evidence = evidence_on_device(out, pair_valid, K, image_hw, levels, compat)
    sgc_hi = upper_with_unseen(sgc, sgc_hi, evidence["evidence"], xp=jnp)
    ecd_trans, ecd_rot = mean("t_g_norm"), mean("R_g_angle_deg")
    reason = out["reason"]
    return dict(
        sgc=sgc, sgc_lo=sgc_lo, sgc_hi=sgc_hi, **components, **floors, **evidence,
        sgc_floor=floor_score(floors, calibration, xp=jnp),
        reproj_error=mean("reproj_error"), ecd_trans=ecd_trans, ecd_rot=ecd_rot,
        ecd=camera_dynamics(ecd_trans, ecd_rot, xp=jnp), status=clip_status(reason, pair_valid, sgc, evidence["evidence"]),
        n_pairs=jnp.sum(pair_valid, axis=-1, dtype=jnp.int32),
        n_pairs_scored=jnp.sum(pair_valid & (reason == PAIR_REASON_CODE["ok"]), axis=-1, dtype=jnp.int32),
        n_ill_conditioned=jnp.sum(jnp.where(pair_valid, out["n_ill_conditioned"], 0), axis=-1, dtype=jnp.int32),
        depth_unit=depth_unit)
