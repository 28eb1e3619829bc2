"""The score formula (docs/semantics.md §5.1), written once: components -> SGC under a calibration.
``xp`` is the array module: NumPy in float64 (the tables), ``jax.numpy`` in float32 (the Scorer)."""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from .model import COMPONENTS, Calibration


def _float(xp) -> Any:
    return np.float64 if xp is np else xp.float32


def _as_float(m, xp) -> Any:
    """float64 in NumPy; in jax.numpy float32, or float64 where given (gradient checks)."""
    m = xp.asarray(m)
    return m.astype(np.float64) if xp is np else m.astype(xp.promote_types(m.dtype, xp.float32))


def transform(components: Mapping[str, Any], calibration: Calibration, xp=np) -> dict[str, Any]:
    """p_k: log1p(max(0, m_k)) for flagged components, m_k otherwise; arrays broadcast."""
    out = {}
    for k in COMPONENTS:
        m = _as_float(components[k], xp)
        out[k] = xp.log1p(xp.maximum(m, 0.0)) if calibration.log1p[k] else m
    return out


def normalise(components: Mapping[str, Any], calibration: Calibration, xp=np,
              floor_at_zero: bool = True) -> dict[str, Any]:
    """M''_k = max(0, (z_k - zmin_k) / (zmax_k - zmin_k)), z_k = (p_k - mu_k) / sigma_k.

    sigma_k = 0 gives z_k = 0, a zero z span gives M''_k = 0; NaN stays NaN; no upper clip; no
    floor either with ``floor_at_zero=False`` (the reward's unclipped form, §9.4).
    """
    p = transform(components, calibration, xp)
    out = {}
    for k in COMPONENTS:
        sigma, span = calibration.sigma[k], calibration.z_max[k] - calibration.z_min[k]
        z = (p[k] - calibration.mu[k]) / sigma if sigma != 0 else xp.where(xp.isnan(p[k]), np.nan, 0.0)
        scaled = (z - calibration.z_min[k]) / span if span != 0 else xp.where(xp.isnan(z), np.nan, 0.0)
        out[k] = xp.where(xp.isnan(scaled), np.nan, xp.maximum(scaled, 0.0) if floor_at_zero else scaled)
    return out


def sgc_score(components: Mapping[str, Any], calibration: Calibration, xp=np, floor_at_zero: bool = True) -> Any:
    """SGC = sum_k w_k M''_k / sum_k w_k over the non-NaN M''_k (NaN when all are NaN). Lower is better."""
    normalised = normalise(components, calibration, xp, floor_at_zero)
    stacked = xp.stack([normalised[k] for k in COMPONENTS], axis=-1)
    weights = xp.asarray([calibration.weight[k] for k in COMPONENTS], _float(xp))
    present = ~xp.isnan(stacked)
    total_weight = (weights * present).sum(-1)
    weighted = xp.where(present, stacked, 0.0) @ weights
    return xp.where(total_weight > 0, weighted / xp.where(total_weight > 0, total_weight, 1.0), np.nan)


# Where the smooth bound of the differentiable score departs from max(0, x) (docs/semantics.md §10.3),
# in units of the normalised components M'' (each spans 0..1 over the calibration's corpus).
SMOOTH_FLOOR_WIDTH = 0.05


def smooth_floor(x, width: float = SMOOTH_FLOOR_WIDTH, xp=np):
    """x for x >= width; width^2 / (2 width - x) below: C^1, positive, and its slope decays as
    1 / x^2, so a component far below the calibration's zero still has a gradient."""
    below = width**2 / (2.0 * width - xp.minimum(x, width))
    return xp.where(x >= width, x, below)


def sgc_smooth_score(components: Mapping[str, Any], present: Mapping[str, Any], calibration: Calibration,
                     xp=np, width: float = SMOOTH_FLOOR_WIDTH) -> Any:
    """The score with each M''_k's floor at 0 replaced by ``smooth_floor``, over the components
    where ``present`` (bool, same shapes); NaN where none is present, with a zero (not NaN)
    gradient. Equals ``sgc_score`` where every present M''_k >= width."""
    safe = {k: xp.where(present[k], components[k], 0.0) for k in COMPONENTS}  # no NaN enters the formula
    normalised = normalise(safe, calibration, xp, floor_at_zero=False)
    weights = [calibration.weight[k] * xp.asarray(present[k], normalised[k].dtype) for k in COMPONENTS]
    total_weight = sum(weights)
    weighted = sum(w * smooth_floor(normalised[k], width, xp) for w, k in zip(weights, COMPONENTS))
    return xp.where(total_weight > 0, weighted / xp.where(total_weight > 0, total_weight, 1.0), np.nan)
