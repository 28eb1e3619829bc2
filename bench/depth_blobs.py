"""Where the depth check could see an unmasked mover the poses cannot (issues 58 and 59, a lead; not
part of the score): compact blobs of large depth disagreement, against the mean the score takes.

    python bench/depth_blobs.py [--pool fit] [--first 0] [--scenes 24] [--tracks 1000] [--rel 0.1] [--erode 1 2]
    python bench/depth_blobs.py --real ../shared/realdata

Each pair's depth check as docs/semantics.md §3.6 defines it (the reference engine's warp, hole
rule and comparison mask) under the exact relative pose of the clip's cameras (scale 1, or
``--scale`` for a translation scale that errs), giving a relative error |ẑ − d| / d per compared
pixel. Per clip, the mean over its pairs of:

- ``depth %``: the mean of it, the score's depth error;
- ``large %``: the share of compared pixels whose error exceeds ``--rel``;
- ``blob % (r)``: the share of them left after an erosion by a square of radius r px: a
  disagreement at least 2r + 1 px across in both directions, which a depth edge's band of smeared
  or flying pixels narrower than that is not.

Variants of each scene of a random pool (``protocol.random_scene``; FIT's pool by default, on which
a constant may be chosen): ``clean``, the same scene with one moving sphere masked (``masked``, the
mover's consistent twin) and unmasked (``mover``; *hidden* when fewer usable tracks per pair than
``min_region_points`` lie on it, ``protocol.tracks_on_mover``), each consistent one under the
protocol's depth noise (``+depth``: 1 % smooth, edges blended 1 px wide) and with edges blended
3 px wide (``+edges3``), and ``depth_warp`` at 0.1 and 0.25. ``--real DIR`` runs every clip of
DIR as it is (its own cameras). Prints one row per clip and, per variant, the median and the
largest over the scenes, and how often each mover's statistic exceeds the largest of every
consistent variant's.
"""

from __future__ import annotations

import argparse
import dataclasses
import glob
import os
from collections import defaultdict

import cv2
import numpy as np

from sgc_jax import SGCConfig
from sgc_jax.engines import reference
from sgc_jax.io.loading import load_clip
from sgc_jax.research import protocol
from sgc_jax.research.noise import NOISE_MODELS, add_noise
from sgc_jax.research.perturb import perturb_clip

CONSISTENT = ("clean", "masked", "clean+depth", "masked+depth", "clean+edges3")


def relative_errors(clip, scale: float, config: SGCConfig):
    """Per pair: (relative error (H, W), compared (H, W) bool) under the cameras' relative pose."""
    out = []
    for i in range(1, clip.n_frames):
        R = clip.R_wc[i] @ clip.R_wc[i - 1].T
        t = scale * (clip.t_wc[i] - R @ clip.t_wc[i - 1])
        warped, _ = reference.pair_depth_error(clip, i, R, t, config)
        depth = clip.depth[i]
        static = clip.static_mask[i] if config.use_mos else np.ones(clip.image_size, bool)
        compared = (warped > 0) & reference.valid_depth(depth) & static
        out.append((np.where(compared, np.abs(warped - depth) / np.where(compared, depth, 1.0), 0.0), compared))
    return out


def blob_statistics(clip, rel: float, erode: tuple[int, ...], scale: float, config: SGCConfig) -> list[float]:
    """[depth %, large %, blob % for each erosion radius], each the mean over the clip's pairs."""
    per_pair = []
    for error, compared in relative_errors(clip, scale, config):
        n = max(int(compared.sum()), 1)
        large = ((error > rel) & compared).astype(np.uint8)
        row = [100 * error[compared].mean() if compared.any() else np.nan, 100 * large.sum() / n]
        row += [100 * (cv2.erode(large, np.ones((2 * r + 1,) * 2, np.uint8)) > 0).sum() / n for r in erode]
        per_pair.append(row)
    return list(np.nanmean(np.array(per_pair), axis=0))


def variants(scene, n_tracks: int, config: SGCConfig) -> tuple[dict, bool, float]:
    """The scene's clips by variant name, whether its mover is hidden, and the mover's share of the image [%]."""
    masked = scene.clip(n_tracks, moving=True)
    hidden = protocol.tracks_on_mover(masked, config.min_track_conf) < config.min_region_points
    area = 100 * float((~masked.static_mask).mean())
    mover = dataclasses.replace(masked, static_mask=np.ones_like(masked.static_mask), mask_source="none")
    clean = scene.clip(n_tracks)
    depth_noise = NOISE_MODELS["depth"].replace(px=0.0)
    clips = {"clean": clean, "masked": masked, "mover": mover,
             "clean+depth": add_noise(clean, depth_noise, scene.seed),
             "masked+depth": add_noise(masked, depth_noise, scene.seed),
             "mover+depth": add_noise(mover, depth_noise, scene.seed),
             "clean+edges3": add_noise(clean, depth_noise.replace(depth_edge_px=3), scene.seed),
             "depth_warp 0.1": perturb_clip(clean, "depth_warp", 0.1, seed=scene.seed),
             "depth_warp 0.25": perturb_clip(clean, "depth_warp", 0.25, seed=scene.seed)}
    return clips, hidden, area


def pool_parser(description: str) -> argparse.ArgumentParser:
    """The options of a depth study over a random pool's scenes, or over a directory of clips (--real)."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--pool", default="fit", choices=sorted(protocol.RANDOM_POOLS))
    parser.add_argument("--first", type=int, default=0)
    parser.add_argument("--scenes", type=int, default=24)
    parser.add_argument("--tracks", type=int, default=1000)
    parser.add_argument("--real", help="a directory of clips to run as they are instead of the pool")
    return parser


def print_real_rows(directory: str, statistics, label: str = "as recorded") -> None:
    """One row per clip of ``directory``: ``statistics(clip)``, a list of figures, under ``label``."""
    for path in sorted(glob.glob(os.path.join(directory, "*.npz"))):
        clip = load_clip(path)
        print(f"| {clip.clip_id} | {label} | " + " | ".join(f"{v:.3f}" for v in statistics(clip)) + " |",
              flush=True)


def print_variant_summary(table: dict, header) -> None:
    """Per variant of ``table`` (name -> rows of figures, one row per scene) the median and the
    largest of each figure over its scenes."""
    print("\n| variant | clips | " + " | ".join(f"{h}: median (largest)" for h in header) + " |\n|---|---|"
          + "---|" * len(header))
    for name, rows in table.items():
        a = np.array(rows)
        print(f"| {name} | {len(rows)} | " + " | ".join(f"{np.median(a[:, j]):.3f} ({a[:, j].max():.3f})"
                                                       for j in range(a.shape[1])) + " |")


def main() -> None:
    parser = pool_parser(__doc__.splitlines()[0])
    parser.add_argument("--rel", type=float, default=0.1, help="relative depth error that counts as large")
    parser.add_argument("--erode", type=int, nargs="+", default=[1, 2], help="erosion radii [px]")
    parser.add_argument("--scale", type=float, default=1.0, help="translation scale of the warp (1: exact)")
    args = parser.parse_args()
    config = SGCConfig()
    header = ["depth %", "large %"] + [f"blob % ({r})" for r in args.erode]
    print("| clip | variant | " + " | ".join(header) + " |\n|---|---|" + "---|" * len(header))
    if args.real:
        print_real_rows(args.real, lambda clip: blob_statistics(clip, args.rel, tuple(args.erode), args.scale, config))
        return
    table = defaultdict(list)
    for k in range(args.first, args.first + args.scenes):
        scene = protocol.random_scene(k, pool=args.pool)
        clips, hidden, area = variants(scene, args.tracks, config)
        for name, clip in clips.items():
            if name.startswith("mover"):
                name = f"{name} ({'hidden' if hidden else 'seen'})"
            values = blob_statistics(clip, args.rel, tuple(args.erode), args.scale, config)
            table[name].append(values)
            print(f"| {scene.name} (mover {area:.2f} % of the image) | {name} | "
                  + " | ".join(f"{v:.3f}" for v in values) + " |", flush=True)
    print_variant_summary(table, header)
    consistent_max = np.max([np.array(table[name]).max(axis=0) for name in CONSISTENT if name in table], axis=0)
    print("\nMovers above the largest value of any consistent variant (" + ", ".join(
        f"{h} {v:.3f}" for h, v in zip(header, consistent_max)) + "):")
    for name in [n for n in table if n.startswith("mover")]:
        a = np.array(table[name])
        print(f"- {name}: " + ", ".join(f"{h} {int((a[:, j] > consistent_max[j]).sum())} of {len(a)}"
                                        for j, h in enumerate(header)))


if __name__ == "__main__":
    main()
