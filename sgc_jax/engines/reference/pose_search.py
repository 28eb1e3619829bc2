"""The spec reference's local-pose search (docs/semantics.md §3.2 step 6, §7.2): NumPy + OpenCV.

An independent searcher for the optimum the semantics define, written to search harder than the
JAX engine rather than fast: OpenCV's P3P on many random triples (every triple of a small region)
with no early stop, the pair's other regions' optima and the global pose as further starts,
local optima (least squares on the inliers until they stop changing) of the best ones, then the
descent at the noise-level cut and the rival. Least squares is a Levenberg-Marquardt on the
pixel residuals through the whole K (skew included).

Conventions: poses (R (3, 3), t (3,)) map camera i-1 coordinates to camera i (x_i = R x_{i-1} +
t); X (n, 3) region points in camera i-1, uv (n, 2) their pixels in frame i; errors in pixels.
"""

from __future__ import annotations

import itertools
import math
from typing import NamedTuple

import cv2
import numpy as np

from ...config import MIN_CUT_PX, NOISE_CUT

# Candidates from the triples that go on to local optimisation, and the rotation [deg] under
# which two of them count as the same start. On a small region with outlier tracks the first
# candidate in the lowest basin can rank sixth or lower among the distinct ones; with 16 the
# search reaches the same optima under every seed tried (bench/history/issue-20.md, "Both engines search until
# the optimum stops moving").
LO_STARTS = 16
DISTINCT_DEG = 0.5
# Least-squares fits per local optimisation (each on the inliers of the previous one) and
# Levenberg-Marquardt steps per fit; a fit has converged when a step lowers the squared error by
# less than LM_RTOL of it. In the flat valley of a weak region (rotation traded against
# translation) a fit needs tens of steps.
LO_ROUNDS = 10
LM_STEPS = 100
LM_RTOL = 1e-10


class Pose(NamedTuple):
    R: np.ndarray  # (3, 3)
    t: np.ndarray  # (3,)


def rotation_angles_deg(R_a: np.ndarray, Rs: np.ndarray) -> np.ndarray:
    """Angles [deg] (m,) of R_a^T R for rotations Rs (m, 3, 3), by atan2 (accurate near 0)."""
    M = np.einsum("ji,mjk->mik", R_a, Rs)
    sin = 0.5 * np.linalg.norm(np.stack([M[:, 2, 1] - M[:, 1, 2], M[:, 0, 2] - M[:, 2, 0],
                                         M[:, 1, 0] - M[:, 0, 1]], -1), axis=-1)
    return np.degrees(np.arctan2(sin, 0.5 * (np.trace(M, axis1=1, axis2=2) - 1.0)))


def errors_sq(Rs: np.ndarray, ts: np.ndarray, X: np.ndarray, uv: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Squared reprojection errors [px^2] (m, n) of poses Rs (m, 3, 3), ts (m, 3); inf behind the
    camera (z <= 0)."""
    P = K @ np.concatenate([Rs, ts[:, :, None]], axis=2)  # (m, 3, 4)
    proj = P @ np.concatenate([X, np.ones((len(X), 1))], axis=1).T  # (m, 3, n)
    z = proj[:, 2]
    front = z > 0
    safe_z = np.where(front, z, 1.0)
    err = (proj[:, 0] / safe_z - uv[:, 0]) ** 2 + (proj[:, 1] / safe_z - uv[:, 1]) ** 2
    return np.where(front, err, np.inf)


def truncated_costs(err_sq: np.ndarray, tau: float) -> np.ndarray:
    """MSAC cost (...,) of squared errors (..., n): sum of min(e^2, tau^2) (behind the camera: tau^2)."""
    return np.sum(np.minimum(err_sq, tau * tau), axis=-1)


def pose_errors_sq(pose: Pose, X: np.ndarray, uv: np.ndarray, K: np.ndarray) -> np.ndarray:
    return errors_sq(pose.R[None], pose.t[None], X, uv, K)[0]


# ----------------------------------------------------------------------------- least squares


def residual_jacobian(X: np.ndarray, uv: np.ndarray, K: np.ndarray, R: np.ndarray,
                      t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Residuals (2n,) (u errors, then v errors) and their Jacobian (2n, 6) in the left perturbation
    (w, dt): exp([w]) R X + t + dt, through the whole K."""
    RX = X @ R.T
    return _residual_jacobian(RX, RX + t, uv, K)


def _residual_jacobian(RX: np.ndarray, Y: np.ndarray, uv: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``residual_jacobian`` from the rotated points RX = R X and the camera points Y = RX + t (n, 3)."""
    z = Y[:, 2]
    proj = (Y / z[:, None]) @ K.T
    n = len(Y)
    grad_u = np.stack([K[0, 0] / z, K[0, 1] / z, -(K[0, 0] * Y[:, 0] + K[0, 1] * Y[:, 1]) / z**2], axis=1)
    grad_v = np.stack([np.zeros(n), K[1, 1] / z, -K[1, 1] * Y[:, 1] / z**2], axis=1)
    # d residual = grad . (w x RX + dt) = w . (RX x grad) + dt . grad
    grad = np.concatenate([grad_u, grad_v])
    (ax, ay, az), (gx, gy, gz) = np.concatenate([RX, RX]).T, grad.T
    J = np.column_stack([ay * gz - az * gy, az * gx - ax * gz, ax * gy - ay * gx, grad])
    return np.concatenate([proj[:, 0] - uv[:, 0], proj[:, 1] - uv[:, 1]]), J


def least_squares_pose(X: np.ndarray, uv: np.ndarray, K: np.ndarray, start: Pose, steps: int = LM_STEPS) -> Pose:
    """The pose minimising the summed squared reprojection error of X, uv (Levenberg-Marquardt from
    ``start``, Nielsen's damping update; a step is taken only when it lowers the error and keeps
    every point in front)."""
    R, t = start
    if len(X) < 3:
        return start
    r, J = residual_jacobian(X, uv, K, R, t)
    cost, damping, growth = r @ r, 1e-3, 2.0
    for _ in range(steps):
        H, g = J.T @ J, J.T @ r
        delta = -np.linalg.solve(H + np.diag(damping * (np.diag(H) + 1e-12)), g)
        step = cv2.Rodrigues(delta[:3])[0]
        R_new, t_new = step @ R, t + delta[3:]  # the Jacobian's perturbation: exp([w]) R X + t + dt
        RX = X @ R_new.T
        Y = RX + t_new
        if np.all(Y[:, 2] > 0):
            r_new, J_new = _residual_jacobian(RX, Y, uv, K)
            cost_new = r_new @ r_new
        else:
            cost_new = np.inf
        if cost_new < cost:
            # the gain ratio: actual decrease over the decrease the linear model predicts
            predicted = -(2.0 * g @ delta + delta @ H @ delta)
            rho = (cost - cost_new) / max(predicted, 1e-300)
            converged = cost - cost_new <= LM_RTOL * cost
            R, t, r, J, cost = R_new, t_new, r_new, J_new, cost_new
            damping, growth = max(damping * max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3), 1e-12), 2.0
            if converged:
                break
        else:
            damping, growth = damping * growth, growth * 2.0
            if damping > 1e8:
                break
    return Pose(R, t)


def local_optimum(X: np.ndarray, uv: np.ndarray, K: np.ndarray, start: Pose, tau: float) -> tuple[Pose, float]:
    """Iterated least squares on the inliers at tau (error < tau, in front) until they stop
    changing, each fit kept only when it lowers the truncated cost at tau -> (pose, cost)."""
    pose = start
    err = pose_errors_sq(pose, X, uv, K)
    cost = truncated_costs(err, tau)
    inliers = err < tau * tau
    for _ in range(LO_ROUNDS):
        if inliers.sum() < 4:
            break
        fitted = least_squares_pose(X[inliers], uv[inliers], K, pose)
        err_new = pose_errors_sq(fitted, X, uv, K)
        cost_new = truncated_costs(err_new, tau)
        if not cost_new < cost:
            break
        pose, err, cost = fitted, err_new, cost_new
        if np.array_equal(err < tau * tau, inliers):
            break
        inliers = err < tau * tau
    return pose, float(cost)


# ----------------------------------------------------------------------------- minimal samples


def triples(n: int, count: int, rng: np.random.Generator) -> np.ndarray:
    """(m, 3) index triples of n points: every triple when there are at most ``count``, else
    ``count`` random triples of distinct points."""
    if math.comb(n, 3) <= count:
        return np.array(list(itertools.combinations(range(n), 3)), np.int64).reshape(-1, 3)
    out = rng.integers(0, n, (count, 3))
    while True:
        bad = (out[:, 0] == out[:, 1]) | (out[:, 0] == out[:, 2]) | (out[:, 1] == out[:, 2])
        if not bad.any():
            return out
        out[bad] = rng.integers(0, n, (int(bad.sum()), 3))


def p3p_candidates(X: np.ndarray, uv: np.ndarray, K: np.ndarray, samples: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every P3P solution (OpenCV, AP3P) of the triples ``samples`` (m, 3) -> (Rs (c, 3, 3), ts (c, 3)).

    P3P only needs each pixel's viewing ray K^-1 (u, v, 1), so the pixels are first moved into the
    skew-free camera with the same fx, fy, cx, cy (exact for any skew)."""
    K0 = np.array([[K[0, 0], 0.0, K[0, 2]], [0.0, K[1, 1], K[1, 2]], [0.0, 0.0, 1.0]])
    rays = np.linalg.solve(K, np.column_stack([uv, np.ones(len(uv))]).T).T
    uv0 = (rays @ K0.T)[:, :2]
    rvecs, tvecs = [], []
    for points, pixels in zip(X[samples], uv0[samples]):
        try:
            n_sol, rv, tv = cv2.solveP3P(points, pixels, K0, None, flags=cv2.SOLVEPNP_AP3P)
        except cv2.error:
            continue
        rvecs.extend(rv[:n_sol])
        tvecs.extend(tv[:n_sol])
    if not rvecs:
        return np.zeros((0, 3, 3)), np.zeros((0, 3))
    rvecs, tvecs = np.asarray(rvecs, np.float64).reshape(-1, 3), np.asarray(tvecs, np.float64).reshape(-1, 3)
    finite = np.isfinite(rvecs).all(1) & np.isfinite(tvecs).all(1)
    return rotation_matrices(rvecs[finite]), tvecs[finite]


def rotation_matrices(rotvecs: np.ndarray) -> np.ndarray:
    """Rotation matrices (m, 3, 3) of rotation vectors (m, 3) [rad] (Rodrigues' formula)."""
    theta = np.linalg.norm(rotvecs, axis=1)
    axis = rotvecs / np.where(theta > 0, theta, 1.0)[:, None]
    x, y, z = axis.T
    zero = np.zeros_like(x)
    cross = np.stack([zero, -z, y, z, zero, -x, -y, x, zero], axis=1).reshape(-1, 3, 3)
    s, c = np.sin(theta)[:, None, None], np.cos(theta)[:, None, None]
    return np.eye(3) + s * cross + (1.0 - c) * cross @ cross


def leading_distinct(costs: np.ndarray, Rs: np.ndarray, ts: np.ndarray, count: int) -> list[Pose]:
    """Up to ``count`` poses of lowest cost, each more than DISTINCT_DEG in rotation from the ones
    before it (ties: lower index first)."""
    order = np.argsort(costs, kind="stable")
    order = order[np.isfinite(costs[order])]
    eligible = np.arange(len(order))  # positions in ``order`` still eligible, in cost order
    chosen: list[Pose] = []
    while len(chosen) < count and eligible.size:
        j = order[eligible[0]]
        chosen.append(Pose(Rs[j], ts[j]))
        # every later candidate as close to this one is no longer distinct
        eligible = eligible[rotation_angles_deg(Rs[j], Rs[order[eligible]]) > DISTINCT_DEG]
    return chosen


# ----------------------------------------------------------------------------- the search


class RegionSearch(NamedTuple):
    """A region's own search: the local optima at inlier_px (``local_optimum``) its triples led
    to, lowest cost first, and their costs."""

    optima: list[Pose]
    costs: list[float]


def search_region(X: np.ndarray, uv: np.ndarray, K: np.ndarray, inlier_px: float, n_triples: int,
                  rng: np.random.Generator) -> RegionSearch | None:
    """P3P on ``n_triples`` random triples (every triple when there are fewer), the LO_STARTS best
    distinct candidates optimised locally at inlier_px; None when no triple gives a pose."""
    Rs, ts = p3p_candidates(X, uv, K, triples(len(X), n_triples, rng))
    if not len(Rs):
        return None
    costs = np.concatenate([truncated_costs(errors_sq(Rs[c:c + 512], ts[c:c + 512], X, uv, K), inlier_px)
                            for c in range(0, len(Rs), 512)])
    optima = sorted((local_optimum(X, uv, K, start, inlier_px) for start in leading_distinct(costs, Rs, ts, LO_STARTS)),
                    key=lambda pc: pc[1])
    return RegionSearch([p for p, _ in optima], [c for _, c in optima])


def noise_cut(err_sq: np.ndarray, inlier_px: float) -> float:
    """clip(NOISE_CUT * sigma, min(MIN_CUT_PX, inlier_px), inlier_px) [px], sigma^2 = mean e^2 / 2 over
    the errors under inlier_px (inlier_px when there are none)."""
    inl = err_sq < inlier_px**2
    if not inl.any():
        return inlier_px
    sigma = math.sqrt(float(np.mean(err_sq[inl])) / 2.0)
    return float(np.clip(NOISE_CUT * sigma, min(MIN_CUT_PX, inlier_px), inlier_px))


class FoundPose(NamedTuple):
    """A region's local pose (docs/semantics.md §3.2 step 6) and whether its rival makes it
    ``ambiguous`` (§3.3)."""

    pose: Pose
    ambiguous: bool


def region_pose(X: np.ndarray, uv: np.ndarray, K: np.ndarray, search: RegionSearch, others: list[Pose],
                rival_rotation: np.ndarray, inlier_px: float, ambiguous_rot_deg: float,
                ambiguous_inlier_frac: float) -> FoundPose:
    """The region's pose (docs/semantics.md §3.2 step 6) from its own search and ``others`` (the
    pair's other regions' best optima, the global pose), each taken to its local optimum at
    inlier_px:

    1. the coarse optimum: the lowest truncated cost at inlier_px; its noise-level cut
       (``noise_cut``);
    2. the pose: the local optimum at the cut from the coarse optimum;
    3. the rival (``rival_pose``, whose optimum at inlier_px, where it costs less, is the coarse
       optimum and sets the cut) replaces the pose where it costs less at the cut;
    4. ambiguous: the rival lies more than ``ambiguous_rot_deg`` away in rotation and keeps all
       but max(1, floor(``ambiguous_inlier_frac`` m)) of the pose's m members within the cut.
    """
    coarse = list(zip(search.optima, search.costs))
    for start in others:
        if np.all(np.isfinite(start.R)) and np.all(np.isfinite(start.t)):
            coarse.append(local_optimum(X, uv, K, start, inlier_px))
    best, best_cost = min(coarse, key=lambda pose_cost: pose_cost[1])
    cut = noise_cut(pose_errors_sq(best, X, uv, K), inlier_px)
    pose, _ = local_optimum(X, uv, K, best, cut)
    rival, cut = rival_pose(X, uv, K, pose, cut, rival_rotation, inlier_px, best_cost)
    if truncated_costs(pose_errors_sq(rival, X, uv, K), cut) < truncated_costs(pose_errors_sq(pose, X, uv, K), cut):
        pose = rival
    return FoundPose(pose, is_ambiguous(X, uv, K, pose, cut, rival, ambiguous_rot_deg, ambiguous_inlier_frac))


def translation_for_rotation(X: np.ndarray, uv: np.ndarray, K: np.ndarray, R: np.ndarray) -> np.ndarray:
    """The translation t (3,) that best explains pixels uv (n, 2) of points X (n, 3) under the
    rotation R: linear least squares of t_k - r_k t_3 = r_k Y_3 - Y_k on both image axes k (r =
    K^-1 (u, v, 1), Y = R X), each divided by Y_3 so that it weighs as a pixel error over f.
    Points with Y_3 <= 0 are left out; zeros when fewer than two remain."""
    rays = np.linalg.solve(K, np.column_stack([uv, np.ones(len(uv))]).T).T
    Y = X @ R.T
    front = Y[:, 2] > 0
    if front.sum() < 2:
        return np.zeros(3)
    rays, Y = rays[front], Y[front]
    rows, rhs = [], []
    for axis in (0, 1):
        a = np.zeros((len(Y), 3))
        a[:, axis], a[:, 2] = 1.0, -rays[:, axis]
        rows.append(a / Y[:, 2:])
        rhs.append(rays[:, axis] - Y[:, axis] / Y[:, 2])
    return np.linalg.lstsq(np.concatenate(rows), np.concatenate(rhs), rcond=None)[0]


def rival_pose(X: np.ndarray, uv: np.ndarray, K: np.ndarray, pose: Pose, cut: float, rotation: np.ndarray,
               inlier_px: float, coarse_cost: float) -> tuple[Pose, float]:
    """The region's rival (docs/semantics.md §3.3) and the cut: from ``rotation`` (the camera's,
    R_g) with the translation that best explains the pose's members within the cut
    (``translation_for_rotation``), the local optimum at inlier_px, which sets the cut where it
    costs less than ``coarse_cost`` (it is then the coarse optimum), then at the cut."""
    near = pose_errors_sq(pose, X, uv, K) < cut * cut
    start = Pose(rotation, translation_for_rotation(X[near], uv[near], K, rotation))
    coarse, cost = local_optimum(X, uv, K, start, inlier_px)
    if cost < coarse_cost:
        cut = noise_cut(pose_errors_sq(coarse, X, uv, K), inlier_px)
    return local_optimum(X, uv, K, coarse, cut)[0], cut


def is_ambiguous(X: np.ndarray, uv: np.ndarray, K: np.ndarray, pose: Pose, cut: float, rival: Pose,
                 rot_deg: float, inlier_frac: float) -> bool:
    """The rival lies more than ``rot_deg`` away in rotation and keeps all but max(1, floor(
    inlier_frac * m)) of the m members within ``cut`` of ``pose`` (docs/semantics.md §3.3)."""
    inl = pose_errors_sq(pose, X, uv, K) < cut * cut
    m = int(inl.sum())
    margin = max(1, int(np.floor(inlier_frac * m)))
    apart = rotation_angles_deg(pose.R, rival.R[None])[0] > rot_deg
    shared = int(np.sum((pose_errors_sq(rival, X, uv, K) < cut * cut) & inl))
    return bool(apart and shared >= m - margin)
