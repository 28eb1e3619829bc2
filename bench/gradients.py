"""The differentiable score's cost (docs/semantics.md §10): the time of one Scorer call (forward
only) against one ``jax.grad`` of ``sgc_smooth`` with respect to every float input (the forward
pass, the differentiable recomputation and its backward pass), same clips, same run.

    python bench/gradients.py [--batch-size 1] [--shape 16 288 512 4096] [--repeats 3]

Standard clips by default (bench/stream.py's scene). Compiles are timed apart (the first gradient
call compiles the forward pass again as traced programs, and the backward pass); the figures are
medians of --repeats warm calls, each waited for. The issue's aim: the backward pass (gradient
call minus forward call) at most 3x the forward call.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import jax

from sgc_jax import Scorer, enable_compilation_cache
from sgc_jax.scoring.scorer import batch_of

sys.path.insert(0, str(Path(__file__).resolve().parent))
from reward import clips_of  # noqa: E402

FLOATS = ("depth", "track_prev", "track_curr", "R_wc", "t_wc", "K")


def timed(call, repeats: int) -> tuple[float, float]:
    """(the first call's seconds, the median of ``repeats`` more), each waited for."""
    times = []
    for _ in range(repeats + 1):
        begin = time.perf_counter()
        jax.block_until_ready(call())
        times.append(time.perf_counter() - begin)
    return times[0], statistics.median(times[1:])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--batch-size", type=int, default=1)
    parser.add_argument("--shape", type=int, nargs=4, default=(16, 288, 512, 4096), metavar=("T", "H", "W", "P"))
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    enable_compilation_cache()
    B, shape = args.batch_size, tuple(args.shape)
    batch = batch_of([clips_of(shape, B)[i % 8] for i in range(B)], shape)
    floats = {name: batch[name] for name in FLOATS}

    begin = time.perf_counter()
    scorer = Scorer((B, *shape), differentiable=True)
    print(f"device: {jax.devices()[0].device_kind}; B={B}, shape {shape}; Scorer compiled in "
          f"{time.perf_counter() - begin:.1f} s", flush=True)
    plain = Scorer((B, *shape))  # the ordinary forward: same stage programs, without sgc_smooth

    def gradient():
        return jax.grad(lambda x: scorer({**batch, **x})["sgc_smooth"].sum())(floats)

    _, forward = timed(lambda: plain(batch)["sgc"], args.repeats)
    _, forward_smooth = timed(lambda: scorer(batch)["sgc_smooth"], args.repeats)
    first, both = timed(gradient, args.repeats)
    backward = both - forward
    print(f"forward (Scorer call, sgc):            {forward / B * 1e3:8.1f} ms per clip")
    print(f"forward with sgc_smooth:               {forward_smooth / B * 1e3:8.1f} ms per clip")
    print(f"forward + backward (jax.grad, 6 inputs): {both / B * 1e3:8.1f} ms per clip "
          f"(first call, compiling: {first:.1f} s)")
    print(f"backward / forward: {backward / forward:.2f} (aim <= 3)")


if __name__ == "__main__":
    main()
