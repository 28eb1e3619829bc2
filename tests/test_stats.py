"""sgc_jax.stats: rank correlations against scipy.stats, NaN handling, bootstrap CIs, min-max (SPEC §5)."""

import numpy as np
import pytest
from scipy import stats as scipy_stats

from sgc_jax.stats import agreement, bootstrap_ci, kendall_tau, min_max, pearson, rankdata, spearman


def tied_lists(seed: int, n: int):
    """Two correlated integer-valued lists: many ties in both, the case tau-b exists for."""
    rng = np.random.default_rng(seed)
    a = rng.integers(0, 6, n).astype(float)
    return a, a + rng.integers(-2, 3, n)


@pytest.mark.parametrize("seed, n", [(0, 7), (1, 40), (2, 300)])
def test_rank_correlations_match_scipy_with_ties(seed, n):
    a, b = tied_lists(seed, n)
    assert spearman(a, b) == pytest.approx(scipy_stats.spearmanr(a, b).statistic, abs=1e-12)
    assert kendall_tau(a, b) == pytest.approx(scipy_stats.kendalltau(a, b).statistic, abs=1e-12)
    assert pearson(a, b) == pytest.approx(scipy_stats.pearsonr(a, b).statistic, abs=1e-12)
    np.testing.assert_array_equal(rankdata(a), scipy_stats.rankdata(a))


def test_rank_correlations_match_scipy_on_continuous_scores():
    rng = np.random.default_rng(5)
    a = rng.normal(size=200)
    b = a + rng.normal(scale=2.0, size=200)
    assert spearman(a, b) == pytest.approx(scipy_stats.spearmanr(a, b).statistic, abs=1e-12)
    assert kendall_tau(a, b) == pytest.approx(scipy_stats.kendalltau(a, b).statistic, abs=1e-12)


def test_kendall_blocks_do_not_change_the_value():
    a, b = tied_lists(3, 150)
    assert kendall_tau(a, b, block=7) == pytest.approx(kendall_tau(a, b, block=4096), abs=1e-12)


def test_pairs_with_nan_or_none_are_dropped():
    a, b = tied_lists(4, 30)
    a_nan, b_nan = a.copy(), b.copy()
    a_nan[[2, 9]] = np.nan
    b_nan[17] = np.nan
    keep = np.ones(30, bool)
    keep[[2, 9, 17]] = False
    assert spearman(a_nan, b_nan) == pytest.approx(scipy_stats.spearmanr(a[keep], b[keep]).statistic, abs=1e-12)
    assert kendall_tau(a_nan, b_nan) == pytest.approx(scipy_stats.kendalltau(a[keep], b[keep]).statistic, abs=1e-12)
    with_none = [None if np.isnan(v) else v for v in a_nan]
    assert spearman(with_none, b_nan) == spearman(a_nan, b_nan)
    assert agreement(a_nan, b_nan)["n"] == 27


def test_perfect_and_reversed_orders():
    a = np.arange(10.0)
    assert spearman(a, a**3) == pytest.approx(1.0)
    assert kendall_tau(a, -a) == pytest.approx(-1.0)


@pytest.mark.parametrize("a, b", [([1.0], [2.0]), ([1.0, np.nan], [2.0, 3.0]), ([1.0, 1.0, 1.0], [1.0, 2.0, 3.0])])
def test_too_few_pairs_or_constant_list_gives_nan(a, b):
    assert np.isnan(spearman(a, b)) and np.isnan(kendall_tau(a, b)) and np.isnan(pearson(a, b))


def test_length_mismatch_is_an_error():
    with pytest.raises(ValueError, match="length"):
        spearman([1.0, 2.0], [1.0, 2.0, 3.0])


def test_bootstrap_ci_brackets_the_mean_and_is_reproducible():
    rng = np.random.default_rng(0)
    x = rng.normal(loc=3.0, scale=1.0, size=200)
    lo, hi = bootstrap_ci(x, seed=1)
    assert lo < x.mean() < hi
    # the normal-theory 95% half-width is 1.96 * sd / sqrt(n) ~ 0.139: the percentile one is close
    assert (hi - lo) / 2 == pytest.approx(1.96 * x.std() / np.sqrt(x.size), rel=0.15)
    assert bootstrap_ci(x, seed=1) == (lo, hi)
    assert bootstrap_ci(x, seed=2) != (lo, hi)
    med_lo, med_hi = bootstrap_ci(x, np.median, seed=1)
    assert med_lo < np.median(x) < med_hi


def test_bootstrap_ci_edge_cases():
    assert bootstrap_ci([2.5, np.nan]) == (2.5, 2.5)
    assert all(np.isnan(bootstrap_ci([np.nan])))
    with pytest.raises(ValueError, match="level"):
        bootstrap_ci([1.0, 2.0], level=95)


def test_min_max_scales_to_unit_range_and_keeps_nan():
    np.testing.assert_allclose(min_max([2.0, np.nan, 4.0, 3.0]), [0.0, np.nan, 1.0, 0.5])
    np.testing.assert_array_equal(min_max([7.0, 7.0]), [0.0, 0.0])
    assert np.isnan(min_max([np.nan, np.nan])).all()
