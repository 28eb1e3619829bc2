"""The host's summary of scored clips (issue 61, item 3): milliseconds per clip for
``summarize_clip`` one clip at a time and for a group of clips summarised at once
(``pair_summaries``, as a lane of ``score_batch`` does with the clips of one program call), in
this checkout and, with --baseline, in an older one on the same per-pair arrays.

    git worktree add /tmp/sgc-base d6c5e8b
    python bench/summaries.py [--baseline /tmp/sgc-base] [--clips 64] [--groups 16 64] [--rounds 3]

Scores --clips synthetic clips of 16 frames (15 pairs, as a standard clip has; the summary reads
only per-pair arrays, so image size and track count do not enter it) once, then for each round
times each way, in fresh processes for each tree, alternating, and prints each way's median over
rounds of the best of 5 passes. The summary holds the GIL: on an accelerator the lanes' summaries
compete with the thread that feeds the device (bench/history/issue-61.md).
"""

from __future__ import annotations

import argparse
import os
import pickle
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent.parent
TIME = """
import pickle, sys, time
from sgc_jax.calibration import Calibration
from sgc_jax.scoring import result
pairs = pickle.load(open(sys.argv[1], "rb"))
calibration = Calibration.load("sgc-spec-2026")
def one_at_a_time(group):
    return [result.summarize_clip("c", p, calibration, compat="spec") for p in group]
def at_once(group):
    summaries = result.pair_summaries(group, calibration, "spec")
    return [result.summarize_clip("c", p, calibration, compat="spec", summary=s) for p, s in zip(group, summaries)]
ways = {"one at a time": one_at_a_time}
if hasattr(result, "pair_summaries"):
    ways.update({f"groups of {g}": (lambda group, g=g: [c for i in range(0, len(group), g) for c in at_once(group[i:i + g])])
                 for g in map(int, sys.argv[2].split(","))})
for name, way in ways.items():
    way(pairs)
    best = float("inf")
    for _ in range(5):
        start = time.perf_counter()
        way(pairs)
        best = min(best, time.perf_counter() - start)
    print(f"{name}\\t{1e3 * best / len(pairs)}")
"""


def timed(tree: Path, pairs_file: Path, groups: list[int]) -> dict[str, float]:
    env = {**os.environ, "PYTHONPATH": str(tree)}
    done = subprocess.run([sys.executable, "-c", TIME, str(pairs_file), ",".join(map(str, groups))], env=env,
                          text=True, capture_output=True, check=True, cwd=tree)
    return {name: float(ms) for name, ms in (line.split("\t") for line in done.stdout.strip().splitlines())}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--baseline", type=Path, default=None, help="an older checkout, timed on the same pairs")
    parser.add_argument("--clips", type=int, default=64)
    parser.add_argument("--groups", type=int, nargs="*", default=[16, 64], help="clips summarised at once")
    parser.add_argument("--rounds", type=int, default=3, help="processes per tree, alternating")
    args = parser.parse_args()
    sys.path.insert(0, str(HERE))
    sys.path.insert(0, str(HERE / "bench"))
    from stream import host_cpu

    from sgc_jax import score_batch
    from sgc_jax.research.synth import synth_clip

    # 8 distinct scenes at four noise levels, copied up to --clips (the summary's cost does not
    # depend on the values)
    clips = [synth_clip(seed=i, n_frames=16, height=144, width=192, n_tracks=1000, noise_px=0.5 * (1 + i % 4))
             for i in range(8)]
    scored = score_batch(clips, progress=False).clips
    pairs = [scored[i % len(scored)].pairs for i in range(args.clips)]
    trees = {"this tree": HERE, **({"baseline": args.baseline.resolve()} if args.baseline else {})}
    with tempfile.TemporaryDirectory() as folder:
        pairs_file = Path(folder) / "pairs.pkl"
        pairs_file.write_bytes(pickle.dumps(pairs))
        runs: dict[tuple[str, str], list[float]] = {}
        for round_ in range(args.rounds):
            for tree_name, tree in trees.items():
                for way, ms in timed(tree, pairs_file, args.groups).items():
                    runs.setdefault((tree_name, way), []).append(ms)
                    print(f"round {round_ + 1}, {tree_name}, {way}: {ms:.3f} ms per clip", flush=True)
    print(f"{host_cpu()}; {args.clips} clips of 15 pairs; medians of {args.rounds} rounds, each the best of 5 passes")
    for (tree_name, way), values in runs.items():
        print(f"{tree_name:>10}  {way:>14}: {statistics.median(values):.3f} ms per clip")


if __name__ == "__main__":
    main()
