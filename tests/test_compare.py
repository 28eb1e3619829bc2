"""compare.py: per-group tables, per-clip ranks, agreement of two score files, dependence on ECD."""

import math

import numpy as np
import pytest
from scipy import stats as scipy_stats

from sgc_jax import COMPONENTS
from sgc_jax.cli import main
from sgc_jax.io.tables import write_scores
from sgc_jax.research.compare import (
    GROUP_COLUMNS,
    MIN_N,
    agreement_between,
    clip_table,
    format_group_table,
    format_ranking,
    group_table,
    motion_dependence,
    ranking_table,
)

NAN = math.nan


def row(clip_id, group, sgc, ecd_trans=1.0, ecd_rot=1.0, status="ok"):
    return {"clip_id": clip_id, "group": group, "status": status, "sgc": sgc, "ecd_trans": ecd_trans,
            "ecd_rot": ecd_rot}


def corpus():
    """Group "good" scores low, "bad" high, "mid" ties "good"'s mean (binary-exact values)."""
    return [row("g1", "good", 0.125, 0.0, 0.0), row("g2", "good", 0.375, 1.0, 0.5), row("g3", "good", 0.25, 2.0, 1.0),
            row("b1", "bad", 0.9, 4.0, 2.0), row("b2", "bad", 0.7, 3.0, 1.5),
            row("m1", "mid", 0.25), row("m2", "mid", 0.25),
            row("x1", "bad", NAN, NAN, NAN, status="error"), row("x2", "mid", 5.0, status="error")]


def test_group_table_statistics_and_ranks():
    table = group_table(corpus(), n_boot=500, seed=0)
    assert [t["group"] for t in table][-1] == "bad"
    by = {t["group"]: t for t in table}
    assert set(table[0]) == set(GROUP_COLUMNS)
    assert by["good"]["n"] == 3 and by["bad"]["n"] == 2 and by["mid"]["n"] == 2  # error rows left out
    assert by["good"]["mean"] == 0.25 and by["good"]["median"] == 0.25
    assert by["bad"]["mean"] == pytest.approx(0.8)
    assert by["good"]["rank"] == by["mid"]["rank"] == 1.5 and by["bad"]["rank"] == 3.0  # tie: average rank
    assert by["good"]["ci_low"] < 0.25 < by["good"]["ci_high"]
    assert 0.125 <= by["good"]["ci_low"] and by["good"]["ci_high"] <= 0.375  # a mean's CI stays in the data range
    assert math.isnan(by["mid"]["ci_low"]) and math.isnan(by["bad"]["ci_high"])  # two clips: no CI
    # ECD over every row with inputs (trans 0..4 -> /4, rot 0..2 -> /2): "good" gets 0, 1/4, 1/2
    ecd_good = np.array([0.0, 0.25, 0.5])
    assert by["good"]["r_ecd"] == pytest.approx(scipy_stats.pearsonr([0.125, 0.375, 0.25], ecd_good).statistic)
    assert by["good"]["ecd_mean"] == pytest.approx(ecd_good.mean())


def test_group_table_of_another_column():
    rows = [{**r, "depth_error": i * 1.0} for i, r in enumerate(corpus())]
    by = {t["group"]: t for t in group_table(rows, "depth_error", n_boot=10)}
    assert by["good"]["mean"] == pytest.approx(1.0)  # rows 0, 1, 2
    with pytest.raises(KeyError, match="no_such"):
        group_table(rows, "no_such")


def test_clip_table_ranks_scored_clips():
    table = clip_table(corpus())
    assert [t["clip_id"] for t in table][:1] == ["g1"] and table[-1]["clip_id"] == "b1"
    assert len(table) == 7 and {t["rank"] for t in table if t["value"] == 0.25} == {3.0}  # three tied: ranks 2-4


def test_clip_table_carries_each_clips_score_interval():
    rows = [{**r, "sgc_lo": r["sgc"] - 0.1, "sgc_hi": r["sgc"] + 0.1} for r in corpus()]
    assert all(t["lo"] == pytest.approx(t["value"] - 0.1) and t["hi"] == pytest.approx(t["value"] + 0.1)
               for t in clip_table(rows))
    assert all(np.isnan(t["lo"]) for t in clip_table(rows, "ecd_trans"))  # only the score has one


def test_agreement_by_clip_and_by_group_matches_scipy():
    a = corpus()
    rng = np.random.default_rng(0)
    b = [{**r, "sgc": r["sgc"] + rng.normal(scale=0.15)} for r in a] + [row("only_b", "new", 0.5)]
    ok = [r for r in a if r["status"] == "ok"]
    b_by_id = {r["clip_id"]: r["sgc"] for r in b}
    expected = scipy_stats.kendalltau([r["sgc"] for r in ok], [b_by_id[r["clip_id"]] for r in ok]).statistic
    agree = agreement_between(a, b, by="clip")
    assert agree["n"] == 7 and agree["kendall_tau"] == pytest.approx(expected, abs=1e-12)
    assert agree["unmatched"] == ["only_b"]  # error rows count as absent in both
    by_group = agreement_between(a, b, by="group")
    assert by_group["n"] == 3 and by_group["unmatched"] == ["new"]
    assert agreement_between(a, a, by="group")["spearman"] == pytest.approx(1.0)


def test_agreement_by_clip_needs_unique_ids():
    with pytest.raises(ValueError, match="twice"):
        agreement_between(corpus() + [row("g1", "good", 0.4)], corpus())


def test_motion_dependence_of_a_score_driven_by_camera_motion():
    rows = [row(f"c{i}", "g", 0.1 + 0.05 * i, ecd_trans=float(i), ecd_rot=0.0) for i in range(6)]
    motion = motion_dependence(rows)
    assert motion["n_ecd"] == 6 and motion["pearson"] == pytest.approx(1.0) and motion["r2"] == pytest.approx(1.0)
    flat = motion_dependence([{**r, "sgc": 0.3 + 0.01 * (-1) ** i} for i, r in enumerate(rows)])
    assert abs(flat["spearman"]) < 0.5


def test_ranking_table_between_variants_like_the_papers_table_3():
    full = corpus()
    ablated = [{**r, "sgc": r["sgc"] * 2 if r["group"] != "mid" else 2.0} for r in full]  # "mid" moves to last
    rows = ranking_table({"full": full, "w/o global pose": ablated})
    ranks = {(r["variant"], r["key"]): r["rank"] for r in rows}
    assert ranks[("full", "good")] == ranks[("full", "mid")] == 1.5 and ranks[("full", "bad")] == 3
    assert ranks[("w/o global pose", "mid")] == 3 and ranks[("w/o global pose", "good")] == 1
    rho = {r["variant"]: r["spearman_vs_first"] for r in rows}
    assert rho["full"] == pytest.approx(1.0)
    assert rho["w/o global pose"] == pytest.approx(scipy_stats.spearmanr([0.25, 0.8, 0.25], [0.5, 1.6, 2.0])[0])
    text = format_ranking(rows)
    assert text.splitlines()[0].split()[:4] == ["variant", "good", "mid", "bad"] and "w/o global pose" in text


# ----------------------------------------------------------------------------- too few values


def small_groups():
    """Groups of 1, 2 and 3 clips whose scores follow ECD exactly (any two points would give r = 1)."""
    sizes = {"one": 1, "two": 2, "three": 3}
    return [row(f"{g}{i}", g, 0.1 * (j + 1) + 0.01 * i, ecd_trans=float(i + j), ecd_rot=0.0)
            for j, (g, n) in enumerate(sizes.items()) for i in range(n)]


def test_groups_of_fewer_than_three_clips_get_no_ci_and_no_correlation():
    assert MIN_N == 3
    by = {t["group"]: t for t in group_table(small_groups(), n_boot=200)}
    for g in ("one", "two"):
        assert math.isnan(by[g]["ci_low"]) and math.isnan(by[g]["ci_high"]) and math.isnan(by[g]["r_ecd"]), g
        assert not math.isnan(by[g]["mean"]) and by[g]["rank"] > 0  # the mean and rank stay
    assert by["three"]["ci_low"] < by["three"]["mean"] < by["three"]["ci_high"]
    assert by["three"]["r_ecd"] == pytest.approx(1.0)
    text = format_group_table(group_table(small_groups(), n_boot=200))
    footnote = text.splitlines()[-1]
    assert footnote.startswith("* n < 3 (one, two): no CI, no r_ecd") and "three" not in footnote
    assert "* n < 3" not in format_group_table(group_table(corpus()[:3], n_boot=10))  # only "good", n = 3


def test_correlations_of_fewer_than_three_keys_are_nan():
    a = small_groups()
    b = [{**r, "sgc": 2 * r["sgc"]} for r in a]
    two = [r for r in a if r["group"] != "three"], [r for r in b if r["group"] != "three"]
    agree = agreement_between(*two, by="group")
    assert agree["n"] == 2 and all(math.isnan(agree[k]) for k in ("spearman", "kendall_tau", "pearson"))
    assert agreement_between(a, b, by="group")["spearman"] == pytest.approx(1.0)  # three groups
    ranking = ranking_table({"a": two[0], "b": two[1]})
    assert all(math.isnan(r["spearman_vs_first"]) for r in ranking)
    assert format_ranking(ranking).splitlines()[-1].startswith("* 2 shared keys (< 3): no rho")
    assert math.isnan(motion_dependence(a[:2])["pearson"]) and math.isnan(motion_dependence(a[:2])["spearman"])
    assert motion_dependence(a[:3])["n_ecd"] == 3 and not math.isnan(motion_dependence(a[:3])["pearson"])


def test_compare_command_prints_the_small_sample_caveats(tmp_path, capsys):
    rows = [{**r, **{k: 0.0 for k in COMPONENTS}} for r in small_groups() if r["group"] != "three"]
    path = write_scores(tmp_path / "scores.csv", rows)
    assert main(["compare", str(path), "--against", str(path), "--by", "group", "--boot", "50"]) == 0
    out = capsys.readouterr().out
    assert "* n < 3 (one, two): no CI, no r_ecd" in out
    assert "sgc vs ECD over 3 clips: Pearson r" in out  # three clips with ECD: a correlation
    assert "2 matched groups (< 3), no correlation" in out and "Spearman rho = 1.0000" not in out
    assert "* 2 shared keys (< 3): no rho" in out
