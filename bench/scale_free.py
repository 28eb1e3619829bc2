"""Evidence for the scale-free default semantics (issue 17), printed as Markdown (bench/history/issue-17.md).

1. Units: a rigid scene seen through 0.5 px track noise, with depth and t_wc scaled together
   (0.01 ... 100) and t_wc alone (0.02, 37): SGC and the largest relative change of a component,
   per engine, under compat="spec" and compat="authors".
2. Masked moving objects: three rigid scenes scored with and without moving objects (masked):
   the depth error's ratio with the spec warp (static source) and the authors' warp (every pixel).
3. The demo corpus: SGC per clip and engine under the defaults, and whether each demo claim holds.
4. The calibration corpus (with ``--scores``, the CSV that ``python -m sgc_jax.research.spec_calibration
   --scores`` writes): medians per perturbation kind and severity, and how each perturbed clip
   orders against its clean scene.

    python bench/scale_free.py [--only units|objects|demo|corpus] [--scores corpus.csv]
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np

import sgc_jax
from sgc_jax import score_batch
from sgc_jax.calibration import COMPONENTS, Calibration
from sgc_jax.research.synth import demo_claims, demo_corpus, synth_clip

SCENE = dict(n_layers=3, static_spheres=4, height=96, width=128, n_tracks=1024, n_frames=8)
ENGINES = ("jax", "reference")


def rescaled(clip, depth_factor, pose_factor, dtype=np.float64):
    """Depth scaled in ``dtype`` (float64: the same data; float32: rounded again, as a stored file)."""
    return dataclasses.replace(clip, clip_id=f"{clip.clip_id} x{depth_factor:g}/{pose_factor:g}",
                               depth=(clip.depth.astype(dtype) * dtype(depth_factor)).astype(dtype),
                               t_wc=clip.t_wc * pose_factor)


def units_table() -> None:
    base = synth_clip(seed=1, clip_id="rigid", noise_px=0.5, **SCENE)
    factors = [(1, 1, np.float64), *((s, s, dtype) for dtype in (np.float64, np.float32)
                                     for s in (0.01, 0.1, 10, 100)), (1, 0.02, np.float64), (1, 37, np.float64)]
    clips = [rescaled(base, d, p, dtype) for d, p, dtype in factors]
    print("| engine | compat | depth x / t_wc x (depth scaled in) | SGC | largest relative change of a component |")
    print("|---|---|---|---|---|")
    for engine in ENGINES:
        for compat in ("spec", "authors"):
            # authors' raw units are scored with the paper's calibration, as published
            result = score_batch(clips, engine=engine, compat=compat)
            ref = result.clips[0]
            for (d, p, dtype), scored in zip(factors, result.clips):
                change = max(abs(scored.components[k] - ref.components[k]) / max(abs(ref.components[k]), 1e-12)
                             for k in COMPONENTS)
                print(f"| {engine} | {compat} | {d:g} / {p:g} ({np.dtype(dtype).name}) | {scored.sgc:.4f} | "
                      f"{change:.2e} |")


def objects_table() -> None:
    print("| engine | scene | depth error without / with objects, spec (%) | ratio | authors' warp ratio |")
    print("|---|---|---|---|---|")
    for engine in ENGINES:
        for seed in (2, 4, 8):
            still = synth_clip(seed=seed, clip_id=f"still{seed}", **SCENE)
            moving = synth_clip(seed=seed, clip_id=f"moving{seed}", moving_objects=3, **SCENE)
            spec = [c.components["depth_error"] for c in score_batch([still, moving], engine=engine).clips]
            authors = [c.components["depth_error"] for c in score_batch(
                [still, moving], engine=engine, compat="authors").clips]
            print(f"| {engine} | seed {seed} | {spec[0]:.3f} / {spec[1]:.3f} | {spec[1] / spec[0]:.2f} | "
                  f"{authors[1] / authors[0]:.2f} |")


def demo_table() -> None:
    corpus = demo_corpus()
    results = {engine: score_batch(corpus, engine=engine) for engine in ENGINES}
    print("| clip | " + " | ".join(f"SGC {e}" for e in ENGINES) + " |")
    print("|---|" + "---|" * len(ENGINES))
    for i, clip in enumerate(corpus):
        print(f"| {clip.clip_id} | " + " | ".join(f"{results[e].clips[i].sgc:.3f}" for e in ENGINES) + " |")
    for engine, result in results.items():
        for claim, holds in demo_claims({c.clip_id: c.sgc for c in result.clips}):
            print(f"- {engine}: {'holds' if holds else 'FAILS'}: {claim}")


def corpus_table(scores_csv: str) -> None:
    import pandas as pd

    rows = pd.read_csv(scores_csv, keep_default_na=False, na_values=[""])
    rows["kind"] = rows["kind"].fillna("")
    rows["scene"] = rows["clip_id"].str.split("~").str[0]
    print("| kind | severity | SGC median (min-max) | " + " | ".join(COMPONENTS) + " |")
    print("|---|---|---|" + "---|" * len(COMPONENTS))
    for (kind, severity), part in rows.groupby(["kind", "severity"]):
        print(f"| {kind or 'clean'} | {severity:g} | {part.sgc.median():.3f} ({part.sgc.min():.3f}-"
              f"{part.sgc.max():.3f}) | " + " | ".join(f"{part[k].median():.3g}" for k in COMPONENTS) + " |")
    clean = rows[rows.kind == ""].set_index("scene").sgc
    perturbed = rows[rows.kind != ""]
    above = perturbed.sgc.to_numpy() > clean.loc[perturbed.scene].to_numpy()
    print(f"\nclean SGC: max {clean.max():.3f}, {int((clean == 0).sum())} of {len(clean)} exactly 0; perturbed "
          f"strictly above their clean scene: {int(above.sum())} of {len(perturbed)}")
    for clip_id in perturbed.clip_id[~above]:
        print(f"- not above: {clip_id}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--only", choices=("units", "objects", "demo", "corpus"))
    parser.add_argument("--scores", help="the calibration corpus's scores "
                        "(python -m sgc_jax.research.spec_calibration --scores)")
    args = parser.parse_args()
    sgc_jax.enable_compilation_cache()
    print(f"calibration: {Calibration.load('sgc-spec-2026').name} (spec), sgc-paper-2026 (authors)\n")
    tables = [("units", units_table), ("objects", objects_table), ("demo", demo_table)]
    if args.scores:
        tables.append(("corpus", lambda: corpus_table(args.scores)))
    elif args.only == "corpus":
        parser.error("--only corpus needs --scores")
    for name, table in tables:
        if args.only in (None, name):
            print(f"### {name}\n")
            table()
            print()


if __name__ == "__main__":
    main()
