"""What in a real tracker's errors the real clips' excess comes from (issue 41): each clip of
``../shared/realdata/`` scored with its own tracks and with frame-i positions built from its ground
truth, under the default config and calibration.

    python bench/track_errors.py [--dir ../shared/realdata] [--seed 0] [--scale-fits]
                                 [--lk-windows 7 11 21 31] [--coherence] [--aperture [--synthetic fit|test]]

Every variant keeps the clip's frame i-1 positions and its usable tracks that have a ground truth
(valid depth at frame i-1's floor pixel, in front of camera i); per pair, with e = real - exact:

- real: the tracker's frame-i positions;
- exact: the ground-truth projections (depth at the floor pixel, the true relative pose, frame i's
  K), what a perfect tracker reports on this depth;
- iid: exact + independent Gaussian errors of the pair's typical spread (per axis, 1.4826 x the
  median absolute deviation of e from its median: a shift shared by all tracks is no spread);
- shuffled: exact + the pair's own error vectors e dealt to its tracks at random (the same errors,
  outliers included, without their places).

Printed per clip and variant: SGC, its 90 % interval, and each pose component over its floor
(under ``exact`` both are near zero and their ratio says nothing). ``--scale-fits`` also prints the
translation scale s (docs/semantics.md §3.4's equations, an L1 fit by reweighted least squares)
with R_g held, as the engines fit it, and with a small rotation correction per pair fitted
together with s (linearised), to see whether that would make s robust on these clips.
``--lk-windows W ...`` adds the clip retracked from its frames by pyramidal Lucas-Kanade with W x W
windows (3 pyramid levels, forward-backward check under 0.5 px) from the same frame i-1 positions:
the same tracker with more or less overlap between neighbouring tracks' windows.
``--coherence`` prints, instead of scores, how e is shared: between two tracks of a pair by their
distance in frame i-1, and at one scene point between consecutive pairs; for the real clips and
for a synthetic scene of their size under ``warp``, ``squeeze`` and ``depth_warp`` at 0.25 (there e
is the perturbation's own displacement: the synthetic tracks are exact).
``--aperture`` prints, instead, whether the tracks that miss the ground-truth motion by more than
``MISS_PX`` sit on lines and slide along them (the aperture problem): the image structure at their
frame i-1 positions (the ratio of the structure tensor's eigenvalues over a 9x9 window, 0 on a
straight edge), how much of each miss lies along the line, and SGC with the real tracks, with
every line-like track's miss along its line taken out (``LINE_RATIO``; a diagnosis that uses
the ground truth) and with the line-like tracks left out (no ground truth: the frames alone).
With ``--synthetic SPLIT`` the clips are the protocol split's scenes instead (sgc_jax.research.protocol,
1,000 tracks, rendered frames: checkerboards and stripes), their frame-i positions retracked by
LK with 21 px windows from the exact frame i-1 positions.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial import cKDTree

from sgc_jax import COMPONENTS, SGCConfig, load_clip, score_batch
from sgc_jax.adapters.line_tracks import LINE_RATIO, leave_out_line_tracks, line_structure
from sgc_jax.engines.reference import back_project, global_relative_pose
from sgc_jax.research import protocol
from sgc_jax.research.ground_truth import exact_positions, points_prev
from sgc_jax.research.perturb import perturb_clip
from sgc_jax.research.synth import synth_clip

POSE_COMPONENTS = [c for c in COMPONENTS if c != "depth_error"]
DEFAULT_DIR = Path(__file__).resolve().parents[2] / "shared" / "realdata"
VARIANTS = ("real", "exact", "iid", "shuffled")
DISTANCE_BINS_PX = (0, 8, 32, 64, 128, np.inf)
CLIP_ERROR_PX = 5.0  # e clipped per axis: tartan_000080's 37 px failures would swamp the sums
SAME_POINT_PX = 1.5  # a pair's track starts at the scene point another ended at (frame i positions)
MISS_PX = 3.0  # a track this far from its exact frame-i position misses the ground-truth motion


def variants(clip, rng: np.random.Generator) -> dict:
    """The clip under each of VARIANTS (see the module docstring)."""
    usable = clip.usable_tracks(SGCConfig().min_track_conf)
    curr = {name: clip.track_curr.astype(np.float64).copy() for name in VARIANTS}
    vis = clip.track_vis.copy()
    for pair in range(1, clip.n_frames):
        exact, front = exact_positions(clip, pair)
        keep = usable[pair - 1] & front
        vis[pair - 1] &= front
        e = clip.track_curr[pair - 1][keep] - exact[keep]
        scale = 1.4826 * np.median(np.abs(e - np.median(e, axis=0)), axis=0)
        curr["exact"][pair - 1][keep] = exact[keep]
        curr["iid"][pair - 1][keep] = exact[keep] + rng.normal(size=e.shape) * scale
        curr["shuffled"][pair - 1][keep] = exact[keep] + e[rng.permutation(len(e))]
    return {name: dataclasses.replace(clip, clip_id=f"{clip.clip_id}/{name}", track_vis=vis,
                                      track_curr=curr[name].astype(np.float32))
            for name in VARIANTS}


def lk_step(gray_from, gray_to, start: np.ndarray, window: int) -> tuple[np.ndarray, np.ndarray]:
    """Points start (P, 2) of one frame followed into the next by pyramidal LK (``window`` px square
    windows, 3 levels) -> (positions (P, 2), found: both ways found and back within 0.5 px of start)."""
    lk = {"winSize": (window, window), "maxLevel": 3}
    start = start.astype(np.float32).reshape(-1, 1, 2)
    ahead, found, _ = cv2.calcOpticalFlowPyrLK(gray_from, gray_to, start, None, **lk)
    back, found_back, _ = cv2.calcOpticalFlowPyrLK(gray_to, gray_from, ahead, None, **lk)
    agree = np.linalg.norm(back - start, axis=-1)[:, 0] < 0.5
    return ahead[:, 0], (found[:, 0] == 1) & (found_back[:, 0] == 1) & agree


def retracked(clip, window: int):
    """The clip with frame-i positions from pyramidal LK (``window`` px square windows) on its frames."""
    gray = [cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY) for frame in clip.frames]
    curr, vis = clip.track_curr.copy(), clip.track_vis.copy()
    for i in range(clip.n_pairs):
        curr[i], found = lk_step(gray[i], gray[i + 1], clip.track_prev[i], window)
        vis[i] &= found
    return dataclasses.replace(clip, clip_id=f"{clip.clip_id}/lk{window}", track_curr=curr, track_vis=vis)


def scale_equations(clip, pair: int, usable: np.ndarray, with_rotation: bool) -> tuple[np.ndarray, np.ndarray]:
    """Rows (m, 1 or 4) and right-hand sides (m,) of pair ``pair``'s equations a s (+ c . w) = b in
    pixels (§3.4; w the pair's rotation correction [rad], R_g -> (I + [w]x) R_g)."""
    X, valid = points_prev(clip, pair)
    R_g, t_g = global_relative_pose(clip, pair, SGCConfig())
    Y = X @ R_g.T
    curr = clip.track_curr[pair - 1].astype(np.float64)
    n = back_project(clip.K[pair], curr, np.ones(len(curr)))  # K^-1 (u, v, 1)
    keep = usable[pair - 1] & valid & (Y[:, 2] > 0)
    Y, n = Y[keep], n[keep]
    zero = np.zeros(len(Y))
    d_cross_z = np.stack([Y[:, 1], -Y[:, 0], zero], -1)  # d (w x Y)_z / dw
    d_cross = (np.stack([zero, Y[:, 2], -Y[:, 1]], -1), np.stack([-Y[:, 2], zero, Y[:, 0]], -1))
    rows, rhs = [], []
    for k in (0, 1):
        px = clip.K[pair][k, k] / Y[:, 2]
        columns = [(n[:, k] * t_g[2] - t_g[k])[:, None]]
        if with_rotation:
            columns.append(n[:, k, None] * d_cross_z - d_cross[k])
        rows.append(np.concatenate(columns, axis=1) * px[:, None])
        rhs.append((Y[:, k] - n[:, k] * Y[:, 2]) * px)
    return np.concatenate(rows), np.concatenate(rhs)


def fitted_scale(clip, with_rotation: bool) -> float:
    """s by the L1 fit of every pair's equations (iteratively reweighted least squares), R_g held
    or corrected per pair."""
    usable = clip.usable_tracks(SGCConfig().min_track_conf)
    blocks = [scale_equations(clip, pair, usable, with_rotation) for pair in range(1, clip.n_frames)]
    width = 1 + 3 * len(blocks) * with_rotation
    A = np.zeros((sum(len(b) for _, b in blocks), width))
    b = np.concatenate([rhs for _, rhs in blocks])
    start = 0
    for i, (rows, rhs) in enumerate(blocks):
        A[start:start + len(rhs), 0] = rows[:, 0]
        if with_rotation:
            A[start:start + len(rhs), 1 + 3 * i:4 + 3 * i] = rows[:, 1:]
        start += len(rhs)
    theta = np.linalg.lstsq(A, b, rcond=None)[0]
    for _ in range(100):
        root_w = 1.0 / np.sqrt(np.maximum(np.abs(A @ theta - b), 1e-3))
        theta = np.linalg.lstsq(A * root_w[:, None], b * root_w, rcond=None)[0]
    return float(theta[0])


# ----------------------------------------------------------------------------- coherence


@dataclasses.dataclass
class PairErrors:
    """One pair's usable tracks with a ground truth: frame i-1 positions, exact frame-i positions
    (P, 2) and e = frame-i position - exact, less its median over the pair, clipped [px]."""

    prev: np.ndarray
    exact: np.ndarray
    e: np.ndarray


def pair_errors(clip) -> list[PairErrors]:
    usable = clip.usable_tracks(SGCConfig().min_track_conf)
    out = []
    for pair in range(1, clip.n_frames):
        exact, front = exact_positions(clip, pair)
        keep = usable[pair - 1] & front
        e = clip.track_curr[pair - 1][keep].astype(np.float64) - exact[keep]
        e = np.clip(e - np.median(e, axis=0), -CLIP_ERROR_PX, CLIP_ERROR_PX)
        out.append(PairErrors(clip.track_prev[pair - 1][keep].astype(np.float64), exact[keep], e))
    return out


def pooled_correlation(u: np.ndarray, w: np.ndarray) -> float:
    """sum u.w / sqrt(sum |u|^2 sum |w|^2) over rows of (m, 2) error vectors: the share of their
    variance two sets of errors have in common (1: equal, 0: unrelated)."""
    return float(np.sum(u * w) / np.sqrt(np.sum(u * u) * np.sum(w * w)))


def correlation_by_distance(errors: list[PairErrors]) -> np.ndarray:
    """(bins,) median over pairs of the pooled correlation of two tracks' e, by their distance in
    frame i-1 (DISTANCE_BINS_PX)."""
    per_pair = []
    for pair in errors:
        i, j = np.triu_indices(len(pair.e), 1)
        distance = np.linalg.norm(pair.prev[i] - pair.prev[j], axis=-1)
        per_pair.append([pooled_correlation(pair.e[i][m], pair.e[j][m]) if (m := (distance >= lo) & (distance < hi)).any()
                         else np.nan for lo, hi in zip(DISTANCE_BINS_PX[:-1], DISTANCE_BINS_PX[1:])])
    return np.nanmedian(np.array(per_pair), axis=0)


def correlation_over_time(errors: list[PairErrors]) -> tuple[float, int]:
    """The pooled correlation of e at one scene point in consecutive pairs (a track of pair i+1
    starting within SAME_POINT_PX of where pair i's track truly ended), and how many such points."""
    now, after = [], []
    for first, second in zip(errors[:-1], errors[1:]):
        distance, index = cKDTree(second.prev).query(first.exact, distance_upper_bound=SAME_POINT_PX)
        found = np.isfinite(distance)
        now.append(first.e[found])
        after.append(second.e[index[found]])
    now, after = np.concatenate(now), np.concatenate(after)
    return pooled_correlation(now, after), len(now)


def print_coherence(clips: list) -> None:
    H, W = clips[0].image_size
    scene = synth_clip(seed=1, height=H, width=W, n_tracks=2048, n_frames=8)
    clips = clips + [perturb_clip(scene, kind, 0.25) for kind in ("warp", "squeeze", "depth_warp")]
    bins = [f"{lo:g}-{hi:g} px" for lo, hi in zip(DISTANCE_BINS_PX[:-1], DISTANCE_BINS_PX[1:])]
    print("| clip | per-axis RMS of e, px | " + " | ".join(bins) + " | next pair, same point (points) |")
    print("|---|---|" + "---|" * len(bins) + "---|")
    for clip in clips:
        errors = pair_errors(clip)
        rms = np.sqrt(np.mean(np.concatenate([pair.e for pair in errors]) ** 2))
        over_time, points = correlation_over_time(errors)
        print(f"| {clip.clip_id} | {rms:.2f} | " + " | ".join(f"{c:.2f}" for c in correlation_by_distance(errors))
              + f" | {over_time:.2f} ({points}) |")


# ----------------------------------------------------------------------------- aperture


def print_aperture(clips: list) -> None:
    print(f"| clip | tracks off the GT motion by > {MISS_PX:g} px | structure ratio, median: those / the others | "
          "share of their miss along the line, median abs cos | SGC | SGC, line-like misses along the line "
          "taken out | SGC, line-like tracks left out (their share) |")
    print("|---|---|---|---|---|---|---|")
    usable_conf = SGCConfig().min_track_conf
    rows, normal_only = [], []
    for clip in clips:
        usable = clip.usable_tracks(usable_conf)
        curr = clip.track_curr.astype(np.float64).copy()
        ratios, misses, cosines = [], [], []
        for pair in range(1, clip.n_frames):
            exact, front = exact_positions(clip, pair)
            keep = usable[pair - 1] & front
            ratio, weak = (a[keep] for a in line_structure(clip.frames[pair - 1],
                                                            clip.track_prev[pair - 1].astype(np.float64)))
            e = curr[pair - 1][keep] - exact[keep]
            along = np.sum(e * weak, axis=1)
            line = ratio < LINE_RATIO
            curr[pair - 1][np.flatnonzero(keep)[line]] -= along[line, None] * weak[line]
            miss = np.linalg.norm(e, axis=1)
            ratios.append(ratio)
            misses.append(miss)
            cosines.append(np.abs(along) / np.maximum(miss, 1e-12))
        ratio, miss, cosine = map(np.concatenate, (ratios, misses, cosines))
        rows.append((clip.clip_id, miss > MISS_PX, ratio, cosine))
        normal_only.append(dataclasses.replace(clip, clip_id=f"{clip.clip_id}/normal", track_curr=curr.astype(np.float32)))
    corners_only = [leave_out_line_tracks(clip) for clip in clips]
    scored = score_batch(clips + normal_only + corners_only, progress=False).clips
    n = len(clips)
    for i, (name, off, ratio, cosine) in enumerate(rows):
        left_out = 1.0 - corners_only[i].usable_tracks(usable_conf).sum() / clips[i].usable_tracks(usable_conf).sum()
        print(f"| {name} | {off.sum()} of {len(off)} | {np.median(ratio[off]):.3f} / {np.median(ratio[~off]):.3f} | "
              f"{np.median(cosine[off]):.2f} | {scored[i].sgc:.3f} | {scored[n + i].sgc:.3f} | "
              f"{scored[2 * n + i].sgc:.3f} ({left_out:.0%}) |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dir", default=str(DEFAULT_DIR))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--scale-fits", action="store_true")
    parser.add_argument("--lk-windows", type=int, nargs="*", default=[])
    parser.add_argument("--coherence", action="store_true")
    parser.add_argument("--aperture", action="store_true")
    parser.add_argument("--synthetic", choices=sorted(protocol.SPLITS), default=None,
                        help="with --aperture: the split's synthetic scenes retracked by LK instead of --dir")
    args = parser.parse_args()
    paths = sorted(Path(args.dir).glob("*.npz"))
    if not paths:
        raise SystemExit(f"no .npz clips in {args.dir}")
    if args.coherence:
        return print_coherence([load_clip(str(path)) for path in paths])
    if args.aperture and args.synthetic:
        return print_aperture([retracked(synth_clip(seed=scene.seed, clip_id=scene.name, n_tracks=1000, **scene.spec), 21)
                               for scene in protocol.SPLITS[args.synthetic]])
    if args.aperture:
        return print_aperture([load_clip(str(path)) for path in paths])
    rng = np.random.default_rng(args.seed)
    clips = []
    for path in paths:
        clip = load_clip(str(path))
        clips += [*variants(clip, rng).values(), *(retracked(clip, w) for w in args.lk_windows)]
    result = score_batch(clips, progress=False)
    print("| clip | tracks per pair | SGC | 90 % interval | "
          + " | ".join(f"{k} / floor" for k in POSE_COMPONENTS) + " |")
    print("|---|---|---|---|" + "---|" * len(POSE_COMPONENTS))
    for clip in result.clips:
        ratios = [clip.components[k] / clip.floors[f"{k}_floor"] for k in POSE_COMPONENTS]
        print(f"| {clip.clip_id} | {clip.pairs.n_tracks.mean():.0f} | {clip.sgc:.3f} | "
              f"{clip.sgc_lo:.3f}-{clip.sgc_hi:.3f} | " + " | ".join(f"{r:.2f}" for r in ratios) + " |")
    if args.scale_fits:
        print("\n| clip | s, the engine's | s, R_g held (this fit) | s, with a rotation correction per pair |")
        print("|---|---|---|---|")
        for clip, scored in zip(clips, result.clips):
            print(f"| {clip.clip_id} | {scored.scale:.3f} | {fitted_scale(clip, False):.3f} | "
                  f"{fitted_scale(clip, True):.3f} |")


if __name__ == "__main__":
    main()
