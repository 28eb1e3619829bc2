"""What in a real tracker's errors the real clips' excess comes from (issue 41): each clip of
``../shared/realdata/`` scored with its own tracks and with frame-i positions built from its ground
truth, under the default config and calibration.

    python bench/track_errors.py [--dir ../shared/realdata] [--seed 0]

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
(under ``exact`` both are near zero and their ratio says nothing).
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np

from sgc_jax import COMPONENTS, SGCConfig, load_clip, score_batch

POSE_COMPONENTS = [c for c in COMPONENTS if c != "depth_error"]
DEFAULT_DIR = Path(__file__).resolve().parents[2] / "shared" / "realdata"
VARIANTS = ("real", "exact", "iid", "shuffled")


def exact_positions(clip, pair: int) -> tuple[np.ndarray, np.ndarray]:
    """Ground-truth frame-i positions (P, 2) of pair ``pair``'s tracks, and where they exist (P,)."""
    H, W = clip.image_size
    prev = clip.track_prev[pair - 1].astype(np.float64)
    col = np.clip(np.floor(prev[:, 0]).astype(int), 0, W - 1)
    row = np.clip(np.floor(prev[:, 1]).astype(int), 0, H - 1)
    z = clip.depth[pair - 1][row, col].astype(np.float64)
    rays = np.linalg.solve(clip.K[pair - 1], np.column_stack([prev, np.ones(len(prev))]).T).T
    X = rays * z[:, None]
    R = clip.R_wc[pair] @ clip.R_wc[pair - 1].T
    t = clip.t_wc[pair] - R @ clip.t_wc[pair - 1]
    Y = X @ R.T + t
    front = np.isfinite(z) & (z > 0) & (Y[:, 2] > 1e-6)
    proj = (np.where(front[:, None], Y, 1.0) / np.where(front, Y[:, 2], 1.0)[:, None]) @ clip.K[pair].T
    return proj[:, :2], front


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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dir", default=str(DEFAULT_DIR))
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    paths = sorted(Path(args.dir).glob("*.npz"))
    if not paths:
        raise SystemExit(f"no .npz clips in {args.dir}")
    rng = np.random.default_rng(args.seed)
    clips = [c for p in paths for c in variants(load_clip(str(p)), rng).values()]
    result = score_batch(clips, progress=False)
    print("| clip | SGC | 90 % interval | " + " | ".join(f"{k} / floor" for k in POSE_COMPONENTS) + " |")
    print("|---|---|---|" + "---|" * len(POSE_COMPONENTS))
    for clip in result.clips:
        ratios = [clip.components[k] / clip.floors[f"{k}_floor"] for k in POSE_COMPONENTS]
        print(f"| {clip.clip_id} | {clip.sgc:.3f} | {clip.sgc_lo:.3f}-{clip.sgc_hi:.3f} | "
              + " | ".join(f"{r:.2f}" for r in ratios) + " |")


if __name__ == "__main__":
    main()
