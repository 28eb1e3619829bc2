"""Tracks on lines (issue 58, docs/semantics.md §1.7): the protocol's scenes seen through a real
tracker, with and without the tracks that start on lines (sgc_jax.adapters.line_tracks).

    python bench/line_tracks.py [--split fit|test] [--ratios 0 0.02 0.05 0.1 0.2] [--tracks 1000]
                                [--window 21]

Each scene of the split (sgc_jax.research.protocol), with its rendered frames (checkerboards and
stripes), is retracked by pyramidal LK (``--window`` px windows, 3 levels, forward-backward check
under 0.5 px; bench/track_errors.py's ``retracked``) from its exact frame i-1 positions: the tracker's own errors on a consistent world,
at both ends after the first pair as LK chains them per pair. Then each perturbation at severity
0.25 on those tracks. For every ratio (0: every track kept) the table gives the median and largest
consistent SGC over the scenes, the median share of usable tracks left out, the median evidence,
and the share of (scene, perturbation) where the perturbed clip scores above its consistent twin.

``LINE_RATIO`` is chosen on ``--split fit`` (the highest detection at 0.25; bench/history/issue-58.md,
"Real footage: tracks that slide along lines", says how) and reported on ``--split test``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from sgc_jax import SGCConfig, score_batch
from sgc_jax.adapters.line_tracks import leave_out_line_tracks
from sgc_jax.research import protocol
from sgc_jax.research.perturb import PERTURBATIONS, perturb_clip
from sgc_jax.research.synth import synth_clip

sys.path.insert(0, str(Path(__file__).resolve().parent))
from track_errors import retracked  # noqa: E402

SEVERITY = 0.25


def scene_clips(split: str, tracks: int, window: int) -> list[tuple[str, str, object]]:
    """(scene, kind or "" for consistent, clip): each scene retracked, then perturbed."""
    out = []
    for scene in protocol.SPLITS[split]:
        tracked = retracked(synth_clip(seed=scene.seed, clip_id=scene.name, n_tracks=tracks, **scene.spec), window)
        out.append((scene.name, "", tracked))
        out += [(scene.name, kind, perturb_clip(tracked, kind, SEVERITY, seed=scene.seed)) for kind in PERTURBATIONS]
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--split", default="fit", choices=sorted(protocol.SPLITS))
    parser.add_argument("--ratios", type=float, nargs="+", default=[0.0, 0.02, 0.05, 0.1, 0.2])
    parser.add_argument("--tracks", type=int, default=1000)
    parser.add_argument("--window", type=int, default=21)
    args = parser.parse_args()
    started = time.perf_counter()
    conf = SGCConfig().min_track_conf
    clips = scene_clips(args.split, args.tracks, args.window)
    print(f"split {args.split}: {len(protocol.SPLITS[args.split])} scenes, {args.tracks} tracks, LK {args.window} px; "
          f"perturbations at {SEVERITY}", file=sys.stderr)
    print("| line ratio | consistent SGC, median | largest | usable tracks left out, median | evidence, median "
          "| detection at 0.25 |")
    print("|---|---|---|---|---|---|")
    for ratio in args.ratios:
        variants = [leave_out_line_tracks(clip, ratio) for _, _, clip in clips]  # 0 keeps every track
        scored = score_batch(variants, progress=False).clips
        consistent = {scene: s for (scene, kind, _), s in zip(clips, scored) if kind == ""}
        sgc = np.array([s.sgc for s in consistent.values()])
        detected = [s.sgc > consistent[scene].sgc for (scene, kind, _), s in zip(clips, scored) if kind]
        left_out = [1.0 - v.usable_tracks(conf).sum() / max(1, c.usable_tracks(conf).sum())
                    for (_, kind, c), v in zip(clips, variants) if kind == ""]
        evidence = np.median([s.evidence for s in consistent.values()])
        print(f"| {ratio:g} | {np.median(sgc):.3f} | {sgc.max():.3f} | {np.median(left_out):.0%} | {evidence:.2f} "
              f"| {np.mean(detected):.0%} ({sum(detected)} of {len(detected)}) |", flush=True)
    print(f"{time.perf_counter() - started:.0f} s", file=sys.stderr)


if __name__ == "__main__":
    main()
