"""How closely the engines agree on issue 20's agreement corpus, and how closely each agrees with
itself under another seed (the ceiling of any cross-engine figure).

    python bench/engine_agreement.py [--seeds 0 1] [--reference-hypotheses 300]

Scores the 30 clips of ``sgc_jax.research.agreement.agreement_corpus`` with both engines
(``compat="spec"``) under each seed, and the reference again with more RANSAC hypotheses (30 P3P
triples per hypothesis, so 300 draws 9000 triples against the default's 3000), then prints one
row per comparison of a and b: (clip, component) cases within tolerance (relative to a's value),
Spearman rho of SGC, regions of the same status, and of the regions both posed, the ones whose
poses lie more than 1 deg apart and which side of each is the worse optimum (higher truncated
cost at the cut).
"""

from __future__ import annotations

import argparse
import time

from sgc_jax import SGCConfig, score_batch
from sgc_jax.research.agreement import agreement_corpus, compare

COLUMNS = ("a", "b", "components within", "Spearman rho", "same status", "posed", "> 1 deg apart",
           "a worse", "b worse")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs=2, default=(0, 1))
    parser.add_argument("--reference-hypotheses", type=int, default=300,
                        help="the reference's harder search (0: leave it out)")
    args = parser.parse_args()
    clips = agreement_corpus()
    scored = {}

    def score(name, engine, **config):
        start = time.perf_counter()
        scored[name] = score_batch(clips, engine=engine, config=SGCConfig(**config), progress=False)
        print(f"{name}: {time.perf_counter() - start:.1f} s", flush=True)

    s0, s1 = args.seeds
    for seed in args.seeds:
        score(f"reference seed {seed}", "reference", seed=seed)
        score(f"jax seed {seed}", "jax", seed=seed)
    # a is the base of the relative tolerance: the reference, or the first seed
    rows = [(f"reference seed {s0}", f"jax seed {s0}"), (f"reference seed {s1}", f"jax seed {s1}"),
            (f"reference seed {s0}", f"reference seed {s1}"), (f"jax seed {s0}", f"jax seed {s1}")]
    if args.reference_hypotheses:
        hard = f"reference x{args.reference_hypotheses} hypotheses seed"
        for seed in args.seeds:
            score(f"{hard} {seed}", "reference", seed=seed, ransac_hypotheses=args.reference_hypotheses)
        rows += [(f"{hard} {s0}", f"{hard} {s1}"), (f"{hard} {s0}", f"reference seed {s0}"),
                 (f"{hard} {s0}", f"jax seed {s0}")]
    print()
    print("| " + " | ".join(COLUMNS) + " |")
    print("|" + "---|" * len(COLUMNS))
    for a, b in rows:
        f = compare(clips, scored[a], scored[b])
        print(f"| {a} | {b} | {f.components_within}/{f.components} ({f.component_share:.0%}) | {f.spearman:.4f} | "
              f"{f.same_status}/{f.regions} ({f.status_share:.1%}) | {f.posed} | {f.differ} | {f.a_worse} | {f.b_worse} |")


if __name__ == "__main__":
    main()
