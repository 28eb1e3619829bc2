"""The depth error with and without the pair's depth scale (issue 58; docs/semantics.md §3.6 step
7): how much of it a depth estimator's per-frame scale makes, and what the inconsistencies keep.

    python bench/depth_scale.py [--pool fit] [--first 0] [--scenes 24] [--tracks 1000]
    python bench/depth_scale.py --real ../shared/realdata

Each pair's depth check as docs/semantics.md §3.6 defines it (the reference engine's warp, hole rule
and comparison mask) under the exact relative pose of the clip's cameras, giving the warped depth ẑ
and frame i's depth d at each compared pixel. Per clip, the mean over its pairs of:
- ``depth %``: the mean of |ẑ − d| / d, the depth error without the pair's scale (the score's until
  2026-12-02);
- ``scaled %``: the same after the pair's scale, |α ẑ − d| / d with α = the median of d / ẑ over all
  the compared pixels (the score takes it on a sub-grid, step 7);
- ``scale %``: the RMS over the pairs of log α, in % (a per-frame depth scale's size).
Variants of each scene of a random pool (``protocol.random_scene``; FIT's pool by default, on which
a constant may be chosen): ``clean``; the protocol's depth noise (``+depth``: a 1 % smooth field,
edges blended 1 px wide) and edges blended 3 px wide (``+edges3``); each frame's depth times its own
factor, 1 % and 2 % RMS (``+scale``, ``research.noise.NoiseModel.depth_scale_rel``, nothing else);
``depth_warp`` at 0.1, 0.25 and 0.5; the scene's mover unmasked (``mover``). ``--real DIR`` runs
every clip of DIR as it is (its own cameras). Prints one row per clip, then per variant the median
and the largest over the scenes.
"""

from __future__ import annotations

import dataclasses
from collections import defaultdict

import numpy as np
from depth_blobs import pool_parser, print_real_rows, print_variant_summary

from sgc_jax import SGCConfig
from sgc_jax.engines import reference
from sgc_jax.research import protocol
from sgc_jax.research.noise import NOISE_MODELS, add_noise
from sgc_jax.research.perturb import perturb_clip

HEADER = ("depth %", "scaled %", "scale %")


def depth_statistics(clip, config: SGCConfig) -> list[float]:
    """[depth %, scaled %, scale %] of the clip, under its cameras' relative poses (scale 1)."""
    plain, scaled, log_scales = [], [], []
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
    return [100 * np.mean(plain), 100 * np.mean(scaled), 100 * np.sqrt(np.mean(np.square(log_scales)))]


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
    clips.update({f"depth_warp {s}": perturb_clip(clean, "depth_warp", s, seed=scene.seed) for s in (0.1, 0.25, 0.5)})
    clips["mover"] = dataclasses.replace(masked, static_mask=np.ones_like(masked.static_mask), mask_source="none")
    return clips


def main() -> None:
    args = pool_parser(__doc__.splitlines()[0]).parse_args()
    config = SGCConfig()
    print("| clip | variant | " + " | ".join(HEADER) + " |\n|---|---|" + "---|" * len(HEADER))
    if args.real:
        print_real_rows(args.real, lambda clip: depth_statistics(clip, config))
        return
    table = defaultdict(list)
    for k in range(args.first, args.first + args.scenes):
        scene = protocol.random_scene(k, pool=args.pool)
        for name, clip in variants(scene, args.tracks).items():
            values = depth_statistics(clip, config)
            table[name].append(values)
            print(f"| {scene.name} | {name} | " + " | ".join(f"{v:.3f}" for v in values) + " |", flush=True)
    print_variant_summary(table, HEADER)


if __name__ == "__main__":
    main()
