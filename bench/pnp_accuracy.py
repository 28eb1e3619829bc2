"""PnP-RANSAC accuracy on synthetic problems: sgc_jax.ransac_pnp vs OpenCV vs PoseLib.

Prints a markdown table: median / 95th-percentile rotation error [deg] and success rate
(rotation error < 1 deg and a pose returned) per setting. Camera: 60 deg horizontal fov,
512x288 image; points at depth 2-12 seen in both frames; rotations up to 10 deg, |t| ~ 0.2;
outliers are uniform random pixels. The JAX column runs ``ransac_pnp`` with min_inlier_frac=0
(like the others, it only has to return its best pose); a pose that is not returned counts as
180 deg. Timings: JAX is warm and batched over the trials (vmap), the others loop in C++.
Also prints the warm / compile time of one SGC pair (``ransac_pnp_regions``, as the engine calls
it): 10 regions x 100 hypotheses x 4096 points.
Run: ``python bench/pnp_accuracy.py [--trials 100] [--no-pair-timing]``.
"""

from __future__ import annotations

import argparse
import time

import cv2
import jax
import jax.numpy as jnp
import numpy as np

from sgc_jax.config import SGCConfig
from sgc_jax.engines.jax_engine.pose_stage import PoseStage
from sgc_jax.kernels.ransac import ransac_pnp, ransac_pnp_regions

W, H = 512, 288
FOV_DEG = 60.0
FAILED_DEG = 180.0  # error charged to a method that returns no pose


def intrinsics():
    f = 0.5 * W / np.tan(np.radians(FOV_DEG / 2))
    return np.array([[f, 0.0, (W - 1) / 2], [0.0, f, (H - 1) / 2], [0.0, 0.0, 1.0]])


def rotation_from_rotvec(w):
    R, _ = cv2.Rodrigues(np.asarray(w, np.float64).reshape(3, 1))
    return R


def rotation_error_deg(R_est, R_true):
    """Angle of R_est^T R_true [deg], float64, atan2 form."""
    M = R_est.T @ R_true
    s = 0.5 * np.linalg.norm([M[2, 1] - M[1, 2], M[0, 2] - M[2, 0], M[1, 0] - M[0, 1]])
    return float(np.degrees(np.arctan2(s, 0.5 * (np.trace(M) - 1.0))))


def make_problem(rng, n, outlier_frac, noise_px, K, max_rot_deg=10.0, t_scale=0.2):
    """n correspondences (X in camera 1, uv in camera 2) with the true (R, t) of camera 2."""
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    R = rotation_from_rotvec(axis * np.radians(rng.uniform(0.0, max_rot_deg)))
    t = rng.normal(size=3) * t_scale / np.sqrt(3.0)
    X_all, uv_all = [], []
    while sum(len(x) for x in X_all) < n:
        m = 4 * n
        uv0 = np.stack([rng.uniform(0, W - 1, m), rng.uniform(0, H - 1, m)], -1)
        z = rng.uniform(2.0, 12.0, m)
        X = np.stack([(uv0[:, 0] - K[0, 2]) * z / K[0, 0], (uv0[:, 1] - K[1, 2]) * z / K[1, 1], z], -1)
        Y = X @ R.T + t
        uv = Y[:, :2] / Y[:, 2:] * [K[0, 0], K[1, 1]] + K[:2, 2]
        keep = (Y[:, 2] > 0) & (uv[:, 0] >= 0) & (uv[:, 0] <= W - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= H - 1)
        X_all.append(X[keep])
        uv_all.append(uv[keep])
    X = np.concatenate(X_all)[:n]
    uv = np.concatenate(uv_all)[:n] + rng.normal(size=(n, 2)) * noise_px
    n_out = int(round(outlier_frac * n))
    out = rng.permutation(n)[:n_out]
    uv[out] = np.stack([rng.uniform(0, W - 1, n_out), rng.uniform(0, H - 1, n_out)], -1)
    return X, uv, R, t


def options(args, min_inlier_frac: float):
    """The engine's RANSAC options with this run's hypotheses, threshold and steps."""
    config = SGCConfig(ransac_hypotheses=args.hypotheses, inlier_px=args.inlier_px, lm_steps=args.steps,
                       min_inlier_frac=min_inlier_frac)
    return PoseStage.of(config).ransac


def run_jax(problems, K, args):
    """Batched over trials with one jitted vmap (one compile per point count)."""
    solve = jax.jit(
        jax.vmap(
            lambda X, uv, key: ransac_pnp(
                X,
                uv,
                jnp.ones(X.shape[0], bool),
                jnp.asarray(K, jnp.float32),
                key,
                options(args, min_inlier_frac=0.0),
            )
        )
    )
    X = jnp.asarray(np.stack([p[0] for p in problems]), jnp.float32)
    uv = jnp.asarray(np.stack([p[1] for p in problems]), jnp.float32)
    keys = jax.random.split(jax.random.key(args.seed), len(problems))
    jax.block_until_ready(solve(X, uv, keys))  # compile
    t0 = time.perf_counter()
    res = jax.block_until_ready(solve(X, uv, keys))
    ms = 1e3 * (time.perf_counter() - t0) / len(problems)
    R = np.asarray(res.R, np.float64)
    ok = np.asarray(res.status) == 0
    return [rotation_error_deg(R[i], p[2]) if ok[i] else FAILED_DEG for i, p in enumerate(problems)], ms


def run_opencv(problems, K, args):
    errs = []
    t0 = time.perf_counter()
    for X, uv, R_true, _ in problems:
        found, rvec, _, _ = cv2.solvePnPRansac(
            X, uv, K, None,
            iterationsCount=args.hypotheses, reprojectionError=args.inlier_px, confidence=0.99,
            flags=cv2.SOLVEPNP_ITERATIVE,
        )
        errs.append(rotation_error_deg(rotation_from_rotvec(rvec), R_true) if found else FAILED_DEG)
    return errs, 1e3 * (time.perf_counter() - t0) / len(problems)


def run_poselib(problems, K, args, poselib, max_iterations=None):
    camera = {"model": "PINHOLE", "width": W, "height": H, "params": [K[0, 0], K[1, 1], K[0, 2], K[1, 2]]}
    ransac_opt = {"max_reproj_error": args.inlier_px, "seed": args.seed}
    if max_iterations is not None:
        ransac_opt.update(max_iterations=max_iterations, min_iterations=max_iterations)
    errs = []
    t0 = time.perf_counter()
    for X, uv, R_true, _ in problems:
        pose, info = poselib.estimate_absolute_pose(uv, X, camera, ransac_opt, {})
        found = info["num_inliers"] >= 4
        errs.append(rotation_error_deg(np.asarray(pose.R), R_true) if found else FAILED_DEG)
    return errs, 1e3 * (time.perf_counter() - t0) / len(problems)


def summary(errs):
    e = np.asarray(errs)
    return f"{np.median(e):.4f} / {np.percentile(e, 95):.4f} / {100 * np.mean(e < 1.0):.0f}%"


def time_pair(args, regions=10, n_points=4096, repeats=20):
    """Warm and compile time of ransac_pnp_regions on one SGC pair (the engine's call)."""
    K = intrinsics()
    rng = np.random.default_rng(args.seed)
    X, uv, _, _ = make_problem(rng, n_points, 0.3, 1.0, K)
    order = np.argsort(X[:, 2])  # regions = depth slabs, as the depth clustering makes them
    region = np.zeros(n_points, np.int32)
    for r, idx in enumerate(np.array_split(order, regions)):
        region[idx] = r + 1
    solve = jax.jit(
        lambda region, keys: ransac_pnp_regions(X, uv, region, K, keys, options(args, min_inlier_frac=0.3))
    )
    X, uv, K = (jnp.asarray(a, jnp.float32) for a in (X, uv, K))
    region, keys = jnp.asarray(region), jax.random.split(jax.random.key(args.seed), regions)
    t0 = time.perf_counter()
    jax.block_until_ready(solve(region, keys))
    cold_s = time.perf_counter() - t0
    warm = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(solve(region, keys))
        warm.append(1e3 * (time.perf_counter() - t0))
    print(f"\none pair, {regions} regions x {args.hypotheses} hypotheses x {n_points} points, 30% outliers "
          f"({jax.devices()[0].platform}): warm {np.min(warm):.1f} ms (median {np.median(warm):.1f} ms), "
          f"first call incl. compile {cold_s:.1f} s")


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    algo = parser.add_argument_group("algorithm")
    algo.add_argument("--hypotheses", type=int, default=100)
    algo.add_argument("--inlier-px", type=float, default=8.0)
    algo.add_argument("--steps", type=int, default=10, help="Gauss-Newton steps per solve (JAX)")
    data = parser.add_argument_group("data")
    data.add_argument("--trials", type=int, default=100)
    data.add_argument("--points", type=int, nargs="+", default=[20, 200, 2000])
    data.add_argument("--outliers", type=float, nargs="+", default=[0.0, 0.3, 0.6])
    data.add_argument("--noise-px", type=float, nargs="+", default=[0.5, 2.0])
    data.add_argument("--seed", type=int, default=0)
    output = parser.add_argument_group("output")
    output.add_argument("--no-pair-timing", action="store_true", help="skip the one-pair timing")
    args = parser.parse_args()

    try:
        import poselib
    except ImportError:
        poselib = None
        print("poselib is not installed: its columns are skipped (pip install poselib)\n")

    K = intrinsics()
    cols = ["sgc_jax ransac_pnp", "cv2.solvePnPRansac"]
    if poselib is not None:
        cols += ["poselib (defaults)", f"poselib ({args.hypotheses} iters)"]
    print(f"rotation error [deg]: median / p95 / success (< 1 deg), {args.trials} trials per row; "
          f"hypotheses={args.hypotheses}, inlier_px={args.inlier_px}\n")
    print("| points | outliers | noise px | " + " | ".join(cols) + " |")
    print("|---|---|---|" + "---|" * len(cols))
    timings = {c: [] for c in cols}
    for n in args.points:
        for frac in args.outliers:
            for noise in args.noise_px:
                rng = np.random.default_rng([args.seed, n, int(100 * frac), int(100 * noise)])
                problems = [make_problem(rng, n, frac, noise, K) for _ in range(args.trials)]
                results = [run_jax(problems, K, args), run_opencv(problems, K, args)]
                if poselib is not None:
                    results.append(run_poselib(problems, K, args, poselib))
                    results.append(run_poselib(problems, K, args, poselib, max_iterations=args.hypotheses))
                for c, (_, ms) in zip(cols, results):
                    timings[c].append((n, ms))
                cells = " | ".join(summary(errs) for errs, _ in results)
                print(f"| {n} | {int(100 * frac)}% | {noise} | {cells} |", flush=True)
    print("\nmean time per problem [ms] by point count (JAX: warm, batched over trials):")
    for c in cols:
        by_n = {}
        for n, ms in timings[c]:
            by_n.setdefault(n, []).append(ms)
        print(f"- {c}: " + ", ".join(f"{n} pts {np.mean(v):.2f}" for n, v in by_n.items()))
    if not args.no_pair_timing:
        time_pair(args)


if __name__ == "__main__":
    main()
