"""Where a warm standard clip's XLA time goes, by the source that emitted each operation (issue 61).

    python bench/stage_profile.py [--clips 4] [--repeat 2] [--stages pixel pose finish] [--top 25]
    python bench/stage_profile.py --shape 81 480 832 4096 --clips 1 --stages finish  # another size (T H W P)

Scores --clips standard clips of bench/stream.py's corpus once (compiling or loading the stage
programs), then traces each stage program alone over the clips --repeat times (``jax.profiler``,
a Perfetto trace) and attributes every XLA operation's time to the Python source that emitted it,
read from the compiled program's stack frames (HLO metadata). Per stage and per clip it prints the
operations' total time (all threads, so above the wall time where both cores work), how much of
it falls in operations under 2 us, and two tables: the inclusive time of each function (an
operation counts for every function on its stack) and the innermost source line. Loops,
conditionals and calls are containers: their bodies' operations are counted, not the container.
The figures are op time as XLA's profiler sees it; the tracer adds ~15 % to a clip's wall time.
The programs are score_batch's one-clip programs as a CPU runs them (an accelerator's vectorized
programs: ``bench/reward.py --profile``).
"""

from __future__ import annotations

import argparse
import collections
import glob
import gzip
import json
import re
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
TABLES = ("FileNames", "FunctionNames", "FileLocations", "StackFrames")
CONTAINERS = (" while(", " conditional(", " call(")
Frame = tuple[str, str, int]  # (file, function, line)
# frames every operation of a program shares (the compile path, the script that compiled it): left
# out of the functions' table
OUTSIDE = ("/", "engines/jax_engine/programs.py")


def source_frames(hlo_text: str) -> tuple[dict[str, list[Frame]], set[str]]:
    """The compiled HLO's text -> (each instruction's stack, innermost first; the names of its
    loops, conditionals and calls). Files are shortened to the part below sgc_jax/ or
    site-packages/."""
    tables: dict[str, dict[int, str]] = {name: {} for name in TABLES}
    section = None
    for line in hlo_text.splitlines():
        if line in TABLES:
            section = line
        elif not line.strip():
            section = None
        elif section and (entry := re.match(r"(\d+) (.*)", line)):
            tables[section][int(entry.group(1))] = entry.group(2)
    short = lambda name: re.split(r"sgc_jax/|site-packages/", name.strip('"'))[-1]  # noqa: E731
    fields = lambda text: {k: int(v) for k, v in re.findall(r"(\w+)=(\d+)", text)}  # noqa: E731
    locations = {}
    for i, text in tables["FileLocations"].items():
        f = fields(text)
        locations[i] = (short(tables["FileNames"][f["file_name_id"]]),
                        tables["FunctionNames"][f["function_name_id"]].strip('"'), f["line"])
    parents = {i: (fields(text)["file_location_id"], fields(text)["parent_frame_id"] - 1)
               for i, text in tables["StackFrames"].items()}  # a parent id is stored one above, 0: none

    def stack(frame: int) -> list[Frame]:
        out, seen = [], set()
        while frame in parents and frame not in seen:
            seen.add(frame)
            location, frame = parents[frame]
            out.append(locations[location])
        return out

    stacks, containers = {}, set()
    for line in hlo_text.splitlines():
        op = re.match(r"\s*(?:ROOT )?%?([\w.\-]+) = (.*?)stack_frame_id=(\d+)", line)
        if op:
            stacks[op.group(1)] = stack(int(op.group(3)))
            if any(kind in op.group(2) for kind in CONTAINERS):
                containers.add(op.group(1))
    return stacks, containers


def op_events(trace_dir: Path) -> list[tuple[str, float]]:
    """(operation name, microseconds) of every XLA operation in the Perfetto trace under trace_dir."""
    path = next(iter(glob.glob(str(trace_dir / "**" / "*.json.gz"), recursive=True)))
    with gzip.open(path) as f:
        trace = json.load(f)
    events = trace["traceEvents"] if isinstance(trace, dict) else trace
    return [(e["name"], e["dur"]) for e in events
            if e.get("ph") == "X" and "dur" in e and not e["name"].startswith(("$", "ThunkExecutor"))]


def attribute(events, stacks, containers, calls: int) -> dict:
    """Per-clip op time (ms): total, under 2 us, unattributed; by function (inclusive) and by line."""
    by_function: dict[str, float] = collections.defaultdict(float)
    by_line: dict[str, float] = collections.defaultdict(float)
    total = small = unknown = 0.0
    for name, us in events:
        if name in containers:
            continue
        total += us
        small += us if us < 2 else 0.0
        frames = stacks.get(name)
        if not frames:
            unknown += us
            continue
        file, function, line = frames[0]
        by_line[f"{file}:{line} {function}"] += us
        for file, function in {(f[0], f[1]) for f in frames if not f[0].startswith(OUTSIDE)}:
            by_function[f"{file} {function}"] += us
    per_clip = lambda us: us / calls / 1000  # noqa: E731
    return dict(total=per_clip(total), small=per_clip(small), unknown=per_clip(unknown),
                by_function={k: per_clip(v) for k, v in by_function.items()},
                by_line={k: per_clip(v) for k, v in by_line.items()})


def print_tables(stage: str, figures: dict, top: int) -> None:
    print(f"\n### {stage}: {figures['total']:.1f} ms of op time per clip ({figures['small']:.1f} ms in operations "
          f"under 2 us, {figures['unknown']:.1f} ms without a source)\n")
    for title, table in (("function (inclusive)", figures["by_function"]), ("innermost line", figures["by_line"])):
        print(f"| {title} | ms per clip | share |\n|---|---|---|")
        for key, ms in sorted(table.items(), key=lambda kv: -kv[1])[:top]:
            print(f"| `{key}` | {ms:.2f} | {ms / figures['total']:.0%} |")
        print()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--clips", type=int, default=4)
    parser.add_argument("--repeat", type=int, default=2, help="traced calls of each stage per clip")
    parser.add_argument("--stages", nargs="+", default=["pixel", "pose", "finish"])
    parser.add_argument("--top", type=int, default=25, help="rows of each table")
    parser.add_argument("--corpus", type=Path, default=Path("/tmp/sgc-stream-corpus"))
    parser.add_argument("--shape", type=int, nargs=4, metavar=("T", "H", "W", "P"),
                        help="clips of this size instead of standard ones, in a folder of --corpus's name and the size")
    args = parser.parse_args()
    sys.path.insert(0, str(HERE))
    import jax
    from stream import sized_corpus, write_corpus

    from sgc_jax import SGCConfig, enable_compilation_cache
    from sgc_jax.engines.jax_engine.buckets import PaddedClips
    from sgc_jax.engines.jax_engine.dispatch import prepare_clip
    from sgc_jax.engines.jax_engine.programs import pipeline
    from sgc_jax.io.loading import load_clips

    enable_compilation_cache()
    config = SGCConfig()
    scene, corpus, size = sized_corpus(args.corpus, args.shape)
    calls: dict[str, list] = collections.defaultdict(list)  # stage -> [(program, inputs, key, values)]
    for clip in (prepare_clip(c, config) for c in load_clips(write_corpus(corpus, args.clips, scene))):
        score = pipeline(config, clip.bucket, clip.batch)
        batch, out = PaddedClips(*jax.device_put(tuple(clip.batch))), None
        for stage, program, values in zip(score.stages, score.programs, score.values):
            inputs = stage.inputs(batch, out)
            out = jax.block_until_ready(program(inputs, score.key, values))  # warm
            calls[stage.name].append((program, inputs, score.key, values))
    print(f"jax {jax.__version__}, {jax.devices()[0].device_kind}; {args.clips} {size} clips, "
          f"{args.repeat} traced calls each")
    for stage in args.stages:
        stacks, containers = source_frames(calls[stage][0][0].as_text())
        with tempfile.TemporaryDirectory() as tmp:
            with jax.profiler.trace(tmp, create_perfetto_trace=True):
                for _ in range(args.repeat):
                    for program, inputs, key, values in calls[stage]:
                        jax.block_until_ready(program(inputs, key, values))
            events = op_events(Path(tmp))
        print_tables(stage, attribute(events, stacks, containers, args.repeat * len(calls[stage])), args.top)


if __name__ == "__main__":
    main()
