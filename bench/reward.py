"""The Scorer's throughput (docs/semantics.md §9): clips per second for each batch size B, arrays
already on the device, forward only; against ``score_batch``'s one clip per program call, in
the same run; then, optionally, a corpus scored from disk through ``score_batch``.

    python bench/reward.py [--batch-sizes 1 8 32 64] [--shape 16 288 512 4096] [--repeats 3]
                           [--vectorized] [--disk-clips 1000] [--dir /tmp/sgc-stream-corpus]

Standard clips by default (T=16, 288x512, 4096 tracks per pair, ~10 regions: bench/stream.py's
scene); --shape scores smaller ones. Each B compiles its programs once (timed apart), then runs
--repeats warm calls; the figure is B / the median call. The one-clip-per-call figure scores the
same clips, held in memory, with ``score_batch`` (host preparation and padding per clip, one
program call each). --disk-clips N > 0 writes (once) and scores N standard clip files with
``score_batch(folder, out=...)`` and reports clips per second and the share of the wall time the
scorer waited for input. --vectorized runs the Scorer's accelerator form (docs/semantics.md §9.3)
on any device; it is the default on accelerators.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import jax

from sgc_jax import Scorer, enable_compilation_cache, score_batch
from sgc_jax.research.synth import synth_clip
from sgc_jax.scoring.scorer import batch_of
from sgc_jax.scoring.streaming import StreamStats

sys.path.insert(0, str(Path(__file__).resolve().parent))
from stream import SCENE, write_corpus  # noqa: E402

DISTINCT = 8  # distinct scenes; a batch of B repeats them (a clip's numbers do not depend on its neighbours)


def clips_of(shape: tuple[int, int, int, int], n: int) -> list:
    T, H, W, P = shape
    return [synth_clip(seed=i, **{**SCENE, "n_frames": T, "height": H, "width": W, "n_tracks": P})
            for i in range(min(n, DISTINCT))]


def scorer_rate(clips: list, B: int, shape: tuple, repeats: int, vectorized: bool | None) -> dict:
    begin = time.perf_counter()
    scorer = Scorer((B, *shape), vectorized=vectorized)
    compile_s = time.perf_counter() - begin
    batch = jax.device_put(batch_of([clips[i % len(clips)] for i in range(B)], shape))
    jax.block_until_ready(scorer(batch))  # warm
    calls = []
    for _ in range(repeats):
        begin = time.perf_counter()
        jax.block_until_ready(scorer(batch))
        calls.append(time.perf_counter() - begin)
    call = statistics.median(calls)
    return {"B": B, "compile_s": compile_s, "call_s": call, "clips_per_s": B / call}


def one_clip_per_call_rate(clips: list, repeats: int) -> float:
    score_batch(clips[:1], progress=False)  # compile
    times = []
    for _ in range(repeats):
        begin = time.perf_counter()
        score_batch(clips, progress=False)
        times.append(time.perf_counter() - begin)
    return len(clips) / statistics.median(times)


def disk_rate(folder: Path, n: int) -> StreamStats:
    paths = write_corpus(folder, n)
    score_batch(paths[:1], progress=False)  # compile
    stats = StreamStats()
    with tempfile.TemporaryDirectory() as out:
        score_batch(paths, out=Path(out) / "scores.csv", progress=False, stats=stats)
    return stats


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch-sizes", type=int, nargs="+", default=[1, 8, 32, 64])
    parser.add_argument("--shape", type=int, nargs=4, default=[SCENE["n_frames"], SCENE["height"], SCENE["width"],
                                                                SCENE["n_tracks"]], metavar=("T", "H", "W", "P"))
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--vectorized", action="store_true", default=None)
    parser.add_argument("--disk-clips", type=int, default=0)
    parser.add_argument("--dir", default="/tmp/sgc-stream-corpus")
    args = parser.parse_args()
    enable_compilation_cache()
    shape = tuple(args.shape)
    device = jax.devices()[0]
    print(f"device: {device.device_kind} ({jax.default_backend()}), {jax.device_count()} device(s); "
          f"clips of {shape[0]} frames, {shape[1]}x{shape[2]} px, {shape[3]} tracks per pair")
    clips = clips_of(shape, max(args.batch_sizes))
    baseline = one_clip_per_call_rate(clips, args.repeats)
    print(f"score_batch, one clip per program call, in memory: {baseline:.2f} clips/s")
    print("| B | compile s | call s | clips/s | vs one clip per call |")
    print("|---|---|---|---|---|")
    for B in args.batch_sizes:
        row = scorer_rate(clips, B, shape, args.repeats, args.vectorized)
        print(f"| {B} | {row['compile_s']:.0f} | {row['call_s']:.3f} | {row['clips_per_s']:.2f} | "
              f"{row['clips_per_s'] / baseline:.2f}x |", flush=True)
    if args.disk_clips > 0:
        stats = disk_rate(Path(args.dir), args.disk_clips)
        print(f"from disk, score_batch: {stats.scored} clips in {stats.wall_s:.1f} s = "
              f"{stats.scored / stats.wall_s:.2f} clips/s; waited for input {100 * stats.input_wait_share:.0f} % "
              "of the wall time")


if __name__ == "__main__":
    main()
