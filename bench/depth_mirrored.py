"""The loader's mirrored-depth line (`depth_mirrored`, docs/semantics.md §1.6; rules FL7 and FT2 in
bench/history/issue-58.md "Depth stored mirrored", "Depth turned 180°"): where it and the other depth lines fire, with
the depth as given, mirrored, turned 180° and stored as disparity or range.

    python bench/depth_mirrored.py --pool fit|held-out [--scenes 24] [--battery fit|test]
    python bench/depth_mirrored.py --real [--realdata ../shared/realdata] [--scores]

``--pool``: each scene of a random pool (``protocol.check_pool_clips``: 1,000 tracks, ``iid-both``,
``correlated``, ``depth`` and ``outliers`` at 0.5 and 2 px). ``--battery``: every adversary of
``research.adversaries`` on that split's six scenes, ``iid-both`` 1 px at both ends, two noise
draws. ``--real``: the shared real clips; ``--scores`` also scores them as given and mirrored
(``score_batch``, the default config). Per depth reading: how many clips each depth line names
(``io.validate.check_clip``). Nothing is chosen here.
"""

from __future__ import annotations

import collections
import dataclasses

import numpy as np
from pools import need_one, pool_parser

from sgc_jax import SGCConfig, load_clip, score_batch
from sgc_jax.io.checks.depth import MIRROR_WORDS
from sgc_jax.io.depth_range import range_from_depth
from sgc_jax.io.validate import check_clip
from sgc_jax.research import adversaries, protocol
from sgc_jax.research.noise import NOISE_MODELS, add_noise

LINES = ("depth_mirrored", "depth_like_disparity", "depth_like_range")


READINGS = {
    "as given": lambda c: c.depth,
    "rows bottom-up": lambda c: np.ascontiguousarray(c.depth[:, ::-1]),
    "columns reversed": lambda c: np.ascontiguousarray(c.depth[:, :, ::-1]),
    "turned 180°": lambda c: np.ascontiguousarray(c.depth[:, ::-1, ::-1]),
    "disparity": lambda c: np.where(c.depth > 0, 1.0 / np.maximum(c.depth, 1e-6), 0.0).astype(np.float32),
    "range": lambda c: range_from_depth(c.depth, c.K),
}
FLIP_OF = {"rows bottom-up": "up-down", "columns reversed": "left-right", "turned 180°": "turned 180°"}


def line_counts(label: str, clips: list) -> None:
    """Per depth reading, the clips each of LINES names; for a mirrored reading also those whose
    `depth_mirrored` line gives the right undoing slice."""
    config, counts = SGCConfig(), collections.Counter()
    for clip in clips:
        for reading, depth in READINGS.items():
            problems = check_clip(dataclasses.replace(clip, depth=depth(clip)), config)
            counts.update((reading, line) for line in LINES if line in {p.code for p in problems})
            undo = MIRROR_WORDS[FLIP_OF[reading]][2] if reading in FLIP_OF else None
            counts[reading, "right"] += any(p.code == "depth_mirrored" and undo and p.fix.endswith(undo)
                                            for p in problems)
    print(f"\n{label}, {len(clips)} clips\n\n| depth | " + " | ".join(f"`{line}`" for line in LINES)
          + " | `depth_mirrored` naming the flip |\n|---|" + "---|" * (len(LINES) + 1))
    for reading in READINGS:
        right = counts[reading, "right"] if reading in FLIP_OF else "-"
        print(f"| {reading} | " + " | ".join(str(counts[reading, line]) for line in LINES) + f" | {right} |")


def battery(split: str) -> list:
    return [add_noise(adversaries.adversary(name, scene), NOISE_MODELS["iid-both"].replace(px=1.0), seed=draw)
            for scene in protocol.SPLITS[split] for name in adversaries.ADVERSARIES for draw in (0, 1)]


def real_scores(clips: list) -> None:
    print("\n| clip | SGC as given | rows bottom-up | columns reversed | turned 180° |\n|---|---|---|---|---|")
    scored = {reading: score_batch([dataclasses.replace(c, depth=READINGS[reading](c)) for c in clips],
                                   progress=False).to_pandas().sgc.to_numpy()
              for reading in ("as given", "rows bottom-up", "columns reversed", "turned 180°")}
    for k, clip in enumerate(clips):
        print(f"| {clip.clip_id} | " + " | ".join(f"{scored[r][k]:.3f}" for r in scored) + " |")


def main() -> None:
    parser = pool_parser(__doc__)
    parser.add_argument("--battery", choices=sorted(protocol.SPLITS), help="also this split's adversary battery")
    parser.add_argument("--scores", action="store_true", help="with --real: score the clips as given and mirrored")
    args = parser.parse_args()
    need_one(parser, args)
    if args.pool:
        line_counts(f"{args.pool} pool, {args.scenes} scenes",
                    [clip for _, clip in protocol.check_pool_clips(args.pool, args.scenes)])
    if args.battery:
        line_counts(f"{args.battery}'s adversary battery, two draws", battery(args.battery))
    if args.real:
        clips = [load_clip(str(path)) for path in sorted(args.realdata.glob("*.npz"))]
        line_counts("the shared real clips", clips)
        if args.scores:
            real_scores(clips)


if __name__ == "__main__":
    main()
