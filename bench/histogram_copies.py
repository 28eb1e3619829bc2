"""The depth partition's histograms in the accelerator form, timed for several numbers of copies
of the bins (``kmeans.HISTOGRAM_COPIES``), on any device.

    python bench/histogram_copies.py [--clips 64] [--copies 1 8 32 128] [--repeats 20]

The frames are the depth of --clips standard clips (bench/stream.py's scene, 16 frames, 288x512;
8 distinct scenes repeated), each frame's histogram of 1,024 bins built at once (vmapped, as
``depth_partition_of(..., frames_at_once=True)`` does). Printed per number of copies: ms per call
(median of --repeats) and the largest difference of the prefix sums from one copy's, relative to
their size (the counts must be equal).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from sgc_jax.kernels import kmeans
from sgc_jax.research.synth import synth_clip

sys.path.insert(0, str(Path(__file__).resolve().parent))
from stream import SCENE  # noqa: E402

BINS = 1024


def frame_histogram(depth):
    u, valid, _, _ = kmeans.normalise(depth.reshape(-1), jnp.ones(depth.size, bool))
    return kmeans.histogram(u * BINS, kmeans.bin_of(u, BINS), valid, BINS)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--clips", type=int, default=64)
    parser.add_argument("--copies", type=int, nargs="+", default=[1, 8, 32, 128])
    parser.add_argument("--repeats", type=int, default=20)
    args = parser.parse_args()
    scenes = [np.asarray(synth_clip(seed=i, **SCENE).depth) for i in range(min(8, args.clips))]
    depth = jnp.asarray(np.concatenate([scenes[i % len(scenes)] for i in range(args.clips)]), jnp.float32)
    print(f"device: {jax.devices()[0].device_kind} ({jax.default_backend()}); {depth.shape[0]} frames of "
          f"{depth.shape[1]}x{depth.shape[2]} px, {BINS} bins", flush=True)
    print("| copies | ms per call | counts equal | rel. diff. of the sums |")
    print("|---|---|---|---|", flush=True)
    reference = None
    for copies in args.copies:
        kmeans.HISTOGRAM_COPIES = copies  # read when traced
        build = jax.jit(jax.vmap(frame_histogram))
        out = jax.block_until_ready(build(depth))
        times = []
        for _ in range(args.repeats):
            begin = time.perf_counter()
            jax.block_until_ready(build(depth))
            times.append(time.perf_counter() - begin)
        hist, n_bin = out
        sums = np.concatenate([np.asarray(x, np.float64).reshape(len(depth), -1)
                               for x in (*hist.sum, *hist.sum_sq)], 1)
        if reference is None:
            reference = (np.asarray(n_bin), sums)
        equal = bool(np.array_equal(np.asarray(n_bin), reference[0]))
        diff = float(np.max(np.abs(sums - reference[1])) / max(np.max(np.abs(reference[1])), 1e-30))
        print(f"| {copies} | {1000 * statistics.median(times):.2f} | {equal} | {diff:.1e} |", flush=True)


if __name__ == "__main__":
    main()
