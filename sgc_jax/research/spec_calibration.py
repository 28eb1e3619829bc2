"""The shipped ``compat="spec"`` calibration ``sgc-spec-2026``: its corpus and its fit (docs/semantics.md §5.4).

    python -m sgc_jax.research.spec_calibration --out sgc_jax/calibration/sgc-spec-2026.json

The corpus is synthetic and reproducible: rigid static scenes (:func:`sgc_jax.research.synth.synth_clip`)
at two resolutions, three camera motions and three depth scales, seen by a tracker with 0.5 px
noise, each clean and under the three perturbation kinds of :mod:`sgc_jax.research.perturb` at severities
0.25 to 1. The fit keeps the paper's formula (log1p, z-score, min-max, PC1 weights) and anchors
its two ends in words:

- ``z_min`` of each component is the 90th percentile of the clean clips' z, so a clean rigid
  scene scores 0 or nearly (90% of the corpus's clean clips exactly 0 on each component);
- ``z_max`` is the largest, over perturbation kinds, of the median z of that kind's severity-1
  clips: M'' = 1 is "as inconsistent as a full-severity perturbation, on the component it moves most";
- weights are ``sgc-paper-2026``'s: how the components co-vary on real generated video (the
  paper's PC1 over 1196 videos), which a corpus of perturbations that each target one component
  cannot measure. Normalised components are unit-free, so the weights carry over.
"""

from __future__ import annotations

import argparse
import sys
from typing import Sequence

import numpy as np

from ..calibration import COMPONENTS, LOG1P_COMPONENTS, Calibration
from ..io.clip import Clip
from .perturb import PERTURBATIONS, perturb_clip
from .synth import synth_clip

NAME = "sgc-spec-2026"
RESOLUTIONS = ((96, 128, 1024), (144, 192, 2048))  # H, W, tracks per pair
MOTIONS = ((0.5, 0.05), (1.5, 0.15), (3.0, 0.3))  # (deg, depth units) per frame at scale 1
DEPTH_SCALES = (0.1, 1.0, 10.0)  # the scene, its camera path and its depth scaled together
SEEDS = (0, 1)
SEVERITIES = (0.25, 0.5, 0.75, 1.0)
TRACK_NOISE_PX = 0.5  # a good tracker's error: part of "clean", not an inconsistency
CLEAN_QUANTILE = 90  # z_min: this percentile of the clean clips
WEIGHTS_FROM = "sgc-paper-2026"  # the weights' source (module docstring)
SCENE = dict(n_frames=8, n_layers=3, static_spheres=4)


def clean_scenes() -> list[Clip]:
    """The clean clips: every resolution x motion x seed, each at one of the depth scales in turn."""
    clips = []
    for (H, W, tracks) in RESOLUTIONS:
        for m, (rot, trans) in enumerate(MOTIONS):
            for seed in SEEDS:
                scale = DEPTH_SCALES[(m + seed) % len(DEPTH_SCALES)]
                clip_id = f"spec-{H}x{W}-m{m}-s{seed}"
                clips.append(synth_clip(seed=seed, clip_id=clip_id, group=f"{H}x{W}", height=H, width=W,
                                        n_tracks=tracks, rot_deg_per_frame=rot, trans_per_frame=trans * scale,
                                        depth_range=(2.0 * scale, 12.0 * scale), noise_px=TRACK_NOISE_PX,
                                        **SCENE))
    return clips


def calibration_corpus() -> list[tuple[Clip, str, float]]:
    """(clip, perturbation kind or "" for clean, severity) for every clip of the corpus."""
    corpus = []
    for clip in clean_scenes():
        corpus.append((clip, "", 0.0))
        corpus += [(perturb_clip(clip, kind, s, seed=0), kind, s) for kind in PERTURBATIONS for s in SEVERITIES]
    return corpus


def fit_spec_calibration(matrix: np.ndarray, kinds: Sequence[str], severities: Sequence[float],
                         name: str = NAME) -> Calibration:
    """The calibration of an (n, 5) component matrix (rows in :data:`COMPONENTS` order) with each
    row's perturbation kind ("" = clean) and severity, by the rule in the module docstring."""
    kinds, severities = np.asarray(kinds), np.asarray(severities, np.float64)
    flags = {k: k in LOG1P_COMPONENTS for k in COMPONENTS}
    p = np.column_stack([np.log1p(np.maximum(matrix[:, j], 0.0)) if flags[k] else matrix[:, j]
                         for j, k in enumerate(COMPONENTS)])
    mu, sigma = np.nanmean(p, axis=0), np.nanstd(p, axis=0, ddof=0)
    z = (p - mu) / np.where(sigma > 0, sigma, 1.0)
    clean = kinds == ""
    if not clean.any():
        raise ValueError("the corpus has no clean rows")
    z_min = np.nanpercentile(z[clean], CLEAN_QUANTILE, axis=0)
    full = [np.nanmedian(z[(kinds == kind) & (severities == severities.max())], axis=0)
            for kind in sorted(set(kinds) - {""})]
    z_max = np.nanmax(np.stack(full), axis=0)
    paper = Calibration.load(WEIGHTS_FROM).weight
    weights = np.array([paper[k] for k in COMPONENTS]) / sum(paper.values())
    return Calibration(
        name=name, log1p=flags, **{field: dict(zip(COMPONENTS, map(float, values))) for field, values in (
            ("mu", mu), ("sigma", sigma), ("z_min", z_min), ("z_max", z_max), ("weight", weights))},
        compat="spec", rows="clips",
        description=(
            "sgc_jax's calibration for compat='spec' (scale-free units: rotation variances deg^2, translation "
            "variances (% of the clip's median static depth)^2, depth error %). Fitted by "
            "`python -m sgc_jax.research.spec_calibration` on synthetic rigid scenes (0.5 px track noise) at "
            "two resolutions, three camera motions and three depth scales, clean and under warp, squeeze and "
            "depth_warp at severities 0.25-1. 0 = a clean rigid scene (z_min: 90th percentile of the clean "
            "clips); 1 = a full-severity perturbation on the component it moves most (z_max: largest median "
            "z over the kinds at severity 1); weights: sgc-paper-2026's (the paper's PC1 over real generated "
            "video)."),
        extra={"n_rows": int(matrix.shape[0]), "n_clean": int(clean.sum()), "corpus": corpus_description()})


def corpus_description() -> dict:
    return {"resolutions": [list(r) for r in RESOLUTIONS], "motions_deg_trans": [list(m) for m in MOTIONS],
            "depth_scales": list(DEPTH_SCALES), "seeds": list(SEEDS), "severities": list(SEVERITIES),
            "kinds": list(PERTURBATIONS), "track_noise_px": TRACK_NOISE_PX, "scene": SCENE,
            "clean_quantile": CLEAN_QUANTILE, "weights_from": WEIGHTS_FROM, "engine": "jax"}


def main(argv: Sequence[str] | None = None) -> int:
    from ..engines.jax_engine.compile_cache import enable_compilation_cache
    from ..scoring.api import score_batch

    parser = argparse.ArgumentParser(prog="python -m sgc_jax.research.spec_calibration", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", required=True, help="calibration JSON to write")
    parser.add_argument("--scores", help="also write the corpus's per-clip scores (CSV) here")
    args = parser.parse_args(argv)
    enable_compilation_cache()
    corpus = calibration_corpus()
    print(f"scoring {len(corpus)} calibration clips with the JAX engine", file=sys.stderr)
    # Any calibration of the right semantics: the fit uses the components only.
    provisional = Calibration(name="provisional", compat="spec", mu=dict.fromkeys(COMPONENTS, 0.0),
                              sigma=dict.fromkeys(COMPONENTS, 1.0), z_min=dict.fromkeys(COMPONENTS, 0.0),
                              z_max=dict.fromkeys(COMPONENTS, 1.0), weight=dict.fromkeys(COMPONENTS, 0.2),
                              log1p=dict.fromkeys(COMPONENTS, True))
    result = score_batch([c for c, _, _ in corpus], calibration=provisional, progress=True)
    failed = [c.clip_id for c in result.clips if c.status == "error"]
    if failed:
        print(f"{len(failed)} calibration clip(s) failed to score: {failed[:5]}", file=sys.stderr)
        return 1
    matrix = np.array([[c.components[k] for k in COMPONENTS] for c in result.clips])
    calibration = fit_spec_calibration(matrix, [k for _, k, _ in corpus], [s for _, _, s in corpus])
    calibration.save(args.out)
    if args.scores:
        from ..io.tables import write_scores

        rows = [{**r, "kind": k, "severity": s} for r, (_, k, s) in zip(result.rescore(calibration).to_records(), corpus)]
        write_scores(args.scores, rows)
    print(f"wrote {args.out}", file=sys.stderr)
    for k in COMPONENTS:
        print(f"{k:<18} mu {calibration.mu[k]:9.4f} sigma {calibration.sigma[k]:9.4f} z_min {calibration.z_min[k]:8.4f}"
              f" z_max {calibration.z_max[k]:8.4f} weight {calibration.weight[k]:.4f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
