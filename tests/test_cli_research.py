"""The research subcommands (calibrate, rescore, compare) as real processes on real files."""

import csv
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scenes import TINY
from tolerances import PUBLISHED_SCORE_ATOL, PUBLISHED_WEIGHT_ATOL

import sgc_jax.engines.reference
import sgc_jax.scoring.api
import sgc_jax.scoring.streaming
from sgc_jax import COMPONENTS, Calibration, calibrate, save_clip, sgc_score
from sgc_jax.calibration import kfold_stability
from sgc_jax.cli import main
from sgc_jax.io.tables import read_scores
from sgc_jax.research.compare import GROUP_COLUMNS
from sgc_jax.research.synth import synth_clip

CLI = [sys.executable, "-m", "sgc_jax.cli"]
GROUPS_CSV = Path(__file__).parent / "data" / "sgc-paper-2026-groups.csv"


def run(*args):
    return subprocess.run([*CLI, *map(str, args)], capture_output=True, text=True, timeout=600)


def column(path, name):
    return np.array([float(r[name]) if r[name] else np.nan for r in csv.DictReader(Path(path).open())])


@pytest.fixture(scope="module")
def scores_csv(tmp_path_factory):
    """Six tiny clips in three groups scored by `sgc-jax score --engine reference` (default calibration)."""
    root = tmp_path_factory.mktemp("corpus")
    for seed in range(6):
        save_clip(root / "clips" / f"c{seed}.npz",
                  synth_clip(seed=seed, clip_id=f"c{seed}", group=f"g{seed % 3}", layer_drift=0.05 * seed, **TINY))
    out = root / "scores.csv"
    proc = run("score", root / "clips", "--engine", "reference", "--out", out, "-q")
    assert proc.returncode == 0, proc.stderr
    return out


def test_calibrate_on_published_groups_prints_weights_variance_and_stability(tmp_path):
    out, rescored = tmp_path / "calib.json", tmp_path / "rescored.csv"
    proc = run("calibrate", GROUPS_CSV, "--out", out, "--rescored", rescored, "--folds", "5")
    assert proc.returncode == 0, proc.stderr
    paper = Calibration.load("sgc-paper-2026")
    fitted = Calibration.load(out)
    for k in COMPONENTS:
        assert fitted.weight[k] == pytest.approx(paper.weight[k], abs=PUBLISHED_WEIGHT_ATOL)
        assert f"{paper.weight[k]:.4f}" in proc.stdout
    ratio = calibrate(read_scores(GROUPS_CSV)).extra["pc1_explained_variance_ratio"]
    assert f"PC1 explained variance ratio: {ratio:.4f}" in proc.stdout
    stability = kfold_stability(read_scores(GROUPS_CSV), k=5)
    assert stability.table() in proc.stdout
    assert json.loads(out.read_text())["kfold_stability"]["spearman_mean"] == pytest.approx(stability.spearman_mean)
    np.testing.assert_allclose(column(rescored, "sgc"), column(GROUPS_CSV, "sgc"), atol=PUBLISHED_SCORE_ATOL)


def test_calibrate_with_more_folds_than_rows_says_so_and_runs_leave_one_out(capsys):
    assert main(["calibrate", str(GROUPS_CSV), "--folds", "20"]) == 0
    out, err = capsys.readouterr()
    assert "warning: k=20 folds but only 13 scored rows" in err and "Traceback" not in err
    assert "13-fold stability" in out and kfold_stability(read_scores(GROUPS_CSV), k=13).table() in out


def test_score_with_a_new_calibration_equals_rescoring_the_paper_scores(scores_csv, tmp_path):
    calib = tmp_path / "calib.json"
    proc = run("calibrate", scores_csv, "--by", "group", "--folds", "3", "--out", calib)
    assert proc.returncode == 0, proc.stderr
    assert "3-fold stability" in proc.stdout and "by=group" in proc.stdout
    direct = tmp_path / "direct.csv"
    proc = run("score", scores_csv.parent / "clips", "--engine", "reference", "--calibration", calib,
               "--out", direct, "-q")
    assert proc.returncode == 0, proc.stderr
    rescored = tmp_path / "rescored.csv"
    proc = run("rescore", scores_csv, "--calibration", calib, "--out", rescored)
    assert proc.returncode == 0, proc.stderr
    np.testing.assert_allclose(column(rescored, "sgc"), column(direct, "sgc"), rtol=1e-12)
    assert not np.allclose(column(rescored, "sgc"), column(scores_csv, "sgc"))
    components = {k: column(scores_csv, k) for k in COMPONENTS}
    np.testing.assert_allclose(column(direct, "sgc"), sgc_score(components, Calibration.load(calib)), rtol=1e-12)


def test_rescore_reads_components_and_never_runs_geometry(scores_csv, tmp_path, monkeypatch, capsys):
    def refuse(*_args, **_kwargs):
        raise AssertionError("geometry was re-run")

    monkeypatch.setattr(sgc_jax.scoring.api, "engine_steps", refuse)
    monkeypatch.setattr(sgc_jax.scoring.streaming, "engine_steps", refuse)
    monkeypatch.setattr(sgc_jax.engines.reference, "score_pairs", refuse)
    assert main(["rescore", str(scores_csv), "--calibration", "sgc-spec-2026", "--out", str(tmp_path / "r.csv")]) == 0
    np.testing.assert_allclose(column(tmp_path / "r.csv", "sgc"), column(scores_csv, "sgc"), rtol=1e-12)
    assert main(["calibrate", str(scores_csv), "--folds", "0", "--rescored", str(tmp_path / "c.csv")]) == 0
    assert "PC1 explained variance" in capsys.readouterr().out


def test_compare_by_group_with_agreement(scores_csv, tmp_path):
    table = tmp_path / "groups.csv"
    proc = run("compare", scores_csv, "--by", "group", "--against", scores_csv, "--out", table, "--boot", "200")
    assert proc.returncode == 0, proc.stderr
    rows = list(csv.DictReader(table.open()))
    assert [r["group"] for r in rows] and set(rows[0]) == set(GROUP_COLUMNS)
    assert sorted(float(r["rank"]) for r in rows) == [1.0, 2.0, 3.0]
    assert "sgc vs ECD over 6 clips" in proc.stdout
    assert "over 3 matched groups: Spearman rho = 1.0000" in proc.stdout

    same = run("compare", scores_csv, "--by", "clip", "--against", scores_csv)
    assert same.returncode == 0, same.stderr
    assert "over 6 matched clips: Spearman rho = 1.0000, Kendall tau-b = 1.0000" in same.stdout


def test_research_commands_report_bad_input_without_traceback(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("clip_id,sgc\na,0.1\n")
    for args in (("calibrate", bad), ("rescore", bad, "--calibration", "sgc-spec-2026"), ("compare", bad),
                 ("compare", tmp_path / "missing.csv")):
        proc = run(*args)
        assert proc.returncode == 2 and "Traceback" not in proc.stderr and proc.stderr.startswith("sgc-jax")
    proc = run("rescore", GROUPS_CSV, "--calibration", "no-such-calibration")
    assert proc.returncode == 2 and "no-such-calibration" in proc.stderr


def test_a_missing_optional_package_is_a_usage_error_naming_its_extra(scores_csv, tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "pyarrow", None)  # `import pyarrow` now fails, as without the extra
    table = tmp_path / "scores.parquet"
    table.write_bytes(b"PAR1")
    for args in (["compare", str(table)], ["score", "s3://bucket/clips/"],
                 ["score", str(scores_csv.parent / "clips"), "--engine", "reference", "--out", str(tmp_path / "s.parquet")]):
        assert main(args) == 2, args
        err = capsys.readouterr().err
        assert "sgc-jax[parquet]" in err and "Traceback" not in err and "internal error" not in err, err
