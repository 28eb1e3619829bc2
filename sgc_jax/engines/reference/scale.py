"""The clip's translation scale s (docs/semantics.md §3.4): a truncated L1 fit over every pair's equations."""

from __future__ import annotations

import numpy as np


def scale_equations(members: list[tuple[np.ndarray, np.ndarray]], K: np.ndarray, R_g: np.ndarray,
                    t_g: np.ndarray) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Per pair, the roots and slopes of its lines in s (docs/semantics.md §3.4): each region point X
    (camera pair-1) observed at uv in frame pair, with n = K^-1 (u, v, 1) and Y = R_g X, must satisfy
    n_k (Y_3 + s t_3) = Y_k + s t_k on both image axes k, a line in s with the root b / a and the slope
    |a| f_k / Y_3 in pixels per unit of s (a = n_k t_3 - t_k, b = Y_k - n_k Y_3). ``members[p]`` (X, uv),
    ``K`` (T, 3, 3), ``R_g`` / ``t_g`` per pair."""
    roots, slopes = [], []
    for p, (X, uv) in enumerate(members):
        pair_roots, pair_slopes = [np.zeros(0)], [np.zeros(0)]
        if len(X):
            Y = X @ R_g[p].T
            n = (np.linalg.inv(K[p + 1].astype(np.float64)) @ np.column_stack([uv, np.ones(len(uv))]).T).T
            for k, focal in ((0, K[p + 1][0, 0]), (1, K[p + 1][1, 1])):
                a = n[:, k] * t_g[p][2] - t_g[p][k]
                b = Y[:, k] - n[:, k] * Y[:, 2]
                ok = (Y[:, 2] > 0) & (a != 0)
                pair_roots.append(b[ok] / a[ok])
                pair_slopes.append(np.abs(a[ok]) * focal / Y[ok, 2])
        roots.append(np.concatenate(pair_roots))
        slopes.append(np.concatenate(pair_slopes))
    return roots, slopes


def fit_translation_scale(members: list[tuple[np.ndarray, np.ndarray]], K: np.ndarray, R_g: np.ndarray,
                          t_g: np.ndarray, cut_px: float, fallback: float = 1.0) -> float:
    """Robust s with which (R_g, s t_g) best explains the static tracks (docs/semantics.md §3.4): from
    the start of lowest truncated cost (sum of min(slope |s - root|, cut_px)) among the slope-weighted
    and the plain median of every pair's roots together and of each pair's own
    (``scale_equations``), s is the weighted median of the lines within cut_px of it, or 0 where that
    is negative; ``fallback`` when no line has a slope."""
    roots, slopes = scale_equations(members, K, R_g, t_g)
    every_root, every_slope = np.concatenate(roots), np.concatenate(slopes)
    overall = weighted_median(every_root, every_slope, fallback)
    starts = [overall, weighted_median(every_root, np.ones_like(every_slope), overall)]
    starts += [weighted_median(r, w, overall) for r, w in zip(roots, slopes)]
    starts += [weighted_median(r, np.ones_like(w), overall) for r, w in zip(roots, slopes)]
    costs = [np.minimum(every_slope * np.abs(start - every_root), cut_px).sum() for start in starts]
    start = starts[int(np.argmin(costs))]
    near = every_slope * np.abs(start - every_root) < cut_px
    return max(weighted_median(every_root[near], every_slope[near], start), 0.0)


def weighted_median(values: np.ndarray, weights: np.ndarray, fallback: float) -> float:
    """The smallest value whose cumulative weight (in ascending order) reaches half the total;
    ``fallback`` when the total is 0."""
    if not weights.sum() > 0:
        return float(fallback)
    order = np.argsort(values, kind="stable")
    cumulative = np.cumsum(weights[order])
    return float(values[order][np.searchsorted(cumulative, 0.5 * cumulative[-1])])
