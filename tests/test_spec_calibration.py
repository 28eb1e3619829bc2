"""Calibrations carry their semantics (docs/semantics.md §5.2) and sgc-spec-2026 anchors 0 at a clean
rigid scene (§5.4)."""

import dataclasses

import numpy as np
import pytest
from scenes import DEMO_SCENE

from sgc_jax import Calibration, CalibrationMismatchError, default_calibration, rescore_records, score_batch
from sgc_jax.calibration import COMPONENTS, calibrate
from sgc_jax.research.perturb import PERTURBATIONS, perturb_clip
from sgc_jax.research.spec_calibration import CLEAN_QUANTILE, FLOOR_BAND, corpus_description, fit_spec_calibration
from sgc_jax.research.synth import synth_clip

# The demo's clip size (96x128, 8 frames, 1024 tracks): its bucket is compiled by the CLI tests too.
SEVERITIES = (0.25, 0.5, 0.75, 1.0)
# A rigid static scene must not score above this merely because its depth is large.
RIGID_BAR = 0.05


def test_shipped_calibrations_record_their_semantics():
    spec, paper = Calibration.load("sgc-spec-2026"), Calibration.load("sgc-paper-2026")
    assert spec.weight == pytest.approx(paper.weight)  # the paper's weights, spec normalisation
    assert (spec.compat, paper.compat) == ("spec", "authors")
    assert default_calibration("spec") == "sgc-spec-2026" and default_calibration("authors") == "sgc-paper-2026"
    assert spec.to_dict()["units"]["local_trans_var"] == "(% of D)^2"
    assert spec.extra["corpus"] == corpus_description()  # the JSON was fitted on the corpus the module builds
    assert sum(spec.weight.values()) == pytest.approx(1.0)


def test_a_calibration_of_the_other_semantics_is_refused(rigid_clip):
    with pytest.raises(CalibrationMismatchError, match="compat='authors'.*sgc-spec-2026"):
        score_batch([rigid_clip], engine="reference", calibration="sgc-paper-2026")
    with pytest.raises(CalibrationMismatchError, match="sgc-paper-2026"):
        score_batch([rigid_clip], engine="reference", compat="authors", calibration="sgc-spec-2026")
    result = score_batch([rigid_clip], engine="reference")
    assert result.clips[0].compat == "spec" and result.calibration.name == "sgc-spec-2026"
    with pytest.raises(CalibrationMismatchError):
        rescore_records(result.to_records(), "sgc-paper-2026")
    with pytest.raises(CalibrationMismatchError):
        result.rescore("sgc-paper-2026")
    fitted = calibrate(result.to_records() * 2)
    assert fitted.compat == "spec"
    unknown = dataclasses.replace(Calibration.load("sgc-paper-2026"), compat="")  # an old JSON: no check
    assert np.isfinite(result.rescore(unknown).clips[0].sgc)


def test_fit_rule_puts_no_excess_at_zero_and_full_severity_at_one():
    rng = np.random.default_rng(0)
    clean = rng.gamma(2.0, 0.05, size=(40, 5))
    floors = rng.gamma(2.0, 0.05, size=(70, 4))
    perturbed = clean[:30] + np.repeat(np.array([0.5, 1.0, 2.0, 4.0, 8.0]), 6)[:, None] * [1, 2, 1, 2, 0.1]
    matrix = np.vstack([clean, perturbed])
    kinds = [""] * 40 + ["warp"] * 30
    severities = [0.0] * 40 + list(np.repeat([0.25, 0.5, 0.75, 1.0, 1.0], 6))
    calibration = fit_spec_calibration(matrix, floors, kinds, severities)
    assert calibration.excess
    columns = {k: matrix[:, j] for j, k in enumerate(COMPONENTS)}
    from sgc_jax.calibration import normalise
    from sgc_jax.calibration.formula import scored_values

    floor_columns = {f"{k}_floor": floors[:, j] for j, k in enumerate(COMPONENTS[:4])}
    normalised = np.column_stack([normalise(scored_values(columns, calibration, floor_columns), calibration)[k]
                                  for k in COMPONENTS])
    within_band = matrix[:, :4] <= FLOOR_BAND * floors
    assert within_band.any() and (normalised[:, :4][within_band] == 0).all()
    assert (normalised[:, :4][~within_band] > 0).all()  # any excess counts
    assert np.mean(normalised[:40, 4] == 0) >= CLEAN_QUANTILE / 100 - 0.05  # the depth error: no floor
    assert np.allclose(np.median(normalised[-12:], axis=0).max(), 1.0)


@pytest.fixture(scope="module")
def ladder():
    """Two rigid scenes (one far away: depth 20-120 for the same camera motion) clean and under
    each perturbation kind, scored with the default engine and calibration."""
    bases = [synth_clip(seed=7, clip_id="near", noise_px=0.5, **DEMO_SCENE),
             synth_clip(seed=8, clip_id="far", noise_px=0.5, depth_range=(20.0, 120.0), **DEMO_SCENE)]
    clips = [*bases, *(perturb_clip(b, kind, s) for b in bases for kind in PERTURBATIONS for s in SEVERITIES)]
    result = score_batch(clips)
    assert all(c.status != "error" for c in result.clips), [c.reason for c in result.clips]
    return {c.clip_id: c.sgc for c in result.clips}


def test_clean_rigid_scenes_score_below_every_perturbed_version(ladder):
    for base in ("near", "far"):
        perturbed = {k: v for k, v in ladder.items() if k.startswith(f"{base}~")}
        assert len(perturbed) == len(PERTURBATIONS) * len(SEVERITIES)
        for name, value in perturbed.items():
            assert ladder[base] < value, (name, ladder[base], value)


def test_a_rigid_scene_does_not_score_high_because_it_is_far_away(ladder):
    assert ladder["near"] < RIGID_BAR and ladder["far"] < RIGID_BAR
