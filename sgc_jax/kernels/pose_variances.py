"""The per-pair pose components of docs/semantics.md §3.5: how far the local poses spread about
their mean and about the camera's pose.

Rotations in degrees (variances in deg^2), translations in the inputs' units. Local poses come as
k region slots with an ``accepted`` mask. ``compat="authors"`` reproduces the authors' code
(§3.9): arccos-of-trace distances in float32, and IQR = 0 rejecting every value.
"""

from __future__ import annotations

import jax.numpy as jnp

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


def masked_mean(values, valid):
    """Mean over axis 0 of values (k, ...) where valid (k,); NaN where none is."""
    values = at_least_float32(values)
    mask = valid.reshape(valid.shape + (1,) * (values.ndim - 1))
    n = jnp.sum(valid)
    total = jnp.sum(jnp.where(mask, values, 0.0), axis=0)
    return jnp.where(n > 0, total / jnp.maximum(n, 1).astype(values.dtype), jnp.nan)


def mean_pose(R_local, t_local, accepted):
    """Accepted poses (k, 3, 3), (k, 3), (k,) -> (exp of the mean rotation vector, mean
    translation), float32; NaN with none accepted."""
    R_mean = so3_exp(masked_mean(so3_log(at_least_float32(R_local)), accepted))
    return R_mean, masked_mean(at_least_float32(t_local), accepted)


def pair_pose_components(R_local, t_local, accepted, R_g, t_g, *, compat: str = "spec"):
    """Local poses (k, 3, 3), (k, 3), accepted (k,) against the camera's (3, 3), (3,) -> float32
    local_rot_var, global_rot_var [deg^2], local_trans_var, global_trans_var [units^2], n_poses.
    All NaN with no accepted pose; with one, the local ones are NaN under spec (one pose has no
    spread to measure, docs/semantics.md §3.5) and 0 under authors (the authors' code)."""
    _check_compat(compat)
    angle = rotation_angle_deg_authors if compat == "authors" else rotation_angle_deg
    R_local, t_local = at_least_float32(R_local), at_least_float32(t_local)
    R_g, t_g = at_least_float32(R_g), at_least_float32(t_g)
    n = jnp.sum(accepted).astype(jnp.int32)
    none = n == 0

    R_mean, t_mean = mean_pose(R_local, t_local, accepted)
    R_mean, t_mean = jnp.where(none, jnp.eye(3, dtype=R_local.dtype), R_mean), jnp.nan_to_num(t_mean)
    local_rot = masked_mean(angle(R_local, R_mean[None]) ** 2, accepted)
    local_trans = masked_mean(jnp.sum((t_local - t_mean) ** 2, axis=-1), accepted)
    single_value = 0.0 if compat == "authors" else jnp.nan
    single = n < 2
    local_rot = jnp.where(none, jnp.nan, jnp.where(single, single_value, local_rot))
    local_trans = jnp.where(none, jnp.nan, jnp.where(single, single_value, local_trans))
    global_rot = trimmed_mean(angle(R_local, R_g[None]) ** 2, accepted, compat, xp=jnp)
    global_trans = masked_mean(jnp.sum((t_local - t_g) ** 2, axis=-1), accepted)
    return {"local_rot_var": at_least_float32(local_rot), "local_trans_var": at_least_float32(local_trans),
            "global_rot_var": at_least_float32(global_rot), "global_trans_var": at_least_float32(global_trans),
            "n_poses": n}
