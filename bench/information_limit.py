"""What the data allow (issue 58, docs/semantics.md §7.4): how often an inconsistency at severity
0.25 stands out from a consistent scene's own noise when the two do not share a noise draw, for
the shipped score and for an oracle that knows each scene's noise.

    python bench/information_limit.py [--split test|fit] [--draws 12] [--tracks 1000] [--out rows.csv] [--rows rows.csv]

The protocol's detection (bench/validation.py, table 2) compares each inconsistency with its
consistent twin under the same noise draw (one seed per cell), so the noise cancels between them.
A generator's video has no such twin. Here every scene is drawn ``--draws`` times under each noise
model and level (0.5 and 2 px), consistent and with each perturbation at 0.25; a draw's seed is
shared by its four clips. Prints, per model, level and perturbation, means over the scenes of:

- paired: the share of draws where the perturbed clip's SGC is above its own draw's consistent
  clip's (what validation.py counts);
- calm: the share of perturbed draws whose SGC is above every consistent draw of the scene: what a
  score that keeps every consistent clip below it could detect;
- oracle: the same with the statistic an oracle would choose knowing each scene's consistent
  draws, on the five components the score reads: the best single component (chosen after the
  fact, per scene), and the sum over the five of the log of the component over its median over
  the consistent draws. It bounds what a threshold on these components can do, not what a score
  reading more of the clip (its residuals, its frames) could.

Also the largest consistent SGC of the cell. Noise models as bench/validation.py's (research.noise).
"""

from __future__ import annotations

import argparse
import itertools
import sys
import time

import numpy as np

from sgc_jax import COMPONENTS, score_batch
from sgc_jax.research import protocol
from sgc_jax.research.noise import NOISE_MODELS, add_noise
from sgc_jax.research.perturb import PERTURBATIONS, perturb_clip

MODELS = ("iid-curr", "iid-both", "correlated", "depth")
LEVELS = (0.5, 2.0)
SEVERITY = 0.25


def score_rows(args) -> list[dict]:
    rows = []
    for scene in protocol.SPLITS[args.split]:
        started = time.perf_counter()
        clean = scene.clip(args.tracks)
        variants = [("", clean)] + [(kind, perturb_clip(clean, kind, SEVERITY, seed=scene.seed)) for kind in PERTURBATIONS]
        batch = []
        for (m, model), (l, px), draw in itertools.product(enumerate(MODELS), enumerate(LEVELS), range(args.draws)):
            noise, seed = NOISE_MODELS[model].replace(px=px), ((scene.seed * 10 + m) * 10 + l) * 1000 + draw
            batch += [(model, px, draw, kind, add_noise(clip, noise, seed)) for kind, clip in variants]
        result = score_batch([b[-1] for b in batch], progress=False)
        for (model, px, draw, kind, _), clip in zip(batch, result.clips):
            rows.append(dict(scene=scene.name, model=model, noise_px=px, draw=draw, kind=kind, sgc=clip.sgc,
                             **clip.components, **clip.floors))
        print(f"{scene.name}: {len(batch)} clips in {time.perf_counter() - started:.0f} s", file=sys.stderr, flush=True)
    return rows


def column(rows: list[dict], key: str) -> np.ndarray:
    return np.array([r[key] for r in rows], np.float64)


def above_all(values: np.ndarray, consistent: np.ndarray) -> float:
    """The share of ``values`` strictly above every consistent draw (a NaN is not above)."""
    return float(np.mean(np.nan_to_num(values, nan=-np.inf) > np.nanmax(consistent)))


def scene_shares(rows: list[dict], kind: str) -> dict[str, float]:
    """One scene's draws under one model and level -> its paired, calm and oracle shares for ``kind``."""
    consistent = sorted((r for r in rows if r["kind"] == ""), key=lambda r: r["draw"])
    perturbed = sorted((r for r in rows if r["kind"] == kind), key=lambda r: r["draw"])
    median = {k: max(np.nanmedian(column(consistent, k)), 1e-12) for k in COMPONENTS}

    def log_ratios(draws):  # the oracle's sum over the five components
        return sum(np.log(np.maximum(column(draws, k), 1e-12) / median[k]) for k in COMPONENTS)

    paired = np.nan_to_num(column(perturbed, "sgc"), nan=-1.0) > np.nan_to_num(column(consistent, "sgc"), nan=0.0)
    return dict(paired=float(np.mean(paired)),
                calm=above_all(column(perturbed, "sgc"), column(consistent, "sgc")),
                best=max(above_all(column(perturbed, k), column(consistent, k)) for k in COMPONENTS),
                combined=above_all(log_ratios(perturbed), log_ratios(consistent)),
                largest=float(np.nanmax(column(consistent, "sgc"))))


def print_table(rows: list[dict]) -> None:
    scenes = sorted({r["scene"] for r in rows})
    draws = len({r["draw"] for r in rows})
    print(f"{len(scenes)} scenes, {draws} draws each; perturbations at {SEVERITY:g}; shares are means over scenes")
    print("| noise model | px | perturbation | shipped SGC, paired (as validation.py) | shipped SGC, above every "
          "consistent draw | oracle, best component | oracle, five components | largest consistent SGC |")
    print("|---|---|---|---|---|---|---|---|")
    for model, px, kind in itertools.product(MODELS, LEVELS, PERTURBATIONS):
        cell = [r for r in rows if r["model"] == model and r["noise_px"] == px]
        if not cell:
            continue
        shares = [scene_shares([r for r in cell if r["scene"] == s], kind) for s in scenes]
        mean = {k: np.mean([s[k] for s in shares]) for k in shares[0]}
        print(f"| {model} | {px:g} | {kind} | {mean['paired']:.0%} | {mean['calm']:.0%} | {mean['best']:.0%} | "
              f"{mean['combined']:.0%} | {max(s['largest'] for s in shares):.3f} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--split", default="test", choices=sorted(protocol.SPLITS))
    parser.add_argument("--draws", type=int, default=12, help="noise draws per scene, model and level")
    parser.add_argument("--tracks", type=int, default=1000)
    parser.add_argument("--out", default=None, help="CSV of every clip's score, components and floors")
    parser.add_argument("--rows", default=None, help="print the table from this CSV instead of scoring")
    args = parser.parse_args()
    rows = protocol.rows_scored_or_read(args.rows, args.out, lambda: score_rows(args), ("scene", "model", "kind"), ("draw",))
    print(f"split {args.split}, {args.tracks} tracks")
    print_table(rows)


if __name__ == "__main__":
    main()
