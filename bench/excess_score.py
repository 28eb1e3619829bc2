"""What a score of the components' excess over their noise floors would do (issue 41, item 3): on
synthetic scenes, consistent and perturbed at severity 0.5, across tracker noise and track counts,
the default SGC beside trial "excess" SGCs.

    python bench/excess_score.py [--scenes 3] [--draws 3] [--tracks 200 1000 4000] [--bands 1 2] [--out excess.csv]
                                 [--quality-noise-px 1.0] [--region-frame current|previous] [--k-seg 10]
                                 [--tracks-per-layer 0]

Each scene's geometry is fixed; its tracks get ``--draws`` independent draws of Gaussian noise
(bench/intervals.py's) after the perturbation. A trial score is the spec formula (docs/semantics.md
§5.1) on e_k = max(0, m_k - c floor_k) for the four pose components, c a noise band (1: the excess
over the floor), the depth error as it is (it has no floor, §3.10), with ``sgc-spec-2026``'s mu,
sigma, z_max and weights and each pose component's z_min moved to e_k = 0, so that a clip scores 0
exactly when every pose component sits within its band. It is not a fitted calibration: it shows
whether subtracting the floors removes the dependence on noise before one is refitted for it.

Prints, per band, perturbation and track count, the median over scenes and draws at each noise, the
rise from 0.25 to 2 px (consistent scenes; the bar: <= 0.02) and the largest relative change
against the median over noise (perturbed scenes; the bar: within +-25 %).
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import sys
from pathlib import Path

import numpy as np

from sgc_jax import COMPONENTS, SGCConfig, score_batch
from sgc_jax.calibration import Calibration, sgc_score
from sgc_jax.research.perturb import PERTURBATIONS, perturb_clip
from sgc_jax.research.synth import synth_clip

sys.path.insert(0, str(Path(__file__).resolve().parent))
from intervals import with_track_noise  # noqa: E402

SCENES = [dict(n_layers=2, static_spheres=4), dict(n_layers=3, static_spheres=2), dict(n_layers=4, static_spheres=6)]
NOISE_PX = (0.25, 0.5, 1.0, 2.0)
SEVERITY = 0.5
POSE_COMPONENTS = [c for c in COMPONENTS if c != "depth_error"]


def excess_calibration(base: Calibration) -> Calibration:
    """``base`` with each pose component's zero at p_k = log1p(0) = 0 (no excess)."""
    z_min = {**base.z_min, **{k: (0.0 - base.mu[k]) / base.sigma[k] for k in POSE_COMPONENTS}}
    return dataclasses.replace(base, name=f"{base.name}-excess-trial", z_min=z_min)


def excess_score(row: dict, calibration: Calibration, band: float) -> float:
    excess = {k: max(0.0, row[k] - band * row[f"{k}_floor"]) for k in POSE_COMPONENTS}
    return float(sgc_score({**excess, "depth_error": row["depth_error"]}, calibration))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=3)
    parser.add_argument("--draws", type=int, default=3)
    parser.add_argument("--tracks", type=int, nargs="+", default=[200, 1000, 4000])
    parser.add_argument("--bands", type=float, nargs="+", default=[1.0, 2.0])
    parser.add_argument("--out", default=None, help="CSV of every clip's scores, components and floors")
    parser.add_argument("--quality-noise-px", type=float, default=SGCConfig().quality_noise_px,
                        help="the region-quality rule's cap on the residual sigma (a value: no recompile)")
    parser.add_argument("--region-frame", default=SGCConfig().region_frame, choices=("current", "previous"),
                        help="the frame whose partition gives a pair's regions (docs/semantics.md §3.2 step 5)")
    parser.add_argument("--k-seg", type=int, default=SGCConfig().k_seg, help="region slots per frame")
    parser.add_argument("--tracks-per-layer", type=int, default=SGCConfig().tracks_per_layer,
                        help="at most one depth layer per this many tracks on the background (0: k_seg layers)")
    args = parser.parse_args()
    config = SGCConfig(quality_noise_px=args.quality_noise_px, region_frame=args.region_frame, k_seg=args.k_seg,
                       tracks_per_layer=args.tracks_per_layer)
    trial = excess_calibration(Calibration.load("sgc-spec-2026"))
    rows = []
    for tracks, (s, scene) in itertools.product(args.tracks, enumerate(SCENES[:args.scenes])):
        clean = synth_clip(seed=10 + s, clip_id=f"scene{s}-{tracks}", n_frames=8, height=192, width=256,
                           n_tracks=tracks, with_frames=False, **scene)
        bases = {"none": clean, **{kind: perturb_clip(clean, kind, SEVERITY, seed=s) for kind in PERTURBATIONS}}
        cells = list(itertools.product(bases, NOISE_PX, range(args.draws)))
        clips = [with_track_noise(bases[kind], noise, draw) for kind, noise, draw in cells]
        for (kind, noise, draw), result in zip(cells, score_batch(clips, config=config, progress=False).clips):
            rows.append(dict(scene=s, tracks=tracks, kind=kind, noise_px=noise, draw=draw, sgc=result.sgc,
                             **result.components, **result.floors))
        print(f"scene {s}, {tracks} tracks: scored {len(clips)} clips", flush=True)
    for row in rows:
        row.update({f"sgc_band{band:g}": excess_score(row, trial, band) for band in args.bands})
    if args.out:
        import csv

        with open(args.out, "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
    for score in ("sgc", *(f"sgc_band{band:g}" for band in args.bands)):
        print(f"\n{score}: median over scenes and draws at each noise (px)")
        print("| perturbation | tracks | " + " | ".join(f"{n} px" for n in NOISE_PX) + " | rise or worst change |")
        print("|---|---|" + "---|" * (len(NOISE_PX) + 1))
        for kind, tracks in itertools.product(("none", *PERTURBATIONS), args.tracks):
            medians = np.array([np.median([r[score] for r in rows if (r["kind"], r["tracks"], r["noise_px"])
                                           == (kind, tracks, n)]) for n in NOISE_PX])
            change = (f"{medians[-1] - medians[0]:+.3f}" if kind == "none" else
                      f"{np.max(np.abs(medians / np.median(medians) - 1)):.0%}" if np.median(medians) > 0 else "n/a")
            print(f"| {kind} | {tracks} | " + " | ".join(f"{m:.3f}" for m in medians) + f" | {change} |")

if __name__ == "__main__":
    main()
