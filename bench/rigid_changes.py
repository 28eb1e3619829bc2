"""Real footage changed in ways that keep its world rigid (issue 58): what a consistent world's score
should not see, beside what it should (depth resized with its holes read as 0, larger steps).

    python bench/rigid_changes.py [--dir ../shared/realdata] [--changes NAME ...] [--out rows.csv]

Each clip of ``../shared/realdata/`` as read, then changed (in memory, default config, JAX engine):

- ``reversed``: frames, cameras and masks in reverse order, each pair's tracks swapped end for end;
- ``turned``: every image array rotated 90 degrees clockwise, tracks (u, v) -> (H-1-v, u), K's
  axes swapped, the cameras turned about their optical axis;
- ``half`` / ``twice``: every other pixel from (1, 1) / each pixel repeated 2 x 2, tracks and K on
  the new grid;
- ``crop``: the centre 3/4 of each side, tracks that leave it invisible;
- ``letterbox``: bars of H/8 above and below (depth 0, mask false);
- ``first8``: the first 8 frames; ``depth^1.1``: depth raised to the power 1.1;
- ``network2x``: the depth's holes filled by their nearest valid depth, then shrunk to half by area
  and enlarged bilinearly (``research.noise.enlarged_depth``), as a depth network leaves it;
- ``holes-bilinear2x`` / ``holes-nearest2x``: the depth shrunk to half by nearest neighbour and
  enlarged back bilinearly / by nearest neighbour, its holes read as 0 (the loader warns of the
  first: ``depth_holes_blended``, docs/semantics.md §1.6);
- ``lk-step2`` / ``lk-step3``: every 2nd / 3rd frame, retracked by the clips' own LK (21 px windows,
  3 levels, forward-backward check under 0.5 px) from their frame i-1 grid; ``exact-step2`` /
  ``exact-step3``: the same pairs, their usable tracks at the frame-i positions the ground-truth depth and
  cameras give (``track_errors.variants``);
- ``lk-long``: long-range tracks, as a tracker queried once at frame 0 gives them (DELTA's dense
  output, CoTracker): the clip's first grid followed from frame to frame by the same LK from where
  it put each point in the frame before, a track lost once (the forward-backward check) lost for
  good; its errors lie at both ends of every pair after the first, and grow along the clip;
  ``lk-long-reseeded``: the same, each lost track queried again at the clip's own grid point of
  that slot in the frame it was lost in (a tracker queried in sliding windows keeps its density);
- ``focal0.9`` / ``focal1.1``: every K's focal lengths scaled by 0.9 / 1.1, as an intrinsics
  estimator's error (the world read through them is no longer quite rigid);
- ``depth-offset1%`` / ``depth-offset3%``: each frame's depth plus its own offset, normal with an RMS
  of 1 % / 3 % of the clip's median depth, as a relative-depth estimator's per-frame alignment can
  leave (not rigid: a consistent world's depth maps do not flicker so; what the score sees of it).

Prints SGC per clip and change (status beside where not ``ok``) and, per change, the largest move from
the clip as read. Real data, no split: nothing is chosen here.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path
from typing import Callable

import cv2
import numpy as np
import pandas as pd
from scipy import ndimage

from sgc_jax import load_clip, score_batch
from sgc_jax.io.clip import Clip
from sgc_jax.research.noise import enlarged_depth

sys.path.insert(0, str(Path(__file__).resolve().parent))
from track_errors import lk_step, retracked, variants  # noqa: E402

QUARTER_TURN = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # camera axes turned about z
LK_WINDOW_PX = 21  # the shared clips' own tracker (their README)


def reversed_clip(c: Clip) -> Clip:
    return dataclasses.replace(c, depth=c.depth[::-1].copy(), K=c.K[::-1].copy(), R_wc=c.R_wc[::-1].copy(),
                               t_wc=c.t_wc[::-1].copy(), static_mask=c.static_mask[::-1].copy(),
                               track_prev=c.track_curr[::-1].copy(), track_curr=c.track_prev[::-1].copy(),
                               track_vis=c.track_vis[::-1].copy(), track_conf=c.track_conf[::-1].copy(), frames=None)


def turned(c: Clip) -> Clip:
    H = c.image_size[0]
    turn = lambda a: np.ascontiguousarray(np.rot90(a, -1, axes=(1, 2)))  # noqa: E731  new[y', x'] = old[H-1-x', y']
    K = c.K.copy()
    K[:, 0, 0], K[:, 1, 1], K[:, 0, 2], K[:, 1, 2] = c.K[:, 1, 1], c.K[:, 0, 0], H - 1 - c.K[:, 1, 2], c.K[:, 0, 2]
    positions = lambda t: np.stack([H - 1 - t[..., 1], t[..., 0]], -1).astype(np.float32)  # noqa: E731
    return dataclasses.replace(c, depth=turn(c.depth), K=K, R_wc=QUARTER_TURN @ c.R_wc, t_wc=c.t_wc @ QUARTER_TURN.T,
                               static_mask=turn(c.static_mask), track_prev=positions(c.track_prev),
                               track_curr=positions(c.track_curr), frames=None)


def on_grid(c: Clip, depth, mask, scale: float, offset: float) -> Clip:
    """The clip on a new pixel grid x' = scale x + offset (depth and mask given on it)."""
    K = c.K.copy()
    K[:, :2, :2] *= scale
    K[:, :2, 2] = scale * c.K[:, :2, 2] + offset
    return dataclasses.replace(c, depth=depth, static_mask=mask, K=K, frames=None,
                               track_prev=(scale * c.track_prev + offset).astype(np.float32),
                               track_curr=(scale * c.track_curr + offset).astype(np.float32))


def half(c: Clip) -> Clip:
    return on_grid(c, c.depth[:, 1::2, 1::2].copy(), c.static_mask[:, 1::2, 1::2].copy(), 0.5, -0.5)


def twice(c: Clip) -> Clip:
    grow = lambda a: a.repeat(2, axis=1).repeat(2, axis=2)  # noqa: E731
    return on_grid(c, grow(c.depth), grow(c.static_mask), 2.0, 0.5)


def cropped(c: Clip) -> Clip:
    H, W = c.image_size
    top, left, h, w = H // 8, W // 8, 3 * H // 4, 3 * W // 4
    K = c.K.copy()
    K[:, 0, 2] -= left
    K[:, 1, 2] -= top
    shift = np.array([left, top], np.float32)
    prev, curr = c.track_prev - shift, c.track_curr - shift
    inside = lambda t: (t[..., 0] >= -0.5) & (t[..., 0] <= w - 0.5) & (t[..., 1] >= -0.5) & (t[..., 1] <= h - 0.5)  # noqa: E731
    vis = c.track_vis & inside(prev) & inside(curr)
    return dataclasses.replace(c, depth=c.depth[:, top:top + h, left:left + w].copy(), K=K, frames=None,
                               static_mask=c.static_mask[:, top:top + h, left:left + w].copy(), track_vis=vis,
                               track_prev=np.where(vis[..., None], prev, 0).astype(np.float32),
                               track_curr=np.where(vis[..., None], curr, 0).astype(np.float32))


def letterboxed(c: Clip) -> Clip:
    T, H, W = c.depth.shape
    bar = H // 8
    pad = lambda a, v: np.concatenate([np.full((T, bar, W), v, a.dtype), a, np.full((T, bar, W), v, a.dtype)], 1)  # noqa: E731
    K = c.K.copy()
    K[:, 1, 2] += bar
    shift = np.array([0, bar], np.float32)
    return dataclasses.replace(c, depth=pad(c.depth, 0), K=K, static_mask=pad(c.static_mask, False), frames=None,
                               track_prev=c.track_prev + shift, track_curr=c.track_curr + shift)


def first8(c: Clip) -> Clip:
    return dataclasses.replace(c, depth=c.depth[:8], K=c.K[:8], R_wc=c.R_wc[:8], t_wc=c.t_wc[:8],
                               static_mask=c.static_mask[:8], track_prev=c.track_prev[:7], track_curr=c.track_curr[:7],
                               track_vis=c.track_vis[:7], track_conf=c.track_conf[:7], frames=None)


def filled(frame: np.ndarray) -> np.ndarray:
    """A depth frame with every hole given its nearest valid depth (a network predicts everywhere)."""
    holes = ~(frame > 0)
    if not holes.any():
        return frame
    return frame[tuple(ndimage.distance_transform_edt(holes, return_distances=False, return_indices=True))]


def network2x(c: Clip) -> Clip:
    return dataclasses.replace(c, depth=enlarged_depth(np.stack([filled(d) for d in c.depth]), 2), frames=None)


def resized_with_holes(c: Clip, interpolation: int) -> Clip:
    T, H, W = c.depth.shape
    depth = np.stack([cv2.resize(cv2.resize(np.where(d > 0, d, 0).astype(np.float32), (W // 2, H // 2),
                                            interpolation=cv2.INTER_NEAREST), (W, H), interpolation=interpolation)
                      for d in c.depth])
    return dataclasses.replace(c, depth=depth, frames=None)


def stepped(c: Clip, step: int) -> Clip:
    """Every ``step``-th frame, each pair retracked by the clips' own LK (``track_errors.retracked``, 21 px
    windows) from frame i-1's grid of the pair that starts there."""
    kept = np.arange(0, c.n_frames, step)
    starts = kept[:-1]
    every = dataclasses.replace(c, depth=c.depth[kept], K=c.K[kept], R_wc=c.R_wc[kept], t_wc=c.t_wc[kept],
                                static_mask=c.static_mask[kept], frames=c.frames[kept],
                                track_prev=c.track_prev[starts], track_curr=c.track_prev[starts],
                                track_vis=c.track_vis[starts], track_conf=np.ones((len(starts), c.n_tracks), np.float32))
    return dataclasses.replace(retracked(every, LK_WINDOW_PX), clip_id=c.clip_id, frames=None)


def long_range(c: Clip, reseed: bool = False) -> Clip:
    """Frame 0's grid followed through the clip by the clips' own LK (module docstring, ``lk-long``,
    ``lk-long-reseeded``)."""
    gray = [cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY) for frame in c.frames]
    prev, curr, vis = np.empty_like(c.track_prev), np.empty_like(c.track_curr), np.empty_like(c.track_vis)
    at, alive = c.track_prev[0], c.track_vis[0].copy()  # the grid's points the clip's tracker followed
    for i in range(c.n_pairs):
        if reseed:
            at, alive = np.where(alive[:, None], at, c.track_prev[i]), alive | c.track_vis[i]
        ahead, found = lk_step(gray[i], gray[i + 1], at, LK_WINDOW_PX)
        prev[i], curr[i], vis[i] = at, ahead, alive & found
        at, alive = np.where(vis[i][:, None], ahead, at), vis[i]
    return dataclasses.replace(c, track_prev=prev, track_curr=curr, track_vis=vis,
                               track_conf=np.ones(c.track_vis.shape, np.float32))


def focal_scaled(c: Clip, factor: float) -> Clip:
    K = c.K.copy()
    K[:, 0, 0] *= factor
    K[:, 1, 1] *= factor
    return dataclasses.replace(c, K=K, frames=None)


def depth_offset(c: Clip, rms_rel: float) -> Clip:
    """Each frame's valid depth plus one offset, N(0, rms_rel) x the clip's median depth (seeded by
    the clip's id, so every change of a clip shares its draw)."""
    valid = c.depth > 0
    median = float(np.median(c.depth[valid]))
    offsets = np.random.default_rng(list(c.clip_id.encode())).normal(0.0, rms_rel * median, c.n_frames)
    return dataclasses.replace(c, depth=np.where(valid, c.depth + offsets[:, None, None], c.depth).astype(np.float32),
                               frames=None)


def exact_tracks(c: Clip) -> Clip:
    """The clip with its usable tracks' frame-i positions where the ground-truth depth and cameras put
    them (``track_errors.variants``' exact variant)."""
    return dataclasses.replace(variants(c, np.random.default_rng(0))["exact"], clip_id=c.clip_id)


CHANGES: dict[str, Callable[[Clip], Clip]] = {
    "reversed": reversed_clip, "turned": turned, "half": half, "twice": twice, "crop": cropped,
    "letterbox": letterboxed, "first8": first8,
    "depth^1.1": lambda c: dataclasses.replace(c, depth=np.where(c.depth > 0, c.depth, 0) ** 1.1, frames=None),
    "network2x": network2x,
    "holes-bilinear2x": lambda c: resized_with_holes(c, cv2.INTER_LINEAR),
    "holes-nearest2x": lambda c: resized_with_holes(c, cv2.INTER_NEAREST),
    "lk-step2": lambda c: stepped(c, 2), "lk-step3": lambda c: stepped(c, 3),
    "exact-step2": lambda c: exact_tracks(stepped(c, 2)), "exact-step3": lambda c: exact_tracks(stepped(c, 3)),
    "lk-long": long_range, "lk-long-reseeded": lambda c: long_range(c, reseed=True),
    "focal0.9": lambda c: focal_scaled(c, 0.9), "focal1.1": lambda c: focal_scaled(c, 1.1),
    "depth-offset1%": lambda c: depth_offset(c, 0.01), "depth-offset3%": lambda c: depth_offset(c, 0.03),
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--dir", type=Path, default=Path(__file__).resolve().parents[1].parent / "shared" / "realdata")
    parser.add_argument("--changes", nargs="+", default=list(CHANGES), choices=list(CHANGES))
    parser.add_argument("--out", type=Path, help="every clip's row (CSV)")
    args = parser.parse_args()
    originals = [load_clip(path) for path in sorted(args.dir.glob("*.npz"))]
    clips = []
    for clip in originals:
        clips.append(dataclasses.replace(clip, clip_id=f"{clip.clip_id}|as read", frames=None))
        clips += [dataclasses.replace(CHANGES[name](clip), clip_id=f"{clip.clip_id}|{name}") for name in args.changes]
    rows = score_batch(clips, progress=False).to_pandas()
    rows[["clip", "change"]] = rows["clip_id"].str.split("|", expand=True)
    if args.out:
        rows.to_csv(args.out, index=False)
    cell = rows["sgc"].map("{:.3f}".format) + rows["status"].where(rows["status"] == "ok", " " + rows["status"]).where(
        rows["status"] != "ok", "")
    table = pd.DataFrame({"clip": rows["clip"], "change": rows["change"], "cell": cell}).pivot(
        index="clip", columns="change", values="cell")[["as read", *args.changes]]
    print("| change | " + " | ".join(table.index) + " |\n|---|" + "---|" * len(table.index))
    for change in table.columns:
        print(f"| {change} | " + " | ".join(table[change]) + " |")
    sgc = rows.pivot(index="clip", columns="change", values="sgc")
    moved = (sgc[args.changes].sub(sgc["as read"], axis=0)).abs().max()
    print("\nlargest move from the clip as read:", ", ".join(f"{name} {moved[name]:.3f}" for name in args.changes))


if __name__ == "__main__":
    main()
