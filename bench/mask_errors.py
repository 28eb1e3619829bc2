"""A motion mask's errors on consistent scenes with a masked moving object (issue 58): what a
segmenter (SegAnyMo) that falls short of a mover's outline, or reaches past it, does to the score.

    python bench/mask_errors.py [--pool unseen|fit|held-out] [--scenes 24] [--noise 1]

Each scene of a random pool (``protocol.random_scene``; the unseen pool by default, report only)
with one moving sphere masked (``scene.clip(1000, moving=True)``: consistent), its mask corrupted
by ``sgc_jax.research.perturb``'s mask corruptions (docs/semantics.md §6.4: ``erode`` /
``dilate`` of the dynamic mask by severity x 0.05 of the image diagonal, ``false_negative`` /
``false_positive`` flips of severity x 0.5 of the moving / static pixels), an under-segmented
mask grown back (``erode`` then ``dilate``), and no mask at all (the unmasked mover); then iid-both
track noise of ``--noise`` px. Prints per variant the median SGC, the clips above 0.10 and the
median reward. Nothing is chosen here.
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np
import pandas as pd

from sgc_jax import score_batch
from sgc_jax.research import protocol
from sgc_jax.research.noise import NOISE_MODELS, add_noise
from sgc_jax.research.perturb import perturb_clip

VARIANTS = (  # (name, [(corruption, severity), ...] applied in order)
    ("masked", []),
    ("erode 0.25", [("erode", 0.25)]), ("erode 0.5", [("erode", 0.5)]), ("erode 1", [("erode", 1.0)]),
    ("dilate 0.5", [("dilate", 0.5)]), ("dilate 1", [("dilate", 1.0)]),
    ("false_negative 0.1", [("false_negative", 0.1)]), ("false_negative 0.25", [("false_negative", 0.25)]),
    ("false_negative 0.5", [("false_negative", 0.5)]), ("false_positive 0.5", [("false_positive", 0.5)]),
    ("erode 0.5, dilate 0.5", [("erode", 0.5), ("dilate", 0.5)]),
    ("erode 0.5, dilate 1", [("erode", 0.5), ("dilate", 1.0)]),
    ("false_negative 0.25, dilate 0.25", [("false_negative", 0.25), ("dilate", 0.25)]),
)


def variants(scene: protocol.ProtocolScene) -> list[tuple[str, object]]:
    masked = scene.clip(1000, moving=True)
    out = []
    for name, steps in VARIANTS:
        clip = masked
        for kind, severity in steps:
            clip = perturb_clip(clip, kind, severity, seed=scene.seed)
        out.append((name, clip))
    out.append(("no mask", dataclasses.replace(masked, static_mask=np.ones_like(masked.static_mask), mask_source="none")))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--pool", choices=sorted(protocol.RANDOM_POOLS), default="unseen")
    parser.add_argument("--scenes", type=int, default=24)
    parser.add_argument("--noise", type=float, default=1.0, help="iid-both track noise [px]")
    args = parser.parse_args()
    names, clips = [], []
    for k in range(args.scenes):
        scene = protocol.random_scene(k, pool=args.pool)
        for name, clip in variants(scene):
            names.append(name)
            clips.append(add_noise(clip, NOISE_MODELS["iid-both"].replace(px=args.noise), seed=scene.seed))
    result = score_batch(clips, progress=False)
    rows = pd.DataFrame({"variant": names, "sgc": [c.sgc for c in result.clips], "reward": result.rewards()["reward"]})
    table = rows.groupby("variant", sort=False).agg(median_sgc=("sgc", "median"),
                                                    above_0_10=("sgc", lambda s: int((s > 0.10).sum())),
                                                    clips=("sgc", "size"), median_reward=("reward", "median"))
    print(f"{args.scenes} scenes of the {args.pool} pool, one masked moving sphere, iid-both {args.noise:g} px\n")
    print("| mask | median SGC | above 0.10 | median reward |\n|---|---|---|---|")
    for name, row in table.iterrows():
        print(f"| {name} | {row.median_sgc:.3f} | {int(row.above_0_10)} of {int(row.clips)} | {row.median_reward:.3f} |")


if __name__ == "__main__":
    main()
