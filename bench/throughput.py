"""Clips per second of the JAX engine (cold and warm) and of the reference engine, in one run
(docs/semantics.md §7).

    python bench/throughput.py [--clips 8] [--frames 16] [--height 288] [--width 512] [--tracks 4096]

Generates the standard corpus (T=16, 288x512, 4096 tracks per pair, ~10 regions), then times:
the reference engine per clip under ``compat="authors"`` (cv2.solvePnPRansac with the authors'
settings: it stands for the authors' pipeline) and under ``compat="spec"`` (the independent
search of the spec semantics); JAX cold (first call, compile included) and warm (the best
of --repeat further calls on the same bucket, so a burst of load from other processes on a shared
machine does not decide the figure). Peak memory is the process's maximum resident set size; the
1-minute load average before and after is printed with the figures.

    python bench/throughput.py --compile-cache DIR   # twice with the same DIR

The second run's cold time is a later process's start with JAX's persistent compilation cache
(what the ``sgc-jax`` commands use by default): the compile is loaded from disk, the tracing stays.
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import time
from pathlib import Path

import jax

from sgc_jax import SGCConfig, enable_compilation_cache
from sgc_jax.engines import reference
from sgc_jax.engines.jax_engine.dispatch import score_pairs_batch
from sgc_jax.research.synth import synth_clip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--clips", type=int, default=8)
    parser.add_argument("--frames", type=int, default=16)
    parser.add_argument("--height", type=int, default=288)
    parser.add_argument("--width", type=int, default=512)
    parser.add_argument("--tracks", type=int, default=4096)
    parser.add_argument("--repeat", type=int, default=3, help="warm JAX calls; the fastest counts")
    parser.add_argument("--compile-cache", metavar="DIR", help="JAX persistent compilation cache directory")
    args = parser.parse_args()
    cache_note = "no persistent cache"
    if args.compile_cache:
        cache = Path(args.compile_cache)
        cache_note = "persistent cache " + ("populated" if cache.is_dir() and any(cache.iterdir()) else "empty")
        enable_compilation_cache(cache)
    load_before = os.getloadavg()[0]

    scene = dict(n_frames=args.frames, height=args.height, width=args.width, n_tracks=args.tracks,
                 n_layers=4, static_spheres=3, noise_px=0.5, outlier_frac=0.1)
    clips = [synth_clip(seed=s, **scene) for s in range(args.clips)]

    ref_s = {}
    for compat in ("authors", "spec"):
        config = SGCConfig(compat=compat)
        start = time.perf_counter()
        for clip in clips:
            reference.score_pairs(clip, config)
        ref_s[compat] = time.perf_counter() - start

    start = time.perf_counter()
    score_pairs_batch(clips)
    cold_s = time.perf_counter() - start
    warm_s = float("inf")
    for _ in range(args.repeat):
        start = time.perf_counter()
        score_pairs_batch(clips)
        warm_s = min(warm_s, time.perf_counter() - start)

    n = len(clips)
    peak_mib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, jax {jax.__version__} "
          f"on {jax.default_backend()}; load average {load_before:.1f} before, {os.getloadavg()[0]:.1f} after")
    print(f"corpus: {n} clips of T={args.frames}, {args.height}x{args.width}, {args.tracks} tracks")
    print("| engine | seconds | clips/s | speed vs authors' pipeline | speed vs spec reference |")
    print("|---|---|---|---|---|")
    rows = [("reference, compat=authors (the authors' pipeline)", ref_s["authors"]),
            ("reference, compat=spec", ref_s["spec"]),
            (f"jax cold (compile included, {cache_note})", cold_s), (f"jax warm (best of {args.repeat})", warm_s)]
    for name, seconds in rows:
        print(f"| {name} | {seconds:.2f} | {n / seconds:.2f} | {ref_s['authors'] / seconds:.2f} | "
              f"{ref_s['spec'] / seconds:.2f} |")
    print(f"peak resident memory: {peak_mib:.0f} MiB")


if __name__ == "__main__":
    main()
