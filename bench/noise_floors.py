"""Noise floors of the pose components (issue 41, the validation its design rests on): on synthetic
scenes that are consistent by construction, how much of each pose component the measured noise of
the regions' fits predicts.

    python bench/noise_floors.py [--engine reference|jax] [--scenes 3] [--draws 200] [--out floors.csv]

Scenes of 8 frames, 192x256 px, at tracker noise 0.25, 0.5, 1, 2 px and 200, 1000, 4000 tracks per
pair. Each clip is scored once; per pair, each region's pose uncertainty (``region_rot_std`` deg,
``region_trans_std`` units of D: the RMS of the fit's covariance, docs/semantics.md §3.3) gives
the value each component would take if every accepted local pose were the truth plus independent
isotropic noise of that size:

- first order (closed form): E[local variance] = (1 - 1/n) mean_j sigma_j^2, E[global variance]
  = mean_j sigma_j^2 (the camera's own pose taken as exact, the trim of global_rot_var ignored);
- parametric (seeded Monte Carlo): the components' own formulas, the trimmed mean included, over
  ``--draws`` draws of such noise, averaged.

Prints, per noise and track count, the median over scenes of observed / floor for each component
and the clips' SGC.
"""

from __future__ import annotations

import argparse
import itertools
import time

import numpy as np

from sgc_jax import COMPONENTS, score_batch
from sgc_jax.codes import REGION_OK
from sgc_jax.engines.reference import geometry_weights
from sgc_jax.research.synth import synth_clip

POSE_COMPONENTS = [c for c in COMPONENTS if c != "depth_error"]
SCENES = [dict(n_layers=2, static_spheres=4), dict(n_layers=3, static_spheres=2), dict(n_layers=4, static_spheres=6),
          dict(n_layers=1, static_spheres=8)]
NOISE_PX = (0.25, 0.5, 1.0, 2.0)
TRACKS = (200, 1000, 4000)


def first_order_floors(pairs) -> dict[str, np.ndarray]:
    """Per pair (n_pairs,): the closed-form floor of each pose component (NaN without a pose)."""
    ok = pairs.region_status == REGION_OK
    n = ok.sum(axis=1).astype(np.float64)
    rot2 = np.where(ok, pairs.region_rot_std, 0.0) ** 2
    trans2 = np.where(ok, 100.0 * pairs.region_trans_std, 0.0) ** 2
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_rot2, mean_trans2 = rot2.sum(axis=1) / n, trans2.sum(axis=1) / n
        spread = np.where(n >= 2, 1.0 - 1.0 / n, 0.0)
    floors = {"local_rot_var": spread * mean_rot2, "local_trans_var": spread * mean_trans2,
              "global_rot_var": mean_rot2, "global_trans_var": mean_trans2}
    return {k: np.where(n > 0, v, np.nan) for k, v in floors.items()}


def parametric_floors(pairs, draws: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Per pair: each component's formula (docs/semantics.md §3.5, small angles) on local poses
    drawn as the truth plus isotropic noise of each region's RMS uncertainty, averaged over draws."""
    out = {k: np.full(pairs.n_pairs, np.nan) for k in POSE_COMPONENTS}
    for p in range(pairs.n_pairs):
        ok = pairs.region_status[p] == REGION_OK
        if not ok.any():
            continue
        rot_std, trans_std = pairs.region_rot_std[p, ok], 100.0 * pairs.region_trans_std[p, ok]
        n = ok.sum()
        rot = rng.normal(size=(draws, n, 3)) * (rot_std / np.sqrt(3.0))[None, :, None]  # deg, per axis
        trans = rng.normal(size=(draws, n, 3)) * (trans_std / np.sqrt(3.0))[None, :, None]
        # each pose weighted by its geometry, as the components are (§3.5)
        w_rot, w_trans = geometry_weights(pairs.region_rot_per_px[p, ok]), geometry_weights(pairs.region_trans_per_px[p, ok])

        def local(x, w):
            mean = np.average(x, axis=1, weights=w)[:, None]
            return np.average(np.sum((x - mean) ** 2, axis=2), axis=1, weights=w)

        out["local_rot_var"][p] = local(rot, w_rot).mean() if n > 1 else 0.0
        out["local_trans_var"][p] = local(trans, w_trans).mean() if n > 1 else 0.0
        out["global_rot_var"][p] = np.average(np.sum(rot ** 2, axis=2), axis=1, weights=w_rot).mean()
        out["global_trans_var"][p] = np.average(np.sum(trans ** 2, axis=2), axis=1, weights=w_trans).mean()
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--engine", default="reference")
    parser.add_argument("--scenes", type=int, default=3)
    parser.add_argument("--draws", type=int, default=200)
    parser.add_argument("--out", default=None, help="CSV of every clip's observed components and floors")
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    rows = []
    for (s, scene), noise, tracks in itertools.product(enumerate(SCENES[:args.scenes]), NOISE_PX, TRACKS):
        clip = synth_clip(seed=10 + s, clip_id=f"scene{s}-{noise}px-{tracks}", n_frames=8, height=192, width=256,
                          n_tracks=tracks, noise_px=noise, with_frames=False, **scene)
        begin = time.perf_counter()
        result = score_batch([clip], engine=args.engine, progress=False).clips[0]
        row = dict(scene=s, noise_px=noise, tracks=tracks, sgc=result.sgc, seconds=time.perf_counter() - begin)
        for method, floors in (("first_order", first_order_floors(result.pairs)),
                               ("parametric", parametric_floors(result.pairs, args.draws, rng))):
            for k in POSE_COMPONENTS:
                row[f"{k}_floor_{method}"] = float(np.nanmean(floors[k]))
        for k in POSE_COMPONENTS:
            row[k] = result.components[k]
        rows.append(row)
        print(f"{clip.clip_id}: sgc {result.sgc:.3f} ({row['seconds']:.0f} s)", flush=True)
    if args.out:
        import csv

        with open(args.out, "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
    for method in ("first_order", "parametric"):
        print(f"\nobserved / floor ({method}), median over scenes")
        print("| noise px | tracks | median SGC | " + " | ".join(POSE_COMPONENTS) + " |")
        print("|---|---|---|" + "---|" * len(POSE_COMPONENTS))
        for noise, tracks in itertools.product(NOISE_PX, TRACKS):
            cell = [r for r in rows if r["noise_px"] == noise and r["tracks"] == tracks]
            ratios = [np.median([r[k] / r[f"{k}_floor_{method}"] for r in cell]) for k in POSE_COMPONENTS]
            sgc = np.median([r["sgc"] for r in cell])
            print(f"| {noise} | {tracks} | {sgc:.3f} | " + " | ".join(f"{x:.2f}" for x in ratios) + " |")


if __name__ == "__main__":
    main()
