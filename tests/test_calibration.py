"""SPEC §4: the score formula, the shipped paper calibration, and fitting a calibration."""

import csv
import json
from pathlib import Path

import numpy as np
import pytest
from tolerances import PUBLISHED_SCORE_ATOL, PUBLISHED_WEIGHT_ATOL

from sgc_jax import COMPONENTS, Calibration, calibrate, sgc_score
from sgc_jax.calibration import kfold_stability

GROUPS_CSV = Path(__file__).parent / "data" / "sgc-paper-2026-groups.csv"


def paper_groups():
    with GROUPS_CSV.open() as f:
        rows = list(csv.DictReader(f))
    matrix = np.array([[float(r[k]) for k in COMPONENTS] for r in rows])
    return rows, matrix, np.array([float(r["sgc"]) for r in rows])


@pytest.mark.parametrize("components, expected", [
    ((6.5223, 0.0182, 2.0900, 0.0220, 0.0331), 0.0575),
    ((18.7023, 1395.6600, 29.0294, 1550.7947, 0.1126), 0.8519),
    ((57.1804, 0.0524, 27.6862, 0.0591, 0.0219), 0.2371),
])
def test_score_formula_reproduces_published_rows(components, expected):
    score = sgc_score(dict(zip(COMPONENTS, components)), Calibration.load("sgc-paper-2026"))
    assert abs(float(score) - expected) < PUBLISHED_SCORE_ATOL


def test_score_formula_reproduces_all_thirteen_groups():
    _, matrix, sgc = paper_groups()
    scores = sgc_score({k: matrix[:, j] for j, k in enumerate(COMPONENTS)}, Calibration.load("sgc-paper-2026"))
    np.testing.assert_allclose(scores, sgc, atol=PUBLISHED_SCORE_ATOL)


def test_calibrating_on_published_groups_reproduces_shipped_calibration():
    rows, _, sgc = paper_groups()
    fitted = calibrate(rows, by="clip")  # the CSV rows are already one per group
    paper = Calibration.load("sgc-paper-2026")
    for k in COMPONENTS:
        assert fitted.log1p[k] == paper.log1p[k]
        assert abs(fitted.mu[k] - paper.mu[k]) < 1e-5
        assert abs(fitted.sigma[k] - paper.sigma[k]) < 1e-5
        assert abs(fitted.z_min[k] - paper.z_min[k]) < 1e-3
        assert abs(fitted.z_max[k] - paper.z_max[k]) < 1e-3
        assert abs(fitted.weight[k] - paper.weight[k]) < PUBLISHED_WEIGHT_ATOL
    assert abs(sum(fitted.weight.values()) - 1.0) < 1e-12
    rescored = sgc_score({k: np.array([float(r[k]) for r in rows]) for k in COMPONENTS}, fitted)
    np.testing.assert_allclose(rescored, sgc, atol=PUBLISHED_SCORE_ATOL)


def test_calibration_by_group_averages_clips_first():
    rows, matrix, _ = paper_groups()
    clips = []
    for r, m in zip(rows, matrix):  # two clips per group whose mean is the group row
        for sign in (-1, 1):
            clips.append({"group": r["group"], **{k: m[j] * (1 + sign * 0.1) for j, k in enumerate(COMPONENTS)}})
    by_group = calibrate(clips, by="group")
    direct = calibrate(rows)
    for k in COMPONENTS:
        assert by_group.weight[k] == pytest.approx(direct.weight[k], abs=1e-9)


def test_calibration_round_trips_through_json(tmp_path):
    _, matrix, _ = paper_groups()
    fitted = calibrate(matrix, name="mine")
    path = fitted.save(tmp_path / "calib.json")
    assert Calibration.load(path) == fitted
    assert json.loads(path.read_text())["components"].keys() == set(COMPONENTS)


def test_nan_component_drops_out_of_weighted_mean():
    paper = Calibration.load("sgc-paper-2026")
    values = dict(zip(COMPONENTS, (30.0, 0.5, 10.0, 0.6, 0.05)))
    full = float(sgc_score(values, paper))
    values["depth_error"] = float("nan")
    partial = float(sgc_score(values, paper))
    from sgc_jax.calibration import normalise

    m = normalise(values, paper)
    expected = sum(paper.weight[k] * m[k] for k in COMPONENTS[:4]) / sum(paper.weight[k] for k in COMPONENTS[:4])
    assert partial == pytest.approx(float(expected)) and partial != full
    assert np.isnan(sgc_score({k: float("nan") for k in COMPONENTS}, paper))


def test_degenerate_sigma_and_span_give_zero_not_nan():
    paper = Calibration.load("sgc-paper-2026")
    flat = Calibration.from_dict({**paper.to_dict(), "components": {
        k: {**paper.to_dict()["components"][k], "sigma": 0.0, "z_min": 1.0, "z_max": 1.0} for k in COMPONENTS}})
    assert float(sgc_score(dict(zip(COMPONENTS, (1.0, 1.0, 1.0, 1.0, 1.0))), flat)) == 0.0


def test_unknown_calibration_name_is_a_clear_error():
    with pytest.raises(FileNotFoundError, match="sgc-paper-2026"):
        Calibration.load("no-such-calibration")


# ----------------------------------------------------------------------------- fitting inputs


def test_a_calibration_keyed_excess_is_refused_naming_floor_band():
    spec = Calibration.load("sgc-spec-2026").to_dict()
    spec.pop("floor_band")
    with pytest.raises(ValueError, match="floor_band"):
        Calibration.from_dict({**spec, "excess": True})


def test_a_dataframe_fits_as_its_rows_and_failed_clips_are_left_out():
    import pandas as pd

    rows, matrix, _ = paper_groups()
    frame = pd.DataFrame(rows)
    assert calibrate(frame).weight == pytest.approx(calibrate(rows).weight, abs=1e-12)
    failed = {"clip_id": "broken", "group": "x", "status": "error", **{k: float("nan") for k in COMPONENTS}}
    with_failed = calibrate([*rows, failed])
    assert with_failed.extra["n_rows"] == 13  # the failed clip is left out, not filled in
    assert with_failed.mu == pytest.approx(calibrate(rows).mu, abs=1e-12)


def test_calibration_reports_pc1_explained_variance():
    _, matrix, _ = paper_groups()
    fitted = calibrate(matrix)
    ratio = fitted.extra["pc1_explained_variance_ratio"]
    assert 0.2 < ratio <= 1.0  # five components: PC1 explains at least a fifth
    rank_one = np.outer(np.linspace(0.1, 2.0, 8), np.ones(5)) * np.array([1.0, 2.0, 3.0, 4.0, 0.01])
    # without log1p every column is linear in one variable: the M'' matrix has rank one
    assert calibrate(rank_one, log1p=()).extra["pc1_explained_variance_ratio"] == pytest.approx(1.0, abs=1e-9)
    assert calibrate(rank_one).extra["pc1_explained_variance_ratio"] < 1.0 - 1e-6


def test_grouping_needs_groups_and_calibration_needs_every_component():
    _, matrix, _ = paper_groups()
    with pytest.raises(ValueError, match="group"):
        calibrate(matrix, by="group")
    no_depth = matrix.copy()
    no_depth[:, 4] = np.nan
    with pytest.raises(ValueError, match="depth_error"):
        calibrate(no_depth)


# ----------------------------------------------------------------------------- k-fold stability


def test_kfold_on_published_groups_is_stable_like_the_paper():
    rows, _, _ = paper_groups()
    stability = kfold_stability(rows, k=5, seed=0)
    assert stability.fold_weights.shape == (5, 5)
    np.testing.assert_allclose(stability.fold_weights.sum(axis=1), 1.0, atol=1e-12)
    paper = Calibration.load("sgc-paper-2026").weight
    for k in COMPONENTS:
        assert stability.full_weights[k] == pytest.approx(paper[k], abs=PUBLISHED_WEIGHT_ATOL)
        # appendix C.1 on 1296 clips: |fold mean - full| <= 0.014, fold std <= 0.0354
        assert abs(stability.weight_mean[k] - paper[k]) < 0.03
        assert 0.0 < stability.weight_std[k] < 0.06
    # the hierarchy holds on average: translations and depth above rotations
    mean = stability.weight_mean
    strongest = min(mean["global_trans_var"], mean["local_trans_var"], mean["depth_error"])
    assert strongest > mean["global_rot_var"] > mean["local_rot_var"]
    assert 0.95 < stability.spearman_mean <= 1.0 and stability.spearman.shape == (5,)
    assert "Spearman" in stability.table() and stability.to_dict()["k"] == 5


def test_leave_one_out_folds_are_calibrations_without_one_row():
    rows, _, _ = paper_groups()
    stability = kfold_stability(rows, k=len(rows), seed=3)
    expected = np.array([[calibrate(rows[:i] + rows[i + 1:]).weight[k] for k in COMPONENTS] for i in range(len(rows))])
    for fold in stability.fold_weights:  # fold order follows the shuffle: match each to its row
        assert np.min(np.abs(expected - fold).max(axis=1)) < 1e-12
    # with the whole dataset behind every fold the scores barely move
    assert stability.spearman.min() > 0.95


def test_kfold_by_group_splits_clips_then_averages_groups():
    rows, matrix, _ = paper_groups()
    clips = [{"group": r["group"], **{k: m[j] * (1 + s * 0.1) for j, k in enumerate(COMPONENTS)}}
             for r, m in zip(rows, matrix) for s in (-1, 1)]
    stability = kfold_stability(clips, k=len(clips), by="group", seed=0)
    expected = np.array([[calibrate(clips[:i] + clips[i + 1:], by="group").weight[k] for k in COMPONENTS]
                         for i in range(len(clips))])
    for fold in stability.fold_weights:
        assert np.min(np.abs(expected - fold).max(axis=1)) < 1e-12
    assert stability.full_weights == pytest.approx(calibrate(rows).weight, abs=1e-9)


def test_kfold_is_reproducible_and_checks_k():
    rows, _, _ = paper_groups()
    a, b = kfold_stability(rows, k=4, seed=7), kfold_stability(rows, k=4, seed=7)
    np.testing.assert_array_equal(a.fold_weights, b.fold_weights)
    assert not np.array_equal(a.fold_weights, kfold_stability(rows, k=4, seed=8).fold_weights)
    for k in (1, 0, -3):
        with pytest.raises(ValueError, match="k must be at least 2"):
            kfold_stability(rows, k=k)
    with pytest.raises(ValueError, match="at least 2 scored rows, got 1"):
        kfold_stability(rows[:1], k=2)


# The demo corpus (sgc_jax.research.synth.demo_corpus, `sgc-jax synth`): its per-clip components scored by
# the reference engine (compat="spec"), 4 significant digits; 8 clips in 5 groups.
DEMO_ROWS = [
    ("drift-0.05", "drift", (0.7888, 3.495, 0.357, 4.24, 0.4656)),
    ("drift-0.20", "drift", (86.92, 284.8, 3.522, 317.9, 0.9073)),
    ("moving-masked", "moving", (5.77e-09, 4.273e-09, 3.496e-10, 5.026e-09, 0.3407)),
    ("moving-unmasked", "unmasked", (25.37, 251.9, 0.7475, 280.1, 0.9424)),
    ("noisy-mild", "noisy", (200.2, 161.7, 15.49, 197.2, 0.2706)),
    ("noisy-strong", "noisy", (244.1, 893.5, 104.7, 1104, 0.6057)),
    ("rigid-a", "rigid", (4.36e-09, 1.884e-08, 4.883e-10, 2.285e-08, 0.4234)),
    ("rigid-b", "rigid", (1.654e-09, 3.593e-09, 1.606e-10, 4.093e-09, 0.4363)),
]


def test_readme_kfold_example_runs_on_the_demo_corpus_as_leave_one_out():
    rows = [{"clip_id": c, "group": g, "status": "ok", **dict(zip(COMPONENTS, m))} for c, g, m in DEMO_ROWS]
    with pytest.warns(UserWarning, match=r"k=10 folds but only 8 scored rows .*: using leave-one-out \(k=8\)"):
        stability = kfold_stability(rows, k=10, by="group")  # the README's call
    assert stability.k == 8 and stability.fold_weights.shape == (8, 5) and "over 8 folds" in stability.table()
    loo = kfold_stability(rows, k=8, by="group")
    np.testing.assert_array_equal(stability.fold_weights, loo.fold_weights)
    np.testing.assert_array_equal(stability.spearman, loo.spearman)


def test_repr_of_calibrations_and_stability_is_a_short_summary():
    shipped = Calibration.load("sgc-spec-2026")  # a long description and corpus record in extra
    rows, _, _ = paper_groups()
    loo = kfold_stability(rows, k=len(rows), seed=0)
    for obj, expected in ((shipped, "sgc-spec-2026"), (loo, "k=13")):
        assert len(repr(obj)) < 300 and "\n" not in repr(obj) and expected in repr(obj), repr(obj)
    assert shipped == Calibration.load("sgc-spec-2026")  # equality still compares every field


def test_an_excess_fit_scores_nothing_within_the_noise_band_and_everything_above_it():
    rng = np.random.default_rng(0)
    matrix = rng.gamma(2.0, 1.0, size=(40, len(COMPONENTS)))
    floors = rng.gamma(2.0, 1.0, size=(40, 4))
    rows = [{**dict(zip(COMPONENTS, m)), **{f"{k}_floor": f for k, f in zip(COMPONENTS[:4], fl)}}
            for m, fl in zip(matrix, floors)]
    fitted = calibrate(rows, floor_band=1.25)
    assert fitted.excess and Calibration.from_dict(fitted.to_dict()).floor_band == 1.25
    from sgc_jax.calibration import normalise
    from sgc_jax.calibration.formula import scored_values

    columns = {k: matrix[:, j] for j, k in enumerate(COMPONENTS)}
    floor_columns = {f"{k}_floor": floors[:, j] for j, k in enumerate(COMPONENTS[:4])}
    scaled = normalise(scored_values(columns, fitted, floor_columns), fitted)
    within = matrix[:, :4] <= 1.25 * floors
    assert within.any() and (~within).any()
    for j, k in enumerate(COMPONENTS[:4]):
        assert (scaled[k][within[:, j]] == 0).all() and (scaled[k][~within[:, j]] > 0).all(), k
    with pytest.raises(ValueError, match="noise-floor columns"):
        calibrate([{k: 1.0 for k in COMPONENTS}] * 3, floor_band=1.25)
    stability = kfold_stability(rows, k=4, floor_band=1.25)
    assert stability.spearman_mean > 0.5
