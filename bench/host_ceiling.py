"""How many clips per second the host can feed an accelerator: ``score_batch`` from disk with the
device's work replaced by its answer (issue 61, the 1,000-clips-from-disk bar).

    python bench/host_ceiling.py [--clips 64] [--read-in auto|threads|processes] [--profile]

On a GPU, 1,000 standard clips from disk took 15.4 s where the device alone would take ~2 s: the
host bounds the figure (bench/RESULTS.md). This measures that bound on any machine. The stream runs
as on an accelerator (groups of 16 clips of one bucket, two lanes; readers as ``reading_plan``
chooses) and does all of its host work: reading, hashing, validating and preparing each clip, the
group's arrays stacked as ``dispatch_group`` stacks them, the per-pair arrays of every clip made
from a program's outputs as ``collect`` makes them, each group summarised in its lane, every row
written to the CSV. Only the program call is left out: each group's outputs are the real outputs
of a group of the corpus's first clip, computed once beforehand. Prints clips per second, the time
the scoring thread waited for input, the lanes' summary time, and the process's CPU time per clip;
``--profile``: the scoring thread's and lanes' functions by own time (``cProfile`` in each thread).
"""

from __future__ import annotations

import argparse
import cProfile
import os
import pstats
import resource
import sys
import tempfile
import threading
import time
from pathlib import Path

import jax
import numpy as np

HERE = Path(__file__).resolve().parent
GROUP = 16  # ACCELERATOR_CLIPS_PER_DEVICE: clips per program call on one accelerator
LANES = 2  # ACCELERATOR_LANES


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--clips", type=int, default=64, help="clips scored from disk (a multiple of 16 keeps groups full)")
    parser.add_argument("--dir", type=Path, default=Path(tempfile.gettempdir()) / "sgc-stream-corpus")
    parser.add_argument("--read-in", default="auto", choices=("auto", "threads", "processes"))
    parser.add_argument("--readers", type=int, default=None)
    parser.add_argument("--repeats", type=int, default=2, help="runs; the fastest counts")
    parser.add_argument("--profile", action="store_true", help="the host's functions by own time")
    args = parser.parse_args()
    sys.path.insert(0, str(HERE))
    from stream import host_cpu, write_corpus

    from sgc_jax import SGCConfig, enable_compilation_cache, score_batch
    from sgc_jax.engines.jax_engine import dispatch as device_dispatch
    from sgc_jax.engines.jax_engine.buckets import PaddedClips
    from sgc_jax.io.loading import load_clips
    from sgc_jax.scoring import engine_steps as steps_module, streaming
    from sgc_jax.scoring.readers import reading_plan
    from sgc_jax.scoring.streaming import StreamStats

    enable_compilation_cache()
    config = SGCConfig()
    paths = write_corpus(args.dir, args.clips)
    readers, in_processes = reading_plan(args.readers, args.read_in)
    print(f"{host_cpu()}, {os.cpu_count()} cores; jax {jax.__version__} on {jax.devices()[0].platform}; {args.clips} "
          f"standard clips from {args.dir}, groups of {GROUP} in {LANES} lanes; {readers} readers in "
          f"{'processes' if in_processes else 'threads'}", flush=True)

    # the outputs of one real group: the first clip's program outputs, stacked GROUP times
    first = device_dispatch.prepare_clip(next(iter(load_clips(paths[:1]))), config)
    one = device_dispatch.dispatch(first, config)
    answer = {name: np.concatenate([np.asarray(value)] * GROUP) for name, value in jax.device_get(one.out).items()}

    def dispatch_group(group):  # the host's part of ``dispatch_group``: the group's arrays stacked
        fill = [group[-1].batch] * (GROUP - len(group))
        PaddedClips(*(np.concatenate(arrays) for arrays in zip(*[p.batch for p in group], *fill)))
        return device_dispatch.Dispatched(group, answer)

    def replayed_steps(name, config, devices=None, lanes=None):
        prepare = steps_module.prepare_step(name, config)
        return steps_module.Engine(prepare, dispatch_group, lambda dispatched: device_dispatch.collect(dispatched, config),
                                   GROUP, lambda prepared: prepared.bucket, LANES)

    streaming.engine_steps = replayed_steps
    profiles: list[cProfile.Profile] = []
    if args.profile:  # every thread the stream starts from here on (threading.setprofile is per new thread)
        def start_profile(*_):
            profile = cProfile.Profile()
            profiles.append(profile)
            profile.enable()  # replaces this hook in its thread
        threading.setprofile(start_profile)

    best = None
    for _ in range(args.repeats):
        stats = StreamStats()
        out = Path(tempfile.mkdtemp()) / "scores.csv"
        cpu_before, begin = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter()
        main_profile = cProfile.Profile() if args.profile else None
        if main_profile:
            main_profile.enable()
        score_batch(paths, config=config, out=out, progress=False, readers=args.readers, read_in=args.read_in,
                    stats=stats)
        if main_profile:
            main_profile.disable()
            profiles.append(main_profile)
        wall = time.perf_counter() - begin
        cpu_after = resource.getrusage(resource.RUSAGE_SELF)
        cpu = sum(getattr(cpu_after, f) - getattr(cpu_before, f) for f in ("ru_utime", "ru_stime"))
        children = resource.getrusage(resource.RUSAGE_CHILDREN)
        print(f"  {args.clips / wall:.1f} clips/s ({wall:.2f} s); the scoring thread waited for input "
              f"{100 * stats.input_wait_share:.0f} % of it; summaries in the lanes {1000 * stats.summary_s / args.clips:.2f} "
              f"ms a clip; this process's CPU {1000 * cpu / args.clips:.1f} ms a clip (reader processes so far: "
              f"{children.ru_utime + children.ru_stime:.1f} s)", flush=True)
        best = wall if best is None else min(best, wall)
    print(f"host ceiling: {args.clips / best:.1f} clips/s, 1,000 clips in {1000 * best / args.clips:.1f} s")
    if profiles:
        merged = pstats.Stats(profiles[0])
        for profile in profiles[1:]:
            merged.add(profile)
        merged.sort_stats("tottime").print_stats(25)
        merged.sort_stats("cumulative").print_stats(r"sgc_jax|host_ceiling", 30)


if __name__ == "__main__":
    main()
