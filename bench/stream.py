"""End-to-end scoring from disk against in-memory scoring, and peak memory by corpus size, in one
run (docs/semantics.md §4.1).

    python bench/stream.py [--clips 64] [--memory-sizes 64 256] [--dir /tmp/sgc-stream-corpus]
    python bench/stream.py --clips 1000 --memory-sizes   # the 1,000-clip measurement (on a GPU)
    python bench/stream.py --shape 81 480 832 4096 --clips 8 --in-memory 4 --memory-sizes   # generator-size clips

Writes the standard corpus (T=16, 288x512, 4096 tracks per pair, ~10 regions; clip files of
~10 MB, their float depth stored) to --dir once (kept for later runs), compiles the bucket's
program, then, warm:
- in memory: ``score_batch`` of --in-memory clips already loaded (the device-only figure);
- from disk: ``sgc-jax score``'s path, ``score_batch(folder, out=...)``: find, read, hash,
  validate and pad in readers (threads, or processes on a host of many cores), score, write the
  CSV as clips finish. Prints clips per second of both, their ratio, and the share of the wall
  time the scoring thread waited for a clip to be read (an upper bound of the device's idle time
  for want of input);
- memory: for each of --memory-sizes, a fresh process scores that many files from disk and
  reports its maximum resident set size and what it holds at the end (the results included).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import jax

from sgc_jax import enable_compilation_cache, save_clip, score_batch
from sgc_jax.engines.jax_engine.compile_cache import _cpu_features
from sgc_jax.io.loading import load_clips
from sgc_jax.research.synth import synth_clip
from sgc_jax.scoring.readers import reading_plan
from sgc_jax.scoring.streaming import StreamStats

SCENE = dict(n_frames=16, height=288, width=512, n_tracks=4096, n_layers=4, static_spheres=3, noise_px=0.5,
             outlier_frac=0.1)


# distinct scenes (synthesising a standard scene takes ~4 s on the 2-core box, writing it ~1 s);
# beyond them, clip n is a copy of clip n mod DISTINCT_SCENES's file. The files hold no clip id,
# so each clip takes its file's name.
DISTINCT_SCENES = 16


def host_cpu() -> str:
    """The CPU's model name and whether it has AVX-512 (the flags the compilation cache keys on):
    the CPU programs' vectors are 512 bits wide only with it (docs/semantics.md §7.1), so speed
    figures depend on it."""
    try:
        info = Path("/proc/cpuinfo").read_text()
    except OSError:
        info = ""
    model = next((line.split(":", 1)[1].strip() for line in info.splitlines() if line.startswith("model name")),
                 platform.processor() or "CPU unknown")
    return f"{model}, AVX-512 {'yes' if 'avx512f' in _cpu_features().split() else 'no'}"


def write_corpus(folder: Path, n: int, scene: dict | None = None) -> list[Path]:
    """The first n clips of ``scene`` (default: standard clips) in ``folder``, written where
    missing (so a run with fewer clips reuses a larger corpus's files)."""
    folder.mkdir(parents=True, exist_ok=True)
    paths = [folder / f"clip{i:05d}.npz" for i in range(n)]
    for i, path in enumerate(paths):
        if path.exists():
            continue
        partial = path.with_name(path.stem + ".partial.npz")
        if i < DISTINCT_SCENES:
            save_clip(partial, dataclasses.replace(synth_clip(seed=i, **(scene or SCENE)), clip_id=""))
        else:
            shutil.copyfile(write_corpus(folder, i % DISTINCT_SCENES + 1, scene)[-1], partial)
        os.replace(partial, path)
    return paths


def sized_corpus(folder: Path, shape: tuple[int, int, int, int] | None) -> tuple[dict, Path, str]:
    """(scene, folder, name) of clips of ``shape`` (T, H, W, P): standard clips in ``folder`` where
    None, else ``SCENE`` at that size in a folder of ``folder``'s name and the size."""
    if not shape:
        return SCENE, folder, "standard"
    T, H, W, P = shape
    kind = f"{T}x{H}x{W}x{P}"
    return dict(SCENE, n_frames=T, height=H, width=W, n_tracks=P), folder.with_name(f"{folder.name}-{kind}"), kind


def memory_mib(paths: list[Path]) -> tuple[float, float]:
    """(peak, resident at the end) [MiB] of a fresh process scoring ``paths`` from disk. The peak
    is set by compiling or loading the program (~3 GB); what the stream keeps shows in the end."""
    code = ("import resource, sys, json, tempfile; from sgc_jax import score_batch, enable_compilation_cache; "
            "enable_compilation_cache(); paths = json.load(sys.stdin); "
            "result = score_batch(paths, out=tempfile.mkdtemp() + '/s.csv', progress=False); "
            "rss = [l for l in open('/proc/self/status') if l.startswith('VmRSS')][0].split()[1]; "
            "print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, int(rss) / 1024)")
    done = subprocess.run([sys.executable, "-c", code], input=json.dumps([str(p) for p in paths]), text=True,
                          capture_output=True, check=True)
    peak, end = done.stdout.strip().splitlines()[-1].split()
    return float(peak), float(end)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--clips", type=int, default=64, help="clips scored from disk")
    parser.add_argument("--in-memory", type=int, default=16, help="clips scored from memory (the device-only figure)")
    parser.add_argument("--memory-sizes", type=int, nargs="*", default=[64, 256],
                        help="corpus sizes whose peak memory is measured, each in a fresh process")
    parser.add_argument("--dir", default=os.path.join(tempfile.gettempdir(), "sgc-stream-corpus"))
    parser.add_argument("--readers", type=int, default=None, help="clip readers (default: the scorer's)")
    parser.add_argument("--read-in", default="auto", choices=("auto", "threads", "processes"),
                        help="readers are threads or processes (default: the scorer's choice)")
    parser.add_argument("--lanes", type=int, default=None, help="clips scored at once (default: the scorer's)")
    parser.add_argument("--shape", type=int, nargs=4, metavar=("T", "H", "W", "P"),
                        help="clips of this size instead of standard ones, in a folder of --dir's name and the size")
    args = parser.parse_args()
    enable_compilation_cache()  # the peak-memory processes load the program compiled here
    scene, folder, kind = sized_corpus(Path(args.dir), args.shape)
    begin = time.perf_counter()
    paths = write_corpus(folder, max([args.clips, args.in_memory, *args.memory_sizes]), scene)
    print(f"corpus: {len(paths)} {kind} clips in {folder} ({time.perf_counter() - begin:.0f} s to write the missing)",
          flush=True)
    readers, processes = reading_plan(args.readers, args.read_in)
    print(f"devices: {jax.devices()}; {readers} reader {'processes' if processes else 'threads'}; load average "
          f"{os.getloadavg()[0]:.2f}", flush=True)

    in_memory = list(load_clips([str(p) for p in paths[:args.in_memory]]))
    score_batch(in_memory[:1], progress=False, lanes=args.lanes)  # compile (or load) the bucket's program
    begin = time.perf_counter()
    score_batch(in_memory, progress=False, lanes=args.lanes)
    memory_rate = len(in_memory) / (time.perf_counter() - begin)

    stats = StreamStats()
    with tempfile.TemporaryDirectory() as out:
        begin = time.perf_counter()
        score_batch([str(p) for p in paths[:args.clips]], out=Path(out) / "scores.csv", progress=False,
                    readers=args.readers, read_in=args.read_in, lanes=args.lanes, stats=stats)
        disk_rate = args.clips / (time.perf_counter() - begin)
    print(f"in memory: {memory_rate:.3f} clips/s ({len(in_memory)} clips, warm)")
    print(f"from disk: {disk_rate:.3f} clips/s ({args.clips} clips, reading, hashing, validating, writing the CSV)")
    print(f"  in-memory / from-disk time per clip: {memory_rate / disk_rate:.3f}x; scoring thread waited for input "
          f"{stats.input_wait_share:.1%} of the wall time ({stats.input_wait_s:.1f} of {stats.wall_s:.1f} s)")
    sizes = {n: memory_mib(paths[:n]) for n in args.memory_sizes}
    for n, (peak, end) in sizes.items():
        print(f"memory, {n} clips from disk in a fresh process: peak {peak:.0f} MiB, resident at the end {end:.0f} MiB")
    if len(sizes) > 1:
        peaks, ends = [p for p, _ in sizes.values()], [e for _, e in sizes.values()]
        print(f"  largest / smallest: peak {max(peaks) / min(peaks):.3f}, at the end {max(ends) / min(ends):.3f}")
    print(f"this process: {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MiB; load average "
          f"{os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
