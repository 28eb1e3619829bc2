"""The default score against tracker noise (issue 41): on synthetic scenes, consistent and perturbed
at severity 0.5, across tracker noise and track counts, the default SGC, how well the noise floors
predict the pose components, and the perturbation ladders at 0.5 px.

    python bench/excess_score.py [--scenes 3] [--draws 2] [--tracks 200 1000 4000] [--out cells.csv]
                                 [--calibration NAME|FILE] [--region-frame previous|current]
                                 [--tracks-per-layer 70] [--k-seg 10] [--no-ladders]

Each scene's geometry is fixed; its tracks get ``--draws`` independent draws of Gaussian noise
(bench/intervals.py's) after the perturbation. Prints

1. per perturbation and track count, the median SGC over scenes and draws at each noise, and the
   rise from 0.25 to 2 px (consistent scenes; the bar: <= 0.02) or the largest relative change
   against the median over noise (perturbed scenes; the bar: within +-25 %);
2. per track count and noise, the median over the consistent clips of observed / floor for each
   pose component (the bar: between 0.5 and 2);
3. per base scene (the first two) and perturbation kind, SGC at severities 0, 0.25, 0.5, 0.75, 1
   with 0.5 px of noise and 1000 tracks, and whether it rises strictly (the bar: every ladder).
"""

from __future__ import annotations

import argparse
import itertools
import sys
from pathlib import Path

import numpy as np

from sgc_jax import COMPONENTS, SGCConfig, score_batch
from sgc_jax.research.perturb import PERTURBATIONS, perturb_clip
from sgc_jax.research.synth import synth_clip

sys.path.insert(0, str(Path(__file__).resolve().parent))
from intervals import with_track_noise  # noqa: E402

SCENES = [dict(n_layers=2, static_spheres=4), dict(n_layers=3, static_spheres=2), dict(n_layers=4, static_spheres=6)]
NOISE_PX = (0.25, 0.5, 1.0, 2.0)
SEVERITY = 0.5
LADDER_SEVERITIES = (0.0, 0.25, 0.5, 0.75, 1.0)
LADDER_NOISE_PX, LADDER_TRACKS, LADDER_SCENES = 0.5, 1000, 2
POSE_COMPONENTS = [c for c in COMPONENTS if c != "depth_error"]


def scene_clip(s: int, tracks: int):
    return synth_clip(seed=10 + s, clip_id=f"scene{s}-{tracks}", n_frames=8, height=192, width=256,
                      n_tracks=tracks, with_frames=False, **SCENES[s])


def noise_rows(args, config: SGCConfig) -> list[dict]:
    rows = []
    for tracks, s in itertools.product(args.tracks, range(args.scenes)):
        clean = scene_clip(s, tracks)
        bases = {"none": clean, **{kind: perturb_clip(clean, kind, SEVERITY, seed=s) for kind in PERTURBATIONS}}
        cells = list(itertools.product(bases, NOISE_PX, range(args.draws)))
        clips = [with_track_noise(bases[kind], noise, draw) for kind, noise, draw in cells]
        result = score_batch(clips, config=config, calibration=args.calibration, progress=False)
        for (kind, noise, draw), clip in zip(cells, result.clips):
            rows.append(dict(scene=s, tracks=tracks, kind=kind, noise_px=noise, draw=draw, sgc=clip.sgc,
                             **clip.components, **clip.floors))
        print(f"scene {s}, {tracks} tracks: scored {len(clips)} clips", file=sys.stderr, flush=True)
    return rows


def print_noise_table(rows: list[dict], tracks: list[int]) -> None:
    print("\nDefault SGC: median over scenes and draws at each noise (px)")
    print("| perturbation | tracks | " + " | ".join(f"{n} px" for n in NOISE_PX) + " | rise or worst change |")
    print("|---|---|" + "---|" * (len(NOISE_PX) + 1))
    for kind, t in itertools.product(("none", *PERTURBATIONS), tracks):
        medians = np.array([np.median([r["sgc"] for r in rows if (r["kind"], r["tracks"], r["noise_px"])
                                       == (kind, t, n)]) for n in NOISE_PX])
        change = (f"{medians[-1] - medians[0]:+.3f}" if kind == "none" else
                  f"{np.max(np.abs(medians / np.median(medians) - 1)):.0%}" if np.median(medians) > 0 else "n/a")
        print(f"| {kind} | {t} | " + " | ".join(f"{m:.3f}" for m in medians) + f" | {change} |")


def print_floor_table(rows: list[dict], tracks: list[int]) -> None:
    print("\nConsistent scenes: median observed / floor")
    print("| tracks | noise px | " + " | ".join(POSE_COMPONENTS) + " |")
    print("|---|---|" + "---|" * len(POSE_COMPONENTS))
    for t, n in itertools.product(tracks, NOISE_PX):
        cell = [r for r in rows if (r["kind"], r["tracks"], r["noise_px"]) == ("none", t, n)]
        ratios = [np.nanmedian([r[k] / r[f"{k}_floor"] if r[f"{k}_floor"] > 0 else np.nan for r in cell])
                  for k in POSE_COMPONENTS]
        print(f"| {t} | {n} | " + " | ".join(f"{x:.2f}" for x in ratios) + " |")


def print_ladders(args, config: SGCConfig) -> None:
    print(f"\nLadders at {LADDER_NOISE_PX} px, {LADDER_TRACKS} tracks: SGC by severity")
    print("| scene | perturbation | " + " | ".join(f"{a:g}" for a in LADDER_SEVERITIES) + " | strictly rising |")
    print("|---|---|" + "---|" * (len(LADDER_SEVERITIES) + 1))
    for s in range(min(LADDER_SCENES, args.scenes)):
        clean = scene_clip(s, LADDER_TRACKS)
        for kind in PERTURBATIONS:
            clips = [with_track_noise(perturb_clip(clean, kind, a, seed=s) if a else clean, LADDER_NOISE_PX, 0)
                     for a in LADDER_SEVERITIES]
            sgc = np.array([c.sgc for c in score_batch(clips, config=config, calibration=args.calibration,
                                                       progress=False).clips])
            rising = bool(np.all(np.diff(sgc) > 0))
            print(f"| {s} | {kind} | " + " | ".join(f"{v:.3f}" for v in sgc) + f" | {'yes' if rising else 'NO'} |")


def main() -> None:
    defaults = SGCConfig()
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=3)
    parser.add_argument("--draws", type=int, default=2)
    parser.add_argument("--tracks", type=int, nargs="+", default=[200, 1000, 4000])
    parser.add_argument("--out", default=None, help="CSV of every clip's score, components and floors")
    parser.add_argument("--calibration", default=None, help="a calibration name or file (default: the config's)")
    parser.add_argument("--region-frame", default=defaults.region_frame, choices=("previous", "current"))
    parser.add_argument("--tracks-per-layer", type=int, default=defaults.tracks_per_layer)
    parser.add_argument("--k-seg", type=int, default=defaults.k_seg)
    parser.add_argument("--no-ladders", action="store_true")
    args = parser.parse_args()
    config = SGCConfig(region_frame=args.region_frame, tracks_per_layer=args.tracks_per_layer, k_seg=args.k_seg)
    rows = noise_rows(args, config)
    if args.out:
        import csv

        with open(args.out, "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
    print_noise_table(rows, args.tracks)
    print_floor_table(rows, args.tracks)
    if not args.no_ladders:
        print_ladders(args, config)


if __name__ == "__main__":
    main()
