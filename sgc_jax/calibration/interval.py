"""The score's confidence interval (docs/semantics.md §5.6), written once for NumPy (the tables) and
``jax.numpy`` (the Scorer): a bootstrap over a clip's frame pairs, each resample scored as the clip
is, its spread about the clip's score widened for the few pairs a clip has (Student's t)."""

from __future__ import annotations

import functools
from typing import Any, Mapping

import numpy as np
from scipy.special import ndtri, stdtrit

from .formula import sgc_score
from .model import COMPONENTS, Calibration

INTERVAL_LEVEL = 0.90
INTERVAL_DRAWS = 2000  # resamples per clip
INTERVAL_SEED = 0
MIN_PAIRS = 2  # fewer scored pairs give no interval: one pair says nothing of another


@functools.lru_cache(maxsize=256)
def _uniform_column(j: int) -> np.ndarray:
    return np.random.default_rng((INTERVAL_SEED, j)).random(INTERVAL_DRAWS, dtype=np.float32)


def resample_uniforms(n_columns: int) -> np.ndarray:
    """(INTERVAL_DRAWS, n_columns) float32 uniforms in [0, 1), column j seeded alone, so a clip's
    resamples do not depend on the padding around it."""
    return np.stack([_uniform_column(j) for j in range(n_columns)], axis=1)


def small_sample_widening(n: int, level: float = INTERVAL_LEVEL) -> float:
    """t_{n-1} / z at ``level``, times sqrt(n / (n - 1)): how much a bootstrap over n values
    understates the spread of their mean (5.4 for 2 pairs, 2.2 for 3, 1.3 for 7, 1.1 for 15)."""
    tail = 0.5 * (1.0 + level)
    return float(stdtrit(n - 1, tail) / ndtri(tail) * np.sqrt(n / (n - 1)))


@functools.lru_cache(maxsize=64)
def _widenings(n_pairs: int) -> np.ndarray:
    """(n_pairs + 1,) small_sample_widening(n) by n, NaN below MIN_PAIRS."""
    return np.array([small_sample_widening(m) if m >= MIN_PAIRS else np.nan for m in range(n_pairs + 1)])


def _drawn_positions(n_float: Any, n_pairs: int, xp) -> Any:
    """(..., draws, n_pairs) int32: the counted position each resample position draws, floor(u n)
    for a clip of n counted pairs (``n_float`` float32, (..., 1, 1)); only positions i < n count."""
    drawn = xp.minimum(xp.floor(xp.asarray(resample_uniforms(n_pairs)) * n_float), n_float - 1)
    return xp.maximum(drawn, 0).astype(xp.int32)


@functools.lru_cache(maxsize=256)
def _position_counts(n_pairs: int, n: int) -> np.ndarray:
    """(draws, n_pairs) float64: how often each of the first n counted positions is drawn in each
    resample of a clip of n counted pairs (0 from position n on)."""
    drawn = _drawn_positions(np.float32(n), n_pairs, np)[:, :n]
    cells = np.arange(INTERVAL_DRAWS)[:, None] * n_pairs + drawn
    return np.bincount(cells.ravel(), minlength=INTERVAL_DRAWS * n_pairs).reshape(INTERVAL_DRAWS, n_pairs).astype(
        np.float64)


def _resampled_sums(order: Any, n: Any, columns: Any, xp) -> Any:
    """(..., draws, columns): each resample's sum of each column over the pairs it drew, from the
    columns (..., n_pairs, columns) and the pairs in order of position (``order`` (..., n_pairs),
    the n (...,) counted ones first)."""
    n_pairs = order.shape[-1]
    by_position = xp.take_along_axis(columns, order[..., None], axis=-2)  # (..., position, columns)
    if xp is np:  # the draws depend on n alone: the cached counts of each n times its clips' columns
        flat = by_position.reshape(-1, n_pairs, columns.shape[-1])
        sums = np.empty((len(flat), INTERVAL_DRAWS, columns.shape[-1]))
        for m in np.unique(n):
            clips = np.flatnonzero(np.ravel(n) == m)
            sums[clips] = np.matmul(_position_counts(n_pairs, int(m)), flat[clips])
        return sums.reshape(*np.shape(n), INTERVAL_DRAWS, columns.shape[-1])
    drawn = _drawn_positions(xp.asarray(n, xp.float32)[..., None, None], n_pairs, xp)  # (..., draws, position)
    in_resample = xp.broadcast_to(xp.arange(n_pairs) < n[..., None, None], drawn.shape)  # the first n positions
    # one add per draw: a one-hot over the positions would compare each draw with every one (long clips)
    rows = xp.arange(drawn.size // n_pairs).reshape(drawn.shape[:-1])[..., None]
    counts = xp.zeros(drawn.size, xp.float32).at[(rows * n_pairs + drawn).reshape(-1)].add(
        in_resample.reshape(-1).astype(xp.float32))
    return _matmul(counts.reshape(drawn.shape), by_position, xp)


def _matmul(a: Any, b: Any, xp) -> Any:
    # full float32 on accelerators (their default may round matmul inputs to 10-bit mantissas)
    return np.matmul(a, b) if xp is np else xp.matmul(a, b, precision="highest")


def score_interval(pair_components: Mapping[str, Any], score: Any, calibration: Calibration,
                   valid: Any = True, xp=np, pair_floors: Mapping[str, Any] | None = None) -> tuple[Any, Any]:
    """(sgc_lo, sgc_hi) (...,) from each component's per-pair values (..., n_pairs) and the clip's
    score (...,); the pairs that count are the ``valid`` ones (..., n_pairs; padding excluded) with
    a component. NaN where fewer than MIN_PAIRS pairs count. ``pair_floors`` ("<component>_floor"
    -> (..., n_pairs)): resampled with the components, for an ``excess`` calibration."""
    values = [xp.asarray(pair_components[k]) for k in COMPONENTS]
    usable = valid & ~xp.all(xp.stack([xp.isnan(v) for v in values]), axis=0)
    n_pairs = usable.shape[-1]
    n = xp.sum(usable, axis=-1)  # (...,)
    # the counted pairs first, in order: resample position i draws the floor(u n)-th of them
    order = xp.argsort(xp.where(usable, 0, n_pairs) + xp.arange(n_pairs), axis=-1)
    with_floors = calibration.excess and pair_floors is not None
    resampled_columns = dict(zip(COMPONENTS, values))
    if with_floors:
        resampled_columns.update({name: xp.asarray(v) for name, v in pair_floors.items()})
    # each resample's mean of a column from how often it drew each position: one product for every
    # column and its count of values, instead of a gather of each column's resamples
    columns = xp.stack(list(resampled_columns.values()), axis=-1)  # (..., n_pairs, columns)
    present = ~xp.isnan(columns)
    n_columns = columns.shape[-1]
    sums = _resampled_sums(order, n, xp.concatenate([xp.where(present, columns, 0.0), present.astype(columns.dtype)],
                                                    axis=-1), xp)
    totals, counts = sums[..., :n_columns], sums[..., n_columns:]  # (..., draws, columns) each
    resampled_means = xp.where(counts > 0, totals / xp.maximum(counts, 1), np.nan)
    means = {k: resampled_means[..., j] for j, k in enumerate(resampled_columns)}  # (..., draws) each
    floors = {name: means[name] for name in pair_floors} if with_floors else None
    scores = sgc_score({k: means[k] for k in COMPONENTS}, calibration, xp=xp, floors=floors)
    tail = 50.0 * (1.0 - INTERVAL_LEVEL)
    q_lo = xp.percentile(scores, tail, axis=-1)
    q_hi = xp.percentile(scores, 100.0 - tail, axis=-1)
    widen = xp.asarray(_widenings(n_pairs))[n]
    lo = xp.maximum(0.0, score - widen * xp.maximum(score - q_lo, 0.0))
    hi = score + widen * xp.maximum(q_hi - score, 0.0)
    enough = n >= MIN_PAIRS
    return xp.where(enough, lo, np.nan), xp.where(enough, hi, np.nan)
