"""The score formula (docs/semantics.md §5.1), written once: components -> SGC under a calibration.
``xp`` is the array module: NumPy in float64 (the tables), ``jax.numpy`` in float32 (the Scorer)."""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from .model import COMPONENTS, Calibration


def _float(xp) -> Any:
    return np.float64 if xp is np else xp.float32


def transform(components: Mapping[str, Any], calibration: Calibration, xp=np) -> dict[str, Any]:
    """p_k: log1p(max(0, m_k)) for flagged components, m_k otherwise; arrays broadcast."""
    out = {}
    for k in COMPONENTS:
        m = xp.asarray(components[k], _float(xp))
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
