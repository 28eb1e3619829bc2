"""Corpus tables (docs/semantics.md §6.5, paper §4.2-4.4): per-group summaries with bootstrap CIs and ranks,
agreement between two score files, and how much a score follows camera dynamics (ECD).

Inputs are per-clip rows (columns of docs/semantics.md §4), e.g. ``BatchResult.to_records()`` or
``sgc_jax.read_scores(...)``. Rows with status ``error`` or a NaN value are left out of
every statistic. Ranks: 1 = lowest mean (lower SGC is better), ties share their average rank.
Fewer than :data:`MIN_N` values give no bootstrap CI and no correlation (NaN): the CI of one or
two values is the values themselves, and any two points correlate at exactly +-1.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from ..io.tables import format_table
from ..scoring.result import add_ecd
from ..stats import agreement, bootstrap_ci, paired, pearson, rankdata, spearman

#: The fewest values (clips of a group, matched keys, clips with ECD) that get a CI or a correlation.
MIN_N = 3
GROUP_COLUMNS = ("group", "n", "mean", "median", "ci_low", "ci_high", "rank", "ecd_mean", "r_ecd")
RANKING_COLUMNS = ("variant", "key", "value", "rank", "spearman_vs_first")
CLIP_TABLE_COLUMNS = ("clip_id", "group", "value", "lo", "hi", "ecd", "rank")


def _scored(records: Sequence[dict[str, Any]], column: str) -> list[dict[str, Any]]:
    if records and column not in records[0]:
        raise KeyError(f"no column {column!r} in the rows; columns: {list(records[0])}")
    return [r for r in records if r.get("status", "ok") != "error" and not np.isnan(float(r[column]))]


def _correlation(fn: Any, a: Any, b: Any) -> float:
    """``fn(a, b)``, or NaN when fewer than MIN_N pairs are free of NaN."""
    return fn(a, b) if paired(a, b)[0].size >= MIN_N else float("nan")


def group_table(records: Sequence[dict[str, Any]], column: str = "sgc", *, n_boot: int = 2000,
                level: float = 0.95, seed: int = 0) -> list[dict[str, Any]]:
    """One row per group (sorted by rank): n, mean, median, percentile-bootstrap CI of the mean,
    rank of the mean, mean ECD (normalised over all ``records``) and Pearson r of ``column`` vs
    ECD within the group (the paper's motion-robustness check). CI and r are NaN for a group of
    fewer than :data:`MIN_N` clips (r: clips with an ECD); :func:`format_group_table` says so."""
    rows = _scored(add_ecd(records), column)
    groups = sorted({str(r.get("group", "")) for r in rows})
    table = []
    for g in groups:
        values = np.array([float(r[column]) for r in rows if str(r.get("group", "")) == g])
        ecd = np.array([float(r["ecd"]) for r in rows if str(r.get("group", "")) == g])
        lo, hi = (bootstrap_ci(values, np.mean, n_boot=n_boot, level=level, seed=seed) if values.size >= MIN_N
                  else (float("nan"), float("nan")))
        table.append({"group": g, "n": int(values.size), "mean": float(values.mean()),
                      "median": float(np.median(values)), "ci_low": lo, "ci_high": hi,
                      "ecd_mean": float(np.nanmean(ecd)) if not np.isnan(ecd).all() else float("nan"),
                      "r_ecd": _correlation(pearson, values, ecd)})
    ranks = rankdata([t["mean"] for t in table])
    for t, rank in zip(table, ranks):
        t["rank"] = float(rank)
    return [{k: t[k] for k in GROUP_COLUMNS} for t in sorted(table, key=lambda t: t["rank"])]


def format_group_table(table: Sequence[dict[str, Any]], columns: Sequence[str] = GROUP_COLUMNS) -> str:
    """:func:`group_table` rows as terminal text, with a footnote when a group is too small for a CI
    or a correlation."""
    text = format_table(table, columns)
    small = [t["group"] for t in table if t["n"] < MIN_N]
    if small:
        text += (f"\n* n < {MIN_N} ({', '.join(small)}): no CI, no r_ecd (one or two clips give a CI equal to "
                 "the values and r = +-1 whatever the data)")
    return text


def clip_table(records: Sequence[dict[str, Any]], column: str = "sgc") -> list[dict[str, Any]]:
    """One row per scored clip (sorted by rank): clip_id, group, value of ``column``, its 90 %
    interval ``lo``, ``hi`` (``sgc_lo``, ``sgc_hi`` of docs/semantics.md §5.6 for ``sgc``; NaN for
    other columns), ECD, rank."""
    rows = _scored(add_ecd(records), column)
    ranks = rankdata([float(r[column]) for r in rows])
    bound = lambda r, name: float(r.get(name, "nan")) if column == "sgc" else float("nan")  # noqa: E731
    table = [{"clip_id": r["clip_id"], "group": r.get("group", ""), "value": float(r[column]),
              "lo": bound(r, "sgc_lo"), "hi": bound(r, "sgc_hi"), "ecd": float(r["ecd"]), "rank": float(rank)}
             for r, rank in zip(rows, ranks)]
    return sorted(table, key=lambda t: t["rank"])


def _keyed(records: Sequence[dict[str, Any]], column: str, by: str) -> dict[str, float]:
    rows = _scored(records, column)
    if by == "group":
        values: dict[str, list[float]] = {}
        for r in rows:
            values.setdefault(str(r.get("group", "")), []).append(float(r[column]))
        return {g: float(np.mean(v)) for g, v in values.items()}
    if by != "clip":
        raise ValueError(f"by must be 'clip' or 'group', got {by!r}")
    out: dict[str, float] = {}
    for r in rows:
        if r["clip_id"] in out:
            raise ValueError(f"clip_id {r['clip_id']!r} appears twice; agreement by clip needs unique ids")
        out[r["clip_id"]] = float(r[column])
    return out


def agreement_between(records_a: Sequence[dict[str, Any]], records_b: Sequence[dict[str, Any]],
                      column: str = "sgc", *, by: str = "clip") -> dict[str, Any]:
    """Spearman rho, Kendall tau-b and Pearson r between two score tables, matched by clip_id
    (``by="clip"``) or by group of the per-group means (``by="group"``); ``n`` matched keys and
    ``unmatched`` (keys present in only one table). The correlations are NaN with fewer than
    :data:`MIN_N` matched keys."""
    a, b = _keyed(records_a, column, by), _keyed(records_b, column, by)
    keys = sorted(set(a) & set(b))
    out = agreement([a[k] for k in keys], [b[k] for k in keys])
    if out["n"] < MIN_N:
        out.update(spearman=float("nan"), kendall_tau=float("nan"), pearson=float("nan"))
    return {**out, "by": by, "unmatched": sorted(set(a) ^ set(b))}


def ranking_table(variants: dict[str, Sequence[dict[str, Any]]], column: str = "sgc", *,
                  by: str = "group") -> list[dict[str, Any]]:
    """Paper Table 3 ("ranking consistency across estimators"): for each variant (e.g. the full
    score and the "w/o VGGT" one, docs/semantics.md §6.3), each key's value (group mean, or clip
    value with ``by="clip"``) and rank over the keys every variant shares, and Spearman rho of the
    variant's values against the first variant's (NaN with fewer than :data:`MIN_N` shared keys).
    Long rows of :data:`RANKING_COLUMNS`."""
    keyed = {name: _keyed(records, column, by) for name, records in variants.items()}
    shared = sorted(set.intersection(*(set(k) for k in keyed.values()))) if keyed else []
    first = next(iter(keyed.values()), {})
    rows = []
    for name, values in keyed.items():
        vector = [values[k] for k in shared]
        rho = _correlation(spearman, vector, [first[k] for k in shared])
        rows += [{"variant": name, "key": k, "value": v, "rank": float(r), "spearman_vs_first": rho}
                 for k, v, r in zip(shared, vector, rankdata(np.array(vector)))]
    return rows


def format_ranking(rows: Sequence[dict[str, Any]]) -> str:
    """The ranking table as text: one line per variant, keys ordered by the first variant's rank,
    cells "value (rank)", then rho against the first variant."""
    variants = list(dict.fromkeys(r["variant"] for r in rows))
    if not variants:
        return "(no key shared by every variant)"
    first = sorted((r for r in rows if r["variant"] == variants[0]), key=lambda r: r["rank"])
    keys = [r["key"] for r in first]
    cell = {(r["variant"], r["key"]): f"{r['value']:.3f} ({r['rank']:g})" for r in rows}
    rho = {r["variant"]: r["spearman_vs_first"] for r in rows}
    table = [["variant", *keys, "rho vs first"]]
    table += [[v, *(cell[(v, k)] for k in keys), f"{rho[v]:.3f}"] for v in variants]
    widths = [max(len(row[i]) for row in table) for i in range(len(table[0]))]
    text = "\n".join("  ".join(c.ljust(w) for c, w in zip(row, widths)) for row in table)
    if len(keys) < MIN_N:
        text += f"\n* {len(keys)} shared keys (< {MIN_N}): no rho (two keys always rank at rho = +-1)"
    return text


def motion_dependence(records: Sequence[dict[str, Any]], column: str = "sgc") -> dict[str, Any]:
    """How much ``column`` follows camera motion over the scored clips: Pearson r (and r^2, the
    share of variance motion explains) and Spearman rho against ECD (paper §4.3); ``n_ecd``:
    clips with both values (NaN correlations below :data:`MIN_N`)."""
    rows = _scored(add_ecd(records), column)
    values, ecd = [float(r[column]) for r in rows], [float(r["ecd"]) for r in rows]
    r = _correlation(pearson, values, ecd)
    return {"n": len(rows), "n_ecd": int(np.sum(~np.isnan(ecd))) if ecd else 0, "pearson": r, "r2": r * r,
            "spearman": _correlation(spearman, values, ecd)}
