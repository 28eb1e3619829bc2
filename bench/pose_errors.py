"""How well the noise the floors count predicts each accepted local pose's error (issue 58,
docs/semantics.md §3.10): on scenes consistent by construction, every accepted pose's rotation
error against the ground truth, squared, over its ``region_rot_noise``² (z²; 1 when the floors'
noise is the pose's error) and over its ``region_rot_std``² (the usual covariance alone); its
translation's over ``region_trans_noise``².

    python bench/pose_errors.py [--split fit|test] [--models iid-both iid-curr] [--levels 0.5 2]
                                [--tracks 1000] [--draws 4] [--config FILE]

Each scene of the split is drawn ``--draws`` times under each noise model and level (research.noise),
scored once by the JAX engine. Prints, per cell, the accepted poses, mean z² under both noises
(and the translation's under the floors'),
the median block / usual noise, mean z² by the usual noise's size, and the consistent clips' SGC
(median, largest, how many above 0.10).
"""

from __future__ import annotations

import argparse
import itertools
import json
from pathlib import Path

import numpy as np

from sgc_jax import SGCConfig, score_batch
from sgc_jax.codes import REGION_STATUS
from sgc_jax.engines.units import depth_unit
from sgc_jax.research import protocol
from sgc_jax.research.noise import NOISE_MODELS, add_noise
from sgc_jax.research.pose_jitter import rotation_log_deg

SIZE_BINS_DEG = (0.0, 0.25, 0.5, 1.0, np.inf)  # the usual noise's size [deg]


def pose_rows(truth, result, config: SGCConfig) -> np.ndarray:
    """(n, 6): each accepted pose's squared rotation error [deg²], its floor noise and its usual
    noise [deg], and the same for its translation [units of D], over the clips of ``result``
    against their exact ``truth`` clips (the local translations' unit D: ``units.depth_unit``)."""
    rows = []
    for clip, scored in zip(truth, result.clips):
        pairs, unit = scored.pairs, depth_unit(clip, config)
        for i in range(pairs.n_pairs):
            R_true = clip.R_wc[i + 1] @ clip.R_wc[i].T
            t_true = (clip.t_wc[i + 1] - R_true @ clip.t_wc[i]) / unit
            accepted = pairs.region_status[i] == REGION_STATUS["ok"]
            rotation = rotation_log_deg(pairs.R_local[i][accepted] @ R_true.T)
            translation = pairs.t_local[i][accepted] - t_true
            rows += zip(np.sum(rotation**2, axis=-1), pairs.region_rot_noise[i][accepted],
                        pairs.region_rot_std[i][accepted], np.sum(translation**2, axis=-1),
                        pairs.region_trans_noise[i][accepted], pairs.region_trans_std[i][accepted])
    return np.array(rows, dtype=float).reshape(-1, 6)


def print_cell(label: str, rows: np.ndarray, sgc: np.ndarray) -> None:
    z_floor, z_usual = rows[:, 0] / rows[:, 1] ** 2, rows[:, 0] / rows[:, 2] ** 2
    z_trans = rows[:, 3] / rows[:, 4] ** 2
    by_size = []
    for lo, hi in zip(SIZE_BINS_DEG[:-1], SIZE_BINS_DEG[1:]):
        inside = (rows[:, 2] >= lo) & (rows[:, 2] < hi)
        by_size.append(f"{np.mean(z_floor[inside]):.2f} ({inside.sum()})" if inside.any() else "-")
    print(f"| {label} | {len(rows)} | {np.mean(z_floor):.2f} | {np.mean(z_usual):.2f} | {np.mean(z_trans):.2f} | "
          f"{np.median(rows[:, 1] / rows[:, 2]):.2f} | " + " | ".join(by_size)
          + f" | {np.median(sgc):.3f} / {np.max(sgc):.3f} / {np.sum(sgc > 0.10)} of {len(sgc)} |", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--split", default="fit", choices=sorted(protocol.SPLITS))
    parser.add_argument("--models", nargs="+", default=["iid-both", "iid-curr"], choices=list(NOISE_MODELS))
    parser.add_argument("--levels", type=float, nargs="+", default=[0.5, 2.0], help="RMS error per coordinate [px]")
    parser.add_argument("--tracks", type=int, nargs="+", default=[1000])
    parser.add_argument("--draws", type=int, default=4, help="noise draws of each scene per cell")
    parser.add_argument("--config", default=None, help="a config file (JSON) for the score (default: SGCConfig())")
    args = parser.parse_args()
    config = SGCConfig.from_dict(json.loads(Path(args.config).read_text())) if args.config else SGCConfig()
    bins = " | ".join(f"usual {lo:g}-{hi:g} deg" for lo, hi in zip(SIZE_BINS_DEG[:-1], SIZE_BINS_DEG[1:]))
    print(f"{args.split} split, {args.draws} draws a scene; mean z² (poses) by the usual noise's size")
    print(f"| cell | accepted poses | mean z² (floor noise) | mean z² (usual) | translation: mean z² (floor noise) "
          f"| block / usual, median | {bins} "
          "| consistent SGC: median / largest / above 0.10 |")
    print("|---|---|---|---|---|---|" + "---|" * (len(SIZE_BINS_DEG) - 1) + "---|")
    for model, px, tracks in itertools.product(args.models, args.levels, args.tracks):
        truth, noisy = [], []
        for scene, draw in itertools.product(protocol.SPLITS[args.split], range(args.draws)):
            clean = scene.clip(tracks)
            truth.append(clean)
            noisy.append(add_noise(clean, NOISE_MODELS[model].replace(px=px), scene.seed * 1000 + draw))
        result = score_batch(noisy, config=config, progress=False)
        print_cell(f"{model} {px:g} px, {tracks} tracks", pose_rows(truth, result, config),
                   np.array([clip.sgc for clip in result.clips]))


if __name__ == "__main__":
    main()
