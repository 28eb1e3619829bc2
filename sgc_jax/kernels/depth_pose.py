"""The camera refitted to a pair's tracks (docs/semantics.md §3.6 step 6): where the camera
reprojects the pair's region points worse than CAMERA_REFIT_RATIO times its refit does, the refit
also warps the depth check, and the lesser error counts.

A pose estimator's error in the camera moves every warped pixel, and the depth error counted it as
depth inconsistency; the camera refitted to the tracks warps the same rigid world without it."""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp

from ..config import CAMERA_REFIT_RATIO, REFIT_POINTS, REFIT_UPDATES
from .medians import masked_median
from .pnp import gauss_newton_updates
from .so3 import so3_exp, so3_log
from .truncated_cost import truncated_errors_sq


class CameraRefit(NamedTuple):
    """One pair's camera refitted to its region points, and the motion its tracks show."""

    R: jnp.ndarray  # (3, 3) the refit's rotation; the camera's where it does not warp
    t: jnp.ndarray  # (3,) in units of D
    warps: jnp.ndarray  # () bool: the refit also warps the depth check
    fitted_on: jnp.ndarray  # (P,) bool: the points the refit is the least-squares fit of
    tracks_rot_deg: jnp.ndarray  # () rotation [deg] of the tracks' pose (``tracks_motion``); NaN: none
    tracks_trans: jnp.ndarray  # () its translation's length [units of D]


def median_cut_error_px(R, t, X, uv, K, used, cut_px):
    """Median over the ``used`` (P,) points of min(reprojection error, ``cut_px``) [px] under the
    pose (R, t); a point behind the camera counts ``cut_px``; NaN with none used."""
    return masked_median(jnp.sqrt(truncated_errors_sq(R, t, X, uv, K, used, cut_px)[1]), used)


def strided_points(used, count: int):
    """Indices (count,) of every ceil(n / count)-th of the n ``used`` (P,) points in their order, and
    which of them are points (count,) bool (all n where n <= count)."""
    n = jnp.sum(used)
    stride = jnp.maximum((n + count - 1) // count, 1)
    picked = used & ((jnp.cumsum(used) - 1) % stride == 0)
    index = jnp.nonzero(picked, size=count, fill_value=0)[0]
    return index, jnp.arange(count) < jnp.sum(picked)


def refit_from(R, t, X, uv, K, picked, cut_px):
    """REFIT_UPDATES Gauss-Newton updates from the pose (R, t) on the ``picked`` points within ``cut_px``
    of it -> (the pose (6,) as [so3_log(R), t], those points (P,) bool, whether they were at least 6
    and the pose is finite)."""
    within = truncated_errors_sq(R, t, X, uv, K, picked, cut_px)[0]
    pose = gauss_newton_updates(X, uv, within.astype(X.dtype), K, jnp.concatenate([so3_log(R), t]),
                                updates=REFIT_UPDATES)
    return pose, within, (jnp.sum(within) >= 6) & jnp.all(jnp.isfinite(pose))


def refit_camera(X, uv, used, K, R_g, t_g, has_pose, cut_px) -> CameraRefit:
    """One pair: points X (P, 3) of camera i-1 (units of D), seen at uv (P, 2) in frame i, ``used``
    (P,) (usable, with depth, in a region), the camera's pose (R_g, t_g in units of D) and whether
    the pair has an accepted local pose -> the camera's refit (``refit_from`` its pose), and whether
    the refit also warps: the camera's median cut error exceeds CAMERA_REFIT_RATIO times the
    refit's; and the tracks' motion (``tracks_motion``). All on at most REFIT_POINTS of the points
    (``strided_points``): the refit's leverage is the image's spread, which every n-th point keeps,
    and its cost the points'."""
    index, picked = strided_points(used, min(REFIT_POINTS, used.shape[0]))
    X, uv = X[index], uv[index]
    finite = jnp.all(jnp.isfinite(R_g)) & jnp.all(jnp.isfinite(t_g))
    R_g, t_g = jnp.where(finite, R_g, jnp.eye(3, dtype=R_g.dtype)), jnp.where(finite, t_g, 0.0)
    pose, within, fitted = refit_from(R_g, t_g, X, uv, K, picked, cut_px)
    R_fit, t_fit = so3_exp(pose[:3]), pose[3:]
    refit_error = median_cut_error_px(R_fit, t_fit, X, uv, K, picked, cut_px)
    warps = (finite & has_pose & fitted
             & (median_cut_error_px(R_g, t_g, X, uv, K, picked, cut_px) > CAMERA_REFIT_RATIO * refit_error))
    fitted_on = jnp.zeros_like(used).at[index].max(within & warps)
    motion = tracks_motion(X, uv, picked, K, pose, jnp.where(fitted, refit_error, jnp.inf), cut_px)
    rot_deg, trans = (jnp.where(finite, x, jnp.nan) for x in motion)
    return CameraRefit(jnp.where(warps, R_fit, R_g), jnp.where(warps, t_fit, t_g), warps, fitted_on, rot_deg, trans)


def tracks_motion(X, uv, picked, K, camera_refit, camera_refit_error, cut_px):
    """The motion the tracks show (docs/semantics.md §3.11): of the camera's refit (``camera_refit``
    (6,), its median cut error ``camera_refit_error``, inf where it was not fitted) and the pose
    ``refit_from`` rest, the one of lower median cut error -> (rotation [deg], translation [units of
    D]); NaN where neither was fitted. The rest start finds a video that holds still under moving
    cameras, whose points the camera's pose leaves beyond the cut."""
    dtype = X.dtype
    rest_refit, _, rest_fitted = refit_from(jnp.eye(3, dtype=dtype), jnp.zeros(3, dtype), X, uv, K, picked, cut_px)
    rest_error = jnp.where(rest_fitted, median_cut_error_px(so3_exp(rest_refit[:3]), rest_refit[3:], X, uv, K, picked,
                                                            cut_px), jnp.inf)
    pose = jnp.where(rest_error < camera_refit_error, rest_refit, camera_refit)
    found = jnp.isfinite(jnp.minimum(camera_refit_error, rest_error))
    return (jnp.where(found, jnp.degrees(jnp.linalg.norm(pose[:3])), jnp.nan),
            jnp.where(found, jnp.linalg.norm(pose[3:]), jnp.nan))
