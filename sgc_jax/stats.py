"""Agreement statistics for score lists (docs/semantics.md §6.5): rank correlations, bootstrap CIs,
min-max scaling; the median of a clip's depth values (§4) without a float64 copy; and the means
both engines, the noise floors and the summaries share (NaN-aware, trimmed) and the inlier cut's
variance factor the floors apply (§3.10), written once for NumPy and ``jax.numpy``.

A thin layer over ``scipy.stats`` that fixes our conventions: every paired function drops the pairs
where either value is NaN (or missing, ``None``) and returns NaN, without a warning, when fewer than
two pairs remain or a list is constant. Ties get average ranks (Spearman) and the tau-b correction
(Kendall).
"""

from __future__ import annotations

import warnings
from typing import Any, Callable

import numpy as np

from .config import MAX_CUT_FACTOR


def _as_float(values: Any) -> np.ndarray:
    return np.asarray(values, np.float64).ravel()  # None -> NaN


def _scipy_stats():
    # Imported on first use: scipy.stats takes about a second to import, which `import sgc_jax`
    # and the commands that compute no statistic should not pay.
    import scipy.stats

    return scipy.stats


def paired(a: Any, b: Any) -> tuple[np.ndarray, np.ndarray]:
    """(a, b) as float arrays with the pairs where either is NaN removed; lengths must match."""
    a, b = _as_float(a), _as_float(b)
    if a.shape != b.shape:
        raise ValueError(f"score lists differ in length: {a.size} vs {b.size}")
    keep = ~(np.isnan(a) | np.isnan(b))
    return a[keep], b[keep]


def rankdata(values: Any) -> np.ndarray:
    """Ranks 1..n of a 1-D array, ties given their average rank; a NaN gets rank NaN and the other
    values are ranked among themselves."""
    return np.asarray(_scipy_stats().rankdata(_as_float(values), nan_policy="omit"), np.float64)


def _correlation(name: str, a: Any, b: Any) -> float:
    """``scipy.stats.<name>(a, b).statistic`` over the non-NaN pairs, under the conventions above."""
    a, b = paired(a, b)
    if a.size < 2 or np.all(a == a[0]) or np.all(b == b[0]):
        return float("nan")
    stats = _scipy_stats()
    # nearly constant lists warn and still get a value; an infinity makes Pearson NaN
    with warnings.catch_warnings(), np.errstate(invalid="ignore", divide="ignore"):
        warnings.simplefilter("ignore", stats.DegenerateDataWarning)
        return float(getattr(stats, name)(a, b).statistic)


def pearson(a: Any, b: Any) -> float:
    """Pearson correlation r of the non-NaN pairs (NaN with < 2 pairs or a constant list)."""
    return _correlation("pearsonr", a, b)


def spearman(a: Any, b: Any) -> float:
    """Spearman rho (Pearson r of the average ranks) of the non-NaN pairs."""
    return _correlation("spearmanr", a, b)


def kendall_tau(a: Any, b: Any) -> float:
    """Kendall tau-b of the non-NaN pairs: (C - D) / sqrt((n0 - t_a)(n0 - t_b)), with C, D the
    concordant and discordant pairs, n0 = n(n-1)/2 and t_a, t_b the pairs tied in a, in b."""
    return _correlation("kendalltau", a, b)


def bootstrap_ci(values: Any, statistic: Callable[..., Any] = np.mean, *, n_boot: int = 2000,
                 level: float = 0.95, seed: int = 0) -> tuple[float, float]:
    """Percentile bootstrap interval of ``statistic`` over the non-NaN values.

    ``statistic(x, axis=-1)`` must reduce the last axis (``np.mean``, ``np.median``, ...). One value
    gives a zero-width interval at it; none gives (NaN, NaN). Deterministic for a given ``seed``.
    """
    # Not scipy.stats.bootstrap: it draws the same resamples, but its percentile step differs from
    # np.percentile in the last bits (and between scipy versions), and it refuses a single value.
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


def min_max(values: Any, xp=np) -> Any:
    """(v - min) / (max - min) over the non-NaN values; NaN stays NaN, a zero span gives 0.
    NumPy (float64, any sequence) or ``jax.numpy`` (an array of its dtype, traceable)."""
    x = _as_float(values) if xp is np else values
    if x.size == 0:
        return x
    finite = ~xp.isnan(x)
    lo, hi = xp.min(xp.where(finite, x, xp.inf)), xp.max(xp.where(finite, x, -xp.inf))
    scaled = xp.where(hi > lo, (x - lo) / xp.where(hi > lo, hi - lo, 1.0), 0.0)
    return xp.where(finite, scaled, xp.nan)


def camera_dynamics(ecd_trans: Any, ecd_rot: Any, xp=np) -> Any:
    """ECD (docs/semantics.md §4) per clip: the larger of min-max(mean ||t_g||) and min-max(mean
    angle of R_g) over the clips given, (n,) x2 -> (n,) in [0, 1]; a clip with one NaN input takes
    the other, with two NaN; a constant column scales to 0. NumPy or ``jax.numpy`` (the Scorer)."""
    trans, rot = min_max(ecd_trans, xp), min_max(ecd_rot, xp)
    return xp.where(xp.isnan(trans), rot, xp.where(xp.isnan(rot), trans, xp.maximum(trans, rot)))


def agreement(a: Any, b: Any) -> dict[str, float]:
    """``{"n", "spearman", "kendall_tau", "pearson"}`` between two aligned score lists."""
    pa, _ = paired(a, b)
    return {"n": int(pa.size), "spearman": spearman(a, b), "kendall_tau": kendall_tau(a, b),
            "pearson": pearson(a, b)}


def exact_median(values: np.ndarray) -> float:
    """``np.median(values.astype(np.float64))`` of a non-empty 1-D float array of finite values
    (the two middle values averaged in float64), without the float64 copy that ``np.median``
    would partition: float32 values order the same. Partitions ``values`` in place."""
    half = values.size // 2
    if values.size % 2:
        values.partition(half)
        return float(values[half])
    values.partition((half - 1, half))
    return (float(values[half - 1]) + float(values[half])) / 2.0


# ------------------------------------------------------------------ means written once for NumPy and jax.numpy


def nanmean(values: Any, mask: Any = True, xp=np) -> Any:
    """Mean over the last axis of the non-NaN ``values`` where ``mask`` (broadcast against them);
    NaN where none is. A masked sum, so padded or traced arrays need no compaction."""
    keep = mask & ~xp.isnan(values)
    count = xp.sum(keep, axis=-1)
    total = xp.sum(xp.where(keep, values, 0.0), axis=-1)
    return xp.where(count > 0, total / xp.maximum(count, 1), np.nan)


def percentile_of_sorted(ordered: Any, n: Any, q: int, xp=np) -> Any:
    """The q-th percentile (int 0..100, NumPy's "linear" method) of the first n entries of
    ``ordered``, sorted along the last axis (n broadcasts against its other axes; n <= 0 reads
    the first entry). The position q (n - 1) / 100 is split exactly into integer and fraction."""
    last = xp.maximum(n - 1, 0)
    scaled = q * last
    lo = scaled // 100
    frac = xp.asarray(scaled % 100).astype(ordered.dtype) / 100.0
    hi = xp.minimum(lo + 1, last)
    at = lambda i: xp.take_along_axis(ordered, xp.asarray(i)[..., None].astype(np.int32), axis=-1)[..., 0]  # noqa: E731
    a, b = at(lo), at(hi)
    with np.errstate(invalid="ignore"):  # NumPy evaluates both branches: inf - inf where hi == lo, masked out
        diff = xp.where(hi > lo, b - a, 0.0)
        return xp.where(frac >= 0.5, b - diff * (1.0 - frac), a + diff * frac)


def trimmed(values: Any, valid: Any, compat: str = "spec", xp=np) -> Any:
    """The values the trimmed mean of docs/semantics.md §3.5 averages, over the last axis: the
    valid v with q1 - c IQR <= v <= p98, c = (p98 - q3) / IQR. When IQR = 0, or the bounds keep
    nothing (two distinct values), every valid one under "spec" and none under "authors"."""
    n = xp.sum(valid, axis=-1)
    ordered = xp.sort(xp.where(valid, values, xp.inf), axis=-1)
    q1, q3, p98 = (percentile_of_sorted(ordered, n, q, xp)[..., None] for q in (25, 75, 98))
    with np.errstate(invalid="ignore"):  # no valid value: the percentiles are inf, and inf - inf is masked below
        iqr = q3 - q1
        iqr_safe = xp.where(iqr > 0, iqr, 1.0)
        c = (p98 - q3) / iqr_safe
        kept = valid & (values >= q1 - c * iqr_safe) & (values <= p98)
    if compat == "authors":
        return kept & (iqr > 0)
    keep_all = (iqr == 0) | ~xp.any(kept, axis=-1, keepdims=True)
    return xp.where(keep_all, valid, kept)


def trimmed_mean(values: Any, valid: Any, compat: str = "spec", xp=np) -> Any:
    """The mean of ``trimmed`` values over the last axis; NaN where none is."""
    return nanmean(values, trimmed(values, valid, compat, xp), xp)


# Iterations of the fixed point for the errors' sigma before a cut (converged to 1e-9 relative
# under MAX_CUT_FACTOR).
CUT_ITERATIONS = 16


def cut_variance_factor(sigma_sq: Any, cut_px: Any, xp=np, max_factor: float = MAX_CUT_FACTOR) -> Any:
    """How much larger the covariance of a least-squares fit on the points whose 2-D residual is
    within ``cut_px`` is than sigma_sq (J^T J)^-1 with ``sigma_sq`` their own residual variance per
    coordinate, for isotropic Gaussian errors: (p / g)^2, p = 1 - e^-a the share of the points the
    cut keeps and g = p - a e^-a that of their variance, a = cut² / (2 s²), s² = sigma_sq p / g the
    errors' variance before the cut (a fixed point). 1 without a cut (inf), at most ``max_factor``.
    The cut takes the tail's variance from sigma_sq (p / g) and the points it drops lower the fit's
    efficiency (p / g again: the hard cut's sandwich covariance). NumPy or ``jax.numpy``."""
    sigma_sq = xp.maximum(xp.asarray(sigma_sq), 1e-30)
    true_sq = sigma_sq
    for _ in range(CUT_ITERATIONS):
        a = xp.minimum(cut_px**2 / (2.0 * true_sq), 60.0)  # beyond 60 the cut keeps everything
        kept = -xp.expm1(-a)
        kept_variance = xp.maximum(kept - a * xp.exp(-a), 1e-6)
        true_sq = sigma_sq * kept / kept_variance
    return xp.minimum((kept / kept_variance) ** 2, max_factor)
