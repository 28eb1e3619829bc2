"""Start-up of the JAX engine as a user meets it: fresh processes, wall-clock seconds.

    python bench/startup.py                          # this tree
    python bench/startup.py --baseline /path/tree    # and an older checkout, same run (e.g. a
                                                     # `git worktree add /tmp/old <commit>`)

Per tree, each in a new Python process: `score_batch` of one standard clip (T=16, 288x512, 4096
tracks) with an empty persistent compilation cache (cold), again with the cache that run left
(cached), and `sgc-jax demo` with an empty cache (what a fresh install runs first). The reference
engine on the same clip gives the scale. Timings include the interpreter and the imports.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]
SCORE = ("import sgc_jax, sys; sgc_jax.enable_compilation_cache(); "
         "r = sgc_jax.score_batch(sys.argv[1], engine=sys.argv[2], progress=False); "
         "assert r.clips[0].status == 'ok', r.clips[0].reason")


def run(tree: Path, args: list[str], cache: Path) -> float:
    """Seconds a fresh process in ``tree`` takes; the compile cache in ``cache``."""
    env = dict(os.environ, PYTHONPATH=str(tree), SGC_JAX_COMPILATION_CACHE=str(cache))
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    start = time.perf_counter()
    proc = subprocess.run([sys.executable, *args], env=env, cwd=tree, capture_output=True, text=True)
    if proc.returncode not in (0,):
        raise RuntimeError(f"{' '.join(args)} in {tree} failed:\n{proc.stderr[-3000:]}")
    return time.perf_counter() - start


def measure(tree: Path, clip: Path, work: Path) -> dict[str, float]:
    cache, demo_cache = work / f"cache-{tree.name}", work / f"demo-cache-{tree.name}"
    return {
        "jax cold": run(tree, ["-c", SCORE, str(clip), "jax"], cache),
        "jax cached": run(tree, ["-c", SCORE, str(clip), "jax"], cache),
        "demo (empty cache)": run(tree, ["-m", "sgc_jax.cli", "demo", "-q"], demo_cache),
        "reference": run(tree, ["-c", SCORE, str(clip), "reference"], cache),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--baseline", type=Path, help="an older checkout to time in the same run")
    args = parser.parse_args()
    sys.path.insert(0, str(HERE))
    from sgc_jax import save_clip
    from sgc_jax.research.synth import synth_clip

    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        clip = save_clip(work / "standard.npz", synth_clip(seed=0, clip_id="standard", n_frames=16, height=288,
                                                             width=512, n_tracks=4096, n_layers=3, static_spheres=4))
        trees = [HERE] + ([args.baseline.resolve()] if args.baseline else [])
        print(f"load average before: {os.getloadavg()[0]:.2f}; {os.cpu_count()} CPUs")
        results = {tree: measure(tree, clip, work) for tree in trees}
        print(f"load average after: {os.getloadavg()[0]:.2f}")
    names = list(next(iter(results.values())))
    print(f"{'tree':<40}" + "".join(f"{n:>20}" for n in names))
    for tree, row in results.items():
        print(f"{str(tree)[-40:]:<40}" + "".join(f"{row[n]:>19.1f}s" for n in names))


if __name__ == "__main__":
    main()
