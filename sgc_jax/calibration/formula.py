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


POSE_COMPONENTS = COMPONENTS[:4]  # the components with a noise floor (docs/semantics.md §3.10)
FLOOR_COLUMNS = tuple(f"{k}_floor" for k in POSE_COMPONENTS)  # their floors' columns
# float32's own floor under an excess calibration, in the components' units (deg^2, (% of D)^2): a
# noise-free rigid clip's poses disagree by 1e-10 to 1e-9 in float32 arithmetic, which no floor
# from the fits' residuals describes; 1e-6 deg^2 is a spread of 0.001 deg.
NUMERICAL_FLOOR = 1e-6


def excess_over_floors(components: Mapping[str, Any], floors: Mapping[str, Any], floor_band: float,
                       xp=np) -> dict[str, Any]:
    """The components with each pose component replaced by its excess over its band,
    max(0, m_k - floor_band * floor_k - NUMERICAL_FLOOR) (a NaN floor counts as 0; the depth error
    as it is). ``floors``: "<component>_floor" -> arrays like the components'."""
    out = dict(components)
    for k in POSE_COMPONENTS:
        floor = _as_float(floors[f"{k}_floor"], xp)
        band = floor_band * xp.where(xp.isnan(floor), 0.0, floor)
        out[k] = xp.maximum(_as_float(components[k], xp) - band - NUMERICAL_FLOOR, 0.0)
    return out


def scored_values(components: Mapping[str, Any], calibration: Calibration, floors: Mapping[str, Any] | None,
                  xp=np) -> Mapping[str, Any]:
    """What the formula reads: the components, or under an ``excess`` calibration their
    ``excess_over_floors``."""
    if not calibration.excess:
        return components
    if floors is None:
        raise ValueError(f"calibration {calibration.name!r} scores the pose components' excess over their noise "
                         "floors (docs/semantics.md §5.1): the floors are needed (columns <component>_floor)")
    return excess_over_floors(components, floors, calibration.floor_band, xp)


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
        if sigma == 0:
            z_above = xp.where(xp.isnan(p[k]), np.nan, 0.0 - calibration.z_min[k])
        elif calibration.excess and k in POSE_COMPONENTS:
            # z - z_min as p / sigma - (z_min + mu / sigma): the offset (0 when z_min is the z of no
            # excess) is a float64 constant, so no excess gives exactly 0 in float32 too
            z_above = p[k] / sigma - (calibration.z_min[k] + calibration.mu[k] / sigma)
        else:
            z_above = (p[k] - calibration.mu[k]) / sigma - calibration.z_min[k]
        scaled = z_above / span if span != 0 else xp.where(xp.isnan(z_above), np.nan, 0.0)
        out[k] = xp.where(xp.isnan(scaled), np.nan, xp.maximum(scaled, 0.0) if floor_at_zero else scaled)
    return out


def sgc_score(components: Mapping[str, Any], calibration: Calibration, xp=np, floor_at_zero: bool = True,
              floors: Mapping[str, Any] | None = None) -> Any:
    """SGC = sum_k w_k M''_k / sum_k w_k over the non-NaN M''_k (NaN when all are NaN). Lower is
    better. ``floors``: the pose components' noise floors, needed by an ``excess`` calibration."""
    normalised = normalise(scored_values(components, calibration, floors, xp), calibration, xp, floor_at_zero)
    stacked = xp.stack([normalised[k] for k in COMPONENTS], axis=-1)
    weights = xp.asarray([calibration.weight[k] for k in COMPONENTS], _float(xp))
    present = ~xp.isnan(stacked)
    total_weight = (weights * present).sum(-1)
    # a sum along the components, not a matrix product: BLAS rounds a product of many rows
    # differently from one row, and a clip's score must not depend on the clips beside it
    weighted = (xp.where(present, stacked, 0.0) * weights).sum(-1)
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
                     xp=np, width: float = SMOOTH_FLOOR_WIDTH, floors: Mapping[str, Any] | None = None) -> Any:
    """The score with each M''_k's floor at 0 replaced by ``smooth_floor``, over the components
    where ``present`` (bool, same shapes); NaN where none is present, with a zero (not NaN)
    gradient. Equals ``sgc_score`` where every present M''_k >= width."""
    safe = {k: xp.where(present[k], components[k], 0.0) for k in COMPONENTS}  # no NaN enters the formula
    safe = scored_values(safe, calibration, floors, xp)
    normalised = normalise(safe, calibration, xp, floor_at_zero=False)
    weights = [calibration.weight[k] * xp.asarray(present[k], normalised[k].dtype) for k in COMPONENTS]
    total_weight = sum(weights)
    weighted = sum(w * smooth_floor(normalised[k], width, xp) for w, k in zip(weights, COMPONENTS))
    return xp.where(total_weight > 0, weighted / xp.where(total_weight > 0, total_weight, 1.0), np.nan)
