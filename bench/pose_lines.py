"""The loader's lines that read the tracks' fit to the camera's motion (docs/semantics.md §1.6): which
reading of the pose file or of the tracks each names, with the poses stored as §1.1 asks and as a
conversion plausibly leaves them, the tracks as (y, x), of a smaller frame or in part of it, and
their visibility inverted (an occlusion flag) or mostly hidden.

    python bench/pose_lines.py --pool fit|held-out [--scenes 24] [--ways WAY ...]
    python bench/pose_lines.py --real [--realdata ../shared/realdata] [--ways WAY ...]

``--pool``: each scene of a random pool (``protocol.random_scene``, 1,000 tracks) under ``iid-both``,
``correlated``, ``depth`` and ``outliers`` at 0.5 and 2 px, its poses stored each way of ``STORED``
its tracks each way of ``TRACK_WAYS`` and its visibility each of ``VIS_WAYS``; per way and level, the clips a line fires on, those it
names rightly and those it names wrongly (the (y, x) line read directly, as most such positions fall
off the pool's frames, where ``tracks_outside`` speaks first). ``--real``: the shared real clips
stored each way, the line each draws and the misfit under each pose reading. Nothing is chosen here.
"""

from __future__ import annotations

import collections
import dataclasses
from pathlib import Path

import numpy as np
from pools import need_one, pool_parser

from sgc_jax import SGCConfig, clip_from_arrays
from sgc_jax.io import validate
from sgc_jax.io.checks.motion_fits import (
    POSE_READINGS,
    pose_convention_residuals,
    scaled_tracks,
    track_reading_residuals,
)
from sgc_jax.io.checks.tracks import check_track_axes
from sgc_jax.research import protocol

FLIP = np.diag([1.0, -1.0, -1.0])  # OpenGL's camera axes against OpenCV's


def inverted(R, t):
    R = np.swapaxes(R, 1, 2)
    return R, -np.einsum("tij,tj->ti", R, t)


def in_text_order(R, t, first: int):
    order = np.array(sorted(range(first, first + len(R)), key=str)) - first
    return R[order], t[order]


STORED = {  # how the file holds the poses -> ((R_wc, t_wc) -> stored (R, t), the code its line should give)
    "as given": (lambda R, t: (R, t), None),
    "camera->world": (inverted, "camera_to_world_poses"),
    "opengl": (lambda R, t: (np.einsum("ij,tjk->tik", FLIP, R), t @ FLIP), "opengl_poses"),
    "opengl camera->world": (lambda R, t: inverted(np.einsum("ij,tjk->tik", FLIP, R), t @ FLIP), "opengl_poses"),
    "centres as translation": (lambda R, t: (R, inverted(R, t)[1]), "translation_as_centres"),
    "rotation transposed": (lambda R, t: (np.swapaxes(R, 1, 2), t), "rotation_transposed"),
    "reversed in time": (lambda R, t: (R[::-1], t[::-1]), "poses_reversed_in_time"),
    # listed in the text order of the frames' numbers (from 0 or 1): the same as given below 11 (10) frames
    "text order from 0": (lambda R, t: in_text_order(R, t, 0), "poses_in_text_order"),
    "text order from 1": (lambda R, t: in_text_order(R, t, 1), "poses_in_text_order"),
}
TRACKS_YX = "tracks (y, x)"  # the poses as given, each track position stored row first
SMALLER_FRAMES = (0.667, 0.75, 0.8, 0.9)  # tracks of a frame this much smaller, rescaled about its corner
PART_OF_THE_FRAME = 0.8  # tracks outside the top-left 80 % x 80 % of the frame made invisible
TRACK_WAYS = {TRACKS_YX: "tracks_yx", f"tracks in the top-left {PART_OF_THE_FRAME:.0%}": None} | {
    f"tracks of a frame x{f}": "tracks_of_a_smaller_frame" for f in SMALLER_FRAMES}
# how the visibility may be stored: as a tracker that hides much of it (HIDDEN_SHARE at random, their
# positions kept) or whose hidden tracks failed (their frame-i positions drawn over the image), each
# also inverted (an occlusion flag given as track_vis)
HIDDEN_SHARE = 0.6
VIS_INVERTED, MOSTLY_HIDDEN, HIDDEN_FAILED = "visibility inverted", "60 % hidden at random", "hidden tracks failed"
VIS_WAYS = {VIS_INVERTED: "track_vis_inverted", MOSTLY_HIDDEN: None, f"{MOSTLY_HIDDEN}, inverted": "track_vis_inverted",
            HIDDEN_FAILED: None, f"{HIDDEN_FAILED}, inverted": "track_vis_inverted"}
WAYS = {way: code for way, (_, code) in STORED.items()} | TRACK_WAYS | VIS_WAYS
POSE_CODES = {"camera_to_world_poses", "opengl_poses", "translation_as_centres", "rotation_transposed",
              "poses_reversed_in_time", "poses_in_text_order", "tracks_yx", "tracks_of_a_smaller_frame",
              "track_vis_inverted"}


def stored_visibility(clip, way: str):
    rng = np.random.default_rng(0)
    if way.startswith(MOSTLY_HIDDEN):
        clip = dataclasses.replace(clip, track_vis=clip.track_vis & (rng.random(clip.track_vis.shape) >= HIDDEN_SHARE))
    if way.startswith(HIDDEN_FAILED):
        H, W = clip.image_size
        drawn = rng.uniform([0.0, 0.0], [W - 1.0, H - 1.0], clip.track_curr.shape).astype(clip.track_curr.dtype)
        clip = dataclasses.replace(clip, track_curr=np.where(clip.track_vis[..., None], clip.track_curr, drawn))
    if way.endswith("inverted"):
        clip = dataclasses.replace(clip, track_vis=~clip.track_vis)
    return clip


def stored(clip, way: str):
    if way in VIS_WAYS:
        return stored_visibility(clip, way)
    if way == TRACKS_YX:
        return dataclasses.replace(clip, track_prev=clip.track_prev[..., ::-1].copy(),
                                   track_curr=clip.track_curr[..., ::-1].copy())
    if way.startswith("tracks of a frame x"):
        return scaled_tracks(clip, float(way.rsplit("x", 1)[1]))
    if way.startswith("tracks in the top-left"):
        H, W = clip.image_size
        inside = [(track[..., 0] + 0.5 <= PART_OF_THE_FRAME * W) & (track[..., 1] + 0.5 <= PART_OF_THE_FRAME * H)
                  for track in (clip.track_prev, clip.track_curr)]
        return dataclasses.replace(clip, track_vis=clip.track_vis & inside[0] & inside[1])
    R, t = STORED[way][0](clip.R_wc.astype(np.float64), clip.t_wc.astype(np.float64))
    return dataclasses.replace(clip, R_wc=R.astype(np.float32), t_wc=t.astype(np.float32))


def pose_lines(clip, config: SGCConfig, axes_alone: bool = False) -> list[str]:
    if axes_alone:
        readings = track_reading_residuals(clip, config, ("given", "yx", "reversed"))
        return [p.code for p in check_track_axes(readings)]
    return [p.code for p in validate.check_clip(clip, config) if p.code in POSE_CODES and p.severity == "warning"]


def pool_counts(pool: str, scenes: int, ways: dict[str, str | None]) -> None:
    config, counts = SGCConfig(), collections.Counter()
    for px, noisy in protocol.check_pool_clips(pool, scenes):
        for way, right in ways.items():
            codes = pose_lines(stored(noisy, way), config, axes_alone=way == TRACKS_YX)
            counts[way, px, "clips"] += 1
            counts[way, px, "fires"] += bool(codes)
            counts[way, px, "right"] += right in codes
            counts[way, px, "wrong"] += bool(set(codes) - {right})
    print(f"{pool} pool, {scenes} scenes, 1,000 tracks, {', '.join(protocol.CHECK_POOL_MODELS)}; "
          f"readings {POSE_READINGS}")
    print("| stored | px | clips | a pose line | named rightly | named wrongly |\n|---|---|---|---|---|---|")
    for way in ways:
        for px in protocol.CHECK_POOL_LEVELS_PX:
            print(f"| {way} | {px} | " + " | ".join(str(counts[way, px, key]) for key in ("clips", "fires", "right", "wrong"))
                  + " |")


def real_clips(realdata: Path, ways: dict[str, str | None]) -> None:
    config = SGCConfig()
    for path in sorted(realdata.glob("*.npz")):
        with np.load(path) as arrays:
            clip = clip_from_arrays({name: arrays[name] for name in arrays.files}, clip_id=path.stem, validate=False)
        for way in ways:
            readings = pose_convention_residuals(stored(clip, way), config, POSE_READINGS)
            misfits = ", ".join(f"{reading} {value:.2f}" for reading, value in readings.items())
            print(f"{path.stem} | {way} | lines {pose_lines(stored(clip, way), config)} | misfit px: {misfits}")


def main() -> None:
    parser = pool_parser(__doc__)
    parser.add_argument("--ways", nargs="+", choices=list(WAYS), default=list(WAYS), metavar="WAY",
                        help=f"the ways to store a clip (default all): {', '.join(WAYS)}")
    args = parser.parse_args()
    ways = {way: WAYS[way] for way in args.ways}
    if args.pool:
        pool_counts(args.pool, args.scenes, ways)
    if args.real:
        real_clips(args.realdata, ways)
    need_one(parser, args)


if __name__ == "__main__":
    main()
