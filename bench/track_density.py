"""One tracker at several densities (issues 58, 59): the clips of ``../shared/realdata/`` retracked
by pyramidal LK from a grid of query points in frame i-1, at each stride, and scored.

    python bench/track_density.py [--dir ../shared/realdata] [--strides 16 11 8 6 4] [--config FILE]
                                  [--trackers lk dis] [--out ROWS.csv]

The tracker is the one the clips' own tracks came from (21 px windows, 3 levels, a forward-backward
check under 0.5 px; the shared README), queried per pair on a grid of ``stride`` px: a denser grid
gives more tracks of the same tracker, whose errors neighbours share (overlapping windows). A
consistent world should score the same whatever the density. Prints SGC, reward, the tracks the
poses rest on and the depth layers' accepted poses per pair, per clip and stride ("given": the
clip's own tracks), and each clip's spread of SGC over the strides, and the tracks' distance to the
ground-truth motion at the 95th percentile (px). ``--trackers lk dis`` also follows the same grids
by a dense optical flow, OpenCV's DIS (medium preset, each pair's flow sampled bilinearly at the
points, the same forward-backward check under 0.5 px against the backward flow): a tracker whose
smoothness prior fills weak texture, rows "dis-sNN".
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import cv2
import numpy as np
import pandas as pd

from sgc_jax import SGCConfig, load_clip, score_batch
from sgc_jax.research.ground_truth import motion_errors

sys.path.insert(0, str(Path(__file__).resolve().parent))
from track_errors import retracked  # noqa: E402

DEFAULT_DIR = Path(__file__).resolve().parents[2] / "shared" / "realdata"
LK_WINDOW_PX = 21  # as the shared clips' own tracks
FORWARD_BACKWARD_PX = 0.5  # as LK's check (track_errors.lk_step)


def _at(flow, points):
    """Flow (H, W, 2) sampled bilinearly at points (P, 2) -> (P, 2)."""
    x, y = (points[:, k].reshape(-1, 1).astype(np.float32) for k in (0, 1))
    return np.concatenate([cv2.remap(flow[..., k], x, y, cv2.INTER_LINEAR) for k in (0, 1)], 1)


def flow_retracked(clip):
    """The clip with frame-i positions from OpenCV's DIS dense optical flow (medium preset), visible
    where the backward flow brings them within FORWARD_BACKWARD_PX of their start."""
    gray = [cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY) for frame in clip.frames]
    flow = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    curr, vis = clip.track_curr.copy(), clip.track_vis.copy()
    for i in range(clip.n_pairs):  # host-side preparation, two flows a pair
        start = clip.track_prev[i].astype(np.float32)
        curr[i] = start + _at(flow.calc(gray[i], gray[i + 1], None), start)
        back = curr[i] + _at(flow.calc(gray[i + 1], gray[i], None), curr[i])
        vis[i] &= np.linalg.norm(back - start, axis=1) < FORWARD_BACKWARD_PX
    return dataclasses.replace(clip, track_curr=curr, track_vis=vis)


def grid_label(tracker: str, stride: int) -> str:
    """A grid's row name: "sNN" for LK's, "dis-sNN" for DIS flow's."""
    return f"{'' if tracker == 'lk' else 'dis-'}s{stride:02d}"


def grid_tracks(clip, stride: int, tracker: str = "lk"):
    """``clip`` with its tracks replaced by LK tracks (``track_errors.retracked``) or DIS flow
    tracks (``flow_retracked``, ``tracker`` "dis") from a grid of ``stride`` px in each frame i-1."""
    H, W = clip.image_size
    ys, xs = np.mgrid[stride // 2:H:stride, stride // 2:W:stride]
    start = np.stack([xs.ravel(), ys.ravel()], -1).astype(np.float32)
    prev = np.broadcast_to(start, (clip.n_pairs, *start.shape)).copy()
    on_grid = dataclasses.replace(clip, track_prev=prev, track_curr=prev.copy(),
                                  track_vis=np.ones(prev.shape[:2], bool), track_conf=np.ones(prev.shape[:2], np.float32))
    tracked = retracked(on_grid, LK_WINDOW_PX) if tracker == "lk" else flow_retracked(on_grid)
    return dataclasses.replace(tracked, clip_id=f"{clip.clip_id}/{grid_label(tracker, stride)}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dir", default=str(DEFAULT_DIR))
    parser.add_argument("--strides", type=int, nargs="+", default=[16, 11, 8, 6, 4])
    parser.add_argument("--config", default=None, help="a config file (JSON) for the score (default: SGCConfig())")
    parser.add_argument("--trackers", nargs="+", choices=["lk", "dis"], default=["lk"])
    parser.add_argument("--out", default=None, help="CSV of every clip's row")
    args = parser.parse_args()
    config = SGCConfig.from_dict(json.loads(Path(args.config).read_text())) if args.config else SGCConfig()
    paths = sorted(Path(args.dir).glob("*.npz"))
    if not paths:
        raise SystemExit(f"no .npz clips in {args.dir}")
    clips = []
    for path in paths:
        clip = load_clip(str(path))
        clips += [dataclasses.replace(clip, clip_id=f"{clip.clip_id}/given")]
        clips += [grid_tracks(clip, stride, tracker) for tracker in args.trackers for stride in args.strides]
    result = score_batch(clips, config=config, progress=False)
    rows = result.to_pandas()
    rows["reward"] = result.rewards()["reward"]
    rows[["clip", "tracks"]] = rows["clip_id"].str.rsplit("/", n=1, expand=True)
    pairs = pd.DataFrame(result.pair_records())
    rows["poses_per_pair"] = rows["clip_id"].map(pairs.groupby("clip_id")["n_poses"].mean())
    rows["gt_p95_px"] = [np.percentile(motion_errors(clip), 95) for clip in clips]
    order = ["given", *[grid_label(t, s) for t in args.trackers for s in args.strides]]
    pd.set_option("display.width", 200)
    for column, digits in [("sgc", 3), ("reward", 3), ("pose_tracks", 0), ("poses_per_pair", 1), ("gt_p95_px", 1)]:
        table = rows.pivot(index="tracks", columns="clip", values=column).loc[order]
        print(f"\n{column}\n{table.round(digits).to_string()}")
    grid = rows[rows["tracks"] != "given"].copy()
    grid["tracker"] = np.where(grid["tracks"].str.startswith("dis-"), "dis", "lk")
    spread = grid.groupby(["tracker", "clip"])["sgc"].agg(["min", "max"])
    print(f"\nSGC over the strides {args.strides}: smallest, largest, largest - smallest\n"
          f"{spread.assign(spread=spread['max'] - spread['min']).round(3).to_string()}")
    if args.out:
        rows.to_csv(args.out, index=False)


if __name__ == "__main__":
    main()
