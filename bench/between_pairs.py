"""Shared tracker errors against inconsistencies (issue 58): how far each scatters the local poses,
and a floor taken from how the poses change between pairs (docs/semantics.md §3.10, §7.4).

    python bench/between_pairs.py [--split fit|test] [--tracks 1000] [--models iid-both correlated]
                                  [--levels 0.5 2]

Every scene of the split (sgc_jax.research.protocol) under each noise model and level, consistent
and with each inconsistency at severities 0.1 and 0.25 (the protocol's cells, JAX engine, default
config and calibration). Two tables:

1. the median of each pose component per (model, level, kind): which inconsistency scatters the
   poses as much as a noise model does;
2. a candidate floor. A tracker's errors are drawn anew for every pair, a generator's inconsistency
   persists, so how much each depth layer's pose changes between pairs estimates the noise the
   poses actually carry: its ratio kappa to what the fits' own noise gives that change
   (sgc_jax.research.pose_jitter) scales the floor where it exceeds 1. Per
   (model, kind, severity): the median observed / floor now and with kappa, and the share of cells
   where the excess over 1.25 x floor (rotation plus translation, local components) is above the
   consistent twin's, now and with kappa.
"""

from __future__ import annotations

import argparse
import itertools
import sys
import time

import numpy as np

from sgc_jax import Calibration, default_calibration, score_batch
from sgc_jax.research import protocol
from sgc_jax.research.pose_jitter import pose_jitter

BAND = Calibration.load(default_calibration("spec")).floor_band  # docs/semantics.md §5.4
COMPONENTS = ("local_rot_var", "local_trans_var", "global_rot_var", "global_trans_var", "depth_error")


def ratios(result) -> dict[str, float]:
    """Observed / floor of the clip's two local components and its pose jitter (kappa)."""
    jitter = pose_jitter(result.pairs)
    out = {"rot_kappa": jitter.rot, "trans_kappa": jitter.trans}
    for part, name in (("rot", "local_rot_var"), ("trans", "local_trans_var")):
        out[f"{part}_ratio"] = result.components[name] / result.floors[f"{name}_floor"]
    return out


def excess(ratio: float, kappa: float = 1.0) -> float:
    return max(0.0, ratio / max(1.0, kappa) - BAND) if np.isfinite(ratio) else 0.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--split", default="fit", choices=sorted(protocol.SPLITS))
    parser.add_argument("--tracks", type=int, default=1000)
    parser.add_argument("--models", nargs="+", default=["iid-both", "correlated"])
    parser.add_argument("--levels", type=float, nargs="+", default=[0.5, 2.0])
    args = parser.parse_args()
    started = time.perf_counter()
    rows = []
    for scene in protocol.SPLITS[args.split]:
        exact = protocol.exact_variants(scene, args.tracks, severities=(0.1, 0.25))
        for model, px in itertools.product(args.models, args.levels):
            variants = protocol.cell_clips(protocol.Cell(scene, model, px, args.tracks), severities=(0.1, 0.25), exact=exact)
            for (_, kind, severity), result in zip(variants, score_batch([c for c, _, _ in variants], progress=False).clips):
                row = dict(scene=scene.name, model=model, px=px, kind=kind or "consistent", severity=severity,
                           sgc=result.sgc, **{c: result.components[c] for c in COMPONENTS})
                rows.append(dict(row, **ratios(result)))
        print(f"{scene.name} done, {time.perf_counter() - started:.0f} s", file=sys.stderr, flush=True)
    print_scatter(rows)
    print_candidate(rows)


def print_scatter(rows: list[dict]) -> None:
    print("\n| model | px | kind | severity | " + " | ".join(COMPONENTS) + " | SGC |")
    print("|---|---|---|---|" + "---|" * (len(COMPONENTS) + 1))
    for key in sorted({(r["model"], r["px"], r["kind"], r["severity"]) for r in rows}):
        cell = [r for r in rows if (r["model"], r["px"], r["kind"], r["severity"]) == key]
        values = " | ".join(f"{np.median([r[c] for r in cell]):.3g}" for c in (*COMPONENTS, "sgc"))
        print(f"| {key[0]} | {key[1]:g} | {key[2]} | {key[3]:g} | {values} |")


def print_candidate(rows: list[dict]) -> None:
    def score(r, with_kappa):
        return sum(excess(r[f"{p}_ratio"], r[f"{p}_kappa"] if with_kappa else 1.0) for p in ("rot", "trans"))

    twins = {(r["scene"], r["model"], r["px"], r["kind"]): r for r in rows if r["kind"] in ("consistent", "mover-masked")}
    print("\n| model | kind | severity | cells | rot observed / floor, now -> with kappa | kappa (rot) "
          "| above the twin: SGC | local excess now | with kappa |")
    print("|---|---|---|---|---|---|---|---|---|")
    for model, kind, severity in sorted({(r["model"], r["kind"], r["severity"]) for r in rows}):
        cell = [r for r in rows if (r["model"], r["kind"], r["severity"]) == (model, kind, severity)]
        ratio = np.median([r["rot_ratio"] for r in cell])
        adjusted = np.median([r["rot_ratio"] / max(1.0, r["rot_kappa"]) for r in cell])
        line = f"| {model} | {kind} | {severity:g} | {len(cell)} | {ratio:.2f} -> {adjusted:.2f} | {np.median([r['rot_kappa'] for r in cell]):.2f}"
        if kind in ("consistent", "mover-masked"):
            calm = [score(r, True) for r in cell]
            print(f"{line} | - | largest {max(score(r, False) for r in cell):.2f} | largest {max(calm):.2f} |")
            continue
        twin = [twins[(r["scene"], model, r["px"], "mover-masked" if kind == "mover" else "consistent")] for r in cell]
        shares = [np.mean([a > b for a, b in zip(x, y)]) for x, y in (
            ([r["sgc"] for r in cell], [t["sgc"] for t in twin]),
            ([score(r, False) for r in cell], [score(t, False) for t in twin]),
            ([score(r, True) for r in cell], [score(t, True) for t in twin]))]
        print(f"{line} | " + " | ".join(f"{s:.0%}" for s in shares) + " |")


if __name__ == "__main__":
    main()
