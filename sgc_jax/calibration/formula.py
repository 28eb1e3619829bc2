"""The score formula (docs/semantics.md §5.1), written once: components -> SGC under a calibration."""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from .model import COMPONENTS, Calibration


def transform(components: Mapping[str, Any], calibration: Calibration) -> dict[str, np.ndarray]:
    """p_k: log1p(max(0, m_k)) for flagged components, m_k otherwise; arrays broadcast."""
    out = {}
    for k in COMPONENTS:
        m = np.asarray(components[k], np.float64)
        out[k] = np.log1p(np.maximum(m, 0.0)) if calibration.log1p[k] else m
    return out


def normalise(components: Mapping[str, Any], calibration: Calibration) -> dict[str, np.ndarray]:
    """M''_k = max(0, (z_k - zmin_k) / (zmax_k - zmin_k)), z_k = (p_k - mu_k) / sigma_k.

    sigma_k = 0 gives z_k = 0, a zero z span gives M''_k = 0; NaN stays NaN; no upper clip.
    """
    p = transform(components, calibration)
    out = {}
    for k in COMPONENTS:
        sigma, span = calibration.sigma[k], calibration.z_max[k] - calibration.z_min[k]
        z = (p[k] - calibration.mu[k]) / sigma if sigma != 0 else np.where(np.isnan(p[k]), np.nan, 0.0)
        scaled = (z - calibration.z_min[k]) / span if span != 0 else np.where(np.isnan(z), np.nan, 0.0)
        out[k] = np.where(np.isnan(scaled), np.nan, np.maximum(scaled, 0.0))
    return out


def sgc_score(components: Mapping[str, Any], calibration: Calibration) -> np.ndarray:
    """SGC = sum_k w_k M''_k / sum_k w_k over the non-NaN M''_k (NaN when all are NaN). Lower is better."""
    normalised = normalise(components, calibration)
    stacked = np.stack([normalised[k] for k in COMPONENTS], axis=-1)
    weights = np.array([calibration.weight[k] for k in COMPONENTS])
    present = ~np.isnan(stacked)
    total_weight = (weights * present).sum(-1)
    weighted = np.where(present, stacked, 0.0) @ weights
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(total_weight > 0, weighted / np.where(total_weight > 0, total_weight, 1.0), np.nan)
