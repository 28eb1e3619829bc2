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


def refit_camera(X, uv, used, K, R_g, t_g, has_pose, cut_px) -> CameraRefit:
    """One pair: points X (P, 3) of camera i-1 (units of D), seen at uv (P, 2) in frame i, ``used``
    (P,) (usable, with depth, in a region), the camera's pose (R_g, t_g in units of D) and whether
    the pair has an accepted local pose -> the camera's refit (REFIT_UPDATES Gauss-Newton updates
    from its pose on the points within ``cut_px`` of it), and whether the refit also warps: the
    camera's median cut error exceeds CAMERA_REFIT_RATIO times the refit's. Both on at most
    REFIT_POINTS of the points (``strided_points``): the refit's leverage is the image's spread,
    which every n-th point keeps, and its cost the points'."""
    index, picked = strided_points(used, min(REFIT_POINTS, used.shape[0]))
    X, uv = X[index], uv[index]
    finite = jnp.all(jnp.isfinite(R_g)) & jnp.all(jnp.isfinite(t_g))
    R_g, t_g = jnp.where(finite, R_g, jnp.eye(3, dtype=R_g.dtype)), jnp.where(finite, t_g, 0.0)
    within = truncated_errors_sq(R_g, t_g, X, uv, K, picked, cut_px)[0]
    pose = gauss_newton_updates(X, uv, within.astype(X.dtype), K, jnp.concatenate([so3_log(R_g), t_g]),
                                updates=REFIT_UPDATES)
    R_fit, t_fit = so3_exp(pose[:3]), pose[3:]
    warps = (finite & has_pose & (jnp.sum(within) >= 6) & jnp.all(jnp.isfinite(pose))
             & (median_cut_error_px(R_g, t_g, X, uv, K, picked, cut_px)
                > CAMERA_REFIT_RATIO * median_cut_error_px(R_fit, t_fit, X, uv, K, picked, cut_px)))
    fitted_on = jnp.zeros_like(used).at[index].max(within & warps)
    rot_deg, trans = (jnp.where(finite, x, jnp.nan) for x in tracks_motion(X, uv, picked, K, pose, within, cut_px))
    return CameraRefit(jnp.where(warps, R_fit, R_g), jnp.where(warps, t_fit, t_g), warps, fitted_on, rot_deg, trans)


def tracks_motion(X, uv, picked, K, from_camera, camera_within, cut_px):
    """The motion the tracks show (docs/semantics.md §3.11): of the pose refitted from the camera's
    (``from_camera`` (6,), on its points ``camera_within``) and the pose refitted from rest (the same
    updates on the points within ``cut_px`` of their frame-i−1 position), the one of lower median cut
    error, each where at least 6 points were within -> (rotation [deg], translation [units of D]);
    NaN where neither was. The rest start finds a video that holds still under moving cameras, whose
    points the camera's pose leaves beyond the cut."""
    rest = jnp.zeros(6, X.dtype)
    rest_within = truncated_errors_sq(jnp.eye(3, dtype=X.dtype), rest[3:], X, uv, K, picked, cut_px)[0]
    from_rest = gauss_newton_updates(X, uv, rest_within.astype(X.dtype), K, rest, updates=REFIT_UPDATES)

    def fitted(pose, within):
        ok = (jnp.sum(within) >= 6) & jnp.all(jnp.isfinite(pose))
        pose = jnp.where(ok, pose, rest)
        return pose, jnp.where(ok, median_cut_error_px(so3_exp(pose[:3]), pose[3:], X, uv, K, picked, cut_px), jnp.inf)

    (camera_pose, camera_error), (rest_pose, rest_error) = fitted(from_camera, camera_within), fitted(from_rest, rest_within)
    pose = jnp.where(rest_error < camera_error, rest_pose, camera_pose)
    found = jnp.isfinite(jnp.minimum(camera_error, rest_error))
    return (jnp.where(found, jnp.degrees(jnp.linalg.norm(pose[:3])), jnp.nan),
            jnp.where(found, jnp.linalg.norm(pose[3:]), jnp.nan))
