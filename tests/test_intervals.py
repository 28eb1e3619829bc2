"""The score's confidence interval (docs/semantics.md §5.6): a bootstrap over the clip's frame pairs,
widened for few pairs, that covers the score a clip would get on average over tracker noise."""

import numpy as np
import pytest
from scenes import DEMO_SCENE

from sgc_jax import COMPONENTS, score_batch
from sgc_jax.calibration import Calibration, sgc_score
from sgc_jax.calibration.interval import INTERVAL_LEVEL, resample_uniforms, score_interval, small_sample_widening
from sgc_jax.engines.pairs import PairArrays, empty_pair_arrays
from sgc_jax.io.tables import FLOOR_COLUMNS, INTERVAL_COLUMNS
from sgc_jax.research.synth import synth_clip
from sgc_jax.scoring.result import pair_summaries, rescore_records, summarize_clip

CALIBRATION = Calibration.load("sgc-spec-2026")
# The bar: one draw's 90 % interval holds the median score of repeated draws in >= 80 % of
# draws. Per-pair components drawn as scaled chi-square(6) values of the spec calibration's range;
# CLIPS draws put the coverage's standard error near 0.02 (measured: 0.83 at 3 pairs, 0.90 at 7).
COVERAGE_MIN, CLIPS = 0.80, 300
# float64 rounding: the interval sums each resample's pairs in another order than drawing them one
# by one does (measured 1.3e-14 relative on random columns).
SUM_ORDER_RTOL = 1e-12
# Every pair's noise floors (the calibration scores the excess over them), a quarter of the level
# the components are drawn at.
FLOOR = 0.5


def pairs_with(values: dict[str, np.ndarray]) -> PairArrays:
    """A clip's pairs whose components are ``values`` (name -> (n_pairs,)); the rest empty."""
    n_pairs = len(next(iter(values.values())))
    pairs = empty_pair_arrays(n_pairs, 2)
    for name, column in values.items():
        setattr(pairs, name, np.asarray(column, np.float64))
    return pairs


def pair_floors(pairs: PairArrays) -> dict[str, np.ndarray]:
    return {name: np.full(pairs.n_pairs, FLOOR) for name in FLOOR_COLUMNS}


def clip_score(pairs: PairArrays) -> float:
    floors = {name: FLOOR for name in FLOOR_COLUMNS}
    return float(sgc_score({k: np.nanmean(getattr(pairs, k)) for k in COMPONENTS}, CALIBRATION, floors=floors))


def interval(pairs: PairArrays) -> tuple[float, float]:
    return tuple(float(v) for v in score_interval(pairs.components(), clip_score(pairs), CALIBRATION,
                                                  pair_floors=pair_floors(pairs)))


def random_pairs(rng: np.random.Generator, n_pairs: int, level: float) -> PairArrays:
    return pairs_with({k: level * rng.chisquare(6, n_pairs) / 6 for k in COMPONENTS})


def test_pairs_that_agree_give_an_interval_of_zero_width_at_the_score():
    pairs = pairs_with({k: np.full(5, 2.0) for k in COMPONENTS})
    lo, hi = interval(pairs)
    assert lo == pytest.approx(clip_score(pairs), abs=1e-12) and hi == pytest.approx(lo, abs=1e-12)


def test_one_scored_pair_gives_no_interval():
    pairs = pairs_with({k: np.array([1.0, np.nan, np.nan]) for k in COMPONENTS})
    assert all(np.isnan(interval(pairs)))


def test_the_interval_is_reproducible_brackets_the_score_and_stays_at_or_above_zero():
    pairs = random_pairs(np.random.default_rng(1), 7, 2.0)
    lo, hi = interval(pairs)
    assert interval(pairs) == (lo, hi)
    assert 0.0 <= lo <= clip_score(pairs) <= hi


@pytest.mark.parametrize("n_pairs", [3, 7])
def test_the_90_percent_interval_covers_the_median_score_of_repeated_draws(n_pairs):
    rng = np.random.default_rng(n_pairs)
    clips = [random_pairs(rng, n_pairs, 2.0) for _ in range(CLIPS)]
    median = np.median([clip_score(p) for p in clips])
    bounds = np.array([interval(p) for p in clips])
    assert np.mean((bounds[:, 0] <= median) & (median <= bounds[:, 1])) >= COVERAGE_MIN


def interval_by_gathering(pairs: PairArrays) -> tuple[float, float]:
    """The bootstrap of §5.6 written out for a clip whose scored pairs lack no component: each
    resample's pairs gathered one by one and averaged."""
    columns = {**pairs.components(), **pair_floors(pairs)}
    counted = np.flatnonzero(~np.all([np.isnan(pairs.components()[k]) for k in COMPONENTS], axis=0))
    n = len(counted)
    positions = np.minimum(np.floor(resample_uniforms(pairs.n_pairs)[:, :n] * np.float32(n)), n - 1)
    drawn = counted[positions.astype(int)]  # (draws, n): the pairs each resample holds
    means = {name: column[drawn].mean(axis=-1) for name, column in columns.items()}
    scores = sgc_score({k: means[k] for k in COMPONENTS}, CALIBRATION, floors={k: means[k] for k in FLOOR_COLUMNS})
    tail = 50.0 * (1.0 - INTERVAL_LEVEL)
    q_lo, q_hi = np.percentile(scores, [tail, 100.0 - tail])
    score, widen = clip_score(pairs), small_sample_widening(n)
    return max(0.0, score - widen * max(score - q_lo, 0.0)), score + widen * max(q_hi - score, 0.0)


@pytest.mark.parametrize("n_pairs", [3, 15])
def test_each_resample_is_scored_on_the_pairs_it_drew(n_pairs):
    pairs = random_pairs(np.random.default_rng(n_pairs), n_pairs, 2.0)
    for k in COMPONENTS:
        getattr(pairs, k)[1] = np.nan  # a pair with no component is not counted, nor drawn
    assert interval(pairs) == pytest.approx(interval_by_gathering(pairs), rel=SUM_ORDER_RTOL)


@pytest.fixture(scope="module")
def scored():
    return score_batch([synth_clip(seed=7, clip_id="consistent-1px", noise_px=1.0, **DEMO_SCENE)], progress=False)


def test_scored_clips_carry_their_interval_and_a_rescore_without_pairs_drops_it(scored):
    clip = scored.clips[0]
    assert 0.0 <= clip.sgc_lo <= clip.sgc <= clip.sgc_hi and clip.sgc_hi > clip.sgc_lo
    assert list(scored.to_pandas()[list(INTERVAL_COLUMNS)].iloc[0]) == [clip.sgc_lo, clip.sgc_hi]
    again = scored.rescore("sgc-spec-2026").clips[0]
    assert (again.sgc_lo, again.sgc_hi) == (clip.sgc_lo, clip.sgc_hi)  # the pairs are kept in memory
    from_rows = rescore_records(scored.to_records(), "sgc-spec-2026")[0]
    assert np.isnan(from_rows["sgc_lo"]) and np.isnan(from_rows["sgc_hi"])
    assert from_rows["sgc_floor"] == pytest.approx(clip.sgc_floor)


def test_clips_summarised_together_get_the_numbers_of_one_clip_at_a_time(scored):
    clip = scored.clips[0]
    rng = np.random.default_rng(3)
    shorter = PairArrays(**{name: value[:4] if isinstance(value, np.ndarray) else value
                            for name, value in vars(clip.pairs).items()})
    # a group as large as an accelerator's call: a product of many rows rounds differently from one
    others = [pairs_with({k: 2.0 * rng.chisquare(6, clip.pairs.n_pairs) / 6 for k in COMPONENTS}) for _ in range(30)]
    group = [clip.pairs, shorter, *others, clip.pairs]
    for pairs, summary in zip(group, pair_summaries(group, CALIBRATION, "spec")):
        alone = summarize_clip("c", pairs, CALIBRATION, compat="spec")
        together = summarize_clip("c", pairs, CALIBRATION, compat="spec", summary=summary)
        assert all(v == alone.record()[k] or (v != v and alone.record()[k] != alone.record()[k])
                   for k, v in together.record().items())
        assert all(np.array_equal(together.pair_floors[k], v, equal_nan=True) for k, v in alone.pair_floors.items())
        assert np.array_equal(together.pair_evidence, alone.pair_evidence, equal_nan=True)
