"""The Scorer's reward (docs/semantics.md §9.4): higher is better, ranks clips the calibration
scores 0, and pays nothing for a clip that a static camera, an all-dynamic mask or missing
tracks would make look consistent."""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp

from ..calibration import COMPONENTS, Calibration, sgc_score
from ..codes import SCORER_STATUS_CODE
from ..io.tables import FLOOR_COLUMNS

# The logistic's exponent is clipped here: exp(60) ~ 1e26 is finite in float32, and beyond it the
# reward is 0 or 1 to float32's precision anyway.
EXPONENT_LIMIT = 60.0


@dataclasses.dataclass(frozen=True)
class RewardOptions:
    """The reward's constants (docs/semantics.md §9.4)."""

    full_motion_trans: float = 1.0  # camera translation per frame pair earning the full reward [% of D]
    full_motion_rot_deg: float = 0.5  # ... or camera rotation per frame pair [deg]
    temperature: float = 0.25  # width of the logistic in units of the unclipped score

    def __post_init__(self) -> None:
        for name in ("full_motion_trans", "full_motion_rot_deg", "temperature"):
            value = getattr(self, name)
            if not value > 0:  # 0 would divide by zero into a NaN reward
                raise ValueError(f"RewardOptions.{name} must be > 0, got {value!r}")


def reward(summary: dict, calibration: Calibration, options: RewardOptions) -> dict:
    """Per clip (B,): ``sgc_unclipped``, ``camera_motion``, ``reward``, and the status
    ``static_camera`` for a scored clip whose camera moves less than the full-motion level."""
    unclipped = sgc_score({k: summary[k] for k in COMPONENTS}, calibration, xp=jnp, floor_at_zero=False,
                          floors={k: summary[k] for k in FLOOR_COLUMNS})
    motion = jnp.fmax(summary["ecd_trans"] / options.full_motion_trans, summary["ecd_rot"] / options.full_motion_rot_deg)
    motion = jnp.where(jnp.isnan(motion), 0.0, motion)
    gate = jnp.clip(motion, 0.0, 1.0)
    coverage = summary["n_pairs_scored"] / jnp.maximum(summary["n_pairs"], 1)
    quality = 1.0 / (1.0 + jnp.exp(jnp.clip(unclipped / options.temperature, -EXPONENT_LIMIT, EXPONENT_LIMIT)))
    scored = (summary["status"] == SCORER_STATUS_CODE["ok"]) | (summary["status"] == SCORER_STATUS_CODE["partial"])
    value = jnp.where(scored & ~jnp.isnan(unclipped), quality * gate * coverage, 0.0)
    status = jnp.where(scored & (motion < 1.0), SCORER_STATUS_CODE["static_camera"], summary["status"])
    return dict(sgc_unclipped=unclipped, camera_motion=motion, reward=value.astype(jnp.float32),
                status=status.astype(jnp.int32))
