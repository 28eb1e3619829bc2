"""The pose bias that errors at frame i−1 give through the depth read (issue 58, docs/semantics.md
§3.10): observed over noise draws against its prediction from the depth map, the pose and the
error's size alone.

    python bench/depth_read_bias.py [--scenes fit-0 fit-2] [--px 2] [--draws 30] [--samples 200] [--read both|ray|depth]
                                    [--regions [--min-tracks 30]]

One region per pair, every static track with depth: the scene's exact tracks plus Gaussian errors
of ``--px`` at both ends, each draw fitted by the reference engine's least squares from the true
pose (docs §7.2), as the lifted points X = depth(p') K⁻¹ p' at the displaced frame-(i−1) pixel p'
(the engine's read: the floor pixel). ``--read ray`` displaces the ray only (depth at the exact
pixel), ``--read depth`` the depth read only. Prints per pair the mean rotation error over the
draws (and its standard error), the prediction −(E[JᵀJ])⁻¹ E[Jᵀ r] at the true pose, J and r of
the points lifted at displaced pixels and the exact frame-i track, the expectations over
``--samples`` displacements of every track (no draw of the clip is fitted), and one draw's spread.
With ``--regions``, one pose per depth layer of the pair (the engine's regions, read at the exact
frame-(i−1) pixel; every member fitted, without RANSAC or a cut), and the layers' bias² over
spread², observed and predicted.
"""

from __future__ import annotations

import argparse
from typing import NamedTuple

import numpy as np

from sgc_jax.engines import reference
from sgc_jax.engines.reference.pose_search import least_squares_pose, residual_jacobian
from sgc_jax.research import protocol
from sgc_jax.research.diagnostics import region_labels
from sgc_jax.research.pose_jitter import rotation_log_deg


def lift(clip, i: int, ray_px: np.ndarray, depth_px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points (n, 3) in camera i on the rays of ``ray_px`` at the depth frame i's map has at
    ``depth_px`` (the engines' read, ``reference.back_project_tracks``), and where it is valid (n,)."""
    at_read, valid = reference.back_project_tracks(clip, i + 1, depth_px)
    return reference.back_project(clip.K[i], ray_px, at_read[:, 2]), valid


def displaced(read: str, exact: np.ndarray, noisy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(ray pixel, depth pixel) of a track displaced to ``noisy`` under ``--read``."""
    return (exact if read == "depth" else noisy), (exact if read == "ray" else noisy)


class PairTracks(NamedTuple):
    """A pair's static tracks with depth at their exact frame-(i−1) pixel, and its true pose."""

    i: int  # frames i -> i+1
    R: np.ndarray  # (3, 3) camera i -> i+1
    t: np.ndarray  # (3,)
    prev: np.ndarray  # (n, 2) px
    curr: np.ndarray  # (n, 2) px


def pair_tracks(clip, i: int) -> PairTracks:
    """Pair i's (frames i -> i+1) exact static tracks with depth and its true relative pose."""
    R = clip.R_wc[i + 1] @ clip.R_wc[i].T
    p, c = clip.track_prev[i].astype(np.float64), clip.track_curr[i].astype(np.float64)
    static = reference.point_regions(clip.static_mask[i].astype(np.int32), p) > 0
    keep = clip.track_vis[i] & static & lift(clip, i, p, p)[1]
    return PairTracks(i, R, clip.t_wc[i + 1] - R @ clip.t_wc[i], p[keep], c[keep])


def rotation_bias(clip, tracks: PairTracks, args, rng) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """(observed mean rotation error (3,) [deg] over ``args.draws`` fits, its standard error (3,),
    predicted (3,), one draw's spread [deg]) of one pose fitted to ``tracks``."""
    i, R, t, p, c = tracks
    K_curr = clip.K[i + 1]
    gradient, normal = np.zeros(6), np.zeros((6, 6))
    for _ in range(args.samples):
        X, valid = lift(clip, i, *displaced(args.read, p, p + args.px * rng.standard_normal(p.shape)))
        r, J = residual_jacobian(X[valid], c[valid], K_curr, R, t)
        gradient += J.T @ r / args.samples
        normal += J.T @ J / args.samples
    predicted = np.degrees(-np.linalg.solve(normal, gradient)[:3])
    errors = []
    for _ in range(args.draws):
        X, valid = lift(clip, i, *displaced(args.read, p, p + args.px * rng.standard_normal(p.shape)))
        curr = c + args.px * rng.standard_normal(c.shape)
        fitted = least_squares_pose(X[valid], curr[valid], K_curr, (R, t))
        errors.append(rotation_log_deg(fitted.R @ R.T))
    errors = np.array(errors)
    return (errors.mean(0), errors.std(0, ddof=1) / np.sqrt(len(errors)), predicted,
            float(np.sqrt(np.trace(np.cov(errors.T)))))


def region_subsets(clip, i: int, tracks: PairTracks, min_tracks: int) -> list[tuple[int, PairTracks]]:
    """(label, tracks) of each depth layer of pair i (``research.diagnostics.region_labels``, read at
    the exact frame-(i−1) pixel) holding at least ``min_tracks`` of them."""
    label = reference.point_regions(region_labels(clip, i + 1), tracks.prev)
    return [(int(k), tracks._replace(prev=tracks.prev[label == k], curr=tracks.curr[label == k]))
            for k in np.unique(label) if k > 0 and np.sum(label == k) >= min_tracks]


def fmt(v) -> str:
    return "(" + ", ".join(f"{x:.3f}" for x in v) + ")"


def print_regions(clip, name: str, args, rng) -> list[tuple[float, float, float]]:
    """One row per depth layer; returns (observed bias², predicted bias², spread²) per layer [deg²]."""
    out = []
    for i in range(clip.track_prev.shape[0]):
        for label, tracks in region_subsets(clip, i, pair_tracks(clip, i), args.min_tracks):
            mean, stderr, predicted, spread = rotation_bias(clip, tracks, args, rng)
            out.append((float(mean @ mean - stderr @ stderr), float(predicted @ predicted), spread ** 2))
            print(f"| {name} | {i} | {label} ({len(tracks.prev)}) | {fmt(mean)} | {fmt(stderr)} | {fmt(predicted)} "
                  f"| {spread:.3f} |", flush=True)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="+", default=["fit-0", "fit-2"], help="FIT scenes (protocol.FIT_SCENES)")
    parser.add_argument("--px", type=float, default=2.0, help="RMS error per coordinate at each end [px]")
    parser.add_argument("--draws", type=int, default=30)
    parser.add_argument("--samples", type=int, default=200, help="displacements per track for the prediction")
    parser.add_argument("--read", choices=("both", "ray", "depth"), default="both")
    parser.add_argument("--tracks", type=int, default=1000)
    parser.add_argument("--regions", action="store_true", help="one pose per depth layer instead of per pair")
    parser.add_argument("--min-tracks", type=int, default=30, help="with --regions: the layers' fewest tracks")
    args = parser.parse_args()
    scenes = {scene.name: scene for scene in protocol.FIT_SCENES}
    rng = np.random.default_rng(0)
    print(f"errors {args.px:g} px at both ends, read displaced: {args.read}; {args.draws} draws a "
          + ("depth layer" if args.regions else "pair"))
    print("| scene | pair | " + ("layer (tracks) | " if args.regions else "")
          + "mean rotation error [deg] | its standard error | predicted [deg] | spread of one draw [deg] |")
    print("|---|---|" + ("---|" if args.regions else "") + "---|---|---|---|")
    layers = []
    for name in args.scenes:
        clip = scenes[name].clip(args.tracks)
        if args.regions:
            layers += print_regions(clip, name, args, rng)
            continue
        for i in range(clip.track_prev.shape[0]):
            mean, stderr, predicted, spread = rotation_bias(clip, pair_tracks(clip, i), args, rng)
            print(f"| {name} | {i} | {fmt(mean)} | {fmt(stderr)} | {fmt(predicted)} | {spread:.3f} |", flush=True)
    if layers:
        observed, predicted, spread = np.array(layers).T
        print(f"{len(layers)} layers: bias² / spread², observed (less its sampling share) median "
              f"{np.median(observed / spread):.2f}, mean {np.mean(observed / spread):.2f}; predicted median "
              f"{np.median(predicted / spread):.2f}, mean {np.mean(predicted / spread):.2f}")


if __name__ == "__main__":
    main()
