"""Noise floors (docs/semantics.md §3.10): per frame pair, the value each pose component would take
if the world were perfectly consistent and every accepted local pose missed it only by its own
fit's noise (the region uncertainties of §3.3). Written once for NumPy (the tables) and
``jax.numpy`` (the Scorer)."""

from __future__ import annotations

import functools
from typing import Any, Mapping

import numpy as np

from ..calibration import COMPONENTS, Calibration, sgc_score
from ..codes import REGION_OK
from ..io.tables import FLOOR_COLUMNS
from ..stats import trimmed_mean
from .units import PERCENT

# Draws of the parametric floor of the trimmed global_rot_var: its relative sampling error is about
# sqrt(2/3) / sqrt(FLOOR_DRAWS n) for n regions, under 3 % for every pair.
FLOOR_DRAWS = 1024
FLOOR_SEED = 0


@functools.lru_cache(maxsize=256)
def _unit_square_column(j: int) -> np.ndarray:
    normal = np.random.default_rng((FLOOR_SEED, j)).standard_normal((FLOOR_DRAWS, 3))
    return np.sum(normal ** 2, axis=1) / 3.0


def unit_squares(k: int) -> np.ndarray:
    """(FLOOR_DRAWS, k) |z|^2 / 3 for standard normal z in 3-D: the squared size of an isotropic
    error of RMS size 1; column j seeded alone (the j-th accepted pose of any pair)."""
    return np.stack([_unit_square_column(j) for j in range(k)], axis=1)


def floors_of(region_status: Any, rot_noise_deg: Any, trans_noise_percent: Any, components: dict[str, Any],
              xp=np) -> dict[str, Any]:
    """FLOOR_COLUMNS -> (...,) from each pair's region statuses, RMS rotation noise [deg] and
    translation noise [% of D] of its poses (..., k; ``region_rot_noise``, ``region_trans_noise``),
    and its components (...,): NaN where the pair has no accepted pose or the component is NaN (no
    global pose)."""
    k = region_status.shape[-1]
    accepted = region_status == REGION_OK
    n = xp.sum(accepted, axis=-1)
    mean_square = lambda std: (xp.sum(xp.where(accepted, std, 0.0) ** 2, axis=-1)  # noqa: E731
                               / xp.maximum(n, 1))
    spread = 1.0 - 1.0 / xp.maximum(n, 1)  # E[mean_j |e_j - mean e|^2] = (1 - 1/n) mean_j sigma_j^2
    # the trim has no closed form: the accepted poses first, each with its column of seeded draws
    order = xp.argsort(xp.where(accepted, 0, k) + xp.arange(k), axis=-1)
    rot_sorted = xp.take_along_axis(rot_noise_deg, order, axis=-1)[..., None, :]  # (..., 1, k)
    first_n = (xp.arange(k) < n[..., None])[..., None, :]
    draws = xp.where(first_n, xp.asarray(unit_squares(k)) * rot_sorted ** 2, np.nan)  # (..., draws, k)
    trimmed = xp.mean(trimmed_mean(draws, first_n, xp=xp), axis=-1)
    floors = {"local_rot_var_floor": spread * mean_square(rot_noise_deg),
              "local_trans_var_floor": spread * mean_square(trans_noise_percent),
              "global_rot_var_floor": trimmed,
              "global_trans_var_floor": mean_square(trans_noise_percent)}
    return {name: xp.where((n > 0) & ~xp.isnan(components[name.removesuffix("_floor")]), value, np.nan)
            for name, value in floors.items()}


def floor_score(floors: dict[str, Any], calibration: Calibration, xp=np) -> Any:
    """``sgc_floor`` (...,): the score formula on the pose components' floors, the depth error
    counted as 0 (its floor is not available, docs/semantics.md §3.10); NaN when no floor is known.
    0 under an ``excess`` calibration, whose zero is the floor."""
    values = [xp.asarray(floors[name]) for name in FLOOR_COLUMNS]
    score = sgc_score({**{name.removesuffix("_floor"): v for name, v in zip(FLOOR_COLUMNS, values)},
                       "depth_error": xp.zeros_like(values[0])}, calibration, xp=xp, floors=floors)
    return xp.where(xp.all(xp.stack([xp.isnan(v) for v in values]), axis=0), np.nan, score)


def pair_floors(pairs: Mapping[str, Any], compat: str, xp=np) -> dict[str, Any]:
    """FLOOR_COLUMNS -> (..., n_pairs) of clips' pairs (``PairArrays.columns()`` or the finish
    stage's output) in the components' units; NaN everywhere under compat="authors", whose
    translation units differ between terms."""
    if compat == "authors":
        return {name: xp.full(xp.shape(pairs["global_rot_var"]), np.nan) for name in FLOOR_COLUMNS}
    with np.errstate(invalid="ignore"):  # a pair without a pose: NaN draws, masked in floors_of
        return floors_of(pairs["region_status"], pairs["region_rot_noise"], PERCENT * pairs["region_trans_noise"],
                         {k: pairs[k] for k in COMPONENTS}, xp=xp)
