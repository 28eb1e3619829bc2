"""The per-pair pose components of docs/semantics.md §3.5: how far the local poses spread about
their mean and about the camera's pose.

Rotations in degrees (variances in deg^2), translations in the inputs' units. Local poses come as
k region slots with an ``accepted`` mask. Under ``compat="spec"`` each pose counts by how well
its region's geometry determines it (``pose_weights``: 1 / its variance per px² of tracking
error); ``compat="authors"`` reproduces the authors' code (§3.9): equal weights, a trimmed global
rotation term, arccos-of-trace distances in float32, and IQR = 0 rejecting every value.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from ..config import COMPATS
from ..stats import trimmed_mean
from .so3 import rotation_angle_deg, so3_exp, so3_log


def at_least_float32(x):
    """x as float32, or as given where it is wider (float64 gradient checks)."""
    x = jnp.asarray(x)
    return x.astype(jnp.promote_types(x.dtype, jnp.float32))


def _check_compat(compat: str) -> None:
    if compat not in COMPATS:
        raise ValueError(f"compat must be one of {COMPATS}, got {compat!r}")


def rotation_angle_deg_authors(R_a, R_b):
    """Angle of R_a^T R_b [deg] as arccos((trace - 1) / 2) in float32 (the authors' distance)."""
    M = jnp.swapaxes(R_a, -1, -2).astype(jnp.float32) @ R_b.astype(jnp.float32)
    cos = (jnp.trace(M, axis1=-2, axis2=-1) - 1.0) / 2.0
    return jnp.degrees(jnp.arccos(jnp.clip(cos, -1.0, 1.0)))


def masked_mean(values, valid, weights=None):
    """Mean over axis 0 of values (k, ...) where valid (k,), weighted by ``weights`` (k,) (None:
    equally); NaN where none is valid."""
    values = at_least_float32(values)
    w = jnp.where(valid, 1.0 if weights is None else weights, 0.0).astype(values.dtype)
    w = w.reshape(w.shape + (1,) * (values.ndim - 1))
    total = jnp.sum(jnp.where(w > 0, values, 0.0) * w, axis=0)
    return jnp.where(jnp.any(valid), total / jnp.maximum(jnp.sum(w, axis=0), jnp.finfo(values.dtype).tiny), jnp.nan)


def pose_weights(per_px, accepted, xp=jnp):
    """(..., k) weights of the accepted poses (docs/semantics.md §3.5): 1 / g_j, g_j = per_px_j² the
    variance of pose j per px² of tracking error (its region's geometry alone: not how well the
    region fits), scaled so the largest is 1; 0 for the others. ``per_px`` (..., k): the pose's RMS
    error per px (``region_rot_per_px`` or ``region_trans_per_px``, any unit). One without a
    geometry (0 or not finite, which an accepted pose's 4 inliers rule out) takes the pair's median
    (equal weights when none has one). NumPy or ``jax.numpy``."""
    as_float = at_least_float32 if xp is jnp else (lambda x: np.asarray(x, np.float64))
    per_px = as_float(per_px)
    measured = accepted & (per_px > 0) & xp.isfinite(per_px)
    per_px = xp.where(measured, per_px, xp.inf) ** 2
    ordered = xp.sort(per_px, axis=-1)
    n = xp.sum(measured, axis=-1, keepdims=True)
    middle = lambda i: xp.take_along_axis(ordered, xp.clip(i, 0, per_px.shape[-1] - 1), axis=-1)  # noqa: E731
    median = xp.where(n > 0, 0.5 * (middle((n - 1) // 2) + middle(n // 2)), 1.0)
    per_px = xp.where(measured, per_px, median)
    return xp.where(accepted, xp.min(xp.where(accepted, per_px, xp.inf), axis=-1, keepdims=True) / per_px, 0.0)


def mean_pose(R_local, t_local, accepted, rot_weights=None, trans_weights=None):
    """Accepted poses (k, 3, 3), (k, 3), (k,) -> (exp of the (weighted) mean rotation vector,
    (weighted) mean translation), float32; NaN with none accepted."""
    R_mean = so3_exp(masked_mean(so3_log(at_least_float32(R_local)), accepted, rot_weights))
    return R_mean, masked_mean(at_least_float32(t_local), accepted, trans_weights)


def pair_pose_components(R_local, t_local, accepted, R_g, t_g, rot_per_px=None, trans_per_px=None, *,
                         compat: str = "spec"):
    """Local poses (k, 3, 3), (k, 3), accepted (k,) against the camera's (3, 3), (3,) -> float32
    local_rot_var, global_rot_var [deg^2], local_trans_var, global_trans_var [units^2], n_poses.
    Under spec each pose is weighted by its geometry (``pose_weights`` of ``rot_per_px`` and
    ``trans_per_px``, (k,), required there); under authors equally, the global rotation
    term trimmed (docs/semantics.md §3.5). All NaN with no accepted pose; with one, the local ones
    are NaN under spec (one pose has no spread to measure) and 0 under authors (the authors' code)."""
    _check_compat(compat)
    authors = compat == "authors"
    if not authors and (rot_per_px is None or trans_per_px is None):
        raise ValueError("compat='spec' weights each local pose by its geometry: rot_per_px and trans_per_px are "
                         "needed")
    angle = rotation_angle_deg_authors if authors else rotation_angle_deg
    R_local, t_local = at_least_float32(R_local), at_least_float32(t_local)
    R_g, t_g = at_least_float32(R_g), at_least_float32(t_g)
    n = jnp.sum(accepted).astype(jnp.int32)
    none = n == 0
    w_rot, w_trans = (None, None) if authors else (pose_weights(rot_per_px, accepted),
                                                    pose_weights(trans_per_px, accepted))

    R_mean, t_mean = mean_pose(R_local, t_local, accepted, w_rot, w_trans)
    R_mean, t_mean = jnp.where(none, jnp.eye(3, dtype=R_local.dtype), R_mean), jnp.nan_to_num(t_mean)
    local_rot = masked_mean(angle(R_local, R_mean[None]) ** 2, accepted, w_rot)
    local_trans = masked_mean(jnp.sum((t_local - t_mean) ** 2, axis=-1), accepted, w_trans)
    single_value = 0.0 if authors else jnp.nan
    single = n < 2
    local_rot = jnp.where(none, jnp.nan, jnp.where(single, single_value, local_rot))
    local_trans = jnp.where(none, jnp.nan, jnp.where(single, single_value, local_trans))
    to_camera = angle(R_local, R_g[None]) ** 2
    global_rot = trimmed_mean(to_camera, accepted, compat, xp=jnp) if authors else masked_mean(to_camera, accepted, w_rot)
    global_trans = masked_mean(jnp.sum((t_local - t_g) ** 2, axis=-1), accepted, w_trans)
    return {"local_rot_var": at_least_float32(local_rot), "local_trans_var": at_least_float32(local_trans),
            "global_rot_var": at_least_float32(global_rot), "global_trans_var": at_least_float32(global_trans),
            "n_poses": n}
