"""The depth partition's histograms in the accelerator form, their three segment sums (counts,
offsets, squared offsets) timed with the entries added into several copies of the bins (entry i
into copy i mod C, the copies summed after), on any device. One copy is the package's form.

    python bench/histogram_copies.py [--clips 64] [--copies 1 8 32 128] [--repeats 20]

The frames are the depth of --clips standard clips (bench/stream.py's scene, 16 frames, 288x512;
8 distinct scenes repeated), each frame's sums over 1,024 bins built at once (vmapped, as
``depth_partition_of(..., frames_at_once=True)`` does). On an H200 the three scatters took 33 of
the pixel stage's 44 ms at B = 64 (bench/history/issue-61.md "The least-squares step on an H200"):
neighbouring pixels share a bin, and their atomic adds to one address wait on each other. Printed
per number of copies: ms per call (median of --repeats), whether the counts equal one copy's, and
the largest difference of the float sums from one copy's, relative to their size. The sums are
``kmeans.segment_sums``'s; ``bench/reward.py --histogram-copies C`` times the Scorer with them.
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


def frame_sums(depth, copies: int):
    """(counts, offsets, squared offsets) per bin (BINS,) of one frame's depth, as ``kmeans.histogram``
    sums them before its prefix sums."""
    u, valid, _, _ = kmeans.normalise(depth.reshape(-1), jnp.ones(depth.size, bool))
    bins_of = kmeans.bin_of(u, BINS)
    d = jnp.where(valid, u * BINS - (bins_of.astype(jnp.float32) + 0.5), 0.0)
    return tuple(kmeans.segment_sums(x, bins_of, BINS, copies) for x in (valid.astype(jnp.int32), d, d * d))


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
        build = jax.jit(jax.vmap(lambda depth: frame_sums(depth, copies)))
        out = jax.block_until_ready(build(depth))
        times = []
        for _ in range(args.repeats):
            begin = time.perf_counter()
            jax.block_until_ready(build(depth))
            times.append(time.perf_counter() - begin)
        n_bin, sums = out[0], np.concatenate([np.asarray(x, np.float64) for x in out[1:]], 1)
        if reference is None:
            reference = (np.asarray(n_bin), sums)
        equal = bool(np.array_equal(np.asarray(n_bin), reference[0]))
        diff = float(np.max(np.abs(sums - reference[1])) / max(np.max(np.abs(reference[1])), 1e-30))
        print(f"| {copies} | {1000 * statistics.median(times):.2f} | {equal} | {diff:.1e} |", flush=True)


if __name__ == "__main__":
    main()
