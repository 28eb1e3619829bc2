"""The depth check's look back into frame i−1 (docs/semantics.md §3.6 step 5) at other ratios, on
FIT's random pool: how many pairs need it, and how much of depth_warp's signal it keeps.

    python bench/look_back.py [--scenes 24] [--ratios 1 2 3 5 10 20]

For each of FIT's random scenes (``research.protocol.random_scene``, 1,000 tracks), four clips:
consistent, ``depth_warp`` at 0.25, and each under the ``depth`` noise model at 0.5 px (the unseen
pool's noise draw for that cell). Every pair is warped with the exact relative pose by the reference
engine, and each pixel's error taken as the step does at ratio k: where the warp puts a surface more
than k times farther than frame i sees and frame i−1 has depth where frame i's point lands, the lesser
of the two readings. Prints, per k, the pairs that need the read and the share of depth_warp's rise
of the clip's depth error that is kept (median and least over the scenes), with exact and noisy
depth. The shipped ratio is ``LOOK_BACK_RATIO`` (10).
"""

from __future__ import annotations

import argparse

import numpy as np
from unseen_scenes import CELLS, EXTRA_LEVELS_PX, noise_seed

from sgc_jax.config import SGCConfig
from sgc_jax.engines import reference
from sgc_jax.io.clip import relative_poses
from sgc_jax.research.noise import NOISE_MODELS, add_noise
from sgc_jax.research.perturb import perturb_clip
from sgc_jax.research.protocol import random_scene

NOISE_PX = 0.5


def pair_readings(clip, pair: int, R, t, config: SGCConfig):
    """One pair's compared pixels -> (forward error, the read from frame i−1 (inf where none), the
    warped depth over frame i's), each (n,), relative."""
    source = reference.warp_source(clip, pair, config)
    warped = reference.warp_depth(source, clip.K[pair - 1], clip.K[pair], R, t, mask_holes=True)
    seen, z, iu, iv = reference.previous_view(clip.depth[pair], clip.K[pair - 1], clip.K[pair], R, t)
    depth = clip.depth[pair]
    both = seen & (warped > 0) & reference.valid_depth(depth) & clip.static_mask[pair]
    before = np.where(reference.valid_depth(source), source, 0.0)[iv, iu]
    back = np.where(before > 0, np.abs(before - z) / np.where(seen, z, 1.0), np.inf)
    return np.abs(warped - depth)[both] / depth[both], back[both], warped[both] / depth[both]


def clip_errors(clip, ratios, config: SGCConfig) -> tuple[np.ndarray, np.ndarray]:
    """-> (the clip's depth error [%] without the step and at each ratio (1 + len(ratios),), pairs
    that need the read at each ratio (len(ratios),))."""
    R, t = relative_poses(clip)
    errors, needed = [], []
    for pair in range(1, clip.n_frames):
        forward, back, ratio = pair_readings(clip, pair, R[pair - 1], t[pair - 1], config)
        errors.append([forward.mean()] + [np.where(ratio > k, np.minimum(forward, back), forward).mean()
                                          for k in ratios])
        needed.append([np.any(ratio > k) for k in ratios])
    return 100.0 * np.nanmean(errors, axis=0), np.sum(needed, axis=0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenes", type=int, default=24)
    parser.add_argument("--ratios", type=float, nargs="+", default=[1.0, 2.0, 3.0, 5.0, 10.0, 20.0])
    args = parser.parse_args()
    config = SGCConfig()
    # the draw of `unseen_scenes.py --models correlated depth outliers` for the depth model at NOISE_PX
    cell = len(CELLS) + len(EXTRA_LEVELS_PX) + EXTRA_LEVELS_PX.index(NOISE_PX)
    model = NOISE_MODELS["depth"].replace(px=NOISE_PX)
    errors, pairs, needed = [], 0, np.zeros(len(args.ratios), int)
    for k in range(args.scenes):
        scene = random_scene(k, (60.0,), "fit")
        clean = scene.clip(1000)
        warped = perturb_clip(clean, "depth_warp", 0.25, seed=scene.seed)
        seed = noise_seed(scene.seed, cell, len(CELLS))
        rows = [clip_errors(c, args.ratios, config) for c in
                (clean, warped, add_noise(clean, model, seed=seed), add_noise(warped, model, seed=seed))]
        errors.append([e for e, _ in rows])
        needed += sum(n for _, n in rows)
        pairs += 4 * (clean.n_frames - 1)
        print(f"fit-pool-{k}: done", flush=True)
    errors = np.array(errors)  # (scene, clip, 1 + ratio)
    print(f"\nFIT's random pool, scenes 0-{args.scenes - 1}: the look back at ratio k (exact cameras)\n")
    print("| k | pairs needing the read | depth_warp 0.25's signal kept, exact depth: median / least "
          "| under the depth model at 0.5 px |")
    print("|---|---|---|---|")
    for j, k in enumerate(args.ratios, start=1):
        kept = [(errors[:, b, j] - errors[:, a, j]) / (errors[:, b, 0] - errors[:, a, 0]) for a, b in ((0, 1), (2, 3))]
        print(f"| {k:g} | {needed[j - 1]} of {pairs} | " + " | ".join(f"{np.median(x):.2f} / {np.min(x):.2f}" for x in kept)
              + " |")


if __name__ == "__main__":
    main()
