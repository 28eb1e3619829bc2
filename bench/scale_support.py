"""What the clip's translation scale s rests on, and what its error costs the depth error (issue 58,
a lead; not part of the score; docs/semantics.md §3.4, "What the fit cannot do").

    python bench/scale_support.py [--tracks 5 20 80 1000] [--models iid-both correlated] [--px 0.5 2] [--draws 1]
                                  [--kinds consistent depth_warp warp squeeze] [--severity 0.25]

Each consistent scene of FIT (on which a constant may be chosen) with --tracks tracks a pair, under
each noise model at each level and draw, read by the reference engine's steps: the pairs' points,
the scale's equations (``engines.reference.scale_equations``) and s (``fit_translation_scale``),
as ``score_pairs`` reads them. On these scenes depth and poses share their units, so the true s is
1 / D: ``s`` below is the fitted s over the true one. Its standard error from the clip itself:
SE = sqrt(π / 2) σ / sqrt(Σ w²) over the equations within ``inlier_px`` of s (w their slopes in
pixels per unit of s, σ = 1.4826 x the median of |w (s − root)|): a weighted median's spread under
independent Gaussian errors of σ px. Per clip: s, SE (both relative to the true s), z = (s − 1) /
SE, and the depth error (the mean over the pairs of §3.6's, under the camera's pose alone, without
step 6's refit) at the fitted s, at the true s, and the least over s + k SE, k = -2..2 (one s for
the clip): what a depth check that forgave the scale's own uncertainty would read. ``--kinds``
adds the protocol's perturbations of each scene at ``--severity`` (same noise draw as its
consistent clip): what of their lift the forgiving reading keeps.
"""

from __future__ import annotations

import argparse
import itertools
import math

import numpy as np

from sgc_jax import SGCConfig
from sgc_jax.engines import reference
from sgc_jax.engines.units import in_depth_units
from sgc_jax.research import protocol
from sgc_jax.research.noise import NOISE_MODELS, add_noise
from sgc_jax.research.perturb import PERTURBATIONS, perturb_clip

STEPS_SE = (-2, -1, 0, 1, 2)


def scale_support(clip, config: SGCConfig) -> dict[str, float]:
    """s and its SE relative to the true scale, and the depth error at s, the true s and the best of s + k SE."""
    clip, unit = in_depth_units(clip, config)
    points = [reference.pair_points(clip, pair, config) for pair in range(1, clip.n_frames)]
    poses = [reference.global_relative_pose(clip, pair, config) for pair in range(1, clip.n_frames)]
    R_g, t_g = np.stack([g[0] for g in poses]), np.stack([g[1] for g in poses])
    members = [(pp.X[pp.region > 0], pp.uv[pp.region > 0]) for pp in points]
    s = reference.fit_translation_scale(members, clip.K, R_g, t_g, config.inlier_px, 1.0 / unit)
    roots, slopes = (np.concatenate(x) for x in reference.scale_equations(members, clip.K, R_g, t_g))
    residual = slopes * np.abs(s - roots)
    near = residual < config.inlier_px
    sigma = 1.4826 * np.median(residual[near]) if near.any() else math.nan
    se = math.sqrt(math.pi / 2) * sigma / math.sqrt(np.sum(slopes[near] ** 2)) if near.any() else math.nan

    def depth_error(scale: float) -> float:
        errors = [reference.pair_depth_error(clip, pair, R_g[pair - 1], scale * t_g[pair - 1], config)[1]
                  for pair in range(1, clip.n_frames)]
        return float(np.nanmean(errors))

    steps = STEPS_SE if np.isfinite(se) else (0,)
    grid = dict(zip(steps, (depth_error(max(s + k * se, 0.0)) for k in steps)))
    return {"s": s * unit, "se": se * unit, "z": (s * unit - 1) / (se * unit), "depth at s": grid[0],
            "depth at true s": depth_error(1.0 / unit), "least within 2 SE": min(grid.values()),
            "equations": int(near.sum())}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--tracks", type=int, nargs="+", default=[5, 20, 80, 1000])
    parser.add_argument("--models", nargs="+", default=["iid-both", "correlated"], choices=sorted(NOISE_MODELS))
    parser.add_argument("--px", type=float, nargs="+", default=[0.5, 2.0])
    parser.add_argument("--draws", type=int, default=1, help="noise draws (seeds 1, 2, ...)")
    parser.add_argument("--kinds", nargs="+", default=["consistent"], choices=["consistent", *PERTURBATIONS])
    parser.add_argument("--severity", type=float, default=0.25, help="the perturbations' severity")
    args = parser.parse_args()
    config = SGCConfig()
    print("| scene | tracks | kind | model | px | draw | equations | s | SE | z | depth % at s | at true s "
          "| least within 2 SE |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for scene in protocol.FIT_SCENES:
        for n_tracks in args.tracks:
            consistent = scene.clip(n_tracks)
            for kind in args.kinds:
                exact = (consistent if kind == "consistent"
                         else perturb_clip(consistent, kind, args.severity, seed=scene.seed))
                for model, px, draw in itertools.product(args.models, args.px, range(1, args.draws + 1)):
                    row = scale_support(add_noise(exact, NOISE_MODELS[model].replace(px=px), seed=draw), config)
                    print(f"| {scene.name} | {n_tracks} | {kind} | {model} | {px:g} | {draw} | {row['equations']} "
                          f"| {row['s']:.3f} | {row['se']:.3f} | {row['z']:+.2f} | {row['depth at s']:.3f} "
                          f"| {row['depth at true s']:.3f} | {row['least within 2 SE']:.3f} |", flush=True)


if __name__ == "__main__":
    main()
