"""Noise floors (docs/semantics.md §3.10): per frame pair, the value each pose component would take
if the world were perfectly consistent and every accepted local pose missed it only by its own
fit's noise (the region uncertainties of §3.3)."""

from __future__ import annotations

import functools

import numpy as np

from ..codes import REGION_OK
from ..engines.pairs import PairArrays
from ..engines.units import PERCENT
from ..io.tables import FLOOR_COLUMNS

# Draws of the parametric floor of the trimmed global_rot_var: its relative sampling error is about
# sqrt(2/3) / sqrt(FLOOR_DRAWS n) for n regions, under 3 % for every pair.
FLOOR_DRAWS = 1024
FLOOR_SEED = 0


def trimmed_means(values: np.ndarray) -> np.ndarray:
    """The trimmed mean of docs/semantics.md §3.5 (``global_rot_var``, spec) of each row of
    ``values`` (draws, n): keep q1 - k IQR <= v <= p98, k = (p98 - q3) / IQR; all of the row when
    IQR = 0 or the bounds keep nothing."""
    q1, q3, p98 = np.percentile(values, [25, 75, 98], axis=1, keepdims=True)
    iqr = q3 - q1
    with np.errstate(invalid="ignore", divide="ignore"):
        k = (p98 - q3) / iqr
        kept = (values >= q1 - k * iqr) & (values <= p98) & (iqr > 0)
    count = kept.sum(axis=1)
    trimmed = np.where(kept, values, 0.0).sum(axis=1) / np.maximum(count, 1)
    return np.where(count > 0, trimmed, values.mean(axis=1))


@functools.lru_cache(maxsize=64)
def _unit_squares(n: int) -> np.ndarray:
    """(FLOOR_DRAWS, n) |z|^2 / 3 for standard normal z in 3-D: the squared size of an isotropic
    error of RMS size 1; the same draws for every pair of n regions (seeded)."""
    normal = np.random.default_rng((FLOOR_SEED, n)).standard_normal((FLOOR_DRAWS, n, 3))
    squares = np.sum(normal ** 2, axis=2) / 3.0
    squares.flags.writeable = False
    return squares


def trimmed_floor(rot_std: np.ndarray) -> float:
    """E[trimmed mean of |d_j|^2] for independent isotropic rotation errors d_j of RMS size
    rot_std (n,) deg: Monte Carlo (the trim has no closed form)."""
    return float(trimmed_means(_unit_squares(rot_std.size) * rot_std ** 2).mean())


def pair_floors(pairs: PairArrays, compat: str) -> dict[str, np.ndarray]:
    """FLOOR_COLUMNS -> (n_pairs,) in the components' units (spec); NaN where the pair has no
    accepted pose or the component is NaN (no global pose), and everywhere under compat="authors"."""
    floors = {name: np.full(pairs.n_pairs, np.nan) for name in FLOOR_COLUMNS}
    if compat == "authors":
        return floors
    accepted = pairs.region_status == REGION_OK
    for p in np.flatnonzero(accepted.any(axis=1)):
        rot_std = pairs.region_rot_std[p, accepted[p]].astype(np.float64)
        trans_std = PERCENT * pairs.region_trans_std[p, accepted[p]].astype(np.float64)  # % of D
        spread = 1.0 - 1.0 / rot_std.size  # E[mean_j |e_j - mean e|^2] = (1 - 1/n) mean_j sigma_j^2
        floors["local_rot_var_floor"][p] = spread * np.mean(rot_std ** 2)
        floors["local_trans_var_floor"][p] = spread * np.mean(trans_std ** 2)
        floors["global_rot_var_floor"][p] = trimmed_floor(rot_std)
        floors["global_trans_var_floor"][p] = np.mean(trans_std ** 2)
    for name in floors:
        floors[name][np.isnan(getattr(pairs, name.removesuffix("_floor")))] = np.nan
    return floors
