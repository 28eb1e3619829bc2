"""The camera translation's resolution bound (docs/semantics.md §3.4, `CAMERA_TRANSLATION_RESOLUTION`):
how large float32's rounding makes a held centre's t_g, which pairs the bound holds, and what a
world whose origin lies far from its cameras does to the six real clips.

    python bench/camera_resolution.py [--split fit|test]   # ratios, and the pairs the bound holds
    python bench/camera_resolution.py --origins [--engine jax|reference]   # the real clips, origin moved

The ratio of a pair is |t_g| / (|t_wc[i]| + |t_wc[i-1]|) as the JAX engine forms t_g: the cameras
cast to float32, R_g the nearest rotation of R_wc[i] R_wc[i-1]^T, before the bound. Held centres:
the split's scenes with every camera centre at WORLD_OFFSET (x 1, 10, 100) median depths from the
origin, rotations as given or all the first's, and `repeated_frames`' repeated pairs; on FIT also
the six real clips' cameras with every centre the first's, the origin as given and 10, 100, 1,000
units further. Then every pair of the split's scenes (consistent, masked mover) and battery
adversaries: how many the bound holds and how many lie between it and the old 2^-16.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import jax
import numpy as np

from sgc_jax import load_clip, score_batch
from sgc_jax.config import CAMERA_TRANSLATION_RESOLUTION
from sgc_jax.kernels.so3 import nearest_rotation
from sgc_jax.research import protocol
from sgc_jax.research.adversaries import ADVERSARIES, WORLD_OFFSET, adversary

REALDATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "realdata"
OLD_BOUND = 2.0**-16  # the bound before rule B4
ORIGIN_DIRECTION = np.array([1.0, -2.0, 0.7]) / np.linalg.norm([1.0, -2.0, 0.7])
ORIGIN_SHIFTS = (0.0, 10.0, 100.0, 1000.0)  # units of t_wc (metres on the real clips)


@jax.jit
@jax.vmap
def _unresolved_translation(R_prev, t_prev, R_curr, t_curr):
    return t_curr - nearest_rotation(R_curr @ R_prev.T) @ t_prev


def pair_ratios(clip) -> np.ndarray:
    """(T-1,) |t_g| / (|t_wc[i]| + |t_wc[i-1]|) in the JAX engine's float32; 0 where both are 0."""
    R, t = np.asarray(clip.R_wc, np.float32), np.asarray(clip.t_wc, np.float32)
    t_g = np.linalg.norm(np.asarray(_unresolved_translation(R[:-1], t[:-1], R[1:], t[1:]), np.float64), axis=1)
    size = np.linalg.norm(t[1:].astype(np.float64), axis=1) + np.linalg.norm(t[:-1].astype(np.float64), axis=1)
    return np.where(size > 0, t_g / np.where(size > 0, size, 1.0), np.where(t_g > 0, np.inf, 0.0))


def with_centres(clip, R_wc: np.ndarray, centre: np.ndarray):
    """``clip`` with rotations R_wc (T, 3, 3) and every camera centre at ``centre`` (3,)."""
    return dataclasses.replace(clip, R_wc=R_wc, t_wc=-np.einsum("tij,j->ti", R_wc, centre))


def shifted_origin(clip, shift: float):
    """``clip`` in a world whose origin lies ``shift`` units further along ORIGIN_DIRECTION."""
    return dataclasses.replace(clip, clip_id=f"{clip.clip_id}@{shift:g}",
                               t_wc=clip.t_wc + np.einsum("tij,j->ti", clip.R_wc, shift * ORIGIN_DIRECTION))


def held_centre_ratios(split: str) -> np.ndarray:
    ratios = []
    for scene in protocol.SPLITS[split]:
        clip = scene.clip(1000)
        depth = float(np.nanmedian(clip.depth))
        turning, still = clip.R_wc, np.repeat(clip.R_wc[:1], clip.n_frames, axis=0)
        for factor in (1, 10, 100):
            ratios += [pair_ratios(with_centres(clip, R, factor * WORLD_OFFSET * depth)) for R in (turning, still)]
        repeated = adversary("repeated_frames", scene, 1000)
        same = (np.all(repeated.t_wc[1:] == repeated.t_wc[:-1], axis=1)
                & np.all(repeated.R_wc[1:] == repeated.R_wc[:-1], axis=(1, 2)))
        ratios.append(pair_ratios(repeated)[same])
    if split == "fit":
        for path in sorted(REALDATA.glob("*.npz")):
            clip = load_clip(str(path))
            first_centre = -clip.R_wc[0].T @ clip.t_wc[0]
            for shift in ORIGIN_SHIFTS:
                for R in (clip.R_wc, np.repeat(clip.R_wc[:1], clip.n_frames, axis=0)):
                    ratios.append(pair_ratios(with_centres(clip, R, first_centre + shift * ORIGIN_DIRECTION)))
    return np.concatenate(ratios)


def print_ratios(split: str) -> None:
    held = held_centre_ratios(split)
    suggested = min(2.0 ** np.ceil(np.log2(8 * held.max())), OLD_BOUND)
    print(f"## {split}: held centres\n\n| pairs | exactly 0 | median | 99th percentile | largest | 8x the largest, "
          f"as a power of two | shipped bound |\n|---|---|---|---|---|---|---|")
    print(f"| {held.size} | {(held == 0).sum()} | {np.median(held):.2e} | {np.percentile(held, 99):.2e} | "
          f"{held.max():.2e} | 2^{np.log2(suggested):.0f} | 2^{np.log2(CAMERA_TRANSLATION_RESOLUTION):.0f} |")
    counts = dict(pairs=0, old=0, shipped=0, between=0)
    least_moving = np.inf
    for scene in protocol.SPLITS[split]:
        clips = [scene.clip(1000), scene.clip(1000, moving=True)] + [adversary(n, scene, 1000) for n in ADVERSARIES]
        for r in map(pair_ratios, clips):
            counts["pairs"] += r.size
            counts["old"] += int((r <= OLD_BOUND).sum())
            counts["shipped"] += int((r <= CAMERA_TRANSLATION_RESOLUTION).sum())
            counts["between"] += int(((r > CAMERA_TRANSLATION_RESOLUTION) & (r <= OLD_BOUND)).sum())
            least_moving = min(least_moving, float(np.min(r[r > OLD_BOUND], initial=np.inf)))
    print(f"\n## {split}: the scenes' and the battery's pairs\n\n| pairs | held by 2^-16 | held by the shipped "
          f"bound | between the two | smallest ratio 2^-16 does not hold |\n|---|---|---|---|---|")
    print(f"| {counts['pairs']} | {counts['old']} | {counts['shipped']} | {counts['between']} | {least_moving:.2e} |")


def print_origins(engine: str) -> None:
    clips = [load_clip(str(p)) for p in sorted(REALDATA.glob("*.npz"))]
    variants = [shifted_origin(clip, shift) for clip in clips for shift in ORIGIN_SHIFTS]
    scored = score_batch(variants, engine=engine, progress=False).clips
    header = " | ".join(f"origin +{s:g}" for s in ORIGIN_SHIFTS)
    print(f"## the six real clips, {engine} engine: SGC / depth error [%] / pairs held\n\n| clip | {header} |\n"
          f"|---|{'---|' * len(ORIGIN_SHIFTS)}")
    for i, clip in enumerate(clips):
        cells = []
        for j, variant in enumerate(variants[i * len(ORIGIN_SHIFTS):(i + 1) * len(ORIGIN_SHIFTS)]):
            c = scored[i * len(ORIGIN_SHIFTS) + j]
            held = int((pair_ratios(variant) <= CAMERA_TRANSLATION_RESOLUTION).sum())
            cells.append(f"{c.sgc:.4f} / {c.components['depth_error']:.4f} / {held}")
        print(f"| {clip.clip_id} | {' | '.join(cells)} |")


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--split", choices=sorted(protocol.SPLITS), default="fit")
    parser.add_argument("--origins", action="store_true", help="score the six real clips with their origin moved")
    parser.add_argument("--engine", choices=("jax", "reference"), default="jax")
    args = parser.parse_args(argv)
    if args.origins:
        print_origins(args.engine)
    else:
        print_ratios(args.split)


if __name__ == "__main__":
    main(sys.argv[1:])
