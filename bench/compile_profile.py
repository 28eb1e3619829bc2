"""Where one stage program's cold compile goes (issue 61): XLA's phases, and its kernels' LLVM time
by the Python function that emitted them.

    python bench/compile_profile.py [--stage pose] [--T 16 --H 288 --W 512 --P 4096] [--top 20]
    python bench/compile_profile.py --option xla_cpu_use_fusion_emitters=False

Traces and lowers the stage's program for one bucket (B = 1, score_batch's one-clip programs on a
CPU), then compiles it once with the stage's own CPU options (plus any ``--option``, a Python
literal) and XLA's logging on: the HLO passes, the kernels' emission (HLO fusions to LLVM IR, one
thread) and LLVM's code generation of each kernel module (both cores), read from XLA's timers. Each
kernel's LLVM time is attributed to the Python source of its fusion (the compiled program's stack
frames, as ``stage_profile.py`` reads them): inclusive by function, and the costliest kernels.
Times are CPU seconds of LLVM summed over kernels unless said; the compilation cache is not used.
"""

from __future__ import annotations

import argparse
import ast
import collections
import os
import re
import sys
import tempfile
import time
from pathlib import Path

# XLA reads its logging settings when jaxlib loads: set before jax is imported
os.environ["TF_CPP_MIN_LOG_LEVEL"] = "0"
os.environ["TF_CPP_VMODULE"] = "cpu_compiler=1,ir_compiler=1"

HERE = Path(__file__).resolve().parent
UNITS = {"us": 1e-6, "ms": 1e-3, "s": 1.0}
# the functions whose kernels are counted inclusively (any frame of a kernel's stack)
FUNCTIONS = ("region_start", "sample_distinct", "sample_candidates", "solve_pnp", "refine_poses", "local_optima",
             "solve_pnp_regions", "polish_poses", "pose_uncertainty", "camera_start", "borrow_region_poses",
             "translation_scale", "solve_spd", "so3_exp", "so3_log")


class CapturedStderr:
    """File descriptor 2 (where XLA logs) into a temporary file while open; ``text()`` reads it
    (inside the ``with``)."""

    def __enter__(self):
        sys.stderr.flush()
        self.log = tempfile.TemporaryFile(mode="w+")
        self.saved = os.dup(2)
        os.dup2(self.log.fileno(), 2)
        return self

    def __exit__(self, *exc):
        sys.stderr.flush()
        os.dup2(self.saved, 2)
        os.close(self.saved)
        self.log.close()

    def text(self) -> str:
        sys.stderr.flush()
        self.log.seek(0)
        return self.log.read()


def seconds(match) -> float:
    return float(match.group(1)) * UNITS[match.group(2)]


def phases(log: str) -> dict[str, float]:
    """The program's HLO passes, its compile after them, and within it the kernels' emission (up to
    the first kernel module LLVM finished) and LLVM's wall time, from XLA's timestamps."""
    stamp = lambda line: sum(float(x) * f for x, f in zip(line.split()[1].split(":"), (3600, 60, 1)))  # noqa: E731
    lines = log.splitlines()
    program = [i for i, line in enumerate(lines) if "Running HLO passes on [jit_" in line][-1]
    name = re.search(r"on \[(\S+)\]", lines[program]).group(1)
    start = next(i for i, line in enumerate(lines) if f"Compiling: {name}" in line and i > program)
    modules = [i for i, line in enumerate(lines) if i > start and "Compiled LLVM module" in line]
    done = next(i for i, line in enumerate(lines) if i > start and f"Compiling [{name}]" in line)
    return {"HLO passes": seconds(re.search(r"time: ([\d.]+) (us|ms|s) ", lines[program])),
            "kernel emission (one thread)": stamp(lines[modules[0]]) - stamp(lines[start]),
            "LLVM code generation (wall)": stamp(lines[modules[-1]]) - stamp(lines[modules[0]]),
            "compile after the HLO passes": seconds(re.search(r"time: ([\d.]+) (us|ms|s) ", lines[done]))}


def kernel_times(log: str) -> dict[str, float]:
    """Each kernel module's LLVM time [s], by its fusion's name."""
    times: dict[str, float] = collections.Counter()
    for match in re.finditer(r"Compiled LLVM module: __compute_module_(\S+)_kernel_module time: ([\d.]+) (us|ms|s) ",
                             log):
        times[match.group(1)] += float(match.group(2)) * UNITS[match.group(3)]
    return times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--stage", default="pose", choices=("pixel", "pose", "finish"))
    for name, default in (("T", 16), ("H", 288), ("W", 512), ("P", 4096)):
        parser.add_argument(f"--{name}", type=int, default=default)
    parser.add_argument("--option", action="append", default=[], help="an extra XLA option NAME=VALUE")
    parser.add_argument("--top", type=int, default=20)
    args = parser.parse_args()
    sys.path.insert(0, str(HERE))
    with CapturedStderr() as captured:  # XLA's log of every program, this stage's last
        figures = profile(args)
        log = captured.text()
    report(args, *figures, log)


def profile(args) -> tuple:
    """Trace, lower and compile the stage's program -> (options, traced s, compile wall s, CPU s, HLO text)."""
    import jax
    from program_size import padded_bucket, stage_calls

    from sgc_jax.config import SGCConfig

    for stage, run, inputs in stage_calls(padded_bucket(args.T, args.H, args.W, args.P), SGCConfig()):
        if stage.name == args.stage:
            break
    start = time.perf_counter()
    lowered = jax.jit(run).lower(inputs)
    traced = time.perf_counter() - start
    extra = {k: ast.literal_eval(v) for k, v in (o.split("=", 1) for o in args.option)}
    options = {**stage.cpu_compiler_options, **extra}
    start, cpu_start = time.perf_counter(), time.process_time()
    compiled = lowered.compile(compiler_options=options)
    return options, traced, time.perf_counter() - start, time.process_time() - cpu_start, compiled.as_text()


def report(args, options: dict, traced: float, wall: float, cpu: float, hlo: str, log: str) -> None:
    from stage_profile import source_frames

    stacks, _ = source_frames(hlo)
    kernels = kernel_times(log)
    print(f"bucket T={args.T}, {args.H}x{args.W} (padded to 64), P={args.P}; {args.stage} stage, options {options}")
    print(f"traced and lowered {traced:.1f} s; XLA compile {wall:.1f} s wall, {cpu:.1f} s CPU; "
          f"{hlo.count(' fusion(')} fusions, {len(kernels)} kernel modules, LLVM {sum(kernels.values()):.1f} s CPU")
    print("\n| phase | s |\n|---|---|")
    for phase, s in phases(log).items():
        print(f"| {phase} | {s:.1f} |")
    inclusive_n: dict[str, int] = collections.Counter()
    inclusive_s: dict[str, float] = collections.Counter()
    for name, s in kernels.items():
        functions = {function for _, function, _ in stacks.get(name, [])}
        for function in FUNCTIONS:
            if function in functions:
                inclusive_n[function] += 1
                inclusive_s[function] += s
    total = sum(kernels.values())
    print("\n| function (inclusive) | kernels | LLVM s | share |\n|---|---|---|---|")
    for function in sorted(FUNCTIONS, key=lambda f: -inclusive_s[f]):
        print(f"| `{function}` | {inclusive_n[function]} | {inclusive_s[function]:.2f} | "
              f"{inclusive_s[function] / total:.0%} |")
    print("\n| kernel | LLVM s | source (innermost first) |\n|---|---|---|")
    for name, s in sorted(kernels.items(), key=lambda kv: -kv[1])[:args.top]:
        frames = [f"{function}:{line}" for file, function, line in stacks.get(name, []) if not file.startswith("/")]
        print(f"| {name} | {s:.3f} | {' < '.join(frames[:3])} |")


if __name__ == "__main__":
    main()
