"""The loader's letterbox line (`letterbox_bars`, docs/semantics.md §1.6; rule LB1 in
bench/history/issue-58.md "Letterbox bars"): where it fires, on clips without bars and with them.

    python bench/letterbox_line.py --pool fit|held-out [--scenes 24] [--battery]
    python bench/letterbox_line.py --real [--realdata ../shared/realdata]

``--pool``: each scene of a random pool (``protocol.check_pool_clips``: 1,000 tracks, ``iid-both``,
``correlated``, ``depth`` and ``outliers`` at 0.5 and 2 px), as it is and with bars of 10 % of the
rows at the median depth (``research.noise.letterboxed``). ``--battery``: every adversary of
``research.adversaries`` on the split's six scenes of that pool's split (FIT for ``fit``; none for
the report-only pools). ``--real``: the shared real clips as given, through a lens of k1 -0.1, with
an overlay of 15 % x 8 %, and with bars of 10 % and 5 % at the median and the 99th percentile of
their depth. Prints how many clips of each kind the line fires on, and the bands it counts.
Nothing is chosen here.
"""

from __future__ import annotations

import collections
from pathlib import Path

from pools import need_one, pool_parser

from sgc_jax import SGCConfig, load_clip
from sgc_jax.io.checks.bars import bar_lines, check_bars
from sgc_jax.research import adversaries, protocol
from sgc_jax.research.noise import letterboxed, overlaid, radially_distorted

BATTERY_SPLIT = {"fit": "fit"}  # a pool's split whose adversary battery may be read with it


def fires(clip, config) -> bool:
    return bool(check_bars(clip, config))


def pool_counts(pool: str, scenes: int, battery: bool) -> None:
    config, counts = SGCConfig(), collections.Counter()
    for px, noisy in protocol.check_pool_clips(pool, scenes):
        for kind, clip in (("as it is", noisy), ("bars 10 %", letterboxed(noisy, 0.1))):
            counts[kind, px, "clips"] += 1
            counts[kind, px, "fires"] += fires(clip, config)
    print(f"{pool} pool, {scenes} scenes, 1,000 tracks, {', '.join(protocol.CHECK_POOL_MODELS)}")
    print("| clips | px | clips | the line fires |\n|---|---|---|---|")
    for kind in ("as it is", "bars 10 %"):
        for px in protocol.CHECK_POOL_LEVELS_PX:
            print(f"| {kind} | {px} | {counts[kind, px, 'clips']} | {counts[kind, px, 'fires']} |")
    if battery and pool in BATTERY_SPLIT:
        fired = [(name, scene.name) for scene in protocol.SPLITS[BATTERY_SPLIT[pool]]
                 for name in adversaries.ADVERSARIES if fires(adversaries.adversary(name, scene), config)]
        total = len(protocol.SPLITS[BATTERY_SPLIT[pool]]) * len(adversaries.ADVERSARIES)
        print(f"\n{BATTERY_SPLIT[pool]}'s adversary battery (1,000 tracks, exact): fires on {len(fired)} of {total}"
              + (f": {fired}" if fired else ""))


def real_clips(realdata: Path) -> None:
    config = SGCConfig()
    changes = {
        "as given": lambda c: c,
        "lens k1 -0.1": lambda c: radially_distorted(c, -0.1),
        "overlay 15 % x 8 %": lambda c: overlaid(c, 0.15, 0.08),
        "bars 10 %, median depth": lambda c: letterboxed(c, 0.1),
        "bars 10 %, 99th percentile": lambda c: letterboxed(c, 0.1, 99.0),
        "bars 5 %, median depth": lambda c: letterboxed(c, 0.05),
        "bars 5 %, 99th percentile": lambda c: letterboxed(c, 0.05, 99.0),
    }
    clips = [load_clip(str(path)) for path in sorted(realdata.glob("*.npz"))]
    print("| change | clips the line fires on | bands (lines from top, bottom, left, right) |\n|---|---|---|")
    for name, change in changes.items():
        changed = [change(clip) for clip in clips]
        bands = [tuple(bar_lines(clip, config).values()) for clip in changed]
        print(f"| {name} | {sum(fires(clip, config) for clip in changed)} of {len(changed)} | {bands} |")


def main() -> None:
    parser = pool_parser(__doc__)
    parser.add_argument("--battery", action="store_true", help="also FIT's adversary battery (with --pool fit)")
    args = parser.parse_args()
    if args.pool:
        pool_counts(args.pool, args.scenes, args.battery)
    if args.real:
        real_clips(args.realdata)
    need_one(parser, args)


if __name__ == "__main__":
    main()
