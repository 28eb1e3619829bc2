"""Warm clips per second of this checkout against an older one, in one run (issue 21's 2x bar).

    git worktree add /tmp/sgc-base 0082bfe       # main before issue 21
    python bench/warm_speed.py --baseline /tmp/sgc-base [--clips 8] [--repeat 3] [--rounds 2]
    python bench/warm_speed.py --baseline /tmp/sgc-base --config '{"partition": "depth+spatial"}'

Writes --clips standard clips (T=16, 288x512, 4096 tracks per pair) once, then for each round
times each tree in a fresh process (``PYTHONPATH`` = the tree): ``score_batch`` of the clips held
in memory, compiled first (each tree with a persistent cache of its own, empty in the first
round), the best of --repeat calls. Trees alternate round by round so a drift in the box's load falls on both; the figure is
each tree's best clips per second and their ratio. ``--config``: the SGCConfig fields both trees
score with (JSON; the defaults when not given).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent.parent
WARM = """
import glob, json, sys, time
from sgc_jax import score_batch
from sgc_jax.io.loading import load_clips
clips = list(load_clips(sorted(glob.glob(sys.argv[1] + "/*.npz"))))
config = json.loads(sys.argv[3])
score_batch(clips[:1], config=config, progress=False)
best = float("inf")
for _ in range(int(sys.argv[2])):
    start = time.perf_counter()
    score_batch(clips, config=config, progress=False)
    best = min(best, time.perf_counter() - start)
print(len(clips) / best)
"""


def warm_rate(tree: Path, clips: Path, repeat: int, cache: Path, config: str = "{}") -> float:
    env = {**os.environ, "PYTHONPATH": str(tree), "SGC_JAX_COMPILATION_CACHE": str(cache)}
    done = subprocess.run([sys.executable, "-c", WARM, str(clips), str(repeat), config], env=env, text=True,
                          capture_output=True, check=True, cwd=tree)
    return float(done.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--baseline", type=Path, required=True, help="the older checkout")
    parser.add_argument("--clips", type=int, default=8, help="enough for the scorer's lanes to stay full")
    parser.add_argument("--repeat", type=int, default=3, help="warm calls per process; the fastest counts")
    parser.add_argument("--rounds", type=int, default=2, help="processes per tree, alternating")
    parser.add_argument("--config", default="{}", help="SGCConfig fields as JSON, e.g. a partition")
    args = parser.parse_args()
    sys.path.insert(0, str(HERE))
    sys.path.insert(0, str(HERE / "bench"))
    from stream import host_cpu

    from sgc_jax import save_clip
    from sgc_jax.research.synth import synth_clip

    trees = {"this tree": HERE, "baseline": args.baseline.resolve()}
    rates: dict[str, list[float]] = {name: [] for name in trees}
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for seed in range(args.clips):
            save_clip(work / "clips" / f"c{seed}.npz", synth_clip(
                seed=seed, clip_id=f"c{seed}", n_frames=16, height=288, width=512, n_tracks=4096, n_layers=4,
                static_spheres=3, noise_px=0.5, outlier_frac=0.1))
        print(f"load average before: {os.getloadavg()[0]:.2f}; {os.cpu_count()} CPUs ({host_cpu()})", flush=True)
        for round_ in range(args.rounds):
            for name, tree in trees.items():
                rates[name].append(warm_rate(tree, work / "clips", args.repeat, work / f"cache-{name}", args.config))
                print(f"round {round_ + 1}, {name}: {rates[name][-1]:.3f} clips/s", flush=True)
        print(f"load average after: {os.getloadavg()[0]:.2f}")
    best = {name: max(values) for name, values in rates.items()}
    for name, tree in trees.items():
        print(f"{name} ({tree}): {best[name]:.3f} clips/s warm")
    print(f"this tree / baseline: {best['this tree'] / best['baseline']:.3f}x")


if __name__ == "__main__":
    main()
