"""sgc_jax.stats: our conventions over scipy.stats (NaN pairs dropped, NaN without a warning for too few
pairs or a constant list, average ranks and tau-b for ties), bootstrap CIs, min-max (docs/semantics.md §6.5)."""

import warnings

import numpy as np
import pytest

from sgc_jax.stats import agreement, bootstrap_ci, exact_median, kendall_tau, min_max, pearson, rankdata, spearman

CORRELATIONS = (pearson, spearman, kendall_tau)


def tied_lists(seed: int, n: int):
    """Two correlated integer-valued lists: many ties in both, the case tau-b exists for."""
    rng = np.random.default_rng(seed)
    a = rng.integers(0, 6, n).astype(float)
    return a, a + rng.integers(-2, 3, n)


def test_ties_get_average_ranks():
    np.testing.assert_array_equal(rankdata([3.0, 1.0, 3.0, 2.0, 3.0]), [4.0, 1.0, 4.0, 2.0, 4.0])
    assert rankdata([2.0, 1.0, 2.0]).dtype == np.float64


def test_rankdata_leaves_nan_out_of_the_ranking():
    np.testing.assert_array_equal(rankdata([3.0, np.nan, 1.0, 3.0]), [2.5, np.nan, 1.0, 2.5])
    np.testing.assert_array_equal(rankdata([None, 5.0]), [np.nan, 1.0])


def test_rank_correlations_with_ties_by_hand():
    # a ranks (1, 2.5, 2.5, 4), b ranks (1, 2, 3.5, 3.5): rho = 3.75 / 4.5. Pairs: 4 concordant, 0
    # discordant, one tied in a, one tied in b, n0 = 6: tau-b = 4 / sqrt(5 * 5). r = 2 / sqrt(2 * 2.75).
    a, b = [1.0, 2.0, 2.0, 3.0], [1.0, 2.0, 3.0, 3.0]
    assert spearman(a, b) == pytest.approx(3.75 / 4.5, abs=1e-15)
    assert kendall_tau(a, b) == pytest.approx(0.8, abs=1e-15)
    assert pearson(a, b) == pytest.approx(2 / np.sqrt(5.5), abs=1e-15)


def test_spearman_is_pearson_of_the_average_ranks():
    a, b = tied_lists(2, 300)
    assert spearman(a, b) == pytest.approx(pearson(rankdata(a), rankdata(b)), abs=1e-12)


def test_pairs_with_nan_or_none_are_dropped():
    a, b = tied_lists(4, 30)
    a_nan, b_nan = a.copy(), b.copy()
    a_nan[[2, 9]] = np.nan
    b_nan[17] = np.nan
    keep = np.ones(30, bool)
    keep[[2, 9, 17]] = False
    for fn in CORRELATIONS:
        assert fn(a_nan, b_nan) == fn(a[keep], b[keep])
    with_none = [None if np.isnan(v) else v for v in a_nan]
    assert spearman(with_none, b_nan) == spearman(a_nan, b_nan)
    assert agreement(a_nan, b_nan)["n"] == 27


def test_perfect_and_reversed_orders():
    a = np.arange(10.0)
    assert spearman(a, a**3) == pytest.approx(1.0)
    assert kendall_tau(a, -a) == pytest.approx(-1.0)
    assert all(-1.0 <= fn(*tied_lists(seed, 40)) <= 1.0 for fn in CORRELATIONS for seed in range(5))


@pytest.mark.parametrize("a, b", [([], []), ([1.0], [2.0]), ([1.0, np.nan], [2.0, 3.0]),
                                  ([1.0, 1.0, 1.0], [1.0, 2.0, 3.0]), ([0.1, 0.1, 0.1], [1.0, 2.0, 3.0]),
                                  ([1.0, 2.0, 3.0], [4.0, np.nan, 4.0])])
def test_too_few_pairs_or_constant_list_gives_nan_without_a_warning(a, b):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert all(np.isnan(fn(a, b)) for fn in CORRELATIONS)


def test_nearly_constant_list_or_infinity_warns_nothing():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert np.isfinite(pearson([1.0, 1.0 + 1e-15, 1.0], [1.0, 2.0, 3.0]))
        assert np.isnan(pearson([1.0, np.inf, 2.0], [1.0, 2.0, 3.0]))
        assert spearman([1.0, np.inf, 2.0], [1.0, 3.0, 2.0]) == pytest.approx(1.0)


def test_length_mismatch_is_an_error():
    with pytest.raises(ValueError, match="length"):
        spearman([1.0, 2.0], [1.0, 2.0, 3.0])


def test_bootstrap_ci_is_the_percentile_interval_of_seeded_resamples():
    """The definition, so that a seed keeps giving the same interval: n_boot resamples drawn at once by
    ``default_rng(seed).integers``, then ``np.percentile`` of the statistic at the two tails."""
    x = np.random.default_rng(7).normal(size=23)
    resamples = x[np.random.default_rng(3).integers(0, x.size, size=(500, x.size))]
    expected = np.percentile(np.median(resamples, axis=-1), [5.0, 95.0])
    assert bootstrap_ci(x, np.median, n_boot=500, level=0.9, seed=3) == tuple(expected)


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


@pytest.mark.parametrize("n", [1, 2, 3, 10, 1001, 100_000])
def test_exact_median_is_numpys_float64_median(n):
    rng = np.random.default_rng(n)
    for scale in (1e-3, 1.0, 1e3):
        values = (rng.lognormal(size=n) * scale).astype(np.float32)
        values[: n // 3] = values[-1]  # ties across the middle
        assert exact_median(values.copy()) == float(np.median(values.astype(np.float64)))
