"""Agreement statistics for score lists (docs/semantics.md §6.5): rank correlations, bootstrap CIs,
min-max scaling.

Pure NumPy. Every paired function drops the pairs where either value is NaN (or missing, ``None``)
before computing, and returns NaN when fewer than two pairs remain or a list is constant, as
``scipy.stats`` does. Ties get average ranks (Spearman) and the tau-b correction (Kendall).
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np


def _as_float(values: Any) -> np.ndarray:
    return np.asarray(values, np.float64).ravel()  # None -> NaN


def paired(a: Any, b: Any) -> tuple[np.ndarray, np.ndarray]:
    """(a, b) as float arrays with the pairs where either is NaN removed; lengths must match."""
    a, b = _as_float(a), _as_float(b)
    if a.shape != b.shape:
        raise ValueError(f"score lists differ in length: {a.size} vs {b.size}")
    keep = ~(np.isnan(a) | np.isnan(b))
    return a[keep], b[keep]


def rankdata(values: Any) -> np.ndarray:
    """Ranks 1..n of a 1-D array, ties given their average rank (``scipy.stats.rankdata``)."""
    values = _as_float(values)
    order = np.argsort(values, kind="mergesort")
    sorted_values = values[order]
    new_group = np.concatenate([[True], sorted_values[1:] != sorted_values[:-1]])
    group = np.cumsum(new_group) - 1
    starts = np.flatnonzero(new_group)
    ends = np.concatenate([starts[1:], [values.size]])
    average = (starts + ends + 1) / 2.0  # mean of the 1-based positions start+1..end
    ranks = np.empty(values.size)
    ranks[order] = average[group]
    return ranks


def pearson(a: Any, b: Any) -> float:
    """Pearson correlation r of the non-NaN pairs (NaN with < 2 pairs or a constant list)."""
    a, b = paired(a, b)
    if a.size < 2:
        return float("nan")
    da, db = a - a.mean(), b - b.mean()
    denom = np.sqrt(np.sum(da * da) * np.sum(db * db))
    return float(np.clip(np.sum(da * db) / denom, -1.0, 1.0)) if denom > 0 else float("nan")


def spearman(a: Any, b: Any) -> float:
    """Spearman rho: Pearson r of the average ranks of the non-NaN pairs."""
    a, b = paired(a, b)
    return pearson(rankdata(a), rankdata(b))


def _tied_pairs(values: np.ndarray) -> float:
    _, counts = np.unique(values, return_counts=True)
    return float(np.sum(counts * (counts - 1) / 2.0))


def kendall_tau(a: Any, b: Any, *, block: int = 1024) -> float:
    """Kendall tau-b of the non-NaN pairs: (C - D) / sqrt((n0 - t_a)(n0 - t_b)).

    C, D: concordant and discordant pairs, n0 = n(n-1)/2, t_a, t_b: pairs tied in a, in b. Exact,
    O(n^2) in blocks of ``block`` rows (memory O(block * n)).
    """
    a, b = paired(a, b)
    n = a.size
    if n < 2:
        return float("nan")
    s = 0.0
    for start in range(0, n, block):
        rows = slice(start, min(start + block, n))
        s += float(np.sum(np.sign(a[rows, None] - a[None, :]) * np.sign(b[rows, None] - b[None, :])))
    s /= 2.0  # every unordered pair was counted twice
    n0 = n * (n - 1) / 2.0
    denom = np.sqrt((n0 - _tied_pairs(a)) * (n0 - _tied_pairs(b)))
    return float(np.clip(s / denom, -1.0, 1.0)) if denom > 0 else float("nan")


def bootstrap_ci(values: Any, statistic: Callable[..., Any] = np.mean, *, n_boot: int = 2000,
                 level: float = 0.95, seed: int = 0) -> tuple[float, float]:
    """Percentile bootstrap interval of ``statistic`` over the non-NaN values.

    ``statistic(x, axis=-1)`` must reduce the last axis (``np.mean``, ``np.median``, ...). One value
    gives a zero-width interval at it; none gives (NaN, NaN). Deterministic for a given ``seed``.
    """
    if not 0.0 < level < 1.0:
        raise ValueError(f"level must be in (0, 1), got {level}")
    x = _as_float(values)
    x = x[~np.isnan(x)]
    if x.size == 0:
        return float("nan"), float("nan")
    rng = np.random.default_rng(seed)
    samples = x[rng.integers(0, x.size, size=(int(n_boot), x.size))]
    stats = np.asarray(statistic(samples, axis=-1), np.float64)
    tail = (1.0 - level) / 2.0 * 100.0
    lo, hi = np.percentile(stats, [tail, 100.0 - tail])
    return float(lo), float(hi)


def min_max(values: Any) -> np.ndarray:
    """(v - min) / (max - min) over the non-NaN values; NaN stays NaN, a zero span gives 0."""
    x = _as_float(values)
    if np.all(np.isnan(x)):
        return x
    lo, hi = np.nanmin(x), np.nanmax(x)
    return np.where(np.isnan(x), np.nan, (x - lo) / (hi - lo) if hi > lo else 0.0)


def agreement(a: Any, b: Any) -> dict[str, float]:
    """``{"n", "spearman", "kendall_tau", "pearson"}`` between two aligned score lists."""
    pa, _ = paired(a, b)
    return {"n": int(pa.size), "spearman": spearman(a, b), "kendall_tau": kendall_tau(a, b),
            "pearson": pearson(a, b)}
