"""What a reader spends on one clip, step by step, on one thread (issue 61: the host's share of the
disk bar).

    python bench/reader_cost.py [--clips 16] [--repeats 3] [--dir /tmp/sgc-stream-corpus]

A reader hashes a clip file, reads it (the RGB frames, for plots only, from their header alone), runs the loader's checks (``io.validate.check_clip``) and
prepares it for the device (``engines.jax_engine.dispatch.prepare_clip``). This times each of
those and each check inside ``check_clip`` on standard clips (bench/stream.py's corpus) in this
process, one call after another, no profiler: ms per clip, the least of --repeats passes over the
clips. Under reader threads the checks' many small NumPy calls take turns on the GIL, so a
millisecond here costs the host ceiling more (bench/host_ceiling.py).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Callable

HERE = Path(__file__).resolve().parent


def least_ms(step: Callable, items: list, repeats: int) -> float:
    """The least over ``repeats`` passes of the mean ms ``step(item)`` takes over ``items``."""
    step(items[0])
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        for item in items:
            step(item)
        best = min(best, (time.perf_counter() - start) / len(items) * 1000)
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--clips", type=int, default=16)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--dir", type=Path, default=Path("/tmp/sgc-stream-corpus"))
    args = parser.parse_args()
    sys.path.insert(0, str(HERE))
    from stream import write_corpus

    from sgc_jax import SGCConfig
    from sgc_jax.engines.jax_engine.dispatch import prepare_clip
    from sgc_jax.engines.units import in_depth_units
    from sgc_jax.io import validate
    from sgc_jax.io.batch_layout import PLOTS_ONLY
    from sgc_jax.io.checks import bars, cameras, depth, masks, motion_fits, tracks, visibility
    from sgc_jax.io.loading import entries_from_file, load_clips
    from sgc_jax.io.npz import read_npz
    from sgc_jax.scoring.journal import FileDigests

    config = SGCConfig()
    paths = write_corpus(args.dir, args.clips)
    clips = list(load_clips(paths))
    fits = {id(c): motion_fits.pair_track_fits(c, config, motion_fits.POSE_READINGS) for c in clips}
    given = {id(c): motion_fits.pose_convention_residuals(c, config, motion_fits.POSE_READINGS, fits[id(c)])
             for c in clips}
    readings = ("given", "yx", "reversed")
    file_steps = {
        "hash the file (SHA-256)": lambda p: FileDigests().of(p),
        "read the file as the scorer does (inflate, CRC; the frames' header alone)":
            lambda p: read_npz(p, shape_only=PLOTS_ONLY),
        "load (read, make the Clip, check it)": lambda p: entries_from_file(p, config)[0].read_clip(for_scoring=True),
    }
    clip_steps = {
        "check_clip, all checks": lambda c: validate.check_clip(c, config),
        "  fits under the 7 pose readings": lambda c: motion_fits.pair_track_fits(c, config, motion_fits.POSE_READINGS),
        "  the tracks' other readings": lambda c: motion_fits.track_reading_residuals(c, config, readings, fits[id(c)]),
        "  depth (range, disparity, far backdrop)": lambda c: depth.check_depth(c, config, fits=fits[id(c)]),
        "    the range test": lambda c: depth.depth_range_misfits(c, config, fits=fits[id(c)]),
        "    the disparity test (depth against parallax, by rank)": lambda c: depth.depth_parallax_rho(c, config),
        "  depth edges (ramps, blended holes)": lambda c: depth.check_depth_edges(c, config),
        "  depth in blocks": depth.check_depth_blocks,
        "  letterbox bars": lambda c: bars.check_bars(c, config),
        "  tracks": lambda c: tracks.check_tracks(c, config),
        "  the tracks' scale": lambda c: tracks.check_track_scale(c, config, given[id(c)]),
        "  the mask's side": lambda c: masks.mask_side_residuals(c, config, fits[id(c)]),
        "  the mask": masks.check_mask,
        "  the visibility's direction (the visible share)": lambda c: visibility.check_vis_inverted(c, config, fits[id(c)]),
        "  poses in the text order of the frames' numbers (on its seams)": lambda c: cameras.check_text_order(c, config),
        "  poses, intrinsics, origin": lambda c: (cameras.check_poses(c), cameras.check_intrinsics(c),
                                                  cameras.check_far_origin(c)),
        "prepare_clip": lambda c: prepare_clip(c, config),
        "  depth in units of D (ramps, absurd depth, D, division)": lambda c: in_depth_units(c, config),
    }
    print(f"{args.clips} standard clips of {args.dir}, one thread, least of {args.repeats} passes\n")
    print("| step | ms a clip |\n|---|---|")
    for name, step in file_steps.items():
        print(f"| {name} | {least_ms(step, paths, args.repeats):.2f} |")
    for name, step in clip_steps.items():
        print(f"| {name} | {least_ms(step, clips, args.repeats):.2f} |")


if __name__ == "__main__":
    main()
