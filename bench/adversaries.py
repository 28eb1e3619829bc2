"""The adversary battery (issue 59, docs/semantics.md §3.11, §9.4): what the reward pays clips a
generator could learn to make, against honest clips of the same scenes.

    python bench/adversaries.py [--split test|fit] [--noise 1] [--curve] [--noise-draw K]
                                [--out rows.csv] [--rows rows.csv]

Noise: iid-both (independent Gaussian on both ends of every track). Prints, for the split:

1. honest consistent clips at 200, 1,000 and 4,096 tracks and 0.5, 1 and 2 px: the median reward,
   its evidence, and the spread of the rewards of clips at full evidence (the bar: within ±10 %
   of their median);
2. each adversary (``sgc_jax.research.adversaries``) at 1,000 tracks and ``--noise`` px: its median
   reward over the scenes against the honest median of the same scenes (the bar: <= 0.5x), its
   statuses and one clip's reason; the unmasked mover also over the scenes where it is seen (at
   least a pose's worth of usable tracks on it, ``protocol.hidden_movers``) and where it is hidden;
3. the perturbation ladders (clean, 0.1, 0.25, 0.5 of each perturbation; 1,000 tracks): the share
   where the reward falls strictly with severity (the bar: all);
4. with ``--curve``, the reward below full evidence: honest clips at 50-600 tracks as well (0.5 and
   2 px), the median pose tracks, evidence, reward and status share per track count, beside the
   honest clips of table 1.

``--out`` also keeps each clip's ``least_tracks_share``: its pair of fewest usable tracks over the
median of its pairs (where the rule of docs/semantics.md §3.11, "A break in the tracks", reads it).

The rewards are ``BatchResult.rewards`` (the Scorer's, computed from the tables; tests/test_scorer.py
holds the two equal).
"""

from __future__ import annotations

import argparse
import itertools
import sys
import time
from collections import Counter

import numpy as np

from sgc_jax import SGCConfig, score_batch
from sgc_jax.codes import SCORER_STATUSES
from sgc_jax.research import protocol
from sgc_jax.research.adversaries import ADVERSARIES, adversary
from sgc_jax.research.noise import NOISE_MODELS, add_noise
from sgc_jax.research.perturb import PERTURBATIONS, perturb_clip

HONEST_TRACKS = (200, 1000, 4096)
HONEST_NOISE = (0.5, 1.0, 2.0)
LADDER = (0.1, 0.25, 0.5)
TRACKS = 1000
CURVE_TRACKS = (50, 100, 150, 300, 400, 600)
CURVE_NOISE = (0.5, 2.0)


def noisy(clip, scene, px: float, draw: int = 0):
    """The clip with iid-both noise of ``px``; every clip of a scene at one level shares the draw
    (``draw`` > 0: an independent one, as ``protocol.Cell.draw``)."""
    seed = draw * protocol.NOISE_DRAW_STRIDE + scene.seed * 10 + int(px * 4)
    return add_noise(clip, NOISE_MODELS["iid-both"].replace(px=px), seed)


def least_tracks_share(clip) -> float:
    """A scored clip's fewest usable tracks in a pair over its pairs' median (NaN without pairs)."""
    if clip.pairs is None:
        return float("nan")
    counts = np.asarray(clip.pairs.n_tracks, np.float64)
    return float(counts.min() / np.median(counts)) if np.median(counts) > 0 else float("nan")


def score_rows(args) -> list[dict]:
    rows = []
    for scene in protocol.SPLITS[args.split]:
        started = time.perf_counter()
        batch = [("honest", "", 0.0, n, px, noisy(scene.clip(n), scene, px, args.noise_draw))
                 for n, px in itertools.product(HONEST_TRACKS, HONEST_NOISE)]
        if args.curve:
            batch += [("curve", "", 0.0, n, px, noisy(scene.clip(n), scene, px, args.noise_draw))
                      for n, px in itertools.product(CURVE_TRACKS, CURVE_NOISE)]
        batch += [("adversary", name, 0.0, TRACKS, args.noise, noisy(adversary(name, scene, TRACKS), scene, args.noise,
                                                                         args.noise_draw))
                  for name in ADVERSARIES]
        clean = scene.clip(TRACKS)
        batch += [("ladder", kind, s, TRACKS, args.noise, noisy(perturb_clip(clean, kind, s, seed=scene.seed), scene,
                                                              args.noise, args.noise_draw))
                  for kind, s in itertools.product(PERTURBATIONS, LADDER)]
        result = score_batch([b[-1] for b in batch], progress=False)
        rewards = result.rewards()
        for i, ((group, kind, severity, n, px, _), c) in enumerate(zip(batch, result.clips)):
            rows.append(dict(scene=scene.name, group=group, kind=kind, severity=severity, tracks=n, noise_px=px,
                             status=SCORER_STATUSES[int(rewards["status"][i])], reason=c.reason, sgc=c.sgc,
                             sgc_lo=c.sgc_lo, sgc_hi=c.sgc_hi, sgc_unclipped=float(rewards["sgc_unclipped"][i]),
                             depth_error=c.components["depth_error"], evidence=c.evidence,
                             pose_tracks=c.pose_tracks, reward=float(rewards["reward"][i]),
                             camera_motion=float(rewards["camera_motion"][i]), scale=c.scale,
                             least_tracks_share=least_tracks_share(c)))
        print(f"{scene.name}: {len(batch)} clips in {time.perf_counter() - started:.0f} s", file=sys.stderr, flush=True)
    return rows


def print_honest(rows: list[dict]) -> float:
    honest = [r for r in rows if r["group"] == "honest"]
    print("\n1. Honest consistent clips: median reward (median evidence) over the scenes")
    print("| tracks | " + " | ".join(f"{px:g} px" for px in HONEST_NOISE) + " |")
    print("|---|" + "---|" * len(HONEST_NOISE))
    for n in HONEST_TRACKS:
        cells = [[r for r in honest if r["tracks"] == n and r["noise_px"] == px] for px in HONEST_NOISE]
        print(f"| {n} | " + " | ".join(f"{np.median([r['reward'] for r in c]):.3f} "
                                        f"({np.median([r['evidence'] for r in c]):.2f})" for c in cells) + " |")
    full = [r for r in honest if r["evidence"] >= 1.0]
    by_scene = {}
    for r in full:
        by_scene.setdefault(r["scene"], []).append(r["reward"])
    spread = [max(abs(np.array(v) / np.median(v) - 1)) for v in by_scene.values() if len(v) > 1]
    print(f"clips at full evidence: {len(full)} of {len(honest)}; the largest departure of one from its scene's "
          f"median over tracks and noise: {max(spread, default=float('nan')):.1%} (the bar: 10 %)")
    return float(np.median([r["reward"] for r in honest if r["tracks"] == TRACKS]))


def print_adversaries(rows: list[dict], noise: float, split: str) -> None:
    honest = {r["scene"]: r["reward"] for r in rows
              if r["group"] == "honest" and r["tracks"] == TRACKS and r["noise_px"] == noise}
    print(f"\n2. Adversaries ({TRACKS} tracks, iid-both {noise:g} px): median reward over the scenes, and against "
          f"the same scenes' honest clips (median honest {np.median(list(honest.values())):.3f})")
    print("| adversary | median reward | x honest (median of scenes) | median SGC | statuses | a reason |")
    print("|---|---|---|---|---|---|")
    hidden = {scene for scene, _ in protocol.hidden_movers(split, (TRACKS,), SGCConfig())}
    movers = [r for r in rows if r["group"] == "adversary" and r["kind"] == "unmasked_mover"]
    for name, own in [(name, [r for r in rows if r["group"] == "adversary" and r["kind"] == name])
                      for name in ADVERSARIES] + [
            ("unmasked_mover, seen", [r for r in movers if r["scene"] not in hidden]),
            ("unmasked_mover, hidden", [r for r in movers if r["scene"] in hidden])]:
        if not own:
            continue
        ratio = np.median([r["reward"] / honest[r["scene"]] for r in own if honest.get(r["scene"], 0) > 0])
        statuses = ", ".join(f"{s} {n}" for s, n in Counter(r["status"] for r in own).most_common())
        reason = next((r["reason"] for r in own if r["reason"]), "")
        print(f"| {name} | {np.median([r['reward'] for r in own]):.3f} | {ratio:.2f} | "
              f"{np.nanmedian([r['sgc'] for r in own]):.3f} | {statuses} | {reason[:70]} |")


def print_ladders(rows: list[dict], noise: float) -> None:
    honest = {r["scene"]: r["reward"] for r in rows
              if r["group"] == "honest" and r["tracks"] == TRACKS and r["noise_px"] == noise}
    falls = []
    for scene, kind in itertools.product(sorted(honest), PERTURBATIONS):
        steps = sorted((r["severity"], r["reward"]) for r in rows
                       if r["group"] == "ladder" and r["scene"] == scene and r["kind"] == kind)
        rewards = [honest[scene]] + [reward for _, reward in steps]
        falls.append(bool(np.all(np.diff(rewards) < 0)))
        if not falls[-1]:
            print(f"   {scene} {kind}: " + " -> ".join(f"{x:.3f}" for x in rewards))
    print(f"\n3. Ladders: the reward falls strictly with severity in {sum(falls)} of {len(falls)}")


def print_curve(rows: list[dict]) -> None:
    """Honest clips by track count (table 1's and ``--curve``'s) at CURVE_NOISE: what the reward pays
    below the evidence levels (docs/semantics.md §9.4)."""
    honest = [r for r in rows if r["group"] in ("honest", "curve") and r["noise_px"] in CURVE_NOISE]
    counts = sorted({r["tracks"] for r in honest})
    print("\n4. Honest consistent clips by tracks per pair (iid-both "
          + " and ".join(f"{px:g}" for px in CURVE_NOISE) + " px): medians over the scenes and noise levels")
    print("| tracks per pair | pose tracks | evidence | reward | reward / at 1,000 tracks | low_evidence |")
    print("|---|---|---|---|---|---|")
    full = np.median([r["reward"] for r in honest if r["tracks"] == TRACKS])
    for n in counts:
        cell = [r for r in honest if r["tracks"] == n]
        low = sum(r["status"] == "low_evidence" for r in cell)
        reward = np.median([r["reward"] for r in cell])
        print(f"| {n} | {np.nanmedian([r['pose_tracks'] for r in cell]):.0f} | "
              f"{np.median([r['evidence'] for r in cell]):.2f} | {reward:.3f} | {reward / full:.2f} | "
              f"{low} of {len(cell)} |")


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--split", choices=sorted(protocol.SPLITS), default="test")
    parser.add_argument("--noise", type=float, default=1.0, help="iid-both noise of the adversaries and ladders [px]")
    parser.add_argument("--curve", action="store_true", help="also honest clips at 50-600 tracks (table 4)")
    parser.add_argument("--noise-draw", type=int, default=0,
                        help="an independent draw of every clip's noise (default 0: the battery's draw)")
    parser.add_argument("--out", help="write the rows to this CSV")
    parser.add_argument("--rows", help="print the tables from a CSV written with --out")
    args = parser.parse_args(argv)
    rows = protocol.rows_scored_or_read(args.rows, args.out, lambda: score_rows(args),
                                        ("scene", "group", "kind", "status", "reason"), ("tracks",))
    print(f"split {args.split}")
    print_honest(rows)
    print_adversaries(rows, args.noise, args.split)
    print_ladders(rows, args.noise)
    if any(r["group"] == "curve" for r in rows):
        print_curve(rows)


if __name__ == "__main__":
    main()
