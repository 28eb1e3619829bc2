"""The Scorer's reward (docs/semantics.md §9.4): higher is better, ranks clips the calibration
scores 0, and pays only for the consistency it measured: a clip's reward is scaled by its
evidence (§3.11), so that what a static camera, a thin static area or few tracks leave unseen
earns nothing for being unseen; and the depth error counts in it beyond its share of SGC, since
without parallax it alone sees a depth inconsistency."""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp

from ..calibration import COMPONENTS, Calibration, normalise, sgc_score
from ..codes import SCORER_STATUS_CODE
from ..engines.evidence import EvidenceLevels, camera_motion
from ..io.tables import FLOOR_COLUMNS

# The logistic's exponent is clipped here: exp(60) ~ 1e26 is finite in float32, and beyond it the
# reward is 0 or 1 to float32's precision anyway.
EXPONENT_LIMIT = 60.0


@dataclasses.dataclass(frozen=True)
class RewardOptions:
    """The reward's constants (docs/semantics.md §9.4)."""

    temperature: float = 0.25  # width of the logistic in units of the unclipped score
    depth_weight: float = 0.2  # the depth error's M'' counted again, with this weight (fitted on FIT, rule D2)
    evidence: EvidenceLevels = EvidenceLevels()  # where a pair counts as fully measured, motion included (§3.11)

    def __post_init__(self) -> None:
        if not self.temperature > 0:  # 0 would divide by zero into a NaN reward
            raise ValueError(f"RewardOptions.temperature must be > 0, got {self.temperature!r}")
        if not self.depth_weight >= 0:  # a negative weight would pay for a depth inconsistency
            raise ValueError(f"RewardOptions.depth_weight must be >= 0, got {self.depth_weight!r}")


def reward(summary: dict, calibration: Calibration, options: RewardOptions, xp=jnp) -> dict:
    """Per clip (B,): ``sgc_unclipped``, ``camera_motion``, ``reward`` = σ(−(``sgc_unclipped`` +
    ``depth_weight`` · M''_depth) / τ) · evidence (M''_depth ≥ 0, §5.1), and the status
    ``static_camera`` for a scored clip whose camera moves less than the full-motion level.
    ``summary``: the per-clip components, floors, ``ecd_trans``, ``ecd_rot``, ``evidence`` and
    ``status`` (SCORER_STATUS codes); ``xp``: jax.numpy (the Scorer) or NumPy (``BatchResult.rewards``)."""
    components = {k: summary[k] for k in COMPONENTS}
    unclipped = sgc_score(components, calibration, xp=xp, floor_at_zero=False,
                          floors={k: summary[k] for k in FLOOR_COLUMNS})
    # the depth error has no floor or excess, so its M'' is read from the components as they are;
    # counted only above the calibration's zero: a still pair's depth error is no evidence of a
    # consistent world (repeated frames have the smallest)
    depth = normalise(components, calibration, xp=xp)["depth_error"]
    graded = unclipped + options.depth_weight * xp.where(xp.isnan(depth), 0.0, depth)
    motion = camera_motion(summary["ecd_trans"], summary["ecd_rot"], options.evidence, xp)
    quality = 1.0 / (1.0 + xp.exp(xp.clip(graded / options.temperature, -EXPONENT_LIMIT, EXPONENT_LIMIT)))
    scored = xp.isin(summary["status"], xp.asarray([SCORER_STATUS_CODE[s] for s in ("ok", "partial", "low_evidence")]))
    value = xp.where(scored & ~xp.isnan(unclipped), quality * summary["evidence"], 0.0)
    status = xp.where(scored & (motion < 1.0), SCORER_STATUS_CODE["static_camera"], summary["status"])
    return dict(sgc_unclipped=unclipped, camera_motion=motion, reward=value.astype(xp.float32),
                status=status.astype(xp.int32))
