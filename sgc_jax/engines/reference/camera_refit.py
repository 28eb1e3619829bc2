"""The camera refitted to the tracks (docs/semantics.md §3.6 step 6) and the motion the tracks show (§3.11)."""

from __future__ import annotations

import cv2
import numpy as np

from ...config import CAMERA_REFIT_RATIO, REFIT_POINTS, REFIT_UPDATES
from . import pose_search
from .rotations import rotation_angle_deg


def strided_points(X: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every ceil(n / REFIT_POINTS)-th of the n points: at most REFIT_POINTS of them."""
    stride = max(-(-len(X) // REFIT_POINTS), 1)
    return X[::stride], uv[::stride]


def _refit_from(start: pose_search.Pose, X: np.ndarray, uv: np.ndarray, K: np.ndarray,
                cut_px: float) -> pose_search.Pose | None:
    """REFIT_UPDATES undamped Gauss-Newton updates from ``start`` on the points within ``cut_px`` of
    it (None with fewer than 6); the pose may be non-finite."""
    within = pose_search.pose_errors_sq(start, X, uv, K) < cut_px**2
    if within.sum() < 6:
        return None
    R, t = start.R, start.t
    for _ in range(REFIT_UPDATES):
        r, J = pose_search.residual_jacobian(X[within], uv[within], K, R, t)
        delta = -np.linalg.lstsq(J, r, rcond=None)[0]  # a degenerate spread of points must not raise
        R, t = cv2.Rodrigues(delta[:3])[0] @ R, t + delta[3:]  # the perturbation exp([w]) R X + t + dt
    return pose_search.Pose(R, t)


def _median_cut_error(pose: pose_search.Pose, X: np.ndarray, uv: np.ndarray, K: np.ndarray,
                      cut_px: float) -> float:
    """Median over the points of min(reprojection error, ``cut_px``) [px]."""
    return np.median(np.minimum(np.sqrt(pose_search.pose_errors_sq(pose, X, uv, K)), cut_px))


def camera_refit(X: np.ndarray, uv: np.ndarray, K: np.ndarray, camera: pose_search.Pose,
                 cut_px: float) -> tuple[pose_search.Pose | None, float, bool]:
    """The camera's pose refitted to the (strided, ``strided_points``) points X (n, 3) of the pair's regions,
    seen at uv (n, 2) (``_refit_from`` it) -> (the refit, None where it was not fitted or is not
    finite; its median of min(error, ``cut_px``) px, inf where None; whether it warps: the camera's
    median exceeds CAMERA_REFIT_RATIO times the refit's, docs/semantics.md §3.6 step 6)."""
    refit = _refit_from(camera, X, uv, K, cut_px)
    if refit is None or not (np.all(np.isfinite(refit.R)) and np.all(np.isfinite(refit.t))):
        return None, np.inf, False
    error = _median_cut_error(refit, X, uv, K, cut_px)
    return refit, error, bool(_median_cut_error(camera, X, uv, K, cut_px) > CAMERA_REFIT_RATIO * error)


def tracks_motion(X: np.ndarray, uv: np.ndarray, K: np.ndarray, refit: pose_search.Pose | None,
                  refit_error: float, cut_px: float) -> tuple[float, float]:
    """The motion the tracks show (docs/semantics.md §3.11): of the camera's refit (``camera_refit``:
    ``refit``, its median cut error ``refit_error``) and the pose ``_refit_from`` rest, the one of
    lower median cut error (the camera's refit on a tie) -> (rotation [deg], translation [units of
    D]); NaN where neither was fitted. On the points ``camera_refit`` took."""
    best = (refit_error, refit)
    rest = _refit_from(pose_search.Pose(np.eye(3), np.zeros(3)), X, uv, K, cut_px)
    if rest is not None and np.all(np.isfinite(rest.R)) and np.all(np.isfinite(rest.t)):
        error = _median_cut_error(rest, X, uv, K, cut_px)
        if error < best[0]:
            best = (error, rest)
    pose = best[1]
    return (np.nan, np.nan) if pose is None else (rotation_angle_deg(np.eye(3), pose.R), float(np.linalg.norm(pose.t)))
