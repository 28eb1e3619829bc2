"""Plain NumPy + OpenCV reference scorer of docs/semantics.md §3 (§7.2; the oracle and the speed baseline).

Readable and faithful rather than fast: loops over pairs and regions. Local poses under
``compat="spec"`` come from ``reference_pose.search_region`` (P3P starts, the local optimum and
the noise-level cut of §3.2); under ``compat="authors"`` from ``cv2.solvePnPRansac`` with the
authors' settings (SOLVEPNP_ITERATIVE, 100 iterations, 8 px, confidence 0.99), whose adaptive
RANSAC now and then accepts a wrong pose on small or far regions, left visible in the per-pair
diagnostics as the authors' code leaves it.

Conventions: poses map camera i-1 coordinates to camera i coordinates (x_i = R x_{i-1} + t);
rotations in degrees in every output; depth and local translations in units of D under "spec"
(``units.in_depth_units``), in the input's depth units under "authors".
"""

from __future__ import annotations

from typing import NamedTuple

import cv2
import numpy as np

from ..codes import EXCLUDED_STATUSES, REGION_STATUS
from ..config import (
    BLOCKS_PER_AXIS,
    CAMERA_REFIT_RATIO,
    DEPTH_MAP_DAMPING,
    DEPTH_MAP_GATE,
    DEPTH_MAP_STEPS,
    DEPTH_MAP_WEIGHT_FLOOR,
    DEPTH_SCALE_MIN_PIXELS,
    DEPTH_SCALE_STRIDE,
    HOLE_DEPTH_MARGIN,
    LOOK_BACK_RATIO,
    MAX_HOLE_REACH_PX,
    NOISE_BLOCK_FRAC,
    REFIT_POINTS,
    REFIT_UPDATES,
    SGCConfig,
)
from ..io.clip import Clip
from ..stats import cut_variance_factor, trimmed
from . import reference_pose as reference_pose_search
from .evidence import parallax_px
from .pairs import PairArrays, empty_pair_arrays
from .reference_pose import residual_jacobian
from .units import PERCENT, in_depth_units, resolved_translation, translation_factor

# ----------------------------------------------------------------------------- rotations


def so3_log(R: np.ndarray) -> np.ndarray:
    """Rotation vector (3,) in radians of a rotation matrix (3, 3)."""
    rotvec, _ = cv2.Rodrigues(np.asarray(R, np.float64))
    return rotvec.ravel()


def so3_exp(rotvec: np.ndarray) -> np.ndarray:
    """Rotation matrix (3, 3) of a rotation vector (3,) in radians."""
    R, _ = cv2.Rodrigues(np.asarray(rotvec, np.float64).reshape(3, 1))
    return R


def rotation_angle_deg(R_a: np.ndarray, R_b: np.ndarray) -> float:
    """Angle of R_a^T R_b in degrees via atan2 (stable for tiny angles, unlike arccos)."""
    return float(reference_pose_search.rotation_angles_deg(np.asarray(R_a, np.float64),
                                                           np.asarray(R_b, np.float64)[None])[0])


def rotation_angle_deg_authors(R_a: np.ndarray, R_b: np.ndarray) -> float:
    """The authors' distance: arccos((trace(R_a^T R_b) - 1) / 2) in float32 (0 for tiny angles)."""
    cos = (np.float32(np.trace((R_a.T @ R_b).astype(np.float32))) - np.float32(1)) / np.float32(2)
    return float(np.degrees(np.arccos(np.clip(cos, np.float32(-1), np.float32(1)))))


def nearest_rotation(M: np.ndarray) -> np.ndarray:
    """Closest rotation (det +1) to a 3x3 matrix, by SVD."""
    U, _, Vt = np.linalg.svd(M)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def global_relative_pose(clip: Clip, pair: int, config: SGCConfig) -> tuple[np.ndarray, np.ndarray]:
    """(R_g, t_g) from camera pair-1 to camera pair (docs/semantics.md §3.4)."""
    product = clip.R_wc[pair] @ clip.R_wc[pair - 1].T
    R_g = nearest_rotation(product)
    if config.compat == "authors":
        return R_g, clip.t_wc[pair] - product @ clip.t_wc[pair - 1]
    t_g = clip.t_wc[pair] - R_g @ clip.t_wc[pair - 1]
    return R_g, resolved_translation(t_g, clip.t_wc[pair - 1], clip.t_wc[pair])


# ----------------------------------------------------------------------------- depth regions


def valid_depth(depth: np.ndarray) -> np.ndarray:
    return np.isfinite(depth) & (depth > 0)


def kmeans_1d(values: np.ndarray, k: int, bins: int) -> np.ndarray:
    """Exact 1-D k-means on a ``bins``-bin histogram by dynamic programming.

    values (N,) -> labels (N,) in 0..k-1, clusters in increasing value order. Clusters are
    unions of whole bins; among those the within-cluster sum of squares is minimal.
    """
    values = np.asarray(values, np.float64)
    if values.size == 0:
        return np.zeros(0, np.int64)
    lo, hi = values.min(), values.max()
    if hi - lo <= 0:
        return np.zeros(values.size, np.int64)
    u = (values - lo) / (hi - lo)
    bin_of = np.clip(np.floor(u * bins), 0, bins - 1).astype(np.int64)
    N = np.concatenate([[0.0], np.cumsum(np.bincount(bin_of, minlength=bins))])
    S = np.concatenate([[0.0], np.cumsum(np.bincount(bin_of, weights=u, minlength=bins))])
    Q = np.concatenate([[0.0], np.cumsum(np.bincount(bin_of, weights=u * u, minlength=bins))])
    a = np.arange(bins + 1)[:, None]  # first bin of the last cluster (a == b + 1: empty cluster)
    b = np.arange(bins)[None, :]  # last bin
    n, s, q = N[b + 1] - N[a], S[b + 1] - S[a], Q[b + 1] - Q[a]
    cost = np.maximum(q - s * s / np.maximum(n, 1.0), 0.0)
    cost = np.where(a <= b + 1, np.where(a == b + 1, 0.0, cost), np.inf)
    prev = np.concatenate([[0.0], np.full(bins, np.inf)])  # D_0(a - 1) for a = 0..bins
    choices = []
    for _ in range(k):
        total = prev[:, None] + cost
        choice = np.argmin(total, axis=0)
        choices.append(choice)
        prev = np.concatenate([[0.0], total[choice, np.arange(bins)]])
    cluster_of_bin = np.zeros(bins, np.int64)
    last = bins - 1
    for j in range(k - 1, -1, -1):
        if last < 0:
            break
        first = choices[j][last]
        cluster_of_bin[first: last + 1] = j
        last = first - 1
    return cluster_of_bin[bin_of]


def depth_regions(depth: np.ndarray, region_mask: np.ndarray, config: SGCConfig,
                  layers: int | None = None) -> np.ndarray:
    """Label map (H, W): 1..N_s depth clusters (``layers`` of them, default k_seg) of the masked
    pixels, 0 = no region (docs/semantics.md §3.2)."""
    labels = np.zeros(depth.shape, np.int32)
    cluster = kmeans_1d(depth[region_mask], config.k_seg if layers is None else layers, config.kmeans_bins)
    counts = np.bincount(cluster, minlength=config.k_seg)
    kept = np.flatnonzero(counts >= max(config.min_region_pixels, 1))  # never an empty cluster, as the JAX engine
    renumber = np.zeros(config.k_seg, np.int32)
    renumber[kept] = np.arange(1, kept.size + 1)
    labels[region_mask] = renumber[cluster]
    return labels


def pair_region_mask(clip: Clip, frame: int, config: SGCConfig) -> np.ndarray:
    """S_i: static and valid depth in frame ``frame`` (the pair's region frame; authors: invalid
    static depth too)."""
    static = clip.static_mask[frame] if config.use_mos else np.ones(clip.image_size, bool)
    if config.compat == "authors":
        return static
    return static & valid_depth(clip.depth[frame])


def layer_count(region_mask: np.ndarray, uv: np.ndarray, config: SGCConfig) -> int:
    """Depth layers of a frame whose background (H, W) holds the points uv (n, 2) at their pixels
    (``track_pixel``): one per ``tracks_per_layer`` of them and two from that many on, 1..k_seg; k_seg unless
    ``layers_follow_tracks`` (docs/semantics.md §3.2)."""
    if not config.layers_follow_tracks:
        return config.k_seg
    on_mask = int((point_regions(region_mask.astype(np.int32), uv, config.track_pixel_offset) > 0).sum())
    per_layer = config.tracks_per_layer
    return int(np.clip(max(on_mask // per_layer, 2 * (on_mask >= per_layer)), 1, config.k_seg))


def partition_regions(clip: Clip, frame: int, config: SGCConfig, layers: int | None = None) -> np.ndarray:
    """Region label map (H, W) of frame ``frame`` for the configured partition; ``layers``: depth
    layers (partition ``depth``; default k_seg)."""
    region_mask = pair_region_mask(clip, frame, config)
    depth = np.where(valid_depth(clip.depth[frame]), clip.depth[frame], 0.0)
    if config.partition == "grid":
        return grid_regions(region_mask, config)
    if config.partition == "depth+spatial":
        return spatial_regions(depth, region_mask, config)
    return depth_regions(depth, region_mask, config, layers)


def grid_regions(region_mask: np.ndarray, config: SGCConfig) -> np.ndarray:
    """Label map (H, W): a rows x cols = k_seg grid over the mask's bounding box (h x w pixels),
    the factorisation with the squarest cells (ties: fewer rows); cells numbered row-major,
    cells under min_region_pixels dropped (the paper's "Grid depth" ablation)."""
    labels = np.zeros(region_mask.shape, np.int32)
    if not region_mask.any():
        return labels
    rows_any, cols_any = np.flatnonzero(region_mask.any(1)), np.flatnonzero(region_mask.any(0))
    y0, x0 = rows_any[0], cols_any[0]
    h, w = rows_any[-1] - y0 + 1, cols_any[-1] - x0 + 1
    shapes = [(r, config.k_seg // r) for r in range(1, config.k_seg + 1) if config.k_seg % r == 0]
    rows, cols = min(shapes, key=lambda s: max(s[1] * h, s[0] * w) / min(s[1] * h, s[0] * w))
    y, x = np.mgrid[: region_mask.shape[0], : region_mask.shape[1]]
    cell = np.clip((y - y0) * rows // h, 0, rows - 1) * cols + np.clip((x - x0) * cols // w, 0, cols - 1)
    counts = np.bincount(cell[region_mask], minlength=config.k_seg)
    kept = np.flatnonzero(counts >= max(config.min_region_pixels, 1))
    renumber = np.zeros(config.k_seg, np.int32)
    renumber[kept] = np.arange(1, kept.size + 1)
    labels[region_mask] = renumber[cell[region_mask]]
    return labels


def spatial_regions(depth: np.ndarray, region_mask: np.ndarray, config: SGCConfig) -> np.ndarray:
    """Label map (H, W): depth clusters split into 4-connected components; components under
    min_region_pixels dropped; the k_seg largest kept, numbered by decreasing size (ties: first
    pixel in raster order)."""
    labels = np.zeros(depth.shape, np.int32)
    if not region_mask.any():
        return labels
    cluster = np.full(depth.shape, -1, np.int64)
    cluster[region_mask] = kmeans_1d(depth[region_mask], config.k_seg, config.kmeans_bins)
    components = []  # (size, first raster index, pixel mask)
    for c in np.unique(cluster[region_mask]):
        n, comp = cv2.connectedComponents((cluster == c).astype(np.uint8), connectivity=4)
        for i in range(1, n):
            pixels = comp == i
            components.append((int(pixels.sum()), int(np.flatnonzero(pixels.ravel())[0]), pixels))
    components = [c for c in components if c[0] >= max(config.min_region_pixels, 1)]
    components.sort(key=lambda c: (-c[0], c[1]))
    for new_id, (_, _, pixels) in enumerate(components[: config.k_seg], start=1):
        labels[pixels] = new_id
    return labels


# ----------------------------------------------------------------------------- tracks


class UsablePoints(NamedTuple):
    """A pair's usable tracks with valid depth (docs/semantics.md §3.2 steps 3-4): X (n, 3) in camera
    pair-1, uv (n, 2) in frame pair, uv_prev (n, 2) in frame pair-1, and n_usable, the usable
    tracks with or without depth."""

    X: np.ndarray
    uv: np.ndarray
    uv_prev: np.ndarray
    n_usable: int


def usable_points(clip: Clip, pair: int, config: SGCConfig) -> UsablePoints:
    usable = clip.usable_tracks(config.min_track_conf, repeats=config.counts_repeated_tracks)[pair - 1]
    prev, curr = clip.track_prev[pair - 1][usable].astype(np.float64), clip.track_curr[pair - 1][usable].astype(np.float64)
    X, has_depth = back_project_tracks(clip, pair, prev, config.track_pixel_offset)
    return UsablePoints(X[has_depth], curr[has_depth], prev[has_depth], int(usable.sum()))


def track_pixels(uv: np.ndarray, offset: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """(column, row) int64 (n,) of the pixels points uv (n, 2) are read at: floor(x + offset),
    floor(y + offset); 0.5 reads the nearest pixel, 0 the floor pixel (``SGCConfig.track_pixel_offset``).
    A non-zero offset is added in float32, as the JAX engine does, so both read the same pixel."""
    shifted = uv.astype(np.float32) + np.float32(offset) if offset else uv
    return np.floor(shifted[:, 0]).astype(np.int64), np.floor(shifted[:, 1]).astype(np.int64)


def back_project_tracks(clip: Clip, pair: int, prev: np.ndarray, offset: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Frame pair-1 pixels prev (n, 2) back-projected from that frame's depth at their pixels
    (``track_pixels`` at ``offset``; docs/semantics.md §3.2 steps 3-4): X (n, 3) in camera pair-1,
    and where the depth is valid (n,); depth 1 stands in where it is not."""
    H, W = clip.image_size
    col, row = track_pixels(prev, offset)
    col, row = np.clip(col, 0, W - 1), np.clip(row, 0, H - 1)
    Z = clip.depth[pair - 1][row, col].astype(np.float64)
    has_depth = np.isfinite(Z) & (Z > 0)
    return back_project(clip.K[pair - 1], prev, np.where(has_depth, Z, 1.0)), has_depth


def region_frame(pair: int, config: SGCConfig) -> int:
    """The frame whose partition gives pair ``pair``'s regions: pair (frame i) or, under
    ``region_frame="previous"``, pair - 1 (docs/semantics.md §3.2 steps 2 and 5)."""
    return pair - 1 if config.reads_previous_frame else pair


def back_project(K: np.ndarray, uv: np.ndarray, Z: np.ndarray) -> np.ndarray:
    """Points X (n, 3) = Z K^-1 (u, v, 1) of pixels uv (n, 2) at depths Z (n,) (docs/semantics.md
    §3.2 step 3; the skew K[0, 1] included)."""
    rays = np.linalg.solve(K.astype(np.float64), np.column_stack([uv, np.ones(len(uv))]).T).T
    return rays * Z[:, None]


def project(K: np.ndarray, cam: np.ndarray) -> np.ndarray:
    """Pixels (n, 2) of camera-frame points cam (n, 3): K (x / z, y / z, 1), the skew included;
    |z| floored at 1e-12."""
    z = np.where(np.abs(cam[:, 2]) > 1e-12, cam[:, 2], 1e-12)
    return (np.column_stack([cam[:, :2] / z[:, None], np.ones(len(cam))]) @ K.astype(np.float64).T)[:, :2]


def point_regions(labels: np.ndarray, uv: np.ndarray, offset: float = 0.0) -> np.ndarray:
    """Region label (n,) at the pixels of uv (n, 2) (``track_pixels`` at ``offset``); 0 outside the
    image or outside every region."""
    H, W = labels.shape
    col, row = track_pixels(uv, offset)
    inside = (col >= 0) & (col < W) & (row >= 0) & (row < H)
    out = np.zeros(len(uv), np.int32)
    out[inside] = labels[row[inside], col[inside]]
    return out


# ----------------------------------------------------------------------------- local poses


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
    return reference_pose_search.pose_errors_sq(reference_pose_search.Pose(R, t), X, uv, K) < inlier_px**2


def reprojection_errors(X: np.ndarray, uv: np.ndarray, K: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Pixel distance (n,) between uv and the projection of R X + t with K."""
    return np.linalg.norm(project(K, X @ R.T + t) - uv, axis=1)


# ----------------------------------------------------------------------------- components


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


def warp_depth(depth_prev: np.ndarray, K_prev: np.ndarray, K_curr: np.ndarray, R: np.ndarray,
               t: np.ndarray, nearest: bool = True, mask_holes: bool = False) -> np.ndarray:
    """Forward-warp the valid pixels of depth_prev (H, W) into frame i; 0 where nothing lands.

    Rounds to the nearest pixel (half up), keeps z > 1e-5 inside the image; collisions keep the
    nearest depth (z-buffer), or the farthest with ``nearest=False`` (the authors' code).
    ``mask_holes``: 0 also where a point nearer by more than ``HOLE_DEPTH_MARGIN``, magnified m
    times, lies within max(m, 1) px (``hole_squares``): the splat is seen through a hole in that
    surface or past its last splat.
    """
    H, W = depth_prev.shape
    rows, cols = np.nonzero(valid_depth(depth_prev))
    d = depth_prev[rows, cols].astype(np.float64)
    pix = np.stack([cols, rows, np.ones_like(cols)], axis=0).astype(np.float64)
    X = (np.linalg.inv(K_prev) @ pix) * d
    cam = R @ X + t[:, None]
    z = cam[2]
    front = z > 1e-5
    proj = K_curr @ (cam[:, front] / z[front])
    z_front = z[front]
    focal_ratio = np.sqrt(K_curr[0, 0] * K_curr[1, 1] / (K_prev[0, 0] * K_prev[1, 1]))
    magnification = d[front] * focal_ratio / z_front
    iu, iv, z = np.floor(proj[0] + 0.5).astype(np.int64), np.floor(proj[1] + 0.5).astype(np.int64), z_front
    inside = (iu >= 0) & (iu < W) & (iv >= 0) & (iv < H)
    iu, iv, z = iu[inside], iv[inside], z[inside]
    if nearest:
        buffer = np.full((H, W), np.inf)
        np.minimum.at(buffer, (iv, iu), z)
        if mask_holes:
            cover = _hole_cover(proj, z_front, magnification, H, W)
            buffer[buffer > (1.0 + HOLE_DEPTH_MARGIN) * cover] = np.inf
        return np.where(np.isfinite(buffer), buffer, 0.0)
    buffer = np.zeros((H, W))
    np.maximum.at(buffer, (iv, iu), z)
    return buffer


def hole_squares(centre: np.ndarray, magnification: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per axis, the pixels first .. last - 1 a point at ``centre`` (n,) covers in the hole rule:
    k with centre - r < k <= centre + r, its reach r its magnification m, at least 1 and at most
    MAX_HOLE_REACH_PX -> (first, last) int64 (n,)."""
    reach = np.clip(magnification, 1.0, MAX_HOLE_REACH_PX)
    return (np.floor(centre - reach) + 1).astype(np.int64), (np.floor(centre + reach) + 1).astype(np.int64)


def _hole_cover(proj: np.ndarray, z: np.ndarray, magnification: np.ndarray, H: int, W: int) -> np.ndarray:
    """(H, W) nearest z among the points (projections (2+, n), depths (n,)) whose squares
    (``hole_squares``) include the pixel; inf where none: squares of up to 4 pixels a side (every
    point magnified less than 2x) by their offsets, larger ones point by point."""
    u0, u1 = hole_squares(proj[0], magnification)
    v0, v1 = hole_squares(proj[1], magnification)
    cover = np.full((H, W), np.inf)
    small = (u1 - u0 <= 4) & (v1 - v0 <= 4)
    for du in range(4):
        for dv in range(4):
            iu, iv = u0 + du, v0 + dv
            on = small & (iu < u1) & (iv < v1) & (iu >= 0) & (iu < W) & (iv >= 0) & (iv < H)
            np.minimum.at(cover, (iv[on], iu[on]), z[on])
    for k in np.nonzero(~small)[0]:
        window = cover[max(v0[k], 0):max(v1[k], 0), max(u0[k], 0):max(u1[k], 0)]
        np.minimum(window, z[k], out=window)
    return cover


def affine_depth_map(z: np.ndarray, d: np.ndarray, start: np.ndarray, steps: int = DEPTH_MAP_STEPS + 1) -> np.ndarray:
    """(α, β) float64 of least Σ |α z + β − d| / d over (n,) warped depths z and frame i's d: iteratively
    reweighted least squares from ``start`` (2,), ``steps`` steps, each the weighted regression of d
    on z, centred, weights 1 / max(|e|, DEPTH_MAP_WEIGHT_FLOOR), β shrunk by DEPTH_MAP_DAMPING
    (``kernels.depth_map``)."""
    kappa = DEPTH_MAP_DAMPING / (1.0 + DEPTH_MAP_DAMPING)
    coef = np.asarray(start, np.float64)
    for _ in range(steps):
        u = 1.0 / np.maximum(np.abs((coef[0] * z + coef[1] - d) / d), DEPTH_MAP_WEIGHT_FLOOR) / (d * d)
        total = np.sum(u)
        z_mean, d_mean = np.sum(u * z) / total, np.sum(u * d) / total
        var, cov = np.sum(u * (z - z_mean) ** 2) / total, np.sum(u * (z - z_mean) * (d - d_mean)) / total
        alpha = (cov + kappa * z_mean * d_mean) / (var + kappa * z_mean * z_mean)
        coef = np.array([alpha, (d_mean - alpha * z_mean) / (1.0 + DEPTH_MAP_DAMPING)])
    return coef


def pair_depth_map(warped: np.ndarray, depth_curr: np.ndarray, both: np.ndarray) -> tuple[float, float]:
    """The pair's depth map (α, β) (§3.6 step 7) on the ``both`` (H, W) pixels of every
    DEPTH_SCALE_STRIDE-th row and column, (1, 0) with fewer than DEPTH_SCALE_MIN_PIXELS: the affine map
    (``affine_depth_map``, from the scale) where its median relative error there is below
    DEPTH_MAP_GATE times the scale's, else the scale (the median of d / ẑ in float32, as the JAX
    engine's, and 0)."""
    s = DEPTH_SCALE_STRIDE
    sub = both[::s, ::s]
    if sub.sum() < DEPTH_SCALE_MIN_PIXELS:
        return 1.0, 0.0
    z, d = warped[::s, ::s][sub].astype(np.float64), depth_curr[::s, ::s][sub].astype(np.float64)
    scale = np.array([np.median((depth_curr[::s, ::s][sub] / warped[::s, ::s][sub]).astype(np.float32)), 0.0])
    affine = affine_depth_map(z, d, scale)
    median_error = [np.median(np.abs((c[0] * z + c[1] - d) / d)) for c in (affine, scale)]
    chosen = affine if median_error[0] < DEPTH_MAP_GATE * median_error[1] else scale
    return float(chosen[0]), float(chosen[1])


def depth_error_map(warped: np.ndarray, depth_curr: np.ndarray, static_curr: np.ndarray, relative: bool = False,
                    looked_back: tuple[np.ndarray, np.ndarray] | None = None, pair_scale: bool = False
                    ) -> tuple[np.ndarray, np.ndarray, float, float]:
    """(error (n,) of the compared pixels in row-major order, compared (H, W) bool, the pair's
    depth map α, β): |warped - depth_curr| where both are valid and the pixel is static, divided by
    depth_curr pixel by pixel when ``relative`` (AbsRel). ``looked_back``: (z, depth) (H, W), each
    pixel's point's depth in camera i-1 and frame i-1's depth where it lands (0 where unread):
    where read, the lesser of the error and |depth - z| (relative to z) (§3.6 step 5).
    ``pair_scale``: frame i-1's depths (warped and looked back) read through ``pair_depth_map``
    first, α depth + β (step 7; else (1, 0))."""
    both = (warped > 0) & valid_depth(depth_curr) & static_curr
    scale, offset = pair_depth_map(warped, depth_curr, both) if pair_scale and both.any() else (1.0, 0.0)
    error = np.abs(scale * warped[both] + offset - depth_curr[both])
    if relative:
        error = error / depth_curr[both]
    if looked_back is not None:
        z, depth = (a[both] for a in looked_back)
        read = depth > 0
        back = np.abs(scale * depth + offset - z)
        back = back / np.where(read, z, 1.0) if relative else back
        error = np.where(read, np.minimum(error, back), error)
    return error, both, scale, offset


def depth_error(warped: np.ndarray, depth_curr: np.ndarray, static_curr: np.ndarray, relative: bool = False,
                looked_back: tuple[np.ndarray, np.ndarray] | None = None, pair_scale: bool = False) -> float:
    """The mean of ``depth_error_map``'s errors (the same arguments); NaN if no pixel is compared."""
    error, *_ = depth_error_map(warped, depth_curr, static_curr, relative, looked_back, pair_scale)
    return float(np.mean(error)) if error.size else float("nan")


def previous_view(depth_curr: np.ndarray, K_prev: np.ndarray, K_curr: np.ndarray, R: np.ndarray,
                  t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Frame i's valid pixels (H, W) at depth_curr moved into camera i-1 ((R, t) moves camera i-1's
    points into camera i) and projected with K_prev -> (seen (H, W) bool: in front (z > 1e-5) and
    inside its image when rounded half up; z (H, W) their depth there; iu, iv (H, W) int64 the pixel,
    0 where not seen)."""
    H, W = depth_curr.shape
    rows, cols = np.mgrid[:H, :W]
    valid = valid_depth(depth_curr)
    d = np.where(valid, depth_curr, 1.0).astype(np.float64)
    pix = np.stack([cols.ravel(), rows.ravel(), np.ones(H * W)]).astype(np.float64)
    cam = R.T @ ((np.linalg.inv(K_curr) @ pix) * d.ravel() - t[:, None])
    z = cam[2]
    front = valid.ravel() & (z > 1e-5)
    proj = K_prev @ (cam / np.where(front, z, 1.0))
    iu, iv = np.floor(proj[0] + 0.5), np.floor(proj[1] + 0.5)
    seen = front & (iu >= 0) & (iu < W) & (iv >= 0) & (iv < H)
    iu, iv = (np.where(seen, a, 0).astype(np.int64).reshape(H, W) for a in (iu, iv))
    return seen.reshape(H, W), z.reshape(H, W), iu, iv


def seen_from_previous(depth_curr: np.ndarray, K_prev: np.ndarray, K_curr: np.ndarray, R: np.ndarray,
                       t: np.ndarray) -> np.ndarray:
    """(H, W) bool: valid pixels of frame i whose point at depth_curr lies in front of camera i-1
    (z > 1e-5) and inside its image when rounded half up; (R, t) moves camera i-1's points into
    camera i. Only there can a warp from frame i-1 be compared (§3.6)."""
    return previous_view(depth_curr, K_prev, K_curr, R, t)[0]


def warp_source(clip: Clip, pair: int, config: SGCConfig) -> np.ndarray:
    """Depth of frame pair-1 that the depth check warps: its static, valid pixels under spec (a
    masked moving object must not cover static pixels of frame pair), every valid one (authors)."""
    depth = clip.depth[pair - 1]
    if config.compat == "authors" or not config.use_mos:
        return depth
    return np.where(clip.static_mask[pair - 1], depth, 0.0)


def _strided(X: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every ceil(n / REFIT_POINTS)-th of the n points: at most REFIT_POINTS of them."""
    stride = max(-(-len(X) // REFIT_POINTS), 1)
    return X[::stride], uv[::stride]


def _refit_from(start: reference_pose_search.Pose, X: np.ndarray, uv: np.ndarray, K: np.ndarray,
                cut_px: float) -> reference_pose_search.Pose | None:
    """REFIT_UPDATES undamped Gauss-Newton updates from ``start`` on the points within ``cut_px`` of
    it (None with fewer than 6); the pose may be non-finite."""
    within = reference_pose_search.pose_errors_sq(start, X, uv, K) < cut_px**2
    if within.sum() < 6:
        return None
    R, t = start.R, start.t
    for _ in range(REFIT_UPDATES):
        r, J = reference_pose_search.residual_jacobian(X[within], uv[within], K, R, t)
        delta = -np.linalg.lstsq(J, r, rcond=None)[0]  # a degenerate spread of points must not raise
        R, t = cv2.Rodrigues(delta[:3])[0] @ R, t + delta[3:]  # the perturbation exp([w]) R X + t + dt
    return reference_pose_search.Pose(R, t)


def _median_cut_error(pose: reference_pose_search.Pose, X: np.ndarray, uv: np.ndarray, K: np.ndarray,
                      cut_px: float) -> float:
    """Median over the points of min(reprojection error, ``cut_px``) [px]."""
    return np.median(np.minimum(np.sqrt(reference_pose_search.pose_errors_sq(pose, X, uv, K)), cut_px))


def camera_refit(X: np.ndarray, uv: np.ndarray, K: np.ndarray, camera: reference_pose_search.Pose,
                 cut_px: float) -> tuple[reference_pose_search.Pose | None, float, bool]:
    """The camera's pose refitted to the (strided, ``_strided``) points X (n, 3) of the pair's regions,
    seen at uv (n, 2) (``_refit_from`` it) -> (the refit, None where it was not fitted or is not
    finite; its median of min(error, ``cut_px``) px, inf where None; whether it warps: the camera's
    median exceeds CAMERA_REFIT_RATIO times the refit's, docs/semantics.md §3.6 step 6)."""
    refit = _refit_from(camera, X, uv, K, cut_px)
    if refit is None or not (np.all(np.isfinite(refit.R)) and np.all(np.isfinite(refit.t))):
        return None, np.inf, False
    error = _median_cut_error(refit, X, uv, K, cut_px)
    return refit, error, bool(_median_cut_error(camera, X, uv, K, cut_px) > CAMERA_REFIT_RATIO * error)


def tracks_motion(X: np.ndarray, uv: np.ndarray, K: np.ndarray, refit: reference_pose_search.Pose | None,
                  refit_error: float, cut_px: float) -> tuple[float, float]:
    """The motion the tracks show (docs/semantics.md §3.11): of the camera's refit (``camera_refit``:
    ``refit``, its median cut error ``refit_error``) and the pose ``_refit_from`` rest, the one of
    lower median cut error (the camera's refit on a tie) -> (rotation [deg], translation [units of
    D]); NaN where neither was fitted. On the points ``camera_refit`` took."""
    best = (refit_error, refit)
    rest = _refit_from(reference_pose_search.Pose(np.eye(3), np.zeros(3)), X, uv, K, cut_px)
    if rest is not None and np.all(np.isfinite(rest.R)) and np.all(np.isfinite(rest.t)):
        error = _median_cut_error(rest, X, uv, K, cut_px)
        if error < best[0]:
            best = (error, rest)
    pose = best[1]
    return (np.nan, np.nan) if pose is None else (rotation_angle_deg(np.eye(3), pose.R), float(np.linalg.norm(pose.t)))


class PairDepthError(NamedTuple):
    """A pair's depth check (``pair_depth_check``): frame i-1's depth warped into frame i (H, W) (0
    where nothing is compared), each compared pixel's error (H, W) (NaN elsewhere; percent of depth
    under spec), their mean and the pair's depth map α ẑ + β (§3.6 step 7; 1 and 0 where not applied;
    β in the clip's depth units as scored, units of D under spec)."""

    warped: np.ndarray
    error: np.ndarray
    mean: float
    depth_scale: float
    depth_offset: float = 0.0


def pair_depth_check(clip: Clip, pair: int, R: np.ndarray, t: np.ndarray, config: SGCConfig) -> PairDepthError:
    """Frame pair-1 warped into frame pair with (R, t), compared on the static, valid pixels of
    frame pair -> PairDepthError."""
    spec = config.compat != "authors"
    source = warp_source(clip, pair, config)
    warped = warp_depth(source, clip.K[pair - 1], clip.K[pair], R, t, nearest=spec, mask_holes=spec)
    static = clip.static_mask[pair] if config.use_mos else np.ones(clip.image_size, bool)
    looked_back = None
    if spec:
        seen, z, iu, iv = previous_view(clip.depth[pair], clip.K[pair - 1], clip.K[pair], R, t)
        source = np.where(valid_depth(source), source, 0.0)
        at_landing = source[iv, iu]
        # compared only where frame i's point lands on a pixel frame i-1 warped, and frame i-1 did
        # not see it behind a nearer surface where the warp put a farther one (§3.6 step 4)
        margin = 1.0 + HOLE_DEPTH_MARGIN
        occluded = (margin * at_landing < z) & (warped > margin * clip.depth[pair])
        warped = np.where(seen & (at_landing > 0) & ~occluded, warped, 0.0)
        # frame i-1 read where the warp put a surface LOOK_BACK_RATIO times farther than frame i sees (§3.6 step 5)
        needed = (warped > LOOK_BACK_RATIO * clip.depth[pair]) & valid_depth(clip.depth[pair]) & static
        looked_back = z, np.where(needed, at_landing, 0.0)
    error, compared, scale, offset = depth_error_map(warped, clip.depth[pair], static, relative=config.scale_free,
                                                     looked_back=looked_back, pair_scale=spec and config.scale_free)
    unit = PERCENT if config.scale_free else 1.0
    error_map = np.full(compared.shape, np.nan)
    error_map[compared] = error * unit
    mean = float(np.mean(error)) * unit if error.size else float("nan")
    return PairDepthError(warped, error_map, mean, scale, offset)


def pair_depth_error(clip: Clip, pair: int, R: np.ndarray, t: np.ndarray, config: SGCConfig) -> tuple[np.ndarray, float]:
    """(warped depth (H, W), the pair's depth error) of ``pair_depth_check``."""
    check = pair_depth_check(clip, pair, R, t, config)
    return check.warped, check.mean


# ----------------------------------------------------------------------------- the clip


def region_seed(config: SGCConfig, pair: int, region: int) -> int:
    return (config.seed * 1_000_003 + pair * 1_009 + region) % (2**31 - 1)


class PairPoints(NamedTuple):
    """A pair's points (docs/semantics.md §3.2 steps 1-5): labels (H, W) of the region frame's regions,
    X (n, 3) in camera pair-1, uv (n, 2) in frame pair and uv_prev (n, 2) in frame pair-1 of the
    usable tracks with depth, their region (n,) (0: none) and n_usable, the usable tracks with or
    without depth."""

    labels: np.ndarray
    X: np.ndarray
    uv: np.ndarray
    uv_prev: np.ndarray
    region: np.ndarray
    n_usable: int


def pair_points(clip: Clip, pair: int, config: SGCConfig) -> PairPoints:
    X, uv, uv_prev, n_usable = usable_points(clip, pair, config)
    frame, where = region_frame(pair, config), uv_prev if config.reads_previous_frame else uv
    layers = layer_count(pair_region_mask(clip, frame, config), where, config)
    labels = partition_regions(clip, frame, config, layers)
    return PairPoints(labels, X, uv, uv_prev, point_regions(labels, where, config.track_pixel_offset), n_usable)


class RegionPose(NamedTuple):
    """One region's local pose before the quality rule: status (``ok``, ``rejected`` or
    ``too_few_points``), R, t (NaN unless found) and whether a rival makes it ambiguous (spec)."""

    status: int
    R: np.ndarray
    t: np.ndarray
    ambiguous: bool = False


def accepted_status(X: np.ndarray, uv: np.ndarray, K: np.ndarray, R: np.ndarray, t: np.ndarray,
                    config: SGCConfig) -> int:
    """``ok`` when the pose is finite and proper and its inliers (in front, error < inlier_px)
    number >= max(4, floor(min_inlier_frac * n)), else ``rejected`` (docs/semantics.md §3.2 step 6)."""
    if not (np.isfinite(R).all() and np.isfinite(t).all()) or abs(np.linalg.det(R) - 1.0) >= 1e-3:
        return REGION_STATUS["rejected"]
    inliers = pose_inliers(X, uv, K, R, t, config.inlier_px)
    needed = max(4, int(np.floor(config.min_inlier_frac * len(X))))
    return REGION_STATUS["ok"] if inliers.sum() >= needed else REGION_STATUS["rejected"]


NAN_POSE = (np.full((3, 3), np.nan), np.full(3, np.nan))


def spec_region_poses(points: PairPoints, K: np.ndarray, reference_pose: tuple[np.ndarray, np.ndarray] | None,
                      config: SGCConfig, pair: int) -> list[RegionPose]:
    """Every region's local pose of a pair under ``compat="spec"`` (docs/semantics.md §3.2 step 6),
    searched by ``reference_pose.region_pose``: the region's own triples, then the other regions'
    coarse optima and ``reference_pose`` (R_g, s t_g) as further starts; R_g (the identity without
    it) is the rival's rotation."""
    n_triples = SPEC_TRIPLES_PER_HYPOTHESIS * config.ransac_hypotheses
    K = K.astype(np.float64)
    # the rival's rotation (docs/semantics.md §3.3): the camera's, or none (identity) without it
    rival_rotation = (reference_pose[0].astype(np.float64) if reference_pose is not None
                      and np.isfinite(reference_pose[0]).all() else np.eye(3))
    members = [points.region == r for r in range(1, points.labels.max() + 1)]
    searches = []
    for region, member in enumerate(members, start=1):
        rng = np.random.default_rng(region_seed(config, pair, region))
        searches.append(reference_pose_search.search_region(points.X[member], points.uv[member], K, config.inlier_px,
                                                            n_triples, rng) if member.sum() >= config.min_points else None)
    out = []
    for member, search in zip(members, searches):
        if member.sum() < config.min_points:
            out.append(RegionPose(REGION_STATUS["too_few_points"], *NAN_POSE))
            continue
        if search is None:
            out.append(RegionPose(REGION_STATUS["rejected"], *NAN_POSE))
            continue
        others = [s.optima[0] for s in searches if s is not None and s is not search]
        if reference_pose is not None:
            others.append(reference_pose_search.Pose(*reference_pose))
        X, uv = points.X[member], points.uv[member]
        found = reference_pose_search.region_pose(X, uv, K, search, others, rival_rotation, config.inlier_px,
                                                  config.ambiguous_rot_deg, config.ambiguous_inlier_frac)
        out.append(RegionPose(accepted_status(X, uv, K, *found.pose, config), *found.pose, found.ambiguous))
    return out


def authors_region_poses(points: PairPoints, K: np.ndarray, config: SGCConfig, pair: int) -> list[RegionPose]:
    """Every region's local pose of a pair by ``cv2.solvePnPRansac`` with the authors' settings."""
    out = []
    for region in range(1, points.labels.max() + 1):
        member = points.region == region
        status, R, t = solve_region_pose(points.X[member], points.uv[member], K, config,
                                            region_seed(config, pair, region))
        out.append(RegionPose(status, R, t))
    return out


# Random triples of the spec search per RANSAC hypothesis of the JAX engine (whose adaptive stop
# usually ends far sooner): the reference is meant to be the harder searcher of the two, and with
# 30 (3000 triples at the default) it reaches the same optima under every seed tried.
SPEC_TRIPLES_PER_HYPOTHESIS = 30


def local_poses(clip: Clip, points: list[PairPoints], config: SGCConfig,
                reference_poses: list[tuple[np.ndarray, np.ndarray]] | None = None) -> dict[str, np.ndarray]:
    """Per pair and region (k_seg slots): status, R, t, point count, reprojection error, pose
    uncertainty; plus per pair n_tracks and n_regions (docs/semantics.md §3.2-3.3). ``points``
    per pair (``pair_points``); ``reference_poses`` per pair (R_g, s t_g), a start of the spec
    search."""
    n_pairs, k = clip.n_pairs, config.k_seg
    out = {
        "R_local": np.full((n_pairs, k, 3, 3), np.nan), "t_local": np.full((n_pairs, k, 3), np.nan),
        "region_status": np.full((n_pairs, k), REGION_STATUS["empty"], np.int32),
        "region_points": np.zeros((n_pairs, k), np.int32), "region_reproj": np.full((n_pairs, k), np.nan),
        "region_rot_std": np.full((n_pairs, k), np.nan), "region_trans_std": np.full((n_pairs, k), np.nan),
        "region_rot_noise": np.full((n_pairs, k), np.nan), "region_trans_noise": np.full((n_pairs, k), np.nan),
        "region_sigma_px": np.full((n_pairs, k), np.nan), "region_rot_per_px": np.full((n_pairs, k), np.nan),
        "region_trans_per_px": np.full((n_pairs, k), np.nan),
        "n_tracks": np.array([pp.n_usable for pp in points], np.int32),
        "n_regions": np.array([pp.labels.max() for pp in points], np.int32),
    }
    block_px = NOISE_BLOCK_FRAC * float(np.hypot(*clip.image_size))  # the floors' squares
    for pair in range(1, clip.n_frames):
        p, pp, K = pair - 1, points[pair - 1], clip.K[pair]
        if pp.n_usable < 4:
            continue
        if config.compat == "authors":
            poses = authors_region_poses(pp, K, config, pair)
        else:
            poses = spec_region_poses(pp, K, reference_poses[p] if reference_poses else None, config, pair)
        for j, pose in enumerate(poses):
            member = pp.region == j + 1
            X, uv = pp.X[member], pp.uv[member]
            status = pose.status
            if status == REGION_STATUS["ok"]:
                good, sigma, usual, per_px = region_quality(X, uv, K, pose.R, pose.t, clip.image_size, config)
                out["region_rot_std"][p, j], out["region_trans_std"][p, j] = usual
                out["region_rot_per_px"][p, j], out["region_trans_per_px"][p, j] = per_px
                out["region_sigma_px"][p, j] = sigma
                if config.compat != "authors":  # no floors there
                    out["region_rot_noise"][p, j], out["region_trans_noise"][p, j] = floor_noise(
                        X, uv, K, pose.R, pose.t, usual, sigma, block_px, config.inlier_px)
                if config.applies_quality_rule and pose.ambiguous and sigma <= config.quality_noise_px:
                    status = REGION_STATUS["ambiguous"]
                elif config.applies_quality_rule and not good:
                    status = REGION_STATUS["ill_conditioned"]
            out["region_status"][p, j], out["region_points"][p, j] = status, member.sum()
            if pose.status == REGION_STATUS["ok"]:
                out["R_local"][p, j], out["t_local"][p, j] = pose.R, pose.t
                out["region_reproj"][p, j] = float(reprojection_errors(X, uv, K, pose.R, pose.t).mean())
    return out


def fit_translation_scale(members: list[tuple[np.ndarray, np.ndarray]], K: np.ndarray, R_g: np.ndarray,
                          t_g: np.ndarray, cut_px: float, fallback: float = 1.0) -> float:
    """Robust s with which (R_g, s t_g) best explains the static tracks (docs/semantics.md §3.4).

    Each region point X (camera pair-1) observed at uv in frame pair, with n = K^-1 (u, v, 1)
    and Y = R_g X, must satisfy n_k (Y_3 + s t_3) = Y_k + s t_k on both image axes k: a line in s
    whose slope, in pixels, is |n_k t_3 - t_k| f_k / Y_3. From the start of lowest truncated cost
    (sum of min(slope |s - root|, cut_px)) among the slope-weighted and the plain median of every
    pair's roots together and of each pair's own, s is the weighted median of the lines within
    cut_px of it, or 0 where that is negative; ``fallback`` when no line has a slope.
    ``members[p]``, ``K`` (T, 3, 3), ``R_g`` / ``t_g`` per pair."""
    roots, slopes = [], []
    for p, (X, uv) in enumerate(members):
        pair_roots, pair_slopes = [np.zeros(0)], [np.zeros(0)]
        if len(X):
            Y = X @ R_g[p].T
            n = (np.linalg.inv(K[p + 1].astype(np.float64)) @ np.column_stack([uv, np.ones(len(uv))]).T).T
            for k, focal in ((0, K[p + 1][0, 0]), (1, K[p + 1][1, 1])):
                a = n[:, k] * t_g[p][2] - t_g[p][k]
                b = Y[:, k] - n[:, k] * Y[:, 2]
                ok = (Y[:, 2] > 0) & (a != 0)
                pair_roots.append(b[ok] / a[ok])
                pair_slopes.append(np.abs(a[ok]) * focal / Y[ok, 2])
        roots.append(np.concatenate(pair_roots))
        slopes.append(np.concatenate(pair_slopes))
    every_root, every_slope = np.concatenate(roots), np.concatenate(slopes)
    overall = weighted_median(every_root, every_slope, fallback)
    starts = [overall, weighted_median(every_root, np.ones_like(every_slope), overall)]
    starts += [weighted_median(r, w, overall) for r, w in zip(roots, slopes)]
    starts += [weighted_median(r, np.ones_like(w), overall) for r, w in zip(roots, slopes)]
    costs = [np.minimum(every_slope * np.abs(start - every_root), cut_px).sum() for start in starts]
    start = starts[int(np.argmin(costs))]
    near = every_slope * np.abs(start - every_root) < cut_px
    return max(weighted_median(every_root[near], every_slope[near], start), 0.0)


def weighted_median(values: np.ndarray, weights: np.ndarray, fallback: float) -> float:
    """The smallest value whose cumulative weight (in ascending order) reaches half the total;
    ``fallback`` when the total is 0."""
    if not weights.sum() > 0:
        return float(fallback)
    order = np.argsort(values, kind="stable")
    cumulative = np.cumsum(weights[order])
    return float(values[order][np.searchsorted(cumulative, 0.5 * cumulative[-1])])


def pair_reason(n_tracks: int, region_mask_pixels: int, n_regions: int, n_poses: int, depth_err: float,
                n_ill_conditioned: int = 0, compat: str = "spec") -> str:
    """The first problem of a pair, in pipeline order (``ok`` when every component exists)."""
    if n_tracks < 4:
        return "too_few_tracks"
    if region_mask_pixels == 0:
        return "no_static"
    if n_regions == 0:
        return "no_region"
    if n_poses == 0 and n_ill_conditioned > 0:
        return "ill_conditioned"
    if n_poses == 0:
        return "no_pose"
    if n_poses == 1 and compat != "authors":
        return "one_pose"
    if np.isnan(depth_err):
        return "no_depth_overlap"
    return "ok"


def score_pairs(clip: Clip, config: SGCConfig | None = None) -> PairArrays:
    """Every per-pair component and diagnostic of a clip (docs/semantics.md §3), as :class:`PairArrays`."""
    config = config or SGCConfig()
    clip, unit = in_depth_units(clip, config)
    n_pairs = clip.n_pairs
    points = [pair_points(clip, pair, config) for pair in range(1, clip.n_frames)]
    if config.global_pose:
        globals_ = [global_relative_pose(clip, pair, config) for pair in range(1, clip.n_frames)]
        R_g = np.stack([g[0] for g in globals_])
        t_g = np.stack([g[1] for g in globals_])
        # s maps pose units to units of D; undefined, the units are taken as shared (s = 1 / D)
        members = [(pp.X[pp.region > 0], pp.uv[pp.region > 0]) for pp in points]  # the scale fit uses them all
        scale = (fit_translation_scale(members, clip.K, R_g, t_g, config.inlier_px, 1.0 / unit)
                 if config.fits_translation_scale else 1.0 / unit)
        poses = local_poses(clip, points, config, [(R_g[p], scale * t_g[p]) for p in range(n_pairs)])
    else:  # the "w/o VGGT" variant: each pair's mean local pose stands in for the global one
        poses = local_poses(clip, points, config)
    accepted = poses["region_status"] == REGION_STATUS["ok"]
    posed = [(list(poses["R_local"][p][accepted[p]]), list(poses["t_local"][p][accepted[p]])) for p in range(n_pairs)]
    if not config.global_pose:
        means = [mean_pose(R, t) if R else (np.full((3, 3), np.nan), np.full(3, np.nan)) for R, t in posed]
        R_g = np.stack([m[0] for m in means])
        t_g = np.stack([m[1] for m in means])
        scale = 1.0
    f = translation_factor(config)
    out = empty_pair_arrays(n_pairs, config.k_seg)
    # reported in depth units per pose unit (1 when no global translation is scaled)
    out.scale, out.depth_unit = scale * unit if config.global_pose else 1.0, unit
    for key in ("R_local", "t_local", "region_status", "region_points", "region_reproj", "region_rot_std",
                "region_trans_std", "region_rot_noise", "region_trans_noise", "region_sigma_px", "region_rot_per_px",
                "region_trans_per_px", "n_tracks", "n_regions"):
        setattr(out, key, poses[key])
    for pair in range(1, clip.n_frames):
        p = pair - 1
        R_list, t_list = posed[p]
        spread = tuple(poses[name][p][accepted[p]] for name in ("region_rot_per_px", "region_trans_per_px"))
        local_rot, local_trans = local_variances(R_list, t_list, config, spread)
        global_rot, global_trans = global_variances(R_list, t_list, R_g[p], scale * t_g[p], config, spread)
        if not config.global_pose:
            global_rot = global_trans = float("nan")
        out.local_rot_var[p], out.local_trans_var[p] = local_rot, local_trans * f**2
        out.global_rot_var[p], out.global_trans_var[p] = global_rot, global_trans * f**2
        if np.isfinite(R_g[p]).all():
            out.depth_error[p] = pair_depth_error(clip, pair, R_g[p], scale * t_g[p], config)[1]
            if config.compat != "authors" and config.global_pose:
                member = points[p].region > 0
                X, uv = _strided(points[p].X[member], points[p].uv[member])
                camera = reference_pose_search.Pose(R_g[p], scale * t_g[p])
                refit, refit_error, warps = camera_refit(X, uv, clip.K[pair], camera, config.inlier_px)
                if R_list and warps:
                    # the camera fits the tracks worse than its refit to them: the refit warps too (§3.6 step 6)
                    out.depth_error[p] = np.fmin(out.depth_error[p],
                                                 pair_depth_error(clip, pair, refit.R, refit.t, config)[1])
                rot_deg, trans = tracks_motion(X, uv, clip.K[pair], refit, refit_error, config.inlier_px)
                out.tracks_rot_deg[p], out.tracks_trans[p] = rot_deg, trans * f
            out.t_g_norm[p] = np.linalg.norm(scale * t_g[p] if config.scale_free else t_g[p]) * f
            out.R_g_angle_deg[p] = rotation_angle_deg(np.eye(3), R_g[p])
        out.n_poses[p] = len(R_list)
        out.n_ill_conditioned[p] = int(np.isin(poses["region_status"][p], EXCLUDED_STATUSES).sum())
        out.reproj_error[p] = np.mean(poses["region_reproj"][p][accepted[p]]) if R_list else np.nan
        static_pixels = int(pair_region_mask(clip, region_frame(pair, config), config).sum())
        out.static_frac[p] = static_pixels / (clip.image_size[0] * clip.image_size[1])
        out.reason[p] = pair_reason(int(out.n_tracks[p]), static_pixels, int(out.n_regions[p]), len(R_list),
                                    out.depth_error[p], int(out.n_ill_conditioned[p]), config.compat)
    out.parallax_px = parallax_px(clip.K[1:].astype(np.float64), out.t_g_norm, config.scale_free)
    return out
