"""Noise floors (docs/semantics.md §3.10): per frame pair, the value each pose component would take
if the world were perfectly consistent and every accepted local pose missed it only by its own
fit's noise (the region uncertainties of §3.3). Written once for NumPy (the tables) and
``jax.numpy`` (the Scorer)."""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from ..calibration import COMPONENTS, Calibration, sgc_score
from ..codes import REGION_OK
from ..io.tables import FLOOR_COLUMNS
from ..kernels.pose_variances import pose_weights
from .units import PERCENT


def floors_of(region_status: Any, rot_noise_deg: Any, trans_noise_percent: Any, components: dict[str, Any],
              weights: tuple[Any, Any], xp=np) -> dict[str, Any]:
    """FLOOR_COLUMNS -> (...,) from each pair's region statuses, RMS rotation noise [deg] and
    translation noise [% of D] of its poses (..., k; ``region_rot_noise``, ``region_trans_noise``),
    its components (...,) and the poses' (rotation, translation) weights in them (..., k; §3.5):
    NaN where the pair has no accepted pose or the component is NaN (no global pose). With W =
    sum_j w_j over the accepted poses, E[sum_j w_j |e_j|² / W] = sum_j w_j σ_j² / W, and about the
    weighted mean that minus sum_j w_j² σ_j² / W²."""
    accepted = region_status == REGION_OK
    n = xp.sum(accepted, axis=-1)

    def expected_spreads(noise, w):  # (about the camera's pose, about the weighted mean pose)
        var = xp.where(accepted, noise, 0.0) ** 2
        total = xp.sum(w, axis=-1)
        about_truth = xp.sum(w * var, axis=-1) / total
        return about_truth, about_truth - xp.sum(w * w * var, axis=-1) / total ** 2

    global_rot, local_rot = expected_spreads(rot_noise_deg, weights[0])
    global_trans, local_trans = expected_spreads(trans_noise_percent, weights[1])
    floors = {"local_rot_var_floor": local_rot, "local_trans_var_floor": local_trans,
              "global_rot_var_floor": global_rot, "global_trans_var_floor": global_trans}
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
    with np.errstate(invalid="ignore", divide="ignore"):  # a pair without a pose: 0 / 0, masked in floors_of
        accepted = pairs["region_status"] == REGION_OK
        weights = tuple(pose_weights(pairs[name], accepted, xp) for name in ("region_rot_per_px", "region_trans_per_px"))
        return floors_of(pairs["region_status"], pairs["region_rot_noise"], PERCENT * pairs["region_trans_noise"],
                         {k: pairs[k] for k in COMPONENTS}, weights, xp=xp)
