"""A pair's pose components (docs/semantics.md §3.5): weighted mean pose, local and global variances."""

from __future__ import annotations

import numpy as np

from ...config import SGCConfig
from ...stats import trimmed
from .rotations import rotation_angle_deg, rotation_angle_deg_authors, so3_exp, so3_log


def mean_pose(R_local: list[np.ndarray], t_local: list[np.ndarray], rot_weights: np.ndarray | None = None,
              trans_weights: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(R_mean (3, 3), t_mean (3,)): exp of the (weighted) mean rotation vector and the (weighted)
    mean translation; None: equal weights."""
    return (so3_exp(np.average([so3_log(R) for R in R_local], axis=0, weights=rot_weights)),
            np.average(t_local, axis=0, weights=trans_weights))


def geometry_weights(per_px: np.ndarray) -> np.ndarray:
    """(n,) weights of accepted poses, 1 / per_px², the largest 1 (docs/semantics.md §3.5: by how
    well the region's geometry determines the pose, its RMS error per px of tracking error, not how
    well it fits); one without a geometry (0 or not finite) takes the median of the others' (equal
    weights when none has one)."""
    per_px = np.asarray(per_px, np.float64)
    measured = (per_px > 0) & np.isfinite(per_px)
    if not measured.any():
        return np.ones(per_px.size)
    per_px = np.where(measured, per_px**2, 0.0)
    per_px = np.where(measured, per_px, np.median(per_px[measured]))
    return per_px.min() / per_px


def pose_weights(spread: tuple[np.ndarray, np.ndarray] | None, config: SGCConfig
                 ) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Each accepted pose's (rotation, translation) weight in the components: by its geometry under
    spec, from ``spread`` = (rot_per_px, trans_per_px) (n,) each; equal (None) under authors."""
    if config.compat == "authors":
        return None, None
    if spread is None:
        raise ValueError("compat='spec' weights each local pose by its geometry: (rot_per_px, trans_per_px) "
                         "are needed")
    rot_per_px, trans_per_px = spread
    return geometry_weights(rot_per_px), geometry_weights(trans_per_px)


def local_variances(R_local: list[np.ndarray], t_local: list[np.ndarray], config: SGCConfig,
                    spread: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[float, float]:
    """(local_rot_var deg^2, local_trans_var) around the mean pose, each pose weighted by its
    geometry under spec (``pose_weights`` of ``spread``); NaN with none, and with one under spec (no
    spread to measure); 0 with one under authors."""
    n = len(R_local)
    if n == 0 or (n == 1 and config.compat != "authors"):
        return float("nan"), float("nan")
    if n == 1:
        return 0.0, 0.0
    w_rot, w_trans = pose_weights(spread, config)
    R_mean, t_mean = mean_pose(R_local, t_local, w_rot, w_trans)
    angle = rotation_angle_deg_authors if config.compat == "authors" else rotation_angle_deg
    rot = np.average([angle(R, R_mean) ** 2 for R in R_local], weights=w_rot)
    trans = np.average([np.sum((t - t_mean) ** 2) for t in t_local], weights=w_trans)
    return float(rot), float(trans)


def trimmed_mean_iqr(values: np.ndarray, config: SGCConfig) -> float:
    """The trimmed mean of docs/semantics.md §3.5 (``stats.trimmed``) of values (n,), in float64;
    NaN for none."""
    values = np.asarray(values, np.float64)
    if values.size == 0:
        return float("nan")
    kept = values[trimmed(values, np.ones(values.shape, bool), config.compat)]
    return float(kept.mean()) if kept.size else float("nan")


def global_variances(R_local: list[np.ndarray], t_local: list[np.ndarray], R_g: np.ndarray,
                     t_g: np.ndarray, config: SGCConfig,
                     spread: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[float, float]:
    """(global_rot_var deg^2, global_trans_var) of the local poses against (R_g, t_g): each pose
    weighted by its geometry under spec (``pose_weights``); equally, the rotation term trimmed,
    under authors."""
    if not R_local:
        return float("nan"), float("nan")
    angle = rotation_angle_deg_authors if config.compat == "authors" else rotation_angle_deg
    to_camera = np.array([angle(R, R_g) ** 2 for R in R_local])
    w_rot, w_trans = pose_weights(spread, config)
    rot = trimmed_mean_iqr(to_camera, config) if config.compat == "authors" else float(np.average(to_camera,
                                                                                                  weights=w_rot))
    trans = float(np.average([np.sum((t - t_g) ** 2) for t in t_local], weights=w_trans))
    return rot, trans
