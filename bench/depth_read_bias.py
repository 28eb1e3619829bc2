"""The pose bias that errors at frame i−1 give through the depth read (issue 58, docs/semantics.md
§3.10): observed over noise draws against its prediction from the depth map, the pose and the
error's size alone.

    python bench/depth_read_bias.py [--scenes fit-0 fit-2] [--px 2] [--draws 30] [--samples 200] [--read both|ray|depth]

One region per pair, every static track with depth: the scene's exact tracks plus Gaussian errors
of ``--px`` at both ends, each draw fitted by the reference engine's least squares from the true
pose (docs §7.2), as the lifted points X = depth(p') K⁻¹ p' at the displaced frame-(i−1) pixel p'
(the engine's read: the floor pixel). ``--read ray`` displaces the ray only (depth at the exact
pixel), ``--read depth`` the depth read only. Prints per pair the mean rotation error over the
draws (and its standard error), the prediction −(E[JᵀJ])⁻¹ E[Jᵀ r] at the true pose, J and r of
the points lifted at displaced pixels and the exact frame-i track, the expectations over
``--samples`` displacements of every track (no draw of the clip is fitted), and one draw's spread.
"""

from __future__ import annotations

import argparse

import numpy as np

from sgc_jax.engines.reference_pose import least_squares_pose, residual_jacobian
from sgc_jax.research import protocol
from sgc_jax.research.pose_jitter import rotation_log_deg


def lift(depth: np.ndarray, K: np.ndarray, ray_px: np.ndarray, depth_px: np.ndarray):
    """Points (n, 3) on the rays of ``ray_px`` at the depth read at ``depth_px`` (the floor pixel), and
    whether that depth is valid (n,)."""
    H, W = depth.shape
    col = np.clip(np.floor(depth_px[:, 0]).astype(int), 0, W - 1)
    row = np.clip(np.floor(depth_px[:, 1]).astype(int), 0, H - 1)
    Z = depth[row, col].astype(np.float64)
    return np.linalg.solve(K, np.column_stack([ray_px, np.ones(len(ray_px))]).T).T * Z[:, None], Z > 0


def displaced(read: str, exact: np.ndarray, noisy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(ray pixel, depth pixel) of a track displaced to ``noisy`` under ``--read``."""
    return (exact if read == "depth" else noisy), (exact if read == "ray" else noisy)


def pair_bias(clip, i: int, args, rng) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """(observed mean rotation error (3,) [deg], its standard error (3,), predicted (3,), spread) of pair i."""
    R = clip.R_wc[i + 1] @ clip.R_wc[i].T
    t = clip.t_wc[i + 1] - R @ clip.t_wc[i]
    K0, K1, depth = clip.K[i], clip.K[i + 1], clip.depth[i]
    p, c = clip.track_prev[i].astype(np.float64), clip.track_curr[i].astype(np.float64)
    H, W = clip.image_size
    static = clip.static_mask[i][np.clip(np.floor(p[:, 1]).astype(int), 0, H - 1),
                                 np.clip(np.floor(p[:, 0]).astype(int), 0, W - 1)]
    has_depth = lift(depth, K0, p, p)[1]
    p, c = p[clip.track_vis[i] & static & has_depth], c[clip.track_vis[i] & static & has_depth]
    gradient, normal = np.zeros(6), np.zeros((6, 6))
    for _ in range(args.samples):
        X, valid = lift(depth, K0, *displaced(args.read, p, p + args.px * rng.standard_normal(p.shape)))
        r, J = residual_jacobian(X[valid], c[valid], K1, R, t)
        gradient += J.T @ r / args.samples
        normal += J.T @ J / args.samples
    predicted = np.degrees(-np.linalg.solve(normal, gradient)[:3])
    errors = []
    for _ in range(args.draws):
        X, valid = lift(depth, K0, *displaced(args.read, p, p + args.px * rng.standard_normal(p.shape)))
        curr = c + args.px * rng.standard_normal(c.shape)
        fitted = least_squares_pose(X[valid], curr[valid], K1, (R, t))
        errors.append(rotation_log_deg(fitted.R @ R.T))
    errors = np.array(errors)
    return (errors.mean(0), errors.std(0, ddof=1) / np.sqrt(len(errors)), predicted,
            float(np.sqrt(np.trace(np.cov(errors.T)))))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="+", default=["fit-0", "fit-2"], help="FIT scenes (protocol.FIT_SCENES)")
    parser.add_argument("--px", type=float, default=2.0, help="RMS error per coordinate at each end [px]")
    parser.add_argument("--draws", type=int, default=30)
    parser.add_argument("--samples", type=int, default=200, help="displacements per track for the prediction")
    parser.add_argument("--read", choices=("both", "ray", "depth"), default="both")
    parser.add_argument("--tracks", type=int, default=1000)
    args = parser.parse_args()
    scenes = {scene.name: scene for scene in protocol.FIT_SCENES}
    rng = np.random.default_rng(0)
    print(f"errors {args.px:g} px at both ends, read displaced: {args.read}; {args.draws} draws a pair")
    print("| scene | pair | mean rotation error [deg] | its standard error | predicted [deg] | spread of one draw [deg] |")
    print("|---|---|---|---|---|---|")
    for name in args.scenes:
        clip = scenes[name].clip(args.tracks)
        for i in range(clip.track_prev.shape[0]):
            mean, stderr, predicted, spread = pair_bias(clip, i, args, rng)
            fmt = lambda v: "(" + ", ".join(f"{x:.3f}" for x in v) + ")"  # noqa: E731
            print(f"| {name} | {i} | {fmt(mean)} | {fmt(stderr)} | {fmt(predicted)} | {spread:.3f} |", flush=True)


if __name__ == "__main__":
    main()
