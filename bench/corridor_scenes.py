"""A scene family written apart from research.synth, for reports only: a camera walking down a
corridor (docs/semantics.md §7.4, "A corridor").

    python bench/corridor_scenes.py [--scenes 6] [--tracks 200 1000 4096] [--levels 0.5 2]
                                    [--models iid-curr iid-both correlated depth outliers]
                                    [--perturb 0.25] [--config '{"partition": "grid"}']
                                    [--out rows.csv] [--rows rows.csv] [--ladders] [--street]
                                    [--tracked 6]

Every layout of the protocol's splits and pools (research.synth) stands in front of the camera:
a back wall, rectangles at set depths, spheres, at most a ground. Here every surface but the end
wall is seen obliquely, so depth runs continuously from the camera's feet to the end of the
corridor: two side walls, a floor and a ceiling (the corridor 3-5 units wide, 2.4-3.2 high and
15-30 long), the end wall, and four boxes standing on the floor along the walls. The camera walks
0.25 units a frame down the corridor (about 3 % of the median depth), swaying sideways and turning
1° a frame. Depth is ray-cast at pixel centres, tracks are drawn uniformly over frame i−1 and
projected through the exact geometry into frame i (visible where frame i's depth does not hide
them), as the clip format defines (docs/semantics.md §1.1); NumPy only, every draw from the scene's
seed (``CORRIDOR_SEEDS``, which no split or pool uses). Nothing is chosen on these scenes.

Noise: the protocol's models (research.noise, named as there) at each ``--levels`` px, one draw a
cell, the perturbed clips given their consistent twin's draw (paired, as bench/validation.py).
Inconsistencies: the paper's three perturbations at ``--perturb`` (made on the exact clip), and an
unmasked mover (the nearest box walks across the corridor at 0.08 units a frame) against its
masked twin. Prints, per noise model and track count, the consistent clips' median at each level
and its rise, the largest and how many lie above 0.10, the statuses; the share of cells where each
inconsistency scores above its twin; and, on the exact clips, the depth error and its part that
the depth check's rounding to the nearest pixel makes on oblique surfaces (§3.6 step 2): the mean
relative error of frame i−1's warped points against frame i's depth at the nearest pixel, and
against frame i's inverse depth interpolated bilinearly at the point's own position, over points
whose four neighbours lie on one surface. ``--config``: SGCConfig fields (JSON) to score with.
``--ladders``: also each scene's perturbation ladders (severities 0.1, 0.25, 0.5, 1; 1,000 tracks,
iid-both 1 px, paired): how many rise strictly in SGC and fall strictly in reward (issue 59's bar).
``--street``: the same scenes as streets: no ceiling, the walls and the end wall ending at the same
height, sky above them (depth 0, invalid; its tracks points at infinity, moved by the camera's
rotation alone, as a tracker follows clouds). ``--tracked STRIDE``: every surface is painted with
value noise (``TEXTURE_OCTAVES``) into RGB frames, and each scene's clean clip, warp and depth_warp
at 0.25 and 0.5 and the mover with its masked twin are retracked on their own frames by pyramidal
LK from a grid of STRIDE px (bench/track_density.py): a real tracker's errors on a known world.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
from pathlib import Path

import numpy as np

CORRIDOR_SEEDS = range(9100, 9200)
MOVER_SPEED = 0.08  # units a frame, across the corridor
MASK_MARGIN_PX = 2  # the mover's mask reaches this far past it, as a motion segmenter's does
LADDER_SEVERITIES = (0.1, 0.25, 0.5, 1.0)
TEXTURE_OCTAVES = ((2.4, 90.0), (0.6, 80.0), (0.15, 60.0), (0.04, 40.0))  # value noise: cell [units], grey levels


@dataclasses.dataclass(frozen=True)
class CorridorSpec:
    """One corridor clip: frames, image size [px], tracks per pair, the walk [units a frame, deg]."""

    n_frames: int = 8
    height: int = 144
    width: int = 192
    n_tracks: int = 1000
    speed: float = 0.25
    yaw_deg: float = 1.0
    fov_deg: float = 65.0
    sky: bool = False  # a street: no ceiling, sky above the walls (depth 0, its tracks at infinity)


def _family(sky: bool) -> str:
    return "street" if sky else "corridor"


def _rotation(axis, deg: float) -> np.ndarray:
    x, y, z = axis
    cross = np.array([[0, -z, y], [z, 0, -x], [-y, x, 0]], float)
    a = np.deg2rad(deg)
    return np.eye(3) + np.sin(a) * cross + (1 - np.cos(a)) * cross @ cross


def value_noise(points: np.ndarray, cell: float, seed: int) -> np.ndarray:
    """Smooth random texture at world points (N, 3): values in [0, 1) on a lattice of ``cell`` units,
    interpolated trilinearly (smoothstep weights)."""
    scaled = points / cell
    base = np.floor(scaled).astype(np.int64)
    frac = scaled - base
    weight = frac * frac * (3 - 2 * frac)
    total = np.zeros(len(points))
    for corner in itertools.product((0, 1), repeat=3):
        lattice = base + np.array(corner)
        key = (lattice[:, 0] * 73856093) ^ (lattice[:, 1] * 19349663) ^ (lattice[:, 2] * 83492791) ^ seed
        value = (np.abs(key * 2654435761) % 1000003) / 1000003.0
        share = np.prod(np.where(np.array(corner) == 1, weight, 1 - weight), axis=1)
        total += share * value
    return total


class Corridor:
    """The world of scene ``seed`` (camera 0's frame, OpenCV axes: y down); ``moving``: its nearest
    box walks across the corridor."""

    def __init__(self, seed: int, spec: CorridorSpec, moving: bool):
        rng = np.random.default_rng(seed)
        self.half_w, self.half_h, self.end_z = rng.uniform(1.5, 2.5), rng.uniform(1.2, 1.6), rng.uniform(15, 30)
        self.boxes = []
        for _ in range(4):
            size = rng.uniform(0.3, 0.8, 3)
            x = rng.choice([-1, 1]) * (self.half_w - size[0] / 2 - rng.uniform(0, 0.3))
            centre = np.array([x, self.half_h - size[1] / 2, rng.uniform(3, self.end_z - 2)])
            self.boxes.append((centre - size / 2, centre + size / 2))
        nearest = int(np.argmin([lo[2] for lo, _ in self.boxes]))
        self.boxes.insert(0, self.boxes.pop(nearest))
        lo, hi = self.boxes[0]
        direction = -np.sign(lo[0] + hi[0])  # from its wall across the corridor
        self.velocity = np.array([direction * MOVER_SPEED, 0.0, 0.0]) if moving else np.zeros(3)
        self.spec = spec
        f = 0.5 * spec.width / np.tan(np.deg2rad(spec.fov_deg) / 2)
        self.K = np.array([[f, 0, (spec.width - 1) / 2], [0, f, (spec.height - 1) / 2], [0, 0, 1.0]])
        start = np.array([rng.uniform(-0.4, 0.4), rng.uniform(-0.3, 0.3), 0.0])
        turn = spec.yaw_deg * rng.choice([-1, 1])
        frames = np.arange(spec.n_frames)
        self.centres = start + np.stack([0.05 * np.sin(0.6 * frames), 0.02 * np.sin(0.9 * frames),
                                         spec.speed * frames], 1)
        self.R_wc = np.stack([(_rotation((0, 1, 0), turn * t) @ _rotation((1, 0, 0), 0.4 * np.sin(0.5 * t))).T
                              for t in frames])
        self.t_wc = -np.einsum("tij,tj->ti", self.R_wc, self.centres)
        self.seed = seed

    def _boxes_at(self, t: int):
        return [(lo + self.velocity * t, hi + self.velocity * t) if j == 0 else (lo, hi)
                for j, (lo, hi) in enumerate(self.boxes)]

    def cast(self, t: int, xy: np.ndarray):
        """Pixels (N, 2) of frame t -> (depth (N,), the world points (N, 3), on the mover (N,) bool)."""
        pixels = np.concatenate([xy, np.ones((len(xy), 1))], 1) @ np.linalg.inv(self.K).T
        rays = pixels @ self.R_wc[t]  # world directions, camera z = 1
        origin = self.centres[t]
        hit = np.full(len(xy), np.inf)
        on_mover = np.zeros(len(xy), bool)
        planes = ((0, -self.half_w), (0, self.half_w), (1, self.half_h), (2, self.end_z))
        planes += () if self.spec.sky else ((1, -self.half_h),)
        with np.errstate(divide="ignore", invalid="ignore"):
            for axis, value in planes:
                along = (value - origin[axis]) / rays[:, axis]
                below_top = origin[1] + along * rays[:, 1] >= -self.half_h  # a street's walls end at the roofs
                hit = np.minimum(hit, np.where((along > 1e-6) & (below_top | (axis == 1)), along, np.inf))
            for j, (lo, hi) in enumerate(self._boxes_at(t)):
                near, far = (lo - origin) / rays, (hi - origin) / rays
                enter = np.nanmax(np.minimum(near, far), axis=1)
                leave = np.nanmin(np.maximum(near, far), axis=1)
                closer = (leave >= enter) & (enter > 1e-6) & (enter < hit)
                hit = np.where(closer, enter, hit)
                on_mover = np.where(closer, j == 0, on_mover)
        on_mover &= self.velocity.any()
        sky = ~np.isfinite(hit)  # a direction, not a point
        world = np.where(sky[:, None], rays, origin + np.where(sky, 0.0, hit)[:, None] * rays)
        return np.where(sky, 0.0, hit * pixels[:, 2]), world, on_mover

    def frame(self, t: int, world: np.ndarray, depth: np.ndarray, on_mover: np.ndarray) -> np.ndarray:
        """Frame t's grey values (H W,) at its pixels' world points (H W, 3): two octaves of value noise
        painted on every surface (the mover's on its own body), each faded out where its cells shrink
        below 4 px along the surface (from 2 px, none: a renderer's mipmaps, against aliasing), a flat
        sky; uint8."""
        H, W = self.spec.height, self.spec.width
        on_grid = np.where((depth > 0)[:, None], world, 0.0).reshape(H, W, 3)
        step = [np.linalg.norm(np.gradient(on_grid, axis=a), axis=-1) for a in (0, 1)]
        footprint = np.maximum(*step).reshape(-1)  # units a pixel, along the surface
        body = world - on_mover[:, None] * self.velocity * t
        grey = np.full(len(depth), 120.0)
        for offset, (cell, amplitude) in enumerate(TEXTURE_OCTAVES):
            fade = np.clip((cell / np.maximum(footprint, 1e-9) - 2.0) / 2.0, 0.0, 1.0)
            grey += fade * amplitude * (value_noise(body, cell, self.seed + offset) - 0.5)
        return np.where(depth > 0, grey, 200.0).clip(0, 255).astype(np.uint8)

    def clip(self, seed: int, masked: bool, clip_id: str, with_frames: bool = False):
        """The exact clip (sgc_jax.Clip): depth, cameras, tracks per pair, and RGB frames when
        ``with_frames``; ``masked``: the mover's pixels (and a margin) out of the static mask."""
        import cv2

        from sgc_jax import clip_from_arrays

        spec, H, W = self.spec, self.spec.height, self.spec.width
        grid = np.stack(np.meshgrid(np.arange(W), np.arange(H)), -1).reshape(-1, 2).astype(float)
        cast = [self.cast(t, grid) for t in range(spec.n_frames)]
        depth, mover = zip(*[(d.reshape(H, W), m.reshape(H, W)) for d, _, m in cast])
        frames = np.stack([np.repeat(self.frame(t, w, d, m).reshape(H, W, 1), 3, axis=2)
                           for t, (d, w, m) in enumerate(cast)]) if with_frames else None
        kernel = np.ones((2 * MASK_MARGIN_PX + 1,) * 2, np.uint8)
        dynamic = np.stack([cv2.dilate(m.astype(np.uint8), kernel) > 0 for m in mover])
        rng = np.random.default_rng((seed, spec.n_tracks))
        prev, curr, visible = [], [], []
        for i in range(1, spec.n_frames):
            xy = rng.uniform([0, 0], [W - 1, H - 1], size=(spec.n_tracks, 2))
            depth_prev, world, on_mover = self.cast(i - 1, xy)
            world = world + on_mover[:, None] * self.velocity
            sky = depth_prev == 0  # seen at infinity: the camera's rotation alone moves it
            camera = world @ self.R_wc[i].T + np.where(sky[:, None], 0.0, self.t_wc[i])
            z = np.where(camera[:, 2] > 1e-6, camera[:, 2], np.nan)
            landing = (camera @ self.K.T)[:, :2] / z[:, None]
            inside = np.isfinite(landing).all(1) & (landing >= 0).all(1) & (landing <= [W - 1, H - 1]).all(1)
            seen_depth, _, _ = self.cast(i, np.clip(np.nan_to_num(landing), 0, [W - 1, H - 1]))
            prev.append(xy)
            curr.append(np.where(inside[:, None], landing, -1.0))
            visible.append(inside & np.where(sky, seen_depth == 0, z <= seen_depth * 1.01))
        arrays = dict(depth=np.stack(depth).astype(np.float32), K=self.K.astype(np.float32),
                      R_wc=self.R_wc.astype(np.float32), t_wc=self.t_wc.astype(np.float32),
                      static_mask=~dynamic if masked else np.ones_like(dynamic),
                      track_prev=np.stack(prev).astype(np.float32), track_curr=np.stack(curr).astype(np.float32),
                      track_vis=np.stack(visible), **({} if frames is None else {"frames": frames}))
        return clip_from_arrays(arrays, clip_id=clip_id)


def rounding_part(clip) -> tuple[float, float]:
    """Under the exact cameras, every valid pixel of frame i−1 warped into frame i: the mean relative
    error [%] against frame i's depth at the nearest pixel (§3.6 step 2) and against its inverse
    depth interpolated bilinearly at the point's own position, over points whose four neighbours lie
    within 5 % of one another and whose nearest pixel within 5 % of the point (one surface)."""
    depth, K = clip.depth.astype(float), np.broadcast_to(clip.K, (clip.n_frames, 3, 3)).astype(float)
    R, t = clip.R_wc.astype(float), clip.t_wc.astype(float)
    H, W = clip.image_size
    rows, cols = np.mgrid[0:H, 0:W]
    nearest, interpolated = [], []
    for i in range(1, clip.n_frames):
        valid = depth[i - 1] > 0
        pixels = np.stack([cols[valid], rows[valid], np.ones(valid.sum())])
        world = R[i - 1].T @ (np.linalg.inv(K[i - 1]) @ pixels * depth[i - 1][valid] - t[i - 1][:, None])
        camera = R[i] @ world + t[i][:, None]
        z = camera[2]
        u, v = (K[i] @ camera)[:2] / np.where(z > 1e-5, z, np.nan)
        keep = (z > 1e-5) & (u >= 0) & (u <= W - 1) & (v >= 0) & (v <= H - 1)
        u, v, z = u[keep], v[keep], z[keep]
        at_nearest = depth[i][np.floor(v + 0.5).astype(int), np.floor(u + 0.5).astype(int)]
        u0, v0 = np.minimum(np.floor(u).astype(int), W - 2), np.minimum(np.floor(v).astype(int), H - 2)
        fu, fv = u - u0, v - v0
        four = np.stack([depth[i][v0, u0], depth[i][v0, u0 + 1], depth[i][v0 + 1, u0], depth[i][v0 + 1, u0 + 1]])
        with np.errstate(divide="ignore", invalid="ignore"):
            inverse = ((1 - fu) * (1 - fv) / four[0] + fu * (1 - fv) / four[1] + (1 - fu) * fv / four[2]
                       + fu * fv / four[3])
            surface = (four.min(0) > 0) & (four.max(0) < 1.05 * four.min(0)) & (np.abs(at_nearest / z - 1) < 0.05)
        nearest.append(np.abs(z - at_nearest)[surface] / at_nearest[surface])
        interpolated.append(np.abs(z * inverse - 1)[surface])
    return 100 * float(np.concatenate(nearest).mean()), 100 * float(np.concatenate(interpolated).mean())


def score_rows(args) -> list[dict]:
    """One row per clip: scene, tracks, noise cell, kind ("" consistent, a perturbation, "mover",
    "mover-masked"), severity, the score's outputs and the tracks on the mover."""
    from sgc_jax import score_batch
    from sgc_jax.research.noise import NOISE_MODELS, add_noise
    from sgc_jax.research.perturb import PERTURBATIONS, perturb_clip

    cells = list(itertools.product(args.models, args.levels))
    rows, clips = [], []
    for k, n_tracks in itertools.product(range(args.scenes), args.tracks):
        seed, spec = CORRIDOR_SEEDS[k], CorridorSpec(n_tracks=n_tracks, sky=args.street)
        still, moving = Corridor(seed, spec, moving=False), Corridor(seed, spec, moving=True)
        name = f"{_family(args.street)}-{k}"
        clean = still.clip(seed, masked=False, clip_id=f"{name}-{n_tracks}")
        exact = [(clean, "", 0.0)] + [(perturb_clip(clean, kind, args.perturb, seed=seed), kind, args.perturb)
                                      for kind in PERTURBATIONS]
        exact += [(moving.clip(seed, masked=True, clip_id=f"{name}-{n_tracks}-masked"), "mover-masked", 0.0),
                  (moving.clip(seed, masked=False, clip_id=f"{name}-{n_tracks}-mover"), "mover", 1.0)]
        on_mover = _tracks_on_mover(exact[-2][0])
        for c, (model, px) in enumerate(cells):
            noise = NOISE_MODELS[model].replace(px=px)
            for clip, kind, severity in exact:
                clips.append(add_noise(clip, noise, seed * 100 + c))
                rows.append(dict(scene=name, tracks=n_tracks, model=model, noise_px=px, kind=kind, severity=severity,
                                 tracks_on_mover=on_mover, cell=f"{name}/{n_tracks}/{model}/{px}"))
    result = score_batch(clips, config=args.score_config)
    rewards = result.rewards()["reward"]
    for row, clip, reward in zip(rows, result.clips, rewards):
        row.update(sgc=clip.sgc, status=clip.status, evidence=clip.evidence, depth_error=clip.components["depth_error"],
                   reward=float(reward))
    return rows


def _tracks_on_mover(masked) -> float:
    """Mean over pairs of the usable tracks whose frame-i−1 position lies on the mover (its mask less
    the margin)."""
    import cv2

    kernel = np.ones((2 * MASK_MARGIN_PX + 1,) * 2, np.uint8)
    on = np.stack([cv2.erode((~static).astype(np.uint8), kernel) > 0 for static in masked.static_mask[:-1]])
    H, W = masked.image_size
    column, row = (np.clip(np.rint(masked.track_prev[..., a]).astype(int), 0, size - 1) for a, size in ((0, W), (1, H)))
    hit = on[np.arange(len(on))[:, None], row, column] & masked.usable_tracks(0.0)
    return float(hit.sum(axis=1).mean())


def print_tables(rows: list[dict]) -> None:
    import pandas as pd

    from sgc_jax.research.protocol import detection_table

    frame = pd.DataFrame(rows)
    consistent = frame[frame.kind == ""]
    levels = sorted(consistent.noise_px.unique())
    print("consistent clips: median SGC by level, the rise from the first to the last, the largest, above 0.10")
    print("| model | tracks | " + " | ".join(f"{px} px" for px in levels) + " | rise | largest | above 0.10 | statuses |")
    print("|---|---|" + "---|" * (len(levels) + 4))
    for (model, tracks), cell in consistent.groupby(["model", "tracks"], sort=False):
        medians = [cell[cell.noise_px == px].sgc.median() for px in levels]
        statuses = ", ".join(f"{s} {n}" for s, n in cell.status.value_counts().items())
        print(f"| {model} | {tracks} | " + " | ".join(f"{m:.3f}" for m in medians)
              + f" | {medians[-1] - medians[0]:+.3f} | {cell.sgc.max():.3f} | {(cell.sgc > 0.10).sum()} of {len(cell)}"
              f" | {statuses} |")
    print("\nshare of cells where each inconsistency scores above its consistent twin")
    for model, of_model in frame.groupby("model", sort=False):
        shares = detection_table(of_model.to_dict("records"))
        print(f"{model}: " + ", ".join(f"{kind} {severity:g} {share:.0%}" for (kind, severity), share in shares.items()))
    movers = frame[frame.kind == "mover"].groupby("scene").tracks_on_mover.median()
    print("\ntracks on the mover per pair, by scene (median over track counts):",
          ", ".join(f"{scene} {n:.0f}" for scene, n in movers.items()))
    rewards = frame.groupby("kind").reward.median()
    print("median reward by kind:", ", ".join(f"{kind or 'consistent'} {r:.3f}" for kind, r in rewards.items()))


def print_ladders(scenes: int, config, sky: bool) -> None:
    from sgc_jax import score_batch
    from sgc_jax.research.noise import NOISE_MODELS, add_noise
    from sgc_jax.research.perturb import PERTURBATIONS, perturb_clip

    noise = NOISE_MODELS["iid-both"].replace(px=1.0)
    ladders, clips = [], []
    for k in range(scenes):
        seed = CORRIDOR_SEEDS[k]
        clean = Corridor(seed, CorridorSpec(sky=sky), moving=False).clip(seed, False, f"{_family(sky)}-{k}")
        for kind in PERTURBATIONS:
            ladders.append((f"{_family(sky)}-{k}", kind))
            clips += [add_noise(clean, noise, seed)] + [add_noise(perturb_clip(clean, kind, s, seed=seed), noise, seed)
                                                        for s in LADDER_SEVERITIES]
    result = score_batch(clips, config=config)
    sgc = np.array([c.sgc for c in result.clips]).reshape(len(ladders), -1)
    reward = result.rewards()["reward"].reshape(len(ladders), -1)
    print("\nladders (iid-both 1 px, 1,000 tracks): SGC (reward) at severity 0, " + ", ".join(map(str, LADDER_SEVERITIES)))
    for (scene, kind), scores, rewards in zip(ladders, sgc, reward):
        print(f"{scene} {kind}: " + ", ".join(f"{a:.3f} ({b:.3f})" for a, b in zip(scores, rewards)))
    rising, falling = (np.diff(sgc) > 0).all(1).sum(), (np.diff(reward) < 0).all(1).sum()
    print(f"{rising} of {len(ladders)} ladders rise strictly in SGC; {falling} of {len(ladders)} fall strictly in reward")
    for (scene, kind), scores in zip(ladders, sgc):
        if not (np.diff(scores) > 0).all():
            steps = [f"{a:g} -> {b:g}" for a, b, d in zip((0,) + LADDER_SEVERITIES, LADDER_SEVERITIES, np.diff(scores))
                     if d <= 0]
            print(f"  {scene} {kind} does not rise at {', '.join(steps)} (by {np.diff(scores).min():+.1e})")


def print_tracked(scenes: int, config, sky: bool, stride: int) -> None:
    """Each scene's clean clip, warp and depth_warp at 0.25 and 0.5 (their frames remapped with
    them) and the mover with its masked twin, every one retracked on its own frames by pyramidal
    LK from a grid of ``stride`` px (bench/track_density.py: 21 px windows, the forward-backward
    check under 0.5 px): a real tracker's errors on a known world, in place of a noise model."""
    import sys

    import pandas as pd

    from sgc_jax import score_batch
    from sgc_jax.research.ground_truth import motion_errors
    from sgc_jax.research.perturb import perturb_clip
    from sgc_jax.research.protocol import detection_table

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from track_density import grid_tracks

    rows, clips = [], []
    for k in range(scenes):
        seed, name = CORRIDOR_SEEDS[k], f"{_family(sky)}-{k}"
        still, moving = (Corridor(seed, CorridorSpec(sky=sky), moving=m) for m in (False, True))
        clean = still.clip(seed, False, name, with_frames=True)
        variants = [(clean, "", 0.0)] + [(perturb_clip(clean, kind, s, seed=seed), kind, s)
                                         for kind in ("warp", "depth_warp") for s in (0.25, 0.5)]
        variants += [(moving.clip(seed, True, f"{name}-masked", with_frames=True), "mover-masked", 0.0),
                     (moving.clip(seed, False, f"{name}-mover", with_frames=True), "mover", 1.0)]
        for clip, kind, severity in variants:
            clips.append(grid_tracks(clip, stride))
            rows.append(dict(cell=name, kind=kind, severity=severity))
    result = score_batch(clips, config=config)
    rewards = result.rewards()["reward"]
    for row, clip, scored, reward in zip(rows, clips, result.clips, rewards):
        row.update(sgc=scored.sgc, reward=float(reward), status=scored.status,
                   gt_p95=np.percentile(motion_errors(clip), 95) if row["kind"] == "" else np.nan)
    frame = pd.DataFrame(rows)
    frame["variant"] = frame.kind.where(frame.kind != "", "consistent") + frame.severity.map(lambda s: f" {s:g}")
    print(f"\nretracked by LK from a {stride} px grid: SGC (reward)")
    table = frame.pivot(index="cell", columns="variant", values="sgc").round(3)
    print(table.assign(gt_p95_px=frame.groupby("cell").gt_p95.max().round(2)).to_string())
    print("rewards:\n" + frame.pivot(index="cell", columns="variant", values="reward").round(3).to_string())
    print("statuses:", dict(frame.status.value_counts()))
    print("above the consistent twin: " + ", ".join(f"{kind} {severity:g} {share:.0%}" for (kind, severity), share
                                                    in detection_table(frame.to_dict("records")).items()))


def print_rounding(scenes: int, config, sky: bool) -> None:
    print("\nexact clips (1,000 tracks): the depth error as scored, and frame i−1's warp against frame i's depth "
          "at the nearest pixel / interpolated at the point [%]")
    from sgc_jax import score_batch

    for size in ((144, 192), (72, 96)):
        spec = CorridorSpec(height=size[0], width=size[1], sky=sky)
        clips = [Corridor(CORRIDOR_SEEDS[k], spec, moving=False).clip(CORRIDOR_SEEDS[k], False, f"{_family(sky)}-{k}")
                 for k in range(scenes)]
        scored = score_batch(clips, config=config).clips
        for clip, result in zip(clips, scored):
            nearest, interpolated = rounding_part(clip)
            print(f"{clip.clip_id} {size[1]}x{size[0]}: depth error {result.components['depth_error']:.3f} (SGC {result.sgc:.3f}); "
                  f"nearest {nearest:.3f}, interpolated {interpolated:.4f}")


def main() -> None:
    from sgc_jax import SGCConfig
    from sgc_jax.research.noise import NOISE_MODELS
    from sgc_jax.research.protocol import rows_scored_or_read

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=6)
    parser.add_argument("--tracks", type=int, nargs="+", default=[200, 1000, 4096])
    parser.add_argument("--levels", type=float, nargs="+", default=[0.5, 2.0], help="noise levels [px]")
    parser.add_argument("--models", nargs="+", default=list(NOISE_MODELS), choices=sorted(NOISE_MODELS))
    parser.add_argument("--perturb", type=float, default=0.25, help="the perturbations' severity")
    parser.add_argument("--config", default="{}", help="SGCConfig fields as JSON, e.g. a partition")
    parser.add_argument("--out", type=Path, help="write one row per clip (CSV)")
    parser.add_argument("--rows", type=Path, help="print the tables from this CSV (an earlier --out) instead of scoring")
    parser.add_argument("--ladders", action="store_true", help="also each scene's perturbation ladders")
    parser.add_argument("--street", action="store_true", help="a street: no ceiling, sky above the walls")
    parser.add_argument("--tracked", type=int, default=0, metavar="STRIDE",
                        help="also the clips retracked by LK on their own frames from a grid of STRIDE px")
    args = parser.parse_args()
    args.score_config = SGCConfig(**json.loads(args.config))
    rows = rows_scored_or_read(args.rows, args.out, lambda: score_rows(args),
                               text=("scene", "model", "kind", "status", "cell"), integers=("tracks",))
    print_tables(rows)
    if not args.rows:
        print_rounding(args.scenes, args.score_config, args.street)
    if args.ladders:
        print_ladders(args.scenes, args.score_config, args.street)
    if args.tracked:
        print_tracked(args.scenes, args.score_config, args.street, args.tracked)


if __name__ == "__main__":
    main()
