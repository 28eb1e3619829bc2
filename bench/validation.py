"""The validation protocol (issue 58, docs/semantics.md §7.4): the default score on a split of
synthetic scenes under each noise model, level and track count, consistent and inconsistent.

    python bench/validation.py [--split test|fit] [--models iid-curr iid-both ...] [--levels 0.25 0.5 1 2]
                               [--tracks 200 1000 4096] [--scenes N] [--out rows.csv] [--rows rows.csv]
                               [--intervals] [--config FILE] [--noise-draw K] [--against rows.csv]

Constants are fitted on ``--split fit``; the figures of RESULTS and the docs come from ``--split
test`` (sgc_jax.research.protocol). ``--rows`` prints the tables from a CSV an earlier run wrote
with ``--out`` instead of scoring. Prints, for the split:

1. consistent scenes: per noise model and track count, the median SGC over scenes at each level,
   its rise from 0.5 to 2 px (the bar: <= 0.02), the largest single clip and how many of the
   cell's clips score above 0.10 (the bar: none);
2. detection: per inconsistency and severity, the share of cells (scene, model, level, tracks)
   where it scores strictly above its consistent twin, which carries the same noise draw (the bar
   at 0.25: >= 95 %; bench/information_limit.py counts it against independent draws), also per model;
   the mover also apart in the cells where it is seen and those where it is hidden (fewer usable
   tracks on it than a pose needs, ``protocol.hidden_movers``);
3. floors: per noise model, the range over (level, tracks) cells of the median observed / floor of
   each pose component over the consistent scenes (the bar: within [0.5, 2]);
4. with ``--intervals``: per noise model, how often one draw's 90 % interval holds the median SGC
   of 20 draws (consistent scenes and warp at 0.5, 1 px, 1000 tracks; the bar: >= 85 %);
5. with ``--against ROWS`` (rows of the same grid from another tree, config, seed or noise draw):
   clip by clip, how far these rows are from those: statuses, the change of each clip's SGC, and
   the largest change of a detection share, of a consistent cell's median and of a floors range
   bound (how a constant of the pose search is chosen on FIT: bench/history/issue-61.md, "Eight
   leading fits").
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
import time
from pathlib import Path

import numpy as np

from sgc_jax import COMPONENTS, SGCConfig, score_batch
from sgc_jax.research import protocol
from sgc_jax.research.noise import NOISE_MODELS, add_noise
from sgc_jax.research.perturb import perturb_clip

POSE_COMPONENTS = [c for c in COMPONENTS if c != "depth_error"]
INTERVAL_DRAWS, INTERVAL_PX, INTERVAL_TRACKS, INTERVAL_WARP = 20, 1.0, 1000, 0.5
CONSISTENT_MAX = 0.10  # issue 58's bar: no single consistent clip above it


def score_rows(args, config: SGCConfig) -> list[dict]:
    rows = []
    scenes = protocol.SPLITS[args.split][:args.scenes]
    for scene, tracks in itertools.product(scenes, args.tracks):
        started = time.perf_counter()
        exact = protocol.exact_variants(scene, tracks)  # the same for every noise model and level
        scene_cells = [c for c in protocol.cells(args.split, args.models, args.levels, (tracks,), args.noise_draw)
                       if c.scene == scene]
        batch = [(cell, clip, kind, severity) for cell in scene_cells
                 for clip, kind, severity in protocol.cell_clips(cell, exact=exact)]
        result = score_batch([clip for _, clip, _, _ in batch], config=config, progress=False)
        for (cell, _, kind, severity), clip in zip(batch, result.clips):
            rows.append(dict(scene=scene.name, model=cell.noise_model, noise_px=cell.noise_px, tracks=tracks,
                             kind=kind, severity=severity, status=clip.status, sgc=clip.sgc, sgc_lo=clip.sgc_lo,
                             sgc_hi=clip.sgc_hi, scale=clip.scale, **clip.components, **clip.floors))
        print(f"{scene.name}, {tracks} tracks: {len(batch)} clips in {time.perf_counter() - started:.0f} s",
              file=sys.stderr, flush=True)
    return rows


def consistent_medians(rows: list[dict]) -> dict[tuple, float]:
    """(model, tracks, level) -> the median SGC of the consistent scenes."""
    cells: dict[tuple, list[float]] = {}
    for r in rows:
        if r["kind"] == "":
            cells.setdefault((r["model"], r["tracks"], r["noise_px"]), []).append(r["sgc"])
    return {cell: float(np.nanmedian(scores)) for cell, scores in cells.items()}


def print_consistent(rows: list[dict], models, levels, tracks) -> None:
    print("\n1. Consistent scenes: median SGC over scenes at each noise level (px)")
    print("| noise model | tracks | " + " | ".join(f"{n:g} px" for n in levels)
          + f" | rise 0.5 -> 2 | largest clip | clips above {CONSISTENT_MAX:.2f} |")
    print("|---|---|" + "---|" * (len(levels) + 3))
    cell_medians = consistent_medians(rows)
    for model, t in itertools.product(models, tracks):
        cell = [r for r in rows if (r["kind"], r["model"], r["tracks"]) == ("", model, t)]
        medians = {n: cell_medians.get((model, t, n), np.nan) for n in levels}
        rise = medians.get(2.0, np.nan) - medians.get(0.5, np.nan)
        scores = [r["sgc"] for r in cell]
        above = sum(score > CONSISTENT_MAX for score in scores)
        print(f"| {model} | {t} | " + " | ".join(f"{medians[n]:.3f}" for n in levels)
              + f" | {rise:+.3f} | {np.nanmax(scores):.3f} | {above} of {len(scores)} |")


def print_detection(rows: list[dict], models, split: str, config: SGCConfig) -> None:
    keyed = [{**r, "cell": (r["scene"], r["model"], r["noise_px"], r["tracks"])} for r in rows]
    overall = protocol.detection_table(keyed)
    per_model = {m: protocol.detection_table([r for r in keyed if r["model"] == m]) for m in models}
    print("\n2. Detection: share of cells where the inconsistency scores above its consistent twin")
    print("| inconsistency | severity | all cells | " + " | ".join(models) + " |")
    print("|---|---|---|" + "---|" * len(models))
    for (kind, severity), share in overall.items():
        print(f"| {kind} | {severity:g} | {share:.0%} | "
              + " | ".join(f"{per_model[m].get((kind, severity), np.nan):.0%}" for m in models) + " |")
    hidden = protocol.hidden_movers(split, sorted({r["tracks"] for r in rows}), config)
    for label, keep in (("seen", False), ("hidden", True)):
        movers = [r for r in keyed if r["kind"] in ("mover", "mover-masked") and ((r["scene"], r["tracks"]) in hidden) == keep]
        cells = len({r["cell"] for r in movers})
        share = protocol.detection_table(movers).get(("mover", 1.0), np.nan)
        per = {m: protocol.detection_table([r for r in movers if r["model"] == m]).get(("mover", 1.0), np.nan)
               for m in models}
        print(f"| mover, {label} ({cells} cells) | 1 | {share:.0%} | " + " | ".join(f"{per[m]:.0%}" for m in models) + " |")


def floor_spans(rows: list[dict], models, levels, tracks) -> dict[tuple[str, str], tuple[float, float]]:
    """(model, pose component) -> the lowest and highest, over (level, tracks) cells, of the median
    observed / floor of the consistent scenes (NaN, NaN without a floor)."""
    spans = {}
    for model, k in itertools.product(models, POSE_COMPONENTS):
        medians = []
        for n, t in itertools.product(levels, tracks):
            cell = [r for r in rows if (r["kind"], r["model"], r["noise_px"], r["tracks"]) == ("", model, n, t)]
            ratios = [r[k] / r[f"{k}_floor"] for r in cell if r[f"{k}_floor"] > 0]
            if ratios:
                medians.append(np.median(ratios))
        spans[model, k] = (min(medians), max(medians)) if medians else (np.nan, np.nan)
    return spans


def print_floors(rows: list[dict], models, levels, tracks) -> None:
    print("\n3. Floors: range over (level, tracks) cells of the median observed / floor (consistent scenes)")
    print("| noise model | " + " | ".join(POSE_COMPONENTS) + " |")
    print("|---|" + "---|" * len(POSE_COMPONENTS))
    spans = floor_spans(rows, models, levels, tracks)
    for model in models:
        print(f"| {model} | " + " | ".join("n/a" if np.isnan(spans[model, k][0]) else
                                           f"{spans[model, k][0]:.2f}-{spans[model, k][1]:.2f}" for k in POSE_COMPONENTS) + " |")


def print_intervals(args, config: SGCConfig) -> None:
    print(f"\n4. Intervals: one draw's 90 % interval holds the median of {INTERVAL_DRAWS} draws "
          f"({INTERVAL_PX:g} px, {INTERVAL_TRACKS} tracks; consistent scenes and warp at {INTERVAL_WARP:g})")
    print("| noise model | clip | draws | coverage | median SGC | median width |")
    print("|---|---|---|---|---|---|")
    for model, kind in itertools.product(args.models, ("consistent", "warp")):
        covered, widths, scores = [], [], []
        for scene in protocol.SPLITS[args.split][:args.scenes]:
            base = scene.clip(INTERVAL_TRACKS)
            if kind == "warp":
                base = perturb_clip(base, "warp", INTERVAL_WARP, seed=scene.seed)
            noisy = NOISE_MODELS[model].replace(px=INTERVAL_PX)
            clips = [add_noise(base, noisy, 90_000 + scene.seed * 100 + d) for d in range(INTERVAL_DRAWS)]
            held, width, sgc = protocol.interval_coverage(score_batch(clips, config=config, progress=False).clips)
            covered += list(held)
            widths += list(width)
            scores += list(sgc)
        print(f"| {model} | {kind} | {len(covered)} | {np.mean(covered):.0%} | {np.nanmedian(scores):.3f} "
              f"| {np.nanmedian(widths):.3f} |", flush=True)


CLIP_KEY = ("scene", "model", "noise_px", "tracks", "kind", "severity")
ROW_TEXT, ROW_INTEGERS = ("scene", "model", "kind", "status"), ("tracks",)  # the rows' columns read as written


def largest_change(before: dict, after: dict) -> tuple[float, object]:
    """The largest absolute change of a value between two tables of the same keys, and its key."""
    changes = {key: abs(after[key] - before[key]) for key in before if np.isfinite(after[key] - before[key])}
    key = max(changes, key=changes.get) if changes else None
    return (changes[key] if key is not None else 0.0), key


def print_against(rows: list[dict], other: list[dict], path: str, models, levels, tracks) -> None:
    """Section 5: these rows against ``other`` (the same clips scored otherwise), clip by clip."""
    mine, theirs = {tuple(r[c] for c in CLIP_KEY): r for r in rows}, {tuple(r[c] for c in CLIP_KEY): r for r in other}
    shared = [key for key in mine if key in theirs]
    print(f"\n5. Against {path}: {len(shared)} clips in both ({len(mine) - len(shared)} only here, "
          f"{len(theirs) - len(shared)} only there)")
    if not shared:
        return
    same_status = sum(mine[k]["status"] == theirs[k]["status"] for k in shared)
    print(f"statuses the same: {same_status} of {len(shared)}")
    print("| clips | abs. change of SGC: median | 99th pct. | largest | share above 0.05 |")
    print("|---|---|---|---|---|")
    groups = [("all", shared)] + [(f"{n:g} px", [k for k in shared if k[2] == n]) for n in levels] \
        + [(m, [k for k in shared if k[1] == m]) for m in models] + [("consistent", [k for k in shared if k[4] == ""])]
    for label, keys in groups:
        change = np.array([abs(mine[k]["sgc"] - theirs[k]["sgc"]) for k in keys])
        change = change[np.isfinite(change)]
        if change.size:
            print(f"| {label} | {np.median(change):.1e} | {np.percentile(change, 99):.3f} | {change.max():.3f} "
                  f"| {np.mean(change > 0.05):.1%} |")
    worst = max(shared, key=lambda k: np.nan_to_num(abs(mine[k]["sgc"] - theirs[k]["sgc"])))
    print(f"largest: {dict(zip(CLIP_KEY, worst))}: {theirs[worst]['sgc']:.3f} there, {mine[worst]['sgc']:.3f} here")
    before = [{**theirs[k], "cell": k[:4]} for k in shared]  # cell: (scene, model, noise_px, tracks)
    after = [{**mine[k], "cell": k[:4]} for k in shared]
    detection_before, detection_after = protocol.detection_table(before), protocol.detection_table(after)
    change, key = largest_change(detection_before, detection_after)
    drop = min(detection_after[k] - detection_before[k] for k in detection_before)
    print(f"detection shares: the largest change {change:.1%} ({key}), the largest drop {drop:+.1%}")
    change, key = largest_change(consistent_medians(before), consistent_medians(after))
    above = [sum(r["sgc"] > CONSISTENT_MAX for r in table if r["kind"] == "") for table in (before, after)]
    print(f"consistent cells' medians: the largest change {change:.4f} ({key}); "
          f"clips above {CONSISTENT_MAX:.2f}: {above[0]} there, {above[1]} here")
    bounds = [{(*cell, end): span[end] for cell, span in floor_spans(table, models, levels, tracks).items() for end in (0, 1)}
              for table in (before, after)]
    print("floors' range bounds: the largest change {:.3f} ({})".format(*largest_change(*bounds)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--split", default="test", choices=sorted(protocol.SPLITS))
    parser.add_argument("--models", nargs="+", default=list(NOISE_MODELS), choices=list(NOISE_MODELS))
    parser.add_argument("--levels", type=float, nargs="+", default=list(protocol.NOISE_LEVELS_PX))
    parser.add_argument("--tracks", type=int, nargs="+", default=list(protocol.TRACK_COUNTS))
    parser.add_argument("--scenes", type=int, default=None, help="the split's first N scenes (default: all)")
    parser.add_argument("--out", default=None, help="CSV of every clip's score, components and floors")
    parser.add_argument("--rows", default=None, help="print the tables from this CSV instead of scoring")
    parser.add_argument("--intervals", action="store_true", help="also measure the intervals' coverage")
    parser.add_argument("--config", default=None, help="a config file (JSON) for the score (default: SGCConfig())")
    parser.add_argument("--noise-draw", type=int, default=0,
                        help="an independent draw of every cell's noise (default 0: the protocol's draw)")
    parser.add_argument("--against", default=None, help="rows (CSV) of the same grid scored otherwise: compared clip by clip")
    args = parser.parse_args()
    config = SGCConfig.from_dict(json.loads(Path(args.config).read_text())) if args.config else SGCConfig()
    rows = protocol.rows_scored_or_read(args.rows, args.out, lambda: score_rows(args, config), ROW_TEXT, ROW_INTEGERS)
    print(f"split {args.split}: {len({r['scene'] for r in rows})} scenes, {len(rows)} clips")
    # rows read back may hold part of the grid: the tables cover what they hold
    args.models, args.levels, args.tracks = ([v for v in values if any(r[name] == v for r in rows)]
                                             for name, values in (("model", args.models), ("noise_px", args.levels),
                                                                  ("tracks", args.tracks)))
    print_consistent(rows, args.models, args.levels, args.tracks)
    print_detection(rows, args.models, args.split, config)
    print_floors(rows, args.models, args.levels, args.tracks)
    if args.intervals:
        print_intervals(args, config)
    if args.against:
        other = protocol.read_rows(args.against, ROW_TEXT, ROW_INTEGERS)
        print_against(rows, other, args.against, args.models, args.levels, args.tracks)


if __name__ == "__main__":
    main()
