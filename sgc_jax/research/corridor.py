"""A corridor, a scene family written apart from :mod:`research.synth` (docs/semantics.md §7.4,
"A corridor"): a camera walking down a corridor or a street, every surface but the end wall seen
obliquely, depth running continuously from the camera's feet to the far end.

A scene is two side walls, a floor, a ceiling (none under ``sky``: sky above the walls, depth 0
there, its tracks points at infinity), an end wall and four boxes on the floor; the nearest box
walks across when ``moving``. Every array is ray-cast or projected exactly, with this module's own
ray caster, camera path and track sampler: nothing is shared with the synthesis every split and
pool comes from. Conventions are those of :mod:`sgc_jax.io.clip`: world->camera poses, OpenCV axes
(y down), depth = z along the optical axis in world units, pixel centres at integer coordinates;
the world frame is camera 0's. NumPy (and OpenCV for masks) only; every draw comes from the seed.
"""

from __future__ import annotations

import dataclasses
import itertools

import cv2
import numpy as np

from ..io.arrays import clip_from_arrays
from ..io.clip import Clip

CORRIDOR_SEEDS = range(9100, 9200)  # scene k's seed; no split or pool of research.protocol draws from these
MOVER_SPEED = 0.08  # units a frame, across the corridor
MASK_MARGIN_PX = 2  # the mover's mask reaches this far past it, as a motion segmenter's does
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


def family(sky: bool) -> str:
    """The scenes' name: "street" under ``sky``, else "corridor"."""
    return "street" if sky else "corridor"


def _rotation(axis, deg: float) -> np.ndarray:
    """(3, 3): a turn of ``deg`` degrees about the unit ``axis``."""
    return cv2.Rodrigues(np.deg2rad(deg) * np.asarray(axis, np.float64))[0]


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

    def clip(self, masked: bool, clip_id: str, with_frames: bool = False) -> Clip:
        """The exact clip (sgc_jax.Clip): depth, cameras, tracks per pair, and RGB frames when
        ``with_frames``; ``masked``: the mover's pixels (and a margin) out of the static mask."""
        spec, H, W = self.spec, self.spec.height, self.spec.width
        grid = np.stack(np.meshgrid(np.arange(W), np.arange(H)), -1).reshape(-1, 2).astype(float)
        cast = [self.cast(t, grid) for t in range(spec.n_frames)]
        depth, mover = zip(*[(d.reshape(H, W), m.reshape(H, W)) for d, _, m in cast])
        frames = np.stack([np.repeat(self.frame(t, w, d, m).reshape(H, W, 1), 3, axis=2)
                           for t, (d, w, m) in enumerate(cast)]) if with_frames else None
        kernel = np.ones((2 * MASK_MARGIN_PX + 1,) * 2, np.uint8)
        dynamic = np.stack([cv2.dilate(m.astype(np.uint8), kernel) > 0 for m in mover])
        rng = np.random.default_rng((self.seed, spec.n_tracks))
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
