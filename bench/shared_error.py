"""Errors nearby tracks share (issue 41): how far accepted poses scatter against the noise the
floors count, with the usual covariance and with the floors' (docs/semantics.md §3.10).

    python bench/shared_error.py [--dir ../shared/realdata] [--block-frac 0.05 0.1] [--draws 2]

With the reference engine on the real clips and on consistent synthetic scenes (independent
tracker noise by construction) and these perturbed at severity 0.5:

1. for every two accepted poses of a pair, their squared rotation difference over the sum of their
   squared RMS rotation errors (1 on average when the errors are right), by the usual covariance
   (``region_rot_std``) and by the floors' pose noise with blocks of ``--block-frac`` x the image
   diagonal (``reference.floor_noise``; 0.05 is the engines'; under 1/21 the grid's last row and
   column take the rest);
2. per clip, SGC (default calibration) and observed / floor of each pose component with the floors
   of either;
3. for the real clips' outlying accepted poses (a median rotation more than 10 deg from the pair's
   others), how their tracks move against the ground-truth motion.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

from sgc_jax import Calibration, SGCConfig, default_calibration
from sgc_jax.codes import REGION_OK
from sgc_jax.engines.reference import (
    floor_noise,
    global_relative_pose,
    pair_points,
    project,
    reprojection_errors,
    score_pairs,
)
from sgc_jax.engines.units import in_depth_units
from sgc_jax.io.loading import load_clip
from sgc_jax.research.perturb import PERTURBATIONS, perturb_clip
from sgc_jax.research.synth import synth_clip
from sgc_jax.scoring.result import summarize_clip

sys.path.insert(0, str(Path(__file__).resolve().parent))
from intervals import with_track_noise  # noqa: E402

DEFAULT_DIR = Path(__file__).resolve().parents[2] / "shared" / "realdata"
SYNTH_SCENES = [dict(n_layers=2, static_spheres=4), dict(n_layers=3, static_spheres=2), dict(n_layers=4, static_spheres=6)]
SYNTH_SHAPE = dict(n_frames=8, height=192, width=256, n_tracks=1000)
OUTLIER_DEG = 10.0
SEVERITY, PERTURBED_NOISE_PX = 0.5, 0.5
POSE_COMPONENTS = ("local_rot_var", "local_trans_var", "global_rot_var", "global_trans_var")


def rotation_deg(R_a: np.ndarray, R_b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(R_a @ R_b.T) - 1.0) / 2.0, -1.0, 1.0))))


def scatter_ratios(R: list[np.ndarray], std: list[float]) -> list[float]:
    """Squared rotation difference over the summed squared RMS errors, for every two poses."""
    return [rotation_deg(R[a], R[b]) ** 2 / (std[a] ** 2 + std[b] ** 2)
            for a in range(len(R)) for b in range(a + 1, len(R))]


def analyse(clip, config: SGCConfig, block_fracs, calibration):
    """-> (ratios {name: list}, summaries {name: ClipResult}, outlying-pose lines); names "usual"
    and each block fraction."""
    pairs = score_pairs(clip, config)
    scaled, _ = in_depth_units(clip, config)
    diagonal = float(np.hypot(*clip.image_size))
    noise = {f: (np.full_like(pairs.region_rot_std, np.nan), np.full_like(pairs.region_trans_std, np.nan))
             for f in block_fracs}
    ratios = {name: [] for name in ("usual", *block_fracs)}
    outliers = []
    for pair in range(1, clip.n_frames):
        p, pp, K = pair - 1, pair_points(scaled, pair, config), clip.K[pair]
        accepted = [j for j in range(config.k_seg) if pairs.region_status[p, j] == REGION_OK]
        R = [pairs.R_local[p, j] for j in accepted]
        ratios["usual"] += scatter_ratios(R, [pairs.region_rot_std[p, j] for j in accepted])
        for f in block_fracs:
            for j in accepted:
                member = pp.region == j + 1
                X, uv = pp.X[member], pp.uv[member]
                usual = (pairs.region_rot_std[p, j], pairs.region_trans_std[p, j])
                noise[f][0][p, j], noise[f][1][p, j] = floor_noise(
                    X, uv, K, pairs.R_local[p, j], pairs.t_local[p, j], usual, pairs.region_sigma_px[p, j],
                    f * diagonal, config.inlier_px)
            ratios[f] += scatter_ratios(R, [noise[f][0][p, j] for j in accepted])
        if accepted and not clip.clip_id.startswith("synth"):
            outliers += outlying_regions(clip, scaled, pairs, pair, pp, accepted, config)
    variants = {"usual": (pairs.region_rot_std, pairs.region_trans_std), **noise}
    summaries = {name: summarize_clip(clip.clip_id, dataclasses.replace(pairs, region_rot_noise=rot,
                                                                         region_trans_noise=trans),
                                      calibration, compat=config.compat)
                 for name, (rot, trans) in variants.items()}
    return ratios, summaries, outliers


def outlying_regions(clip, scaled, pairs, pair, pp, accepted, config) -> list[str]:
    """Accepted poses > OUTLIER_DEG from the pair's others: their tracks' displacement against the
    displacement the ground-truth motion and depth predict."""
    p, K = pair - 1, clip.K[pair]
    Rs = [pairs.R_local[p, j] for j in accepted]
    R_g, t_g = global_relative_pose(scaled, pair, config)
    lines = []
    for i, j in enumerate(accepted):
        others = [rotation_deg(Rs[i], S) for m, S in enumerate(Rs) if m != i]
        if not others or np.median(others) <= OUTLIER_DEG:
            continue
        member = pp.region == j + 1
        X, uv, uv_prev = pp.X[member], pp.uv[member], pp.uv_prev[member]
        bad = reprojection_errors(X, uv, K, R_g, t_g) > 2.0
        moved = np.linalg.norm(project(K, X @ R_g.T + t_g) - uv_prev, axis=1)
        tracked = np.linalg.norm(uv - uv_prev, axis=1)
        lines.append(f"{clip.clip_id} pair {pair} region {j + 1}: {int(member.sum())} tracks, median "
                     f"{np.median(others):.0f} deg from the others; {int(bad.sum())} tracks > 2 px from the true "
                     f"motion, which moved them {np.median(moved[bad]) if bad.any() else 0:.1f} px where the "
                     f"tracker says {np.median(tracked[bad]) if bad.any() else 0:.1f} px (median)")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dir", default=str(DEFAULT_DIR))
    parser.add_argument("--block-frac", type=float, nargs="+", default=[0.05, 0.1])
    parser.add_argument("--draws", type=int, default=1, help="noise draws per synthetic scene and noise level")
    parser.add_argument("--noise", type=float, nargs="+", default=[0.5, 2.0])
    args = parser.parse_args()
    config = SGCConfig()
    calibration = Calibration.load(default_calibration("spec"))
    clips = [load_clip(str(p)) for p in sorted(Path(args.dir).glob("*.npz"))]
    for s, scene in enumerate(SYNTH_SCENES):
        base = synth_clip(seed=s, clip_id=f"synth{s}", noise_px=0.0, **scene, **SYNTH_SHAPE)
        clips += [dataclasses.replace(with_track_noise(base, noise, d), clip_id=f"synth{s} {noise} px #{d}")
                  for noise in args.noise for d in range(args.draws)]
        clips += [dataclasses.replace(with_track_noise(perturb_clip(base, kind, SEVERITY, seed=s), PERTURBED_NOISE_PX, 0),
                                      clip_id=f"synth{s} {kind} {SEVERITY}") for kind in PERTURBATIONS]
    names = ["usual", *args.block_frac]
    print("| clip | pose pairs | " + " | ".join(f"median ratio {n}" for n in names)
          + " | " + " | ".join(f"SGC {n}" for n in names) + " |")
    print("|---|---|" + "---|" * (2 * len(names)))
    rows, outliers = [], []
    for clip in clips:
        ratios, summaries, found = analyse(clip, config, args.block_frac, calibration)
        outliers += found
        print(f"| {clip.clip_id} | {len(ratios['usual'])} | "
              + " | ".join(f"{np.median(ratios[n]):.2f}" if ratios[n] else "-" for n in names) + " | "
              + " | ".join(f"{summaries[n].sgc:.3f}" for n in names) + " |", flush=True)
        rows.append((clip.clip_id, summaries))
    print(f"\nobserved / floor: usual floors -> floors with blocks of {names[1]} of the diagonal")
    ratio = lambda summary, k: summary.components[k] / summary.floors[k + "_floor"]  # noqa: E731
    for clip_id, summaries in rows:
        print(f"{clip_id}: " + ", ".join(f"{k} {ratio(summaries['usual'], k):.2f} -> {ratio(summaries[names[1]], k):.2f}"
                                         for k in POSE_COMPONENTS))
    print("\noutlying accepted poses of the real clips:")
    print("\n".join(outliers) or "none")


if __name__ == "__main__":
    main()
