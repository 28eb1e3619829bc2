"""The evidence levels (issue 59, docs/semantics.md §3.11): how much a pair must measure for the
score to see the perturbations at severity 0.25, fitted on the FIT split.

    python bench/evidence_levels.py [--split fit|test] [--levels 0.5 2] [--sweeps tracks parallax static]
                                     [--out rows.csv] [--rows rows.csv]

Three sweeps over the split's scenes, each moving one kind of evidence while the others stay ample
(noise: iid-both, independent Gaussian on both ends of every track, at each level):

- tracks: 50-1,000 tracks per pair;
- parallax: the camera's translation per frame scaled by 0-1 (its rotation kept; 0 a pure rotation);
- static: the static mask cut to a band of 10-100 % of the rows, the tracks per pair raised so
  that about 1,000 fall in the band (at most 4,096 per pair: the thinnest bands hold fewer).

Each point scores the consistent scene and each perturbation at 0.25 (same noise draw) and prints,
beside the clean clips' median evidence value (``pose_tracks``, ``parallax_px``, ``static_frac``),
the *response* (the perturbed clip's SGC minus its consistent twin's; median over scenes, levels
and the three perturbations, then over scenes and levels for each perturbation), the share where it
is above 0 and above 0.05, and the clean clips' median SGC. A level is the clean clips' median
evidence value at the sweep's first point whose response reaches half the response at its fullest
point (1,000 tracks, the scene's own motion, the whole frame static).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time

import numpy as np

from sgc_jax import score_batch
from sgc_jax.research import protocol
from sgc_jax.research.noise import NOISE_MODELS, add_noise
from sgc_jax.research.perturb import PERTURBATIONS, perturb_clip

SEVERITY = 0.25
SWEEPS = {
    "tracks": (50, 100, 150, 200, 300, 500, 1000),
    "parallax": (0.0, 0.03, 0.1, 0.2, 0.35, 0.5, 0.7, 1.0),
    "static": (0.1, 0.2, 0.3, 0.45, 0.6, 0.8, 1.0),
}
MEASURE = {"tracks": "pose_tracks", "parallax": "parallax_px", "static": "static_frac"}
AMPLE_TRACKS = 1000
MAX_TRACKS = 4096  # the protocol's largest count: the thinnest bands hold fewer than AMPLE_TRACKS
HALF = 0.5  # a level's response, against the response at the sweep's fullest point


def band(clip, frac: float):
    """The clip with its static mask cut to the central ``frac`` of its rows."""
    H = clip.static_mask.shape[1]
    rows = max(1, round(frac * H))
    top = (H - rows) // 2
    keep = np.zeros(H, bool)
    keep[top:top + rows] = True
    return dataclasses.replace(clip, static_mask=clip.static_mask & keep[None, :, None], mask_source="band")


def exact_clip(scene, sweep: str, value: float):
    if sweep == "tracks":
        return scene.clip(int(value))
    if sweep == "parallax":
        moved = dataclasses.replace(scene, spec={**scene.spec, "trans_per_frame": scene.spec["trans_per_frame"] * value})
        return moved.clip(AMPLE_TRACKS)
    H, W = scene.spec["height"], scene.spec["width"]
    return band(scene.clip(min(H * W, MAX_TRACKS, round(AMPLE_TRACKS / value))), value)


def score_rows(args) -> list[dict]:
    rows = []
    for scene in protocol.SPLITS[args.split]:
        started = time.perf_counter()
        batch = []
        for sweep in args.sweeps:
            for value in SWEEPS[sweep]:
                clean = exact_clip(scene, sweep, value)
                variants = [(clean, "")] + [(perturb_clip(clean, k, SEVERITY, seed=scene.seed), k) for k in PERTURBATIONS]
                for level in args.levels:
                    model = NOISE_MODELS["iid-both"].replace(px=level)
                    seed = scene.seed * 1000 + int(level * 100)
                    batch += [(sweep, value, level, kind, add_noise(c, model, seed)) for c, kind in variants]
        result = score_batch([b[-1] for b in batch], progress=False)
        for (sweep, value, level, kind, _), c in zip(batch, result.clips):
            rows.append(dict(scene=scene.name, sweep=sweep, value=value, noise_px=level, kind=kind, sgc=c.sgc,
                             status=c.status, evidence=c.evidence, pose_tracks=c.pose_tracks,
                             parallax_px=c.parallax_px, static_frac=c.static_frac))
        print(f"{scene.name}: {len(batch)} clips in {time.perf_counter() - started:.0f} s", file=sys.stderr, flush=True)
    return rows


def responses(rows: list[dict], kind: str | None = None) -> np.ndarray:
    """Each perturbed clip's SGC minus its consistent twin's (NaN counts 0); ``kind``: one
    perturbation's only."""
    clean = {(r["scene"], r["noise_px"]): r["sgc"] for r in rows if r["kind"] == ""}
    return np.array([np.nan_to_num(r["sgc"]) - np.nan_to_num(clean[(r["scene"], r["noise_px"])])
                     for r in rows if r["kind"] and kind in (None, r["kind"])])


def print_sweeps(rows: list[dict]) -> None:
    for sweep, values in SWEEPS.items():
        if not any(r["sweep"] == sweep for r in rows):
            continue
        measure = MEASURE[sweep]
        print(f"\n{sweep}: the perturbations at {SEVERITY} against the clean clips' {measure}")
        print(f"| {sweep} | median {measure} | median response | above 0 | above 0.05 | clean median SGC | "
              + " | ".join(PERTURBATIONS) + " |")
        print("|---|---|---|---|---|---|" + "---|" * len(PERTURBATIONS))
        medians, measured = [], []
        for value in values:
            point = [r for r in rows if r["sweep"] == sweep and r["value"] == value]
            clean = [r for r in point if r["kind"] == ""]
            response = responses(point)
            measured.append(float(np.nanmedian([r[measure] for r in clean])))
            medians.append(float(np.median(response)))
            print(f"| {value:g} | {measured[-1]:.3g} | {medians[-1]:.3f} | {np.mean(response > 0):.0%} | "
                  f"{np.mean(response > 0.05):.0%} | {np.nanmedian([r['sgc'] for r in clean]):.3f} | "
                  + " | ".join(f"{np.median(responses(point, kind)):.3f}" for kind in PERTURBATIONS) + " |")
        reached = [m for m, x in zip(measured, medians) if x >= HALF * medians[-1]]
        print(f"level (half the fullest point's response {medians[-1]:.3f}): {measure} = {reached[0]:.3g}"
              + (" (the sweep's first point: no level within it)" if reached[0] == measured[0] else ""))


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--split", choices=sorted(protocol.SPLITS), default="fit")
    parser.add_argument("--levels", type=float, nargs="+", default=[0.5, 2.0])
    parser.add_argument("--sweeps", nargs="+", choices=sorted(SWEEPS), default=list(SWEEPS))
    parser.add_argument("--out", help="write the rows to this CSV")
    parser.add_argument("--rows", help="print the tables from a CSV written with --out")
    args = parser.parse_args(argv)
    rows = protocol.rows_scored_or_read(args.rows, args.out, lambda: score_rows(args), ("scene", "sweep", "kind", "status"))
    print(f"split {args.split}, noise iid-both at {args.levels} px")
    print_sweeps(rows)


if __name__ == "__main__":
    main()
