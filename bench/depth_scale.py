"""The depth error with and without the pair's depth scale, and up to an affine map per pair (issue
58; docs/semantics.md §3.6 step 7): how much of it a depth estimator's per-frame scale and offset
make, and what the inconsistencies keep.

    python bench/depth_scale.py [--pool fit] [--first 0] [--scenes 24] [--tracks 1000]
    python bench/depth_scale.py --real ../shared/realdata

Each pair's depth check as docs/semantics.md §3.6 defines it (the reference engine's warp, hole rule
and comparison mask) under the exact relative pose of the clip's cameras, giving the warped depth ẑ
and frame i's depth d at each compared pixel. Per clip, the mean over its pairs of:
- ``depth %``: the mean of |ẑ − d| / d, the depth error without the pair's scale (the score's until
  2026-12-02);
- ``scaled %``: the same after the pair's scale, |α ẑ − d| / d with α = the median of d / ẑ over all
  the compared pixels (the score takes it on a sub-grid, step 7);
- ``scale %``: the RMS over the pairs of log α, in % (a per-frame depth scale's size);
- ``affine %``: the same up to an affine map, |α ẑ + β − d| / d with (α, β) the least absolute
  relative error over the compared pixels (``engines.reference.affine_depth_map`` from α; the
  score takes it only where it fits far better than the scale, on a sub-grid, step 7).
Variants of each scene of a random pool (``protocol.random_scene``; FIT's pool by default, on which
a constant may be chosen): ``clean``; the protocol's depth noise (``+depth``: a 1 % smooth field,
edges blended 1 px wide) and edges blended 3 px wide (``+edges3``); each frame's depth times its own
factor, 1 % and 2 % RMS (``+scale``, ``research.noise.NoiseModel.depth_scale_rel``, nothing else);
plus its own offset, 1 % and 3 % RMS of the median depth (``+offset``, ``NoiseModel.depth_offset_rel``);
``depth_warp`` at 0.1, 0.25 and 0.5; the scene's mover unmasked (``mover``); depth_warp at 0.25 and
the mover with offsets of 3 %; the nearest fifth of the depth 10 % farther from the middle frame on
(``near 10 % farther``). ``--real DIR`` runs every clip of DIR as recorded (its own cameras)
and with offsets of 1 % and 3 %. Prints one row per clip, then per variant the median and the
largest over the scenes, and how many of its scenes read above the clean clip (scaled, affine).
"""

from __future__ import annotations

import dataclasses
from collections import defaultdict

import numpy as np
from depth_blobs import pool_parser, print_real_rows, print_variant_summary

from sgc_jax import SGCConfig
from sgc_jax.engines import reference
from sgc_jax.research import protocol
from sgc_jax.research.noise import NOISE_MODELS, NoiseModel, add_noise
from sgc_jax.research.perturb import perturb_clip

HEADER = ("depth %", "scaled %", "scale %", "affine %")
OFFSETS_REL = (0.01, 0.03)


def depth_statistics(clip, config: SGCConfig) -> list[float]:
    """[depth %, scaled %, scale %, affine %] of the clip, under its cameras' relative poses (scale 1)."""
    plain, scaled, log_scales, affine = [], [], [], []
    for i in range(1, clip.n_frames):
        R = clip.R_wc[i] @ clip.R_wc[i - 1].T
        t = clip.t_wc[i] - R @ clip.t_wc[i - 1]
        warped, _ = reference.pair_depth_error(clip, i, R, t, config)
        depth = clip.depth[i]
        static = clip.static_mask[i] if config.use_mos else np.ones(clip.image_size, bool)
        compared = (warped > 0) & reference.valid_depth(depth) & static
        if not compared.any():
            continue
        z, d = warped[compared].astype(np.float64), depth[compared].astype(np.float64)
        alpha = np.median(d / z)
        plain.append(np.mean(np.abs(z - d) / d))
        scaled.append(np.mean(np.abs(alpha * z - d) / d))
        log_scales.append(np.log(alpha))
        a, b = reference.affine_depth_map(z, d, np.array([alpha, 0.0]))
        affine.append(np.mean(np.abs(a * z + b - d) / d))
    return [100 * np.mean(plain), 100 * np.mean(scaled), 100 * np.sqrt(np.mean(np.square(log_scales))),
            100 * np.mean(affine)]


def with_offsets(clip, rms_rel: float, seed: int):
    """The clip with each frame's depth plus its own offset, ``rms_rel`` x its median depth RMS."""
    return add_noise(clip, NoiseModel(depth_offset_rel=rms_rel), seed)


def variants(scene, n_tracks: int) -> dict:
    """The scene's clips by variant name."""
    masked = scene.clip(n_tracks, moving=True)
    clean = scene.clip(n_tracks)
    depth_noise = NOISE_MODELS["depth"].replace(px=0.0)
    scale_only = depth_noise.replace(depth_rel=0.0, depth_edge_px=0)
    clips = {"clean": clean,
             "clean+depth": add_noise(clean, depth_noise, scene.seed),
             "clean+edges3": add_noise(clean, depth_noise.replace(depth_edge_px=3), scene.seed),
             "clean+scale 1 %": add_noise(clean, scale_only.replace(depth_scale_rel=0.01), scene.seed),
             "clean+scale 2 %": add_noise(clean, scale_only.replace(depth_scale_rel=0.02), scene.seed)}
    clips.update({f"clean+offset {100 * r:.0f} %": with_offsets(clean, r, scene.seed) for r in OFFSETS_REL})
    clips.update({f"depth_warp {s}": perturb_clip(clean, "depth_warp", s, seed=scene.seed) for s in (0.1, 0.25, 0.5)})
    clips["mover"] = dataclasses.replace(masked, static_mask=np.ones_like(masked.static_mask), mask_source="none")
    clips["depth_warp 0.25+offset 3 %"] = with_offsets(clips["depth_warp 0.25"], OFFSETS_REL[-1], scene.seed)
    clips["mover+offset 3 %"] = with_offsets(clips["mover"], OFFSETS_REL[-1], scene.seed)
    clips["near 10 % farther"] = near_part_farther(clean)
    return clips


def near_part_farther(clip, factor: float = 1.1):
    """The clip with its nearest fifth (depth below the clip's 20th percentile) ``factor`` times
    farther from the middle frame on: part of the world at another depth in half the frames, which a
    map of the whole frame's depth could take for an estimator's shift where few depths make the scene."""
    valid = np.isfinite(clip.depth) & (clip.depth > 0)
    near = valid & (clip.depth < np.percentile(clip.depth[valid], 20))
    near[: clip.n_frames // 2] = False
    return dataclasses.replace(clip, depth=np.where(near, factor * clip.depth, clip.depth).astype(np.float32))


def print_above_clean(table: dict) -> None:
    """Per variant, the scenes whose depth error reads above the clean clip's, scaled and affine."""
    clean = np.array(table["clean"])
    print("\n| variant | above clean, scaled | above clean, affine |\n|---|---|---|")
    for name, rows in table.items():
        a = np.array(rows)
        print(f"| {name} | {np.sum(a[:, 1] > clean[:, 1])} of {len(a)} | {np.sum(a[:, 3] > clean[:, 3])} of {len(a)} |")


def main() -> None:
    args = pool_parser(__doc__.splitlines()[0]).parse_args()
    config = SGCConfig()
    print("| clip | variant | " + " | ".join(HEADER) + " |\n|---|---|" + "---|" * len(HEADER))
    if args.real:
        print_real_rows(args.real, lambda clip: depth_statistics(clip, config))
        for r in OFFSETS_REL:
            print_real_rows(args.real, lambda clip: depth_statistics(with_offsets(clip, r, 0), config),
                            f"offset {100 * r:.0f} %")
        return
    table = defaultdict(list)
    for k in range(args.first, args.first + args.scenes):
        scene = protocol.random_scene(k, pool=args.pool)
        for name, clip in variants(scene, args.tracks).items():
            values = depth_statistics(clip, config)
            table[name].append(values)
            print(f"| {scene.name} | {name} | " + " | ".join(f"{v:.3f}" for v in values) + " |", flush=True)
    print_variant_summary(table, HEADER)
    print_above_clean(table)


if __name__ == "__main__":
    main()
