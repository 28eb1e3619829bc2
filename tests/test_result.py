"""result.py: the corpus ECD column (SPEC §5), reading scores CSVs back, re-scoring without geometry."""

import csv
import dataclasses
import math
import re
from pathlib import Path

import numpy as np
import pytest
from scenes import TINY

import sgc_jax.engines.reference
import sgc_jax.scoring.api
import sgc_jax.scoring.streaming
from sgc_jax import (
    CLIP_COLUMNS,
    COMPONENTS,
    PAIR_COLUMNS,
    BatchResult,
    Calibration,
    ClipResult,
    calibrate,
    score_batch,
    sgc_score,
)
from sgc_jax.io.tables import read_scores, write_scores
from sgc_jax.research.synth import synth_clip
from sgc_jax.scoring.result import camera_dynamics, clip_from_row, failed_clip, rescore_records


def clip_result(clip_id, ecd_trans, ecd_rot, group="g", status="ok", components=None):
    comps = components or dict(zip(COMPONENTS, (1.0, 0.1, 2.0, 0.2, 0.05)))
    return ClipResult(clip_id=clip_id, group=group, status=status, components=comps, ecd_trans=ecd_trans,
                      ecd_rot=ecd_rot, sgc=0.5)


@pytest.fixture(scope="module")
def scored():
    """Four tiny clips in two groups, scored by the reference engine (about a second)."""
    clips = [synth_clip(seed=s, clip_id=f"c{s}", group=f"g{s % 2}", **TINY) for s in range(4)]
    return score_batch(clips, engine="reference")


def forbid_geometry(monkeypatch):
    def refuse(*_args, **_kwargs):
        raise AssertionError("geometry was re-run")

    monkeypatch.setattr(sgc_jax.scoring.api, "engine_steps", refuse)
    monkeypatch.setattr(sgc_jax.scoring.streaming, "engine_steps", refuse)
    monkeypatch.setattr(sgc_jax.engines.reference, "score_pairs", refuse)


def test_ecd_is_the_larger_of_the_min_max_normalised_inputs():
    batch = BatchResult([clip_result("a", 0.0, 4.0), clip_result("b", 1.0, 2.0), clip_result("c", 2.0, 0.0),
                         clip_result("d", 0.5, 1.0)])
    # trans scaled: 0, .5, 1, .25; rot scaled: 1, .5, 0, .25
    np.testing.assert_allclose(batch.ecd, [1.0, 0.5, 1.0, 0.25])
    records = batch.to_records()
    assert [r["ecd"] for r in records] == pytest.approx([1.0, 0.5, 1.0, 0.25])
    assert [r["ecd_trans"] for r in records] == [0.0, 1.0, 2.0, 0.5]  # raw inputs kept
    np.testing.assert_allclose(batch["ecd"], batch.ecd)
    frame = batch.to_pandas()
    assert list(frame["ecd"]) == pytest.approx([1.0, 0.5, 1.0, 0.25])


def test_failed_clip_has_no_ecd_and_does_not_shift_the_others():
    ok = [clip_result("a", 1.0, 1.0), clip_result("b", 3.0, 2.0)]
    failed = clip_result("x", math.nan, math.nan, status="error")
    np.testing.assert_allclose(BatchResult([*ok, failed]).ecd, [0.0, 1.0, np.nan])
    assert camera_dynamics([], []).shape == (0,)
    assert BatchResult([clip_result("solo", 0.3, 2.0)]).ecd[0] == 0.0  # one clip: zero span


def test_scores_csv_reads_back_with_types_and_extra_columns(scored, tmp_path):
    path = scored.to_csv(tmp_path / "scores.csv")
    rows = read_scores(path)
    assert [r["clip_id"] for r in rows] == scored.clip_ids
    for row, clip in zip(rows, scored.clips):
        assert row["status"] == clip.status and row["n_pairs"] == clip.n_pairs == 2
        for k in COMPONENTS:
            assert row[k] == pytest.approx(clip.components[k], rel=1e-12, nan_ok=True)
        assert row["sgc"] == pytest.approx(clip.sgc, rel=1e-12) and row["source"] == str(path)
    study = tmp_path / "study.csv"
    write_scores(study, [{**r, "base": "c0", "kind": "warp", "severity": 0.25} for r in rows])
    header = next(csv.reader(study.open()))
    assert header[:3] == ["clip_id", "group", "status"] and header[-3:] == ["base", "kind", "severity"]
    back = read_scores(study)
    assert back[0]["kind"] == "warp" and back[0]["severity"] == 0.25 and back[0]["base"] == "c0"


def test_reading_a_file_without_components_names_it(tmp_path):
    bad = tmp_path / "other.csv"
    bad.write_text("clip_id,sgc\na,0.1\n")
    with pytest.raises(ValueError, match="other.csv.*depth_error"):
        read_scores(bad)


def test_rescoring_uses_stored_components_not_geometry(scored, tmp_path, monkeypatch):
    new = calibrate(scored, name="tiny")  # any calibration different from the paper's
    forbid_geometry(monkeypatch)
    rescored = scored.rescore(new)
    assert rescored.calibration is new
    expected = sgc_score({k: scored[k] for k in COMPONENTS}, new)
    np.testing.assert_allclose(rescored.sgc, expected, rtol=1e-12)
    assert not np.allclose(rescored.sgc, scored.sgc)  # the calibration did change the scores
    for a, b in zip(rescored.clips, scored.clips):
        assert a.components == b.components and a.pairs is b.pairs
    # the same from the CSV alone, with only per-clip components
    rows = rescore_records(read_scores(scored.to_csv(tmp_path / "s.csv")), new)
    np.testing.assert_allclose([r["sgc"] for r in rows], expected, rtol=1e-12)
    np.testing.assert_allclose([r["ecd"] for r in rows], scored.ecd, rtol=1e-12)


def test_rescoring_a_resumed_clip_uses_its_stored_components(scored, tmp_path, monkeypatch):
    new = calibrate(scored, name="tiny")
    forbid_geometry(monkeypatch)
    resumed = BatchResult([clip_from_row({k: str(v) for k, v in row.items()})
                           for row in read_scores(scored.to_csv(tmp_path / "s.csv"))], scored.calibration)
    assert all(c.pairs is None for c in resumed.clips)  # as a resumed run keeps them
    rescored = resumed.rescore(new)
    np.testing.assert_allclose(rescored.sgc, scored.rescore(new).sgc, rtol=1e-12)
    assert not np.allclose(rescored.sgc, scored.sgc)
    assert all(math.isnan(c.sgc_lo) and c.run_id == "" for c in rescored.clips)  # the interval needs the pairs


def test_a_row_of_a_table_written_before_the_warnings_column_reads_as_without_warnings(scored, tmp_path):
    [row] = [{k: str(v) for k, v in r.items()} for r in read_scores(scored.to_csv(tmp_path / "s.csv"))][:1]
    del row["warnings"]
    assert clip_from_row(row).warnings == "" and clip_from_row(row).sgc == pytest.approx(scored.sgc[0])
    del row["sgc"]
    with pytest.raises(KeyError, match="sgc"):  # only the columns added later may be absent
        clip_from_row(row)


def test_rescore_by_name_restores_the_shipped_scores(scored, monkeypatch):
    forbid_geometry(monkeypatch)
    there_and_back = scored.rescore(calibrate(scored)).rescore("sgc-spec-2026")
    np.testing.assert_allclose(there_and_back.sgc, scored.sgc, rtol=1e-12)
    assert there_and_back.calibration == Calibration.load("sgc-spec-2026")


def test_repr_of_many_clips_is_a_short_summary(scored):
    clips = [dataclasses.replace(c, clip_id=f"{c.clip_id}-{i}") for i in range(250) for c in scored.clips]
    clips[0] = dataclasses.replace(clips[0], status="error", reason="x" * 500)
    batch = BatchResult(clips, scored.calibration)
    text = repr(batch)
    assert len(text) < 500 and len(text.splitlines()) <= 3, text
    assert "1000 clips" in text and "error 1" in text and "engine reference" in text
    assert repr(scored.calibration.name) in text and ".table()" in text and ".to_pandas()" in text
    for clip in (clips[0], clips[1]):  # one clip and its per-pair arrays are summaries too
        assert len(repr(clip)) < 300 and clip.clip_id in repr(clip)
        assert len(repr(clip.pairs)) < 300
    # the summary repr leaves dataclass equality as it was
    assert batch == BatchResult(list(clips), scored.calibration)
    assert batch != BatchResult(clips[:-1], scored.calibration)


def test_the_printed_table_carries_the_scores_interval_and_every_unit(scored):
    head, units, rule, *rows = scored.table().splitlines()
    assert head.split() == ["clip_id", "group", "status", "sgc", "sgc_lo", "sgc_hi", *COMPONENTS, "evidence"]
    assert units.split() == ["lower=better", "90%", "interval", "90%", "interval", "deg²", "(%", "of", "D)²",
                             "deg²", "(%", "of", "D)²", "%", "of", "depth", "0-1"]
    first = scored.clips[0]
    assert math.isfinite(first.sgc_lo) and first.sgc_lo <= first.sgc_hi
    assert f"{first.sgc_lo:.4g}" in rows[0] and f"{first.sgc_hi:.4g}" in rows[0]


def test_the_printed_table_names_d_and_says_why_a_clip_was_not_scored(scored):
    broken = failed_clip("broken", "clip 'broken': array 'depth': expected shape (T, H, W), found shape (3,)")
    lines = BatchResult([*scored.clips, broken], scored.calibration).table().splitlines()
    assert any(line.startswith("D: the clip's depth unit") for line in lines)
    assert lines[-1] == f"broken (error): {broken.reason}"


ROOT = Path(__file__).resolve().parents[1]


def documented_clip_columns() -> list[str]:
    """The first cells of the per-clip table of docs/semantics.md §4, in order."""
    text = (ROOT / "docs" / "semantics.md").read_text().split("## 4. Units of the output columns", 1)[1]
    table = text.split("Per-clip columns (`CLIP_COLUMNS`", 1)[1].split("\n\n")[1]
    rows = [line for line in table.splitlines() if line.startswith("| `")]
    return [name for line in rows for name in re.findall(r"`([^`]+)`", line.split("|")[1])]


def documented_pair_columns() -> list[str]:
    """The backticked list of per-pair columns in docs/semantics.md §4."""
    text = " ".join((ROOT / "docs" / "semantics.md").read_text().split("Per-pair columns (`PAIR_COLUMNS`", 1)[1].split())
    return [c.strip() for c in re.search(r"\): `([^`]+)`", text).group(1).split(",")]


def test_documented_column_lists_are_the_columns_written(scored, tmp_path):
    scored.to_csv(tmp_path / "clips.csv", pairs_path=tmp_path / "pairs.csv")
    written = next(csv.reader((tmp_path / "clips.csv").open()))
    assert written == list(CLIP_COLUMNS) == documented_clip_columns()
    written_pairs = next(csv.reader((tmp_path / "pairs.csv").open()))
    assert written_pairs == list(PAIR_COLUMNS) == documented_pair_columns()
