"""A candidate floor for errors nearby tracks share (issue 58): the reference engine with the
floors' block covariance (docs/semantics.md §3.10) replaced by a propagated one, on FIT scenes.

    python bench/correlated_floors.py [--scenes 2] [--correlation-px 16] [--tracks 1000] [--shares | --pooled]

The candidate, per accepted pose on its m inliers (pixels u_a in frame i, residuals e_a, Jacobian
rows J_a, A = (JᵀJ)⁻¹ as in §3.3):

1. the residuals' semivariogram over pairs of inliers closer than 2ℓ, g_ab = |e_a − e_b|² / 4 per
   coordinate, fitted by least squares as ν + ψ (1 − exp(−d²/2ℓ²)) (ν, ψ ≥ 0): an error of its own
   (ν) and one shared with correlation exp(−d²/2ℓ²) (ψ). Differences of nearby residuals do not
   see what the pose's own fit absorbed, which the block sums of the current floor miss;
2. Σ_ab = ψ exp(−d_ab²/2ℓ²) + ν δ_ab, and the pose covariance A (Σ_ab Σ_ab J_aᵀ J_b) A.

ℓ is given (``--correlation-px``), not estimated: from one pair's residuals a shared error of
length ℓ cannot be told from a smooth misfit of the region (only ψ/ℓ² is seen at short lags).
Prints, per scene, noise model, level and kind (clean, warp and squeeze at 0.25), SGC and each pose
component over its floor, under the current floors and the candidate. O(m²) per region: the JAX
engine would need it without the pairwise matrix (a grid or a neighbour list).

With ``--shares``: per clip, ν and ψ fitted without the bound at 0 and pooled over the clip's
regions (weighted by their pairs of nearby inliers), the shared share ψ / (ν + ψ), and the mean of ψ
bounded at 0 region by region as step 1 has it: how much the bound alone lifts ψ under independent
errors, and how much of a perturbation's misfit a pooled ψ would read as shared error. With
``--pooled``: the candidate with that pooled share ψ / (ν + ψ) applied to every region's own total.
"""

from __future__ import annotations

import argparse
import itertools

import numpy as np

import sgc_jax.engines.reference as reference
from sgc_jax import COMPONENTS, score_batch
from sgc_jax.engines.reference.pose_search import residual_jacobian
from sgc_jax.research.protocol import FIT_SCENES, Cell, cell_clips

POSE_COMPONENTS = COMPONENTS[:4]
CURRENT_BLOCK_COVARIANCE = reference.block_covariance


def propagated_covariance(correlation_px: float, shared_share: float | None = None):
    """A ``reference.block_covariance`` stand-in: the candidate's (6, 6) covariance (module docstring).
    ``shared_share``: ψ / (ν + ψ) pooled over the clip (``--pooled``), applied to each region's own
    total ν + ψ (at least its residual variance) instead of its ν, ψ bounded at 0."""

    def covariance(X, uv, K, R, t, block_px):
        n = len(X)
        if n < 4:
            return np.full((6, 6), np.nan)
        residuals, J = residual_jacobian(X, uv, K, R, t)
        e = np.stack([residuals[:n], residuals[n:]], axis=1)
        A = np.linalg.pinv(J.T @ J)
        d = np.linalg.norm(uv[:, None] - uv[None], axis=-1)
        shared = np.exp(-d ** 2 / (2 * correlation_px ** 2))
        own_var, shared_var = np.sum(e ** 2) / max(2 * n - 6, 1), 0.0
        fitted = semivariogram_fit(e, d, correlation_px)
        if fitted is not None and shared_share is not None:
            total = max(fitted[0] + fitted[1], own_var)
            own_var, shared_var = (1.0 - shared_share) * total, shared_share * total
        elif fitted is not None:
            own_var, shared_var = np.maximum(fitted[:2], 0.0)
        sigma = shared_var * shared + own_var * np.eye(n)
        rows = np.stack([J[:n], J[n:]], axis=1)  # (n, 2, 6)
        return A @ np.einsum("aci,ab,bcj->ij", rows, sigma, rows) @ A

    return covariance


def semivariogram_fit(e, d, correlation_px: float):
    """(ν, ψ, pairs used) of step 1 without the bound at 0, from residuals e (n, 2) and pixel
    distances d (n, n); None with fewer than 10 pairs of inliers closer than 2ℓ."""
    a, b = np.triu_indices(len(e), 1)
    near = d[a, b] < 2 * correlation_px
    if near.sum() < 10:
        return None
    semivariance = np.sum((e[a] - e[b]) ** 2, axis=1)[near] / 4
    design = np.column_stack([np.ones(near.sum()), 1 - np.exp(-d[a, b][near] ** 2 / (2 * correlation_px ** 2))])
    own_var, shared_var = np.linalg.lstsq(design, semivariance, rcond=None)[0]
    return own_var, shared_var, int(near.sum())


def recording_fits(correlation_px: float, fits: list):
    """The current floors' covariance, appending each region's ``semivariogram_fit`` to ``fits``."""

    def covariance(X, uv, K, R, t, block_px):
        if len(X) >= 4:
            residuals, _ = residual_jacobian(X, uv, K, R, t)
            e = np.stack([residuals[:len(X)], residuals[len(X):]], axis=1)
            fitted = semivariogram_fit(e, np.linalg.norm(uv[:, None] - uv[None], axis=-1), correlation_px)
            if fitted is not None:
                fits.append(fitted)
        return CURRENT_BLOCK_COVARIANCE(X, uv, K, R, t, block_px)

    return covariance


def pooled_fit(clip, correlation_px: float) -> tuple[float, float, float, int]:
    """The clip's regions' ``semivariogram_fit`` pooled (weighted by their pairs of nearby inliers):
    (ν, ψ, the mean of ψ bounded at 0 region by region, regions)."""
    fits: list = []
    score([clip], recording_fits(correlation_px, fits))
    own, shared, pairs = np.array(fits).T
    return (float(np.average(own, weights=pairs)), float(np.average(shared, weights=pairs)),
            float(np.maximum(shared, 0.0).mean()), len(fits))


def pooled_share(clip, correlation_px: float) -> float:
    """ψ / (ν + ψ) of ``pooled_fit``, in [0, 1]."""
    nu, psi, _, _ = pooled_fit(clip, correlation_px)
    return float(np.clip(psi / (nu + psi), 0.0, 1.0))


def print_shares(args) -> None:
    print("| scene | noise | px | kind | regions | pooled ν | pooled ψ | ψ / (ν + ψ) | ψ bounded region by region, mean |")
    print("|---|---|---|---|---|---|---|---|---|")
    for scene, model, px in itertools.product(FIT_SCENES[:args.scenes], ("iid-both", "correlated"), (0.5, 2.0)):
        clips = cell_clips(Cell(scene, model, px, args.tracks), inconsistencies=("warp", "squeeze"), severities=(0.25,))
        for clip, kind, _ in clips:
            nu, psi, bounded, regions = pooled_fit(clip, args.correlation_px)
            print(f"| {scene.name} | {model} | {px:g} | {kind or 'clean'} | {regions} | {nu:.4f} | {psi:.4f} | "
                  f"{psi / (nu + psi):.3f} | {bounded:.4f} |", flush=True)


def score(clips, covariance):
    reference.block_covariance = covariance
    try:
        return score_batch(clips, engine="reference", progress=False).clips
    finally:
        reference.block_covariance = CURRENT_BLOCK_COVARIANCE


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=2)
    parser.add_argument("--correlation-px", type=float, default=16.0)
    parser.add_argument("--tracks", type=int, default=1000)
    parser.add_argument("--shares", action="store_true", help="print the pooled shared share per clip instead")
    parser.add_argument("--pooled", action="store_true", help="the candidate with the clip's pooled shared share")
    args = parser.parse_args()
    if args.shares:
        print_shares(args)
        return
    print("| scene | noise | px | kind | SGC now | SGC candidate | observed / floor now | observed / floor candidate |")
    print("|---|---|---|---|---|---|---|---|")
    for scene, model, px in itertools.product(FIT_SCENES[:args.scenes], ("iid-both", "correlated"), (0.5, 2.0)):
        clips = cell_clips(Cell(scene, model, px, args.tracks), inconsistencies=("warp", "squeeze"), severities=(0.25,))
        now = score([c for c, _, _ in clips], CURRENT_BLOCK_COVARIANCE)
        if args.pooled:
            candidate = [score([c], propagated_covariance(args.correlation_px, pooled_share(c, args.correlation_px)))[0]
                         for c, _, _ in clips]
        else:
            candidate = score([c for c, _, _ in clips], propagated_covariance(args.correlation_px))
        for (_, kind, _), a, b in zip(clips, now, candidate):
            ratios = [" ".join(f"{r.components[k] / r.floors[f'{k}_floor']:.2f}" for k in POSE_COMPONENTS)
                      for r in (a, b)]
            print(f"| {scene.name} | {model} | {px:g} | {kind or 'clean'} | {a.sgc:.3f} | {b.sgc:.3f} | "
                  f"{ratios[0]} | {ratios[1]} |", flush=True)


if __name__ == "__main__":
    main()
