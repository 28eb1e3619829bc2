"""One region's pose (docs/semantics.md §3.2 step 6, §3.3, §3.10): its fit, uncertainty, noise floor and quality rule."""

from __future__ import annotations

import cv2
import numpy as np

from ...codes import REGION_STATUS
from ...config import BLOCKS_PER_AXIS, SGCConfig
from ...stats import cut_variance_factor
from . import pose_search
from .pose_search import residual_jacobian
from .rotations import so3_exp
from .tracks import project


def solve_region_pose(X: np.ndarray, uv: np.ndarray, K: np.ndarray, config: SGCConfig,
                      seed: int) -> tuple[int, np.ndarray, np.ndarray]:
    """PnP-RANSAC with OpenCV's solver: (status, R (3,3), t (3,)).

    Status codes are :data:`REGION_STATUS`. Accepted when inliers >= max(4, floor(frac * n)) and
    R is a proper rotation (docs/semantics.md §3.2 step 6).
    """
    n = len(X)
    nan_pose = np.full((3, 3), np.nan), np.full(3, np.nan)
    if n < config.min_points:
        return REGION_STATUS["too_few_points"], *nan_pose
    cv2.setRNGSeed(seed)
    try:
        found, rvec, tvec, inliers = cv2.solvePnPRansac(
            X.astype(np.float64), uv.astype(np.float64), K.astype(np.float64), None,
            iterationsCount=config.ransac_hypotheses, reprojectionError=config.inlier_px,
            confidence=config.confidence, flags=cv2.SOLVEPNP_ITERATIVE)
    except cv2.error:
        found = False
    if not found or inliers is None or not (np.isfinite(rvec).all() and np.isfinite(tvec).all()):
        return REGION_STATUS["rejected"], *nan_pose
    R, t = so3_exp(rvec), tvec.ravel()
    needed = max(4, int(np.floor(config.min_inlier_frac * n)))
    proper = abs(np.linalg.det(R) - 1.0) < 1e-3
    if len(inliers) < needed or not proper:
        return REGION_STATUS["rejected"], *nan_pose
    return REGION_STATUS["ok"], R, t


def pose_uncertainty(X: np.ndarray, uv: np.ndarray, K: np.ndarray, R: np.ndarray,
                     t: np.ndarray) -> tuple[float, float, float]:
    """(RMS rotation error deg, RMS translation error, sigma px) of a pose fitted to X (n, 3),
    uv (n, 2).

    Cov = sigma^2 (J^T J)^-1 with J (2n, 6) the Jacobian of the reprojection residuals in the
    left perturbation (w, dt): exp([w]) R X + t + dt, and sigma^2 = sum e^2 / (2n - 6);
    the figures are sqrt(trace) of the rotation and translation blocks. NaN under 4 points.
    """
    rot_per_px, trans_per_px, sigma = uncertainty_per_px(X, uv, K, R, t)
    return rot_per_px * sigma, trans_per_px * sigma, sigma


def uncertainty_per_px(X: np.ndarray, uv: np.ndarray, K: np.ndarray, R: np.ndarray,
                       t: np.ndarray) -> tuple[float, float, float]:
    """(RMS rotation error deg, RMS translation error) per px of tracking error, the square roots of
    the traces of (J^T J)^-1's blocks: the region's geometry alone, defined where the fit is exact;
    and sigma px (``pose_uncertainty``'s errors are these times sigma). NaN under 4 points."""
    n = len(X)
    if n < 4:
        return float("nan"), float("nan"), float("nan")
    _, J = residual_jacobian(X, uv, K, R, t)
    sigma_sq = np.sum(reprojection_errors(X, uv, K, R, t) ** 2) / max(2 * n - 6, 1)
    A = np.linalg.pinv(J.T @ J)
    return (float(np.degrees(np.sqrt(max(np.trace(A[:3, :3]), 0.0)))), float(np.sqrt(max(np.trace(A[3:, 3:]), 0.0))),
            float(np.sqrt(sigma_sq)))


def block_covariance(X: np.ndarray, uv: np.ndarray, K: np.ndarray, R: np.ndarray, t: np.ndarray,
                     block_px: float) -> np.ndarray:
    """The cluster-robust covariance (6, 6) of the left-perturbed pose (w, dt) fitted to X (n, 3),
    uv (n, 2) over squares of side block_px (``kernels.uncertainty.block_covariance``): A (sum_b g_b
    g_b^T) A G/(G-1) (2n-1)/(2n-6), A = (J^T J)^-1, g_b = J_b^T e_b. NaN under 4 points."""
    n = len(X)
    if n < 4:
        return np.full((6, 6), np.nan)
    residuals, J = residual_jacobian(X, uv, K, R, t)
    A = np.linalg.pinv(J.T @ J)
    cell = np.clip(np.floor(uv / block_px), 0, BLOCKS_PER_AXIS - 1).astype(np.int64)
    block = np.unique(cell[:, 1] * BLOCKS_PER_AXIS + cell[:, 0], return_inverse=True)[1].ravel()
    G = int(block.max()) + 1
    g = np.zeros((G, 6))
    np.add.at(g, block, J[:n] * residuals[:n, None] + J[n:] * residuals[n:, None])
    return A @ (g.T @ g) @ A * G / max(G - 1, 1) * (2 * n - 1) / max(2 * n - 6, 1)


def floor_noise(X: np.ndarray, uv: np.ndarray, K: np.ndarray, R: np.ndarray, t: np.ndarray,
                usual: tuple[float, float], sigma: float, block_px: float, inlier_px: float) -> tuple[float, float]:
    """(RMS rotation error deg, RMS translation error) the noise floors count for an accepted pose
    (docs/semantics.md §3.10): each the larger of ``usual`` (``pose_uncertainty``'s) and the block
    covariance's on the pose's inliers, times the square root of ``stats.cut_variance_factor`` of
    their residual sigma px and the cut inlier_px."""
    inliers = pose_inliers(X, uv, K, R, t, inlier_px)
    blocks = block_covariance(X[inliers], uv[inliers], K, R, t, block_px)
    cut = float(np.sqrt(cut_variance_factor(sigma**2, inlier_px)))
    return (cut * float(np.maximum(usual[0], np.degrees(np.sqrt(max(np.trace(blocks[:3, :3]), 0.0))))),
            cut * float(np.maximum(usual[1], np.sqrt(max(np.trace(blocks[3:, 3:]), 0.0)))))


def pixel_extent(uv: np.ndarray) -> float:
    """RMS distance [px] of pixels uv (n, 2) from their centroid."""
    return float(np.sqrt(np.mean(np.sum((uv - uv.mean(axis=0)) ** 2, axis=1)))) if len(uv) else float("nan")


def rot_std_limit_deg(K: np.ndarray, config: SGCConfig) -> float:
    """Largest accepted rotation uncertainty [deg]: ``max_rot_std_deg``, or the angle
    ``max_rot_std_px`` pixels subtend at the focal length (mean of fx, fy) when larger."""
    focal = 0.5 * (K[0, 0] + K[1, 1])
    return max(config.max_rot_std_deg, float(np.degrees(config.max_rot_std_px / focal)))


def region_quality(X: np.ndarray, uv: np.ndarray, K: np.ndarray, R: np.ndarray, t: np.ndarray,
                   image_size: tuple[int, int], config: SGCConfig
                   ) -> tuple[bool, float, tuple[float, float], tuple[float, float]]:
    """The region-quality rule on an accepted pose: (well_conditioned, sigma px, (rot std deg, trans
    std), the same per px of tracking error, ``uncertainty_per_px``).

    On the inliers of the pose (error < inlier_px, in front of the camera): at least
    ``min_region_points`` of them, rotation uncertainty <= ``rot_std_limit_deg`` with sigma capped
    at ``quality_noise_px`` (larger residuals are misfit, not noise), RMS radius >=
    ``min_region_extent`` x the image diagonal (docs/semantics.md §3.3; ambiguity is the search's).
    """
    inliers = pose_inliers(X, uv, K, R, t, config.inlier_px)
    rot_per_px, trans_per_px, sigma = uncertainty_per_px(X[inliers], uv[inliers], K, R, t)
    rot_std, trans_std = rot_per_px * sigma, trans_per_px * sigma
    judged_rot_std = rot_std * min(1.0, config.quality_noise_px / max(sigma, 1e-12))
    diagonal = float(np.hypot(*image_size))
    good = (inliers.sum() >= config.min_region_points and judged_rot_std <= rot_std_limit_deg(K, config)
            and pixel_extent(uv[inliers]) >= config.min_region_extent * diagonal)
    return good, sigma, (rot_std, trans_std), (rot_per_px, trans_per_px)


def pose_inliers(X: np.ndarray, uv: np.ndarray, K: np.ndarray, R: np.ndarray, t: np.ndarray,
                 inlier_px: float) -> np.ndarray:
    """(n,) bool: in front of the camera with reprojection error < inlier_px under (R, t)."""
    return pose_search.pose_errors_sq(pose_search.Pose(R, t), X, uv, K) < inlier_px**2


def reprojection_errors(X: np.ndarray, uv: np.ndarray, K: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Pixel distance (n,) between uv and the projection of R X + t with K."""
    return np.linalg.norm(project(K, X @ R.T + t) - uv, axis=1)
