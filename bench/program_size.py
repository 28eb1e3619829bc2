"""Traced size of the JAX engine's programs for one bucket: jaxpr equations per stage (pixel,
pose, finish) and in all, counted through every sub-jaxpr (loops, conds, pjit, custom derivatives).

    python bench/program_size.py                  # the standard bucket T=16, 288x512, P=4096, B=1
    python bench/program_size.py --T 4 --H 128 --W 192 --P 2048
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.extend as jex
import numpy as np

from sgc_jax.config import SGCConfig
from sgc_jax.engines.jax_engine.buckets import Bucket, PaddedClips
from sgc_jax.engines.jax_engine.programs import stages_of


def count_equations(jaxpr) -> int:
    """Equations of a (closed) jaxpr and of every jaxpr nested in its equations' parameters."""
    jaxpr = getattr(jaxpr, "jaxpr", jaxpr)
    return len(jaxpr.eqns) + sum(count_equations(sub) for sub in jex.core.subjaxprs(jaxpr))


def zero_batch(bucket: Bucket, B: int = 1) -> PaddedClips:
    T, H, W, P = bucket.T, bucket.H, bucket.W, bucket.P
    f32 = np.float32
    return PaddedClips(np.zeros((B, T, H, W), f32), np.zeros((B, T, H, W), bool), np.zeros((B, T, 3, 3), f32),
                       np.zeros((B, T, 3, 3), f32), np.zeros((B, T, 3), f32), np.zeros((B, T - 1, P, 2), f32),
                       np.zeros((B, T - 1, P, 2), f32), np.zeros((B, T - 1, P), bool), np.zeros((B, T - 1), bool),
                       np.zeros((B, 2), np.int32), np.ones((B,), f32))


def padded_bucket(T: int, H: int, W: int, P: int) -> Bucket:
    """The shape bucket of clips of T frames, H x W px and P tracks (H and W up to a multiple of 64)."""
    return Bucket(T, -(-H // 64) * 64, -(-W // 64) * 64, P)


def stage_calls(bucket: Bucket, config: SGCConfig):
    """Each stage of ``config`` in pipeline order as (stage, its one-clip call, its zero inputs for
    ``bucket``, B = 1); a stage's inputs come from the shapes of the previous one's outputs."""
    key = jax.random.PRNGKey(config.seed)
    batch, previous = zero_batch(bucket), None
    for stage in stages_of(config):
        inputs = stage.inputs(batch, previous)
        run = lambda x, stage=stage: stage(x, key)  # noqa: E731
        yield stage, run, inputs
        previous = jax.eval_shape(run, inputs)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    for name, default in (("T", 16), ("H", 288), ("W", 512), ("P", 4096)):
        parser.add_argument(f"--{name}", type=int, default=default)
    args = parser.parse_args()
    bucket = padded_bucket(args.T, args.H, args.W, args.P)
    total = 0
    for stage, run, inputs in stage_calls(bucket, SGCConfig()):
        start = time.perf_counter()
        closed = jax.make_jaxpr(run)(inputs)
        traced_s = time.perf_counter() - start
        total += count_equations(closed)
        print(f"bucket {bucket}, {stage.name} stage: {count_equations(closed)} jaxpr equations (traced in {traced_s:.1f} s)")
    print(f"bucket {bucket}: {total} jaxpr equations in all")


if __name__ == "__main__":
    main()
