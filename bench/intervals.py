"""Coverage of the score's confidence interval (issue 41, docs/semantics.md §5.6): for a consistent
and a perturbed version of each synthetic scene, ``--draws`` independent draws of tracker noise on
the same geometry; how often one draw's interval [sgc_lo, sgc_hi] contains the median SGC of all
the draws (the bar: >= 80 % for the 90 % interval).

    python bench/intervals.py [--scenes 3] [--draws 20] [--noise 0.5 2] [--tracks 1000] [--engine jax]

Scenes of 8 frames, 192x256 px (bench/noise_floors.py's); perturbations at severity 0.5. Prints one
row per (scene, perturbation, noise): the median SGC, the median interval width and the coverage.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools

import numpy as np

from sgc_jax import score_batch
from sgc_jax.research.perturb import PERTURBATIONS, perturb_clip
from sgc_jax.research.protocol import interval_coverage
from sgc_jax.research.synth import synth_clip

SCENES = [dict(n_layers=2, static_spheres=4), dict(n_layers=3, static_spheres=2), dict(n_layers=4, static_spheres=6)]
SEVERITY = 0.5
NOISE_SEED = 1000


def with_track_noise(clip, noise_px: float, draw: int):
    """The clip with Gaussian noise of ``noise_px`` on every coordinate of track_curr (the synthetic
    tracker's error, research.synth), from its own seeded stream."""
    rng = np.random.default_rng((NOISE_SEED, draw))
    curr = clip.track_curr + rng.normal(0.0, noise_px, clip.track_curr.shape).astype(clip.track_curr.dtype)
    return dataclasses.replace(clip, track_curr=curr, clip_id=f"{clip.clip_id}-draw{draw}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=3)
    parser.add_argument("--draws", type=int, default=20)
    parser.add_argument("--noise", type=float, nargs="+", default=[0.5, 2.0])
    parser.add_argument("--tracks", type=int, default=1000)
    parser.add_argument("--engine", default="jax")
    args = parser.parse_args()
    print("| scene | perturbation | noise px | median SGC | median width | coverage |")
    print("|---|---|---|---|---|---|")
    total = covered_total = 0
    for (s, scene), kind, noise in itertools.product(enumerate(SCENES[:args.scenes]), ("none", *PERTURBATIONS),
                                                      args.noise):
        clean = synth_clip(seed=10 + s, clip_id=f"scene{s}", n_frames=8, height=192, width=256,
                           n_tracks=args.tracks, with_frames=False, **scene)
        base = clean if kind == "none" else perturb_clip(clean, kind, SEVERITY, seed=s)
        clips = [with_track_noise(base, noise, d) for d in range(args.draws)]
        covered, width, sgc = interval_coverage(score_batch(clips, engine=args.engine, progress=False).clips)
        total, covered_total = total + covered.size, covered_total + covered.sum()
        print(f"| {s} | {kind} | {noise} | {np.median(sgc):.3f} | {np.median(width):.3f} | {covered.mean():.2f} |",
              flush=True)
    print(f"\nall cells: {covered_total}/{total} draws covered ({covered_total / total:.2f})")


if __name__ == "__main__":
    main()
