"""The Scorer's throughput (docs/semantics.md §9): clips per second for each batch size B, arrays
already on the device, forward only; against ``score_batch`` on the same clips in memory, in
the same run; then, optionally, a corpus scored from disk through ``score_batch``.

    python bench/reward.py [--batch-sizes 1 8 32 64] [--shape 16 288 512 4096] [--repeats 3]
                           [--vectorized] [--no-baseline] [--profile DIR]
                           [--disk-clips 1000] [--dir /tmp/sgc-stream-corpus]
                           [--linearise FORM] [--histogram-copies C] [--all-lanes]

Standard clips by default (T=16, 288x512, 4096 tracks per pair, ~10 regions: bench/stream.py's
scene); --shape scores smaller ones. Each B compiles its programs once (timed apart), then runs
--repeats warm calls; the figure is B / the median call. The one-clip-per-call figure scores the
same clips, held in memory, with ``score_batch`` (host preparation and padding per clip, one
program call each). --disk-clips N > 0 writes (once) and scores N standard clip files with
``score_batch(folder, out=...)`` and reports clips per second and the share of the wall time the
scorer waited for input and summarised clips. --vectorized runs the Scorer's accelerator form
(docs/semantics.md §9.3) on any device; it is the default on accelerators. --profile DIR times each
step of each B's call apart (waited for one by one) and writes a Perfetto trace of one call into
DIR/B<B> (and the optimized HLO of the first B's pose program); on a GPU it prints, per step, the kernels
launched, the time the device was busy and the most launched kernels (a while loop's body is
launched once per iteration, so their counts are the loops' iteration counts). --linearise FORM
puts one of bench/normal_equations.py's forms of the least-squares step in the package's place
before anything is compiled; --histogram-copies C makes the accelerator form's depth histograms
add into C copies of their bins (``partitions.ACCELERATOR_HISTOGRAM_COPIES``; bench/histogram_copies.py
times them alone); --all-lanes runs every lane of the vectorized form's draws and least-squares
solves to the end of its loop, as before their finished lanes were left behind (``kernels/lanes.py``).
A variant keeps its compiled programs in a cache directory of its own: the
package's cache keys its traced programs by the source files, which a variant set here leaves as
they are.
"""

from __future__ import annotations

import argparse
import collections
import gzip
import json
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

import jax

from sgc_jax import Scorer, enable_compilation_cache, score_batch
from sgc_jax.engines.jax_engine.compile_cache import default_cache_dir
from sgc_jax.engines.jax_engine.programs import Pipeline
from sgc_jax.kernels import joint_pnp, lanes, partitions
from sgc_jax.research.synth import synth_clip
from sgc_jax.scoring.scorer import batch_of
from sgc_jax.scoring.streaming import StreamStats

sys.path.insert(0, str(Path(__file__).resolve().parent))
from normal_equations import FORMS  # noqa: E402
from stream import SCENE, write_corpus  # noqa: E402

DISTINCT = 8  # distinct scenes; a batch of B repeats them (a clip's numbers do not depend on its neighbours)


def clips_of(shape: tuple[int, int, int, int], n: int) -> list:
    T, H, W, P = shape
    return [synth_clip(seed=i, **{**SCENE, "n_frames": T, "height": H, "width": W, "n_tracks": P})
            for i in range(min(n, DISTINCT))]


def scorer_rate(clips: list, B: int, shape: tuple, repeats: int, vectorized: bool | None,
                profile: Path | None = None, with_hlo: bool = False) -> dict:
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
    if profile is not None:
        profile_steps(scorer, batch, repeats, profile, with_hlo)
    return {"B": B, "compile_s": compile_s, "call_s": call, "clips_per_s": B / call}


def timed_steps(scorer: Scorer, batch: dict) -> dict[str, float]:
    """Seconds of each step of one program call (the first lane's clips on a CPU), each waited
    for, in the order the Scorer runs them; the stage pipeline's stages (pixel, pose, finish) apart."""
    clips = jax.device_put(scorer._rows(scorer.clip_arrays(batch), 0, scorer.call_size), scorer._sharding())
    seconds = {}

    def timed(name, call):
        def timed_call(*args):  # the trace's window of the step (kernel_summary)
            begin = time.perf_counter()
            value = jax.block_until_ready(call(*args))
            seconds[name] = seconds.get(name, 0.0) + time.perf_counter() - begin  # clip by clip on a CPU
            return value
        return timed_call

    def waited(name, program):
        if isinstance(program, Pipeline):  # each stage's program waited for in turn
            return program._replace(programs=tuple(timed(stage.name, call)
                                                   for stage, call in zip(program.stages, program.programs)))
        return timed(name, program)

    scorer._run({name: waited(name, program) for name, program in scorer._compiled.items()}, clips)
    return seconds


def profile_steps(scorer: Scorer, batch: dict, repeats: int, folder: Path, with_hlo: bool) -> None:
    """Each step's median time; a trace of one call (steps waited for one by one) and, with_hlo,
    the pose program's optimized HLO into ``folder``; on a GPU, what the trace says of each step's kernels."""
    folder.mkdir(parents=True, exist_ok=True)
    runs = [timed_steps(scorer, batch) for _ in range(repeats)]
    B = scorer.shape[0]
    print(f"steps of one call, B={B} (median of {repeats}, each waited for): " + ", ".join(
        f"{name} {1000 * statistics.median(r[name] for r in runs):.1f} ms" for name in runs[0]), flush=True)
    if with_hlo:
        with gzip.open(folder / "pose_hlo.txt.gz", "wt") as f:
            f.write(scorer._compiled["stages"].programs[1].as_text())  # pixel, pose, finish
    trace_dir = folder / "trace"
    with jax.profiler.trace(str(trace_dir), create_perfetto_trace=True):
        steps = list(timed_steps(scorer, batch))
    [trace] = trace_dir.glob("**/perfetto_trace.json.gz")
    trace.rename(folder / "perfetto_trace.json.gz")
    shutil.rmtree(trace_dir)
    print(kernel_summary(folder / "perfetto_trace.json.gz", steps), flush=True)


def kernel_summary(trace: Path, steps: list[str], top: int = 8) -> str:
    """Per step of the traced call (``steps`` in call order), the kernels run on the accelerator:
    how many, the time the device was busy (overlaps merged) within the step's window, and the most
    launched kernels."""
    with gzip.open(trace, "rt") as f:
        events = json.load(f)
    events = events["traceEvents"] if isinstance(events, dict) else events
    devices = {e["pid"] for e in events if e.get("ph") == "M" and e.get("name") == "process_name"
               and "/device:" in str(e.get("args", {}).get("name", "")) and "CPU" not in str(e["args"]["name"])}
    kernels = [e for e in events if e.get("ph") == "X" and e.get("pid") in devices]
    if not kernels:
        return "no accelerator kernels in the trace (a CPU run)"
    # the steps' windows: the Python tracer's events of timed_steps' ``timed_call``, in call order
    calls = sorted((float(e["ts"]), float(e["ts"]) + float(e["dur"])) for e in events
                   if e.get("ph") == "X" and str(e.get("name", "")).startswith("$reward.py")
                   and str(e["name"]).endswith(" timed_call"))
    windows = [(name, *call) for name, call in zip(steps, calls)]
    lines = []
    for name, start, stop in windows:
        inside = [e for e in kernels if start <= float(e["ts"]) < stop]
        spans = sorted((float(e["ts"]), float(e["ts"]) + float(e.get("dur", 0))) for e in inside)
        busy, end = 0.0, -1.0
        for begin, finish in spans:
            busy += max(0.0, finish - max(begin, end))
            end = max(end, finish)
        lines.append(f"{name}: {(stop - start) / 1000:.1f} ms, {len(inside)} kernels, device busy "
                     f"{busy / 1000:.1f} ms ({100 * busy / max(stop - start, 1e-9):.0f} %)")
        by_name = collections.defaultdict(lambda: [0, 0.0])
        for e in inside:
            by_name[e["name"]][0] += 1
            by_name[e["name"]][1] += float(e.get("dur", 0))
        for kernel, (count, total) in sorted(by_name.items(), key=lambda kv: -kv[1][0])[:top]:
            lines.append(f"  {count:7d} x, {total / 1000:8.2f} ms  {kernel[:80]}")
    return "\n".join(lines)


def score_batch_rate(clips: list, repeats: int) -> float:
    score_batch(clips[:1], progress=False)  # compile
    times = []
    for _ in range(repeats):
        begin = time.perf_counter()
        score_batch(clips, progress=False)
        times.append(time.perf_counter() - begin)
    return len(clips) / statistics.median(times)


def disk_rate(folder: Path, n: int) -> StreamStats:
    begin = time.perf_counter()
    paths = write_corpus(folder, n)
    print(f"corpus of {n} clips ready in {time.perf_counter() - begin:.0f} s", flush=True)
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
    parser.add_argument("--no-baseline", dest="baseline", action="store_false",
                        help="skip score_batch's in-memory rate (on accelerators it compiles groups of 16)")
    parser.add_argument("--profile", type=Path, default=None, metavar="DIR")
    parser.add_argument("--disk-clips", type=int, default=0)
    parser.add_argument("--dir", default="/tmp/sgc-stream-corpus")
    parser.add_argument("--linearise", choices=sorted(FORMS), default="package")
    parser.add_argument("--histogram-copies", type=int, default=partitions.ACCELERATOR_HISTOGRAM_COPIES)
    parser.add_argument("--all-lanes", action="store_true", help="every lane to its loop's end (no lanes left behind)")
    args = parser.parse_args()
    variant = (args.linearise, args.histogram_copies, args.all_lanes) != (
        "package", partitions.ACCELERATOR_HISTOGRAM_COPIES, False)
    joint_pnp.linearise = FORMS[args.linearise]
    partitions.ACCELERATOR_HISTOGRAM_COPIES = args.histogram_copies
    if args.all_lanes:
        lanes.MIN_LANES = joint_pnp.PAIR_LANES = sys.maxsize
    cache = default_cache_dir()
    enable_compilation_cache(cache / f"variant-{args.linearise}-copies{args.histogram_copies}"
                             f"{'-all-lanes' if args.all_lanes else ''}" if variant and cache is not None else cache)
    shape = tuple(args.shape)
    device = jax.devices()[0]
    print(f"device: {device.device_kind} ({jax.default_backend()}), {jax.device_count()} device(s); "
          f"clips of {shape[0]} frames, {shape[1]}x{shape[2]} px, {shape[3]} tracks per pair; "
          f"the least-squares step's form: {args.linearise}; the histograms' copies: {args.histogram_copies}"
          f"{'; every lane to its loop end' if args.all_lanes else ''}")
    clips = clips_of(shape, max(args.batch_sizes))
    baseline = float("nan")
    if args.baseline:
        baseline = score_batch_rate(clips, args.repeats)
        how = "one clip per program call" if jax.default_backend() == "cpu" else "groups of a bucket per call"
        print(f"score_batch, in memory ({how}): {baseline:.2f} clips/s", flush=True)
    print("| B | compile s | call s | clips/s | vs score_batch |")
    print("|---|---|---|---|---|", flush=True)
    for i, B in enumerate(args.batch_sizes):
        row = scorer_rate(clips, B, shape, args.repeats, args.vectorized,
                          args.profile / f"B{B}" if args.profile else None, with_hlo=i == 0)
        ratio = f"{row['clips_per_s'] / baseline:.2f}x" if args.baseline else "not run"
        print(f"| {B} | {row['compile_s']:.0f} | {row['call_s']:.3f} | {row['clips_per_s']:.2f} | {ratio} |",
              flush=True)
    if args.disk_clips > 0:
        stats = disk_rate(Path(args.dir), args.disk_clips)
        print(f"from disk, score_batch: {stats.scored} clips in {stats.wall_s:.1f} s = "
              f"{stats.scored / stats.wall_s:.2f} clips/s; the scoring thread waited for input "
              f"{100 * stats.input_wait_share:.0f} % of the wall time; the lanes summarised clips "
              f"{100 * stats.summary_s / stats.wall_s:.0f} %", flush=True)


if __name__ == "__main__":
    main()
