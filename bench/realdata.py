"""Real footage of a rigid world (issues 41, 58): the clips of ``../shared/realdata/`` (static scenes
with ground-truth depth and cameras and real tracks; its README says how they were made) under the
default config and calibration.

    python bench/realdata.py [--dir ../shared/realdata] [--engine jax] [--out realdata.csv] [--no-ladders]

Prints

1. per clean clip: SGC, its interval, each pose component against its noise floor, the depth error
   and the tracks' distance to the ground-truth motion (median and 95th percentile over the usable
   tracks, px; sgc_jax.research.ground_truth), sorted by that distance (the bars: SGC <= 0.05 where
   the 95th percentile is within 2 px);
2. the paper's perturbations (§4.3 protocol: warp, squeeze, depth_warp at severities 0.25, 0.5, 1)
   on every clip: SGC by severity, 0 the clean clip (the bar: every ladder rises strictly).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from sgc_jax import COMPONENTS, load_clip, score_batch
from sgc_jax.research.ground_truth import motion_errors
from sgc_jax.research.perturb import PERTURBATIONS, perturb_clip

POSE_COMPONENTS = [c for c in COMPONENTS if c != "depth_error"]
DEFAULT_DIR = Path(__file__).resolve().parents[2] / "shared" / "realdata"
LADDER_SEVERITIES = (0.25, 0.5, 1.0)


def print_clean(clips, result) -> None:
    print("| clip | tracks to GT motion, median / p95 px | SGC | 90 % interval | "
          + " | ".join(f"{k} / floor" for k in POSE_COMPONENTS) + " | depth_error % | tracks per pair |")
    print("|---|---|---|---|" + "---|" * (len(POSE_COMPONENTS) + 2))
    rows = []
    for clip, scored in zip(clips, result.clips):
        distance = motion_errors(clip)
        rows.append((np.percentile(distance, 95), clip, scored, np.median(distance)))
    for p95, clip, scored, median in sorted(rows, key=lambda r: r[0]):
        ratios = [scored.components[k] / scored.floors[f"{k}_floor"] for k in POSE_COMPONENTS]
        tracks = int(scored.pairs.n_tracks.mean()) if scored.pairs is not None else 0
        print(f"| {clip.clip_id} | {median:.2f} / {p95:.2f} | {scored.sgc:.3f} | "
              f"{scored.sgc_lo:.3f}-{scored.sgc_hi:.3f} | " + " | ".join(f"{r:.2f}" for r in ratios)
              + f" | {scored.components['depth_error']:.2f} | {tracks} |")


def print_ladders(clips, clean_sgc, engine: str) -> None:
    print("\nPerturbation ladders: SGC at severity 0 (clean), " + ", ".join(f"{s:g}" for s in LADDER_SEVERITIES))
    print("| clip | perturbation | " + " | ".join(f"{s:g}" for s in (0.0, *LADDER_SEVERITIES)) + " | strictly rising |")
    print("|---|---|" + "---|" * (len(LADDER_SEVERITIES) + 2))
    variants = [perturb_clip(clip, kind, s, seed=0) for clip in clips for kind in PERTURBATIONS for s in LADDER_SEVERITIES]
    scored = iter(score_batch(variants, engine=engine, progress=False).clips)  # in the order made
    rising = 0
    for clip, clean in zip(clips, clean_sgc):
        for kind in PERTURBATIONS:
            sgc = np.array([clean, *(next(scored).sgc for _ in LADDER_SEVERITIES)])
            strictly = bool(np.all(np.diff(sgc) > 0))
            rising += strictly
            print(f"| {clip.clip_id} | {kind} | " + " | ".join(f"{v:.3f}" for v in sgc)
                  + f" | {'yes' if strictly else 'NO'} |")
    print(f"\n{rising} of {len(clips) * len(PERTURBATIONS)} ladders rise strictly")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dir", default=str(DEFAULT_DIR))
    parser.add_argument("--engine", default="jax")
    parser.add_argument("--out", default=None, help="CSV of the clean clips' rows")
    parser.add_argument("--no-ladders", action="store_true")
    args = parser.parse_args()
    paths = sorted(Path(args.dir).glob("*.npz"))
    if not paths:
        raise SystemExit(f"no .npz clips in {args.dir}")
    clips = [load_clip(str(p)) for p in paths]
    result = score_batch(clips, engine=args.engine, progress=False)
    print_clean(clips, result)
    if args.out:
        result.to_pandas().to_csv(args.out, index=False)
    if not args.no_ladders:
        print_ladders(clips, [c.sgc for c in result.clips], args.engine)


if __name__ == "__main__":
    main()
