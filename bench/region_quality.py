"""Evidence for the region-quality rule (issue 7): what it removes, what it keeps.

Three tables, printed as Markdown (figures: bench/history/2026-11-21.md):

1. Rigid scenes built to trigger spurious local poses (six small planar layers, 400 tracks per
   pair, so the near layers carry 6-30 tracks each; 0.5 and 1 px noise): local and global
   rotation variance per engine with the rule off and on.
2. The perturbation ladders (warp, squeeze, depth_warp over 0..1) on the four base scenes of
   tests/test_study.py, at their size and at twice it, JAX engine, rule off and on: mean SGC and the targeted component per
   severity, Spearman rho, and the relative SGC change at severity 0.5.
3. Pose uncertainty vs the spread of poses over repeated noise draws, one region at a time.

    python bench/region_quality.py [--scenes 6] [--quick] [--only sparse|uncertainty|ladders]
"""

from __future__ import annotations

import argparse
import functools
import platform
import time

import jax
import jax.numpy as jnp
import numpy as np

from sgc_jax import score_batch
from sgc_jax.config import SGCConfig
from sgc_jax.engines.jax_engine.pose_stage import PoseStage
from sgc_jax.kernels.ransac import ransac_pnp
from sgc_jax.kernels.so3 import rotation_angle_deg, so3_exp
from sgc_jax.research.perturb import PERTURBATIONS, TARGET_COMPONENT
from sgc_jax.research.study import DEFAULT_SEVERITIES, sensitivity_study
from sgc_jax.research.synth import synth_clip

SPARSE_SCENE = dict(n_layers=6, static_spheres=0, n_tracks=400, height=192, width=320, n_frames=6,
                    with_frames=False)
# The base scenes of tests/test_study.py (96 x 128, fx 111 px) and the same scenes at 192 x 256.
LADDER_SCENES = {"96x128": dict(n_layers=2, static_spheres=4, height=96, width=128, n_tracks=1024, n_frames=4),
                 "192x256": dict(n_layers=2, static_spheres=4, height=192, width=256, n_tracks=2048, n_frames=4,
                                 with_frames=False)}
LADDER_SEEDS = (10, 11, 12, 13)


def sparse_table(n_scenes: int) -> str:
    rows = ["| noise px | engine | rule | local_rot_var mean (max) deg^2 | global_rot_var mean (max) deg^2 "
            "| poses kept / posed | s/clip |", "|---|---|---|---|---|---|---|"]
    for noise in (0.5, 1.0):
        clips = [synth_clip(seed=s, clip_id=f"sparse{s}", noise_px=noise, **SPARSE_SCENE) for s in range(n_scenes)]
        for engine in ("reference", "jax"):
            for rule in (False, True):
                start = time.perf_counter()
                result = score_batch(clips, engine=engine, config=dict(quality_rule=rule), progress=False)
                seconds = (time.perf_counter() - start) / len(clips)
                frame = result.to_pandas()
                kept = sum(int(np.sum(r.pairs.n_poses)) for r in result)
                posed = kept + sum(int(np.sum(r.pairs.n_ill_conditioned)) for r in result)
                rows.append(
                    f"| {noise} | {engine} | {'on' if rule else 'off'} "
                    f"| {frame.local_rot_var.mean():.3g} ({frame.local_rot_var.max():.3g}) "
                    f"| {frame.global_rot_var.mean():.3g} ({frame.global_rot_var.max():.3g}) "
                    f"| {kept} / {posed} | {seconds:.2f} |")
    return "\n".join(rows)


def ladder_table(size: str) -> str:
    bases = [synth_clip(seed=s, clip_id=f"scene{s}", group="synthetic", **LADDER_SCENES[size]) for s in LADDER_SEEDS]
    studies = {rule: sensitivity_study(bases, PERTURBATIONS, DEFAULT_SEVERITIES, progress=False, quality_rule=rule)
               for rule in (False, True)}
    sev = " / ".join(f"{s:g}" for s in DEFAULT_SEVERITIES)
    rows = [f"| size | kind | rule | mean SGC at {sev} | rho | targeted component | its rho | SGC at 0.5, on vs off |",
            "|---|---|---|---|---|---|---|---|"]
    half = list(DEFAULT_SEVERITIES).index(0.5)
    for kind in PERTURBATIONS:
        target = TARGET_COMPONENT[kind]
        for rule, study in studies.items():
            curve = study.curve(kind)
            change = curve[half] / studies[False].curve(kind)[half] - 1.0
            rows.append(
                f"| {size} | {kind} | {'on' if rule else 'off'} | {' / '.join(f'{v:.3f}' for v in curve)} "
                f"| {study.rho(kind):.2f} | {target} {' / '.join(f'{v:.3g}' for v in study.curve(kind, target))} "
                f"| {study.rho(kind, target):.2f} | {change:+.1%} |")
    return "\n".join(rows)


def _region(rng, n, half_px, depth, relief, K):
    cx, cy, f = K[0, 2], K[1, 2], K[0, 0]
    u = rng.uniform(cx - half_px, cx + half_px, n)
    v = rng.uniform(cy - 0.75 * half_px, cy + 0.75 * half_px, n)
    Z = depth * (1.0 + relief * rng.uniform(-1.0, 1.0, n))
    return np.stack([(u - cx) * Z / f, (v - cy) * Z / f, Z], axis=1)


def uncertainty_table(draws: int) -> str:
    """Predicted RMS rotation error (median over draws) vs the RMS error of the fitted poses."""
    rng = np.random.default_rng(0)
    K = np.array([[300.0, 0.0, 200.0], [0.0, 300.0, 150.0], [0.0, 0.0, 1.0]], np.float32)
    R = np.asarray(so3_exp(jnp.array([0.01, 0.02, -0.005])), np.float64)
    t = np.array([0.1, -0.05, 0.05])
    fit = jax.jit(jax.vmap(functools.partial(ransac_pnp, options=PoseStage.of(SGCConfig()).ransac),
                           in_axes=(None, 0, None, None, 0)))
    rows = ["| region | points | noise px | predicted rot std deg | measured RMS deg | ratio | ambiguous |",
            "|---|---|---|---|---|---|---|"]
    cases = [("wide, curved", 300, 150, 0.3, 1.0), ("wide, curved", 300, 150, 0.3, 0.5),
             ("wide, planar", 400, 150, 0.0, 1.0), ("60 px patch", 60, 30, 0.3, 1.0),
             ("30 px patch", 12, 15, 0.3, 0.5), ("30 px planar patch", 12, 15, 0.0, 1.0)]
    for name, n, half, relief, noise in cases:
        X = _region(rng, n, half, 5.0 if n > 20 else 3.0, relief, K)
        Y = X @ R.T + t
        uv = Y[:, :2] / Y[:, 2:] * K[0, 0] + K[:2, 2]
        uvs = (uv[None] + rng.normal(0.0, noise, (draws, n, 2))).astype(np.float32)
        res = fit(X.astype(np.float32), uvs, jnp.ones(n, bool), K, jax.random.split(jax.random.PRNGKey(0), draws))
        err = np.asarray(rotation_angle_deg(jnp.asarray(R, jnp.float32)[None], res.R))
        measured = float(np.sqrt(np.mean(err**2)))
        predicted = float(np.median(res.uncertainty.rot_std_deg))
        rows.append(f"| {name} | {n} | {noise} | {predicted:.3g} | {measured:.3g} | {predicted / measured:.2f} "
                    f"| {np.mean(res.ambiguous):.0%} |")
    return "\n".join(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", type=int, default=6, help="rigid sparse scenes per noise level")
    parser.add_argument("--draws", type=int, default=200, help="noise draws per uncertainty case")
    parser.add_argument("--quick", action="store_true", help="2 scenes, 50 draws, no ladders")
    parser.add_argument("--only", choices=("sparse", "uncertainty", "ladders"), help="one table only")
    args = parser.parse_args()
    scenes, draws = (2, 50) if args.quick else (args.scenes, args.draws)
    print(f"# machine: {platform.machine()} {platform.processor() or ''}, jax {jax.__version__} "
          f"on {jax.default_backend()}\n")
    if args.only in (None, "sparse"):
        print("## Rigid sparse scenes\n")
        print(sparse_table(scenes), "\n")
    if args.only in (None, "uncertainty"):
        print("## Pose uncertainty vs noise draws\n")
        print(uncertainty_table(draws), "\n")
    if args.only in (None, "ladders") and not args.quick:
        print("## Ladders, JAX engine\n")
        print("\n".join(ladder_table(size) for size in LADDER_SCENES))


if __name__ == "__main__":
    main()
