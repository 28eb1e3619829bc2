"""Depth maps smaller than the clip grid (a depth network's output, a sensor's lower resolution): what
bringing them to the grid by nearest neighbour or bilinearly within valid depth does to the score
(rule U1 in bench/history/issue-58.md "Depth maps smaller than the clip grid"; docs/semantics.md
§1.5, "Depth maps of another size").

    python bench/depth_resize.py --pool fit|held-out [--scenes 24]
    python bench/depth_resize.py --real [--realdata ../shared/realdata]
    python bench/depth_resize.py --line --pool fit|held-out [--scenes 24] [--real]

Each clip's depth is point-sampled (nearest at pixel centres) on a grid FACTORS times smaller, then
brought back to the clip grid by each of ``METHODS``: ``nearest`` (``adapters.common.resize_nearest``,
the importer's resize before 2026-12-07) and ``bilinear`` (``adapters.common.resize_depth``); or
the clip is brought down to the depth's grid (``DEPTH_GRID``: masks by nearest, tracks and K at
pixel centres).
``--pool``: each scene of a random pool (``protocol.random_scene``, 1,000 tracks) under ``iid-both``
at 0.5 and 2 px, consistent and with each perturbation at 0.25 (perturbed before its depth is
resampled); per method, factor and level, the consistent clips above 0.10, their median SGC, and
the cells where each perturbation scores above its consistent twin (the same resampling and noise);
the depth as it is beside them.
``--real``: the shared real clips as given and so resampled, SGC and depth error. ``--line``: where
the loader's `depth_in_blocks` line fires instead (``io.checks.depth.check_depth_blocks``), on the
pool's clips under ``protocol.check_pool_clips``' noise models and on the real clips, as given and
with their depth brought up from LINE_FACTORS smaller by nearest neighbour, and from 2x bilinearly.
Nothing is chosen here.
"""

from __future__ import annotations

import collections
import dataclasses
from pathlib import Path

import numpy as np
from pools import need_one, pool_parser

from sgc_jax import load_clip, score_batch
from sgc_jax.adapters.common import map_intrinsics, resize_depth, resize_factors, resize_nearest, resize_points
from sgc_jax.io.checks.depth import check_depth_blocks
from sgc_jax.research import protocol
from sgc_jax.research.noise import NOISE_MODELS, add_noise
from sgc_jax.research.perturb import PERTURBATIONS, perturb_clip

FACTORS = (2.0, 2.5, 4.0)
METHODS = {"nearest": resize_nearest, "bilinear": resize_depth}
LEVELS_PX = (0.5, 2.0)
SEVERITY = 0.25
ABOVE = 0.10  # a consistent clip above this counts (the bar)
DEPTH_GRID = "the depth's grid"  # the whole clip brought down to the depth's grid instead
GRID = [(1.0, "as it is")] + [(factor, method) for method in (*METHODS, DEPTH_GRID) for factor in FACTORS]


def on_depth_grid(clip, small: np.ndarray):
    """``clip`` brought down to the grid of its depth ``small`` (T, h, w): masks by nearest, tracks and K at
    pixel centres (``adapters.common``)."""
    H, W = clip.image_size
    hw = small.shape[1:]
    K = map_intrinsics(clip.K, *resize_factors((H, W), hw)).astype(clip.K.dtype)
    return dataclasses.replace(clip, depth=small.astype(np.float32), K=K, frames=None,
                               static_mask=resize_nearest(clip.static_mask, hw),
                               track_prev=resize_points(clip.track_prev, (H, W), hw),
                               track_curr=resize_points(clip.track_curr, (H, W), hw))


def resampled(clip, factor: float, method: str):
    """``clip`` with its depth point-sampled on a grid ``factor`` times smaller and brought back by ``method``,
    or the clip brought down to that grid (``DEPTH_GRID``); factor 1: as it is."""
    if factor == 1:
        return clip
    H, W = clip.image_size
    small = resize_nearest(clip.depth, (int(round(H / factor)), int(round(W / factor))))
    if method == DEPTH_GRID:
        return on_depth_grid(clip, small)
    return dataclasses.replace(clip, depth=METHODS[method](small, (H, W)).astype(np.float32))


def pool_counts(pool: str, scenes: int) -> None:
    counts, sgc = collections.Counter(), collections.defaultdict(list)
    for k in range(scenes):
        scene = protocol.random_scene(k, pool=pool)
        clean = scene.clip(1000)
        kinds = {"consistent": clean} | {kind: perturb_clip(clean, kind, SEVERITY, seed=scene.seed) for kind in PERTURBATIONS}
        batch, keys = [], []
        for px in LEVELS_PX:
            noisy = {kind: add_noise(clip, NOISE_MODELS["iid-both"].replace(px=px), seed=scene.seed * 100 + int(2 * px))
                     for kind, clip in kinds.items()}
            for factor, method in GRID:
                for kind, clip in noisy.items():
                    batch.append(resampled(clip, factor, method))
                    keys.append((method, factor, px, kind))
        scores = dict(zip(keys, (c.sgc for c in score_batch(batch, progress=False).clips)))
        for factor, method in GRID:
            for px in LEVELS_PX:
                twin = scores[method, factor, px, "consistent"]
                sgc[method, factor, px].append(twin)
                counts[method, factor, px, "above"] += twin > ABOVE
                for kind in PERTURBATIONS:
                    counts[method, factor, px, kind] += scores[method, factor, px, kind] > twin
        print(f"{scene.name} done", flush=True)
    print(f"\n{pool} pool, {scenes} scenes, 1,000 tracks, iid-both; perturbations at {SEVERITY}")
    print(f"| method | factor | px | consistent above {ABOVE} | median consistent SGC | "
          + " | ".join(f"{kind} above its twin" for kind in PERTURBATIONS) + " |")
    print("|---|---|---|---|---|" + "---|" * len(PERTURBATIONS))
    for factor, method in GRID:
        for px in LEVELS_PX:
            print(f"| {method} | {factor:g} | {px:g} | {counts[method, factor, px, 'above']} of {scenes} | "
                  f"{np.median(sgc[method, factor, px]):.3f} | "
                  + " | ".join(f"{counts[method, factor, px, kind]}" for kind in PERTURBATIONS) + " |")


LINE_FACTORS = (1.25, 1.5, 2.0, 2.5, 4.0)
LINE_WAYS = [(1.0, "as it is")] + [(factor, "nearest") for factor in LINE_FACTORS] + [(2.0, "bilinear")]


def line_counts(clips, label: str) -> None:
    counts = collections.Counter()
    for clip in clips:
        for factor, method in LINE_WAYS:
            counts[factor, method] += bool(check_depth_blocks(resampled(clip, factor, method)))
    print(f"`depth_in_blocks` on {label}: " + ", ".join(
        f"{method}{'' if factor == 1 else f' {factor:g}'} {counts[factor, method]} of {len(clips)}"
        for factor, method in LINE_WAYS))


def real_clips(realdata: Path) -> None:
    paths = sorted(realdata.glob("*.npz"))
    clips = [load_clip(path) for path in paths]
    batch, keys = [], []
    for clip in clips:
        batch.append(clip)
        keys.append((clip.clip_id, "as given"))
        for factor in FACTORS:
            for method in METHODS:
                batch.append(resampled(clip, factor, method))
                keys.append((clip.clip_id, f"{method} {factor:g}"))
    result = score_batch(batch, progress=False)
    columns = ["as given"] + [f"{method} {factor:g}" for factor in FACTORS for method in METHODS]
    rows = collections.defaultdict(dict)
    for (clip_id, column), c in zip(keys, result.clips):
        rows[clip_id][column] = f"{c.sgc:.3f} ({c.components['depth_error']:.2f} %)" + (
            "" if c.status == "ok" else f" {c.status}")
    print("SGC (depth error) of the real clips, the depth point-sampled on a grid FACTOR times smaller and brought back")
    print("| clip | " + " | ".join(columns) + " |\n|---|" + "---|" * len(columns))
    for clip_id, row in rows.items():
        print(f"| {clip_id} | " + " | ".join(row[column] for column in columns) + " |")


def main() -> None:
    parser = pool_parser(__doc__)
    parser.add_argument("--line", action="store_true", help="where the loader's depth_in_blocks line fires")
    args = parser.parse_args()
    if args.line:
        if args.pool:
            line_counts([clip for _, clip in protocol.check_pool_clips(args.pool, args.scenes)], f"the {args.pool} pool")
        if args.real:
            line_counts([load_clip(path) for path in sorted(args.realdata.glob("*.npz"))], "the real clips")
    else:
        if args.pool:
            pool_counts(args.pool, args.scenes)
        if args.real:
            real_clips(args.realdata)
    need_one(parser, args)


if __name__ == "__main__":
    main()
