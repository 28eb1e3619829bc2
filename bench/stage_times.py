"""Warm time of each JAX stage program (pixel, pose, finish) per standard clip: where a clip's time goes.

    python bench/stage_times.py [--clips 6] [--repeat 3] [--corpus /tmp/sgc-stream-corpus]
    PYTHONPATH=<another checkout> python bench/stage_times.py     # checkouts from c50b066 on
    python bench/stage_times.py --shape 81 480 832 4096 --clips 2  # another clip size (T H W P)
    python bench/stage_times.py --moving-objects 2  # standard clips with masked moving objects
    python bench/stage_times.py --config '{"depth_check_at": "point"}'  # another SGCConfig

Scores --clips standard clips (bench/stream.py's corpus, written where missing) --repeat times,
each stage called on its own and waited for, and prints each stage's median over the warm calls
(the first clip of the first round, which compiles or loads the programs, is left out), and the
median CPU time of the process over each call (all of XLA's threads). Medians,
not means: the shared 2-core box swings by tens of percent from call to call. The persistent
compilation cache is on, so a second run starts at once.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--clips", type=int, default=6)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--corpus", type=Path, default=Path("/tmp/sgc-stream-corpus"))
    parser.add_argument("--shape", type=int, nargs=4, metavar=("T", "H", "W", "P"),
                        help="clips of this size instead of standard ones, in a folder of --corpus's name and the size")
    parser.add_argument("--moving-objects", type=int, default=0,
                        help="this many masked moving objects in each clip (a folder of --corpus's name and -moversN)")
    parser.add_argument("--config", default="{}", help="SGCConfig fields as JSON, e.g. '{\"depth_check_at\": \"point\"}'")
    args = parser.parse_args()
    sys.path.insert(0, str(HERE))
    import jax
    from stream import host_cpu, sized_corpus, write_corpus

    import sgc_jax
    from sgc_jax import SGCConfig, enable_compilation_cache
    from sgc_jax.engines.jax_engine.buckets import PaddedClips
    from sgc_jax.engines.jax_engine.dispatch import prepare_clip
    from sgc_jax.engines.jax_engine.programs import pipeline
    from sgc_jax.io.loading import load_clips

    enable_compilation_cache()
    config = SGCConfig(**json.loads(args.config))
    scene, corpus, _ = sized_corpus(args.corpus, args.shape)
    if args.moving_objects:
        scene = dict(scene, moving_objects=args.moving_objects)
        corpus = corpus.with_name(f"{corpus.name}-movers{args.moving_objects}")
    prepared = [prepare_clip(clip, config) for clip in load_clips(write_corpus(corpus, args.clips, scene))]
    names = ("pixel", "pose", "finish")
    times: dict[str, list[float]] = {name: [] for name in names}
    cpu: dict[str, list[float]] = {name: [] for name in names}  # process CPU time: all threads
    for round_ in range(args.repeat):
        for i, clip in enumerate(prepared):
            score = pipeline(config, clip.bucket, clip.batch)
            batch = PaddedClips(*jax.device_put(tuple(clip.batch)))
            out = None
            for stage, program, values in zip(score.stages, score.programs, score.values):
                start, start_cpu = time.perf_counter(), time.process_time()
                out = jax.block_until_ready(program(stage.inputs(batch, out), score.key, values))
                if round_ or i:
                    times[stage.name].append(time.perf_counter() - start)
                    cpu[stage.name].append(time.process_time() - start_cpu)
    medians = {stage: statistics.median(t) * 1000 for stage, t in times.items()}
    cpu_medians = {stage: statistics.median(t) * 1000 for stage, t in cpu.items()}
    print(f"{Path(sgc_jax.__file__).parent.parent}, clips of T={scene['n_frames']}, {scene['height']}x{scene['width']}, "
          f"{scene['n_tracks']} tracks, {scene.get('moving_objects', 0)} masked moving objects: "
          + ", ".join(f"{stage} {ms:.0f} ms" for stage, ms in medians.items())
          + f"; a clip {sum(medians.values()):.0f} ms ({len(times['pixel'])} warm calls per stage)")
    print(f"  {host_cpu()}; CPU time (all threads): " + ", ".join(f"{stage} {ms:.0f} ms" for stage, ms in cpu_medians.items())
          + f"; a clip {sum(cpu_medians.values()):.0f} ms")


if __name__ == "__main__":
    main()
