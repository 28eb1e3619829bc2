"""Clips a generator trained on the reward could learn to make (issue 59, docs/semantics.md §9.4):
each keeps the score from seeing an inconsistency, or gives it little to see. Built from an exact
consistent clip (:class:`~sgc_jax.research.protocol.ProtocolScene`); tracker noise is added
afterwards, as for any clip of the protocol.

:data:`ADVERSARIES` maps each name to its builder ``(scene, n_tracks) -> Clip``:

- ``few_tracks``: 80 tracks per pair, warped (``warp`` at 0.5);
- ``low_confidence``: 92 % of the tracks below the confidence threshold, warped;
- ``pure_rotation``: a camera that only turns, with ``depth_warp`` at 0.5;
- ``near_still``: a camera moving 3 % of the scene's speed;
- ``bursty``: one moving pair among still ones (frames 0 0 0 0 1 1 1 1 ...);
- ``thin_band``: the static mask cut to 20 % of the rows, warped;
- ``masked_out``: the static mask cut to 4 % of the rows, warped;
- ``unmasked_mover``: one moving object left out of the mask;
- ``repeated_frames``: every frame shown twice (0 0 1 1 2 2 ...);
- ``half_broken``: the first half of the pairs consistent, the rest warped at 1;
- ``still_video``: every frame the first, the cameras moving as the scene's (a camera-controlled
  generator that ignores the camera it was given, scored with that camera);
- ``backward_cameras``: the scene's video, scored with cameras whose centres run the other way
  along its path (C'_t = 2 C_0 − C_t, rotations the scene's): a camera-controlled generator that
  moves against the camera it was given, each pair's translation the opposite of its tracks';
- ``rotation_only_cameras``: the scene's video, scored with cameras that turn as the scene's but
  hold the first camera's centre: a camera-controlled generator asked for a turn on the spot that
  moves as well;
- ``static_cameras``: the scene's video, scored with every camera the first (a camera-controlled
  generator asked to hold still that moves);
- ``scene_cut``: the scene's first half, then the second half of another world of its layout (a
  hard cut), each half with its own world's depth and cameras, the second world's ``CUT_JUMP``
  median depths away (shots reconstructed apart share no origin), every track lost across the cut
  (as a tracker queried per pair loses them): two consistent shots that are not one world;
- ``scene_cut_tracked``: the same cut, every track across it kept visible, each frame i−1 point
  paired with the other world's track of the same index at frame i (a tracker that reports each
  patch where it matched best).

The last two give their cameras in a world whose origin lies ``WORLD_OFFSET`` median depths from
the first camera (as a SLAM or COLMAP world does; the protocol's scenes put the first camera at
the origin, where a held centre's t_wc is exactly 0).
"""

from __future__ import annotations

import dataclasses
from typing import Callable

import numpy as np

from ..io.clip import Clip
from .perturb import perturb_clip
from .protocol import ProtocolScene

WARP = 0.5  # the severity an adversary's inconsistency carries
LOW_CONFIDENCE = 0.1  # below SGCConfig().min_track_conf
WORLD_OFFSET = np.array([6.0, -2.0, 3.0])  # where held cameras' centre lies, in median depths
CUT_SEED_OFFSET = 1_000_000  # the other world of a cut: a seed no split or corpus holds
CUT_JUMP = np.array([50.0, 0.0, 0.0])  # where the other world's origin lies from the first's, in median depths


def with_frames(clip: Clip, order: list[int]) -> Clip:
    """The clip shown in the frame ``order`` (non-decreasing, steps of 0 or 1): a repeated frame's
    pair holds still (its tracks at their frame-i−1 positions at both ends)."""
    order = list(order)
    steps = np.diff(order)
    if order[0] < 0 or order[-1] >= clip.n_frames or not np.isin(steps, (0, 1)).all():
        raise ValueError(f"frame order {order}: steps of 0 or 1 within the clip's {clip.n_frames} frames")
    prev, curr, vis, conf = [], [], [], []
    for frame, step in zip(order[:-1], steps):
        pair = min(frame, clip.n_pairs - 1)
        at_frame = clip.track_prev[pair] if frame < clip.n_pairs else clip.track_curr[pair]
        prev.append(at_frame if step == 0 else clip.track_prev[pair])
        curr.append(at_frame if step == 0 else clip.track_curr[pair])
        vis.append(np.ones_like(clip.track_vis[pair]) if step == 0 else clip.track_vis[pair])
        conf.append(clip.track_conf[pair])
    return dataclasses.replace(
        clip, depth=clip.depth[order], K=clip.K[order], R_wc=clip.R_wc[order], t_wc=clip.t_wc[order],
        static_mask=clip.static_mask[order], track_prev=np.stack(prev), track_curr=np.stack(curr),
        track_vis=np.stack(vis), track_conf=np.stack(conf), frames=None)


def with_band(clip: Clip, frac: float) -> Clip:
    """The clip with its static mask cut to the central ``frac`` of its rows."""
    H = clip.image_size[0]
    rows = max(1, round(frac * H))
    keep = np.zeros(H, bool)
    keep[(H - rows) // 2:(H - rows) // 2 + rows] = True
    return dataclasses.replace(clip, static_mask=clip.static_mask & keep[None, :, None])


def _moved(scene: ProtocolScene, speed: float = 1.0, rotation_only: bool = False) -> ProtocolScene:
    spec = dict(scene.spec, trans_per_frame=0.0 if rotation_only else scene.spec["trans_per_frame"] * speed,
                rot_deg_per_frame=scene.spec["rot_deg_per_frame"] * speed)
    return dataclasses.replace(scene, spec=spec)


def _warped(clip: Clip, scene: ProtocolScene, severity: float = WARP) -> Clip:
    return perturb_clip(clip, "warp", severity, seed=scene.seed)


def few_tracks(scene: ProtocolScene, n_tracks: int) -> Clip:
    return _warped(scene.clip(80), scene)


def low_confidence(scene: ProtocolScene, n_tracks: int) -> Clip:
    clip = _warped(scene.clip(n_tracks), scene)
    rng = np.random.default_rng(scene.seed)
    low = rng.random(clip.track_conf.shape) < 0.92
    return dataclasses.replace(clip, track_conf=np.where(low, LOW_CONFIDENCE, clip.track_conf).astype(np.float32))


def pure_rotation(scene: ProtocolScene, n_tracks: int) -> Clip:
    return perturb_clip(_moved(scene, rotation_only=True).clip(n_tracks), "depth_warp", WARP, seed=scene.seed)


def near_still(scene: ProtocolScene, n_tracks: int) -> Clip:
    return _moved(scene, speed=0.03).clip(n_tracks)


def bursty(scene: ProtocolScene, n_tracks: int) -> Clip:
    clip = scene.clip(n_tracks)
    half = clip.n_frames // 2
    return with_frames(clip, [0] * half + [1] * (clip.n_frames - half))


def thin_band(scene: ProtocolScene, n_tracks: int) -> Clip:
    return with_band(_warped(scene.clip(n_tracks), scene), 0.2)


def masked_out(scene: ProtocolScene, n_tracks: int) -> Clip:
    return with_band(_warped(scene.clip(n_tracks), scene), 0.04)


def unmasked_mover(scene: ProtocolScene, n_tracks: int) -> Clip:
    clip = scene.clip(n_tracks, moving=True)
    return dataclasses.replace(clip, static_mask=np.ones_like(clip.static_mask), mask_source="none")


def repeated_frames(scene: ProtocolScene, n_tracks: int) -> Clip:
    clip = scene.clip(n_tracks)
    return with_frames(clip, [t // 2 for t in range(clip.n_frames)])


def half_broken(scene: ProtocolScene, n_tracks: int) -> Clip:
    clean = scene.clip(n_tracks)
    broken = _warped(clean, scene, severity=1.0)
    half = clean.n_pairs // 2
    pick = lambda a, b: np.concatenate([a[:half], b[half:]])  # noqa: E731
    return dataclasses.replace(clean, track_prev=pick(clean.track_prev, broken.track_prev),
                               track_curr=pick(clean.track_curr, broken.track_curr))


def still_video(scene: ProtocolScene, n_tracks: int) -> Clip:
    clip = scene.clip(n_tracks)
    still = with_frames(clip, [0] * clip.n_frames)
    return dataclasses.replace(still, K=clip.K, R_wc=clip.R_wc, t_wc=clip.t_wc)


def backward_cameras(scene: ProtocolScene, n_tracks: int) -> Clip:
    clip = scene.clip(n_tracks)
    centres = -np.einsum("tji,tj->ti", clip.R_wc, clip.t_wc)  # C = -R^T t
    mirrored = 2.0 * centres[:1] - centres
    return dataclasses.replace(clip, t_wc=-np.einsum("tij,tj->ti", clip.R_wc, mirrored))


def held_cameras(clip: Clip, R_wc: np.ndarray) -> Clip:
    """``clip`` with cameras of rotations R_wc (T, 3, 3) whose centres all lie at WORLD_OFFSET median
    depths from the world's origin, t_wc in the clip's float type."""
    centre = WORLD_OFFSET * float(np.nanmedian(clip.depth))
    return dataclasses.replace(clip, R_wc=R_wc, t_wc=(-np.einsum("tij,j->ti", R_wc, centre)).astype(clip.t_wc.dtype))


def rotation_only_cameras(scene: ProtocolScene, n_tracks: int) -> Clip:
    clip = scene.clip(n_tracks)
    return held_cameras(clip, clip.R_wc)


def static_cameras(scene: ProtocolScene, n_tracks: int) -> Clip:
    clip = scene.clip(n_tracks)
    return held_cameras(clip, np.repeat(clip.R_wc[:1], clip.n_frames, axis=0))


def scene_cut(scene: ProtocolScene, n_tracks: int, tracked: bool = False) -> Clip:
    first = scene.clip(n_tracks)
    second = dataclasses.replace(scene, seed=scene.seed + CUT_SEED_OFFSET).clip(n_tracks)
    jump = CUT_JUMP * float(np.nanmedian(second.depth))
    second = dataclasses.replace(second, t_wc=(second.t_wc - np.einsum("tij,j->ti", second.R_wc, jump)).astype(
        second.t_wc.dtype))  # its world moved by ``jump``: centres C + jump
    cut = first.n_frames // 2  # frames 0..cut-1 of the first world, then the second's
    frames = lambda a, b: np.concatenate([a[:cut], b[cut:]])  # noqa: E731
    pairs = lambda a, b: np.concatenate([a[:cut - 1], b[cut - 1:]])  # noqa: E731  (pair cut-1 crosses it)
    prev, vis = pairs(first.track_prev, second.track_prev), pairs(first.track_vis, second.track_vis)
    prev[cut - 1] = first.track_prev[cut - 1]  # the first world's points, followed into the second world's frame
    vis[cut - 1] = first.track_vis[cut - 1] & second.track_vis[cut - 1] if tracked else False
    return dataclasses.replace(
        first, depth=frames(first.depth, second.depth), K=frames(first.K, second.K),
        R_wc=frames(first.R_wc, second.R_wc), t_wc=frames(first.t_wc, second.t_wc),
        static_mask=frames(first.static_mask, second.static_mask), track_prev=prev,
        track_curr=pairs(first.track_curr, second.track_curr), track_vis=vis,
        track_conf=pairs(first.track_conf, second.track_conf))


ADVERSARIES: dict[str, Callable[[ProtocolScene, int], Clip]] = {
    "few_tracks": few_tracks, "low_confidence": low_confidence, "pure_rotation": pure_rotation,
    "near_still": near_still, "bursty": bursty, "thin_band": thin_band, "masked_out": masked_out,
    "unmasked_mover": unmasked_mover, "repeated_frames": repeated_frames, "half_broken": half_broken,
    "still_video": still_video, "backward_cameras": backward_cameras,
    "rotation_only_cameras": rotation_only_cameras, "static_cameras": static_cameras, "scene_cut": scene_cut,
    "scene_cut_tracked": lambda scene, n_tracks: scene_cut(scene, n_tracks, tracked=True),
}


def adversary(name: str, scene: ProtocolScene, n_tracks: int = 1000) -> Clip:
    """The named adversary (:data:`ADVERSARIES`) built from ``scene``, its id ``<scene>-<name>``."""
    if name not in ADVERSARIES:
        raise ValueError(f"unknown adversary {name!r}; one of {sorted(ADVERSARIES)}")
    return dataclasses.replace(ADVERSARIES[name](scene, n_tracks), clip_id=f"{scene.name}-{name}")
