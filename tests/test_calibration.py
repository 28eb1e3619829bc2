"""SPEC §4: the score formula, the shipped paper calibration, and fitting a calibration."""

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from sgc_jax import COMPONENTS, Calibration, calibrate, sgc_score

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
    # the published raw values are rounded to 4 decimals, so the score is only good to ~1e-4
    assert abs(float(score) - expected) < 1e-3


def test_score_formula_reproduces_all_thirteen_groups():
    _, matrix, sgc = paper_groups()
    scores = sgc_score({k: matrix[:, j] for j, k in enumerate(COMPONENTS)}, Calibration.load("sgc-paper-2026"))
    np.testing.assert_allclose(scores, sgc, atol=2e-4)


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
        assert abs(fitted.weight[k] - paper.weight[k]) < 1e-4
    assert abs(sum(fitted.weight.values()) - 1.0) < 1e-12
    rescored = sgc_score({k: np.array([float(r[k]) for r in rows]) for k in COMPONENTS}, fitted)
    np.testing.assert_allclose(rescored, sgc, atol=2e-4)


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
