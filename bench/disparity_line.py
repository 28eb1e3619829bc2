"""The loader's disparity line (docs/semantics.md §1.6, `depth_like_disparity`): where it fires with
its rank test alone (Spearman rho > 0.3) and with the camera's translation asked too (the depth's
inverse fits the tracks better, `io.checks.depth.inverse_depth_fits_better`; rule D2).

    python bench/disparity_line.py --pool fit|held-out [--scenes 24]
    python bench/disparity_line.py --real-windows [--realdata ../shared/realdata]

``--pool``: each scene of a random pool (``protocol.random_scene``, 1,000 tracks) under ``iid-both``,
``correlated``, ``depth`` and ``outliers`` at 0.5 and 2 px, as given and with disparity stored as
depth; per reading and level, the clips the line fires on under either rule, then the misfit ratios
(1/z : z) of the disparity clips the rank test finds. ``--real-windows``: the shared real clips cut
to windows of 2, 3, 4 and 8 frames (every second start), as given: every window a line fires on.
Nothing is chosen here.
"""

from __future__ import annotations

import collections
import dataclasses
from pathlib import Path

import numpy as np
from pools import need_one, pool_parser

from sgc_jax import SGCConfig, clip_from_arrays
from sgc_jax.io import validate
from sgc_jax.io.checks import depth as depth_checks
from sgc_jax.io.checks.motion_fits import track_fit, track_samples
from sgc_jax.research import protocol

WINDOW_FRAMES = (2, 3, 4, 8)


def as_disparity(clip):
    depth = clip.depth.copy()
    valid = depth > 0
    depth[valid] = 1.0 / depth[valid]
    return dataclasses.replace(clip, depth=depth)


def disparity_line(clip, config: SGCConfig, rho_alone: bool = False) -> bool:
    """Whether the line fires as shipped, or (``rho_alone``) with its rank test alone."""
    shipped = depth_checks.inverse_depth_fits_better
    if rho_alone:
        depth_checks.inverse_depth_fits_better = lambda *args, **kwargs: True
    try:
        return any(p.code == "depth_like_disparity" and p.severity == "warning"
                   for p in validate.check_clip(clip, config))
    finally:
        depth_checks.inverse_depth_fits_better = shipped


def misfit_ratio(clip, config: SGCConfig) -> float:
    misfits = np.array([(track_fit(clip, pair, prev, curr, z, "given")[0],
                         track_fit(clip, pair, prev, curr, 1.0 / z, "given")[0])
                        for pair, prev, curr, z in track_samples(clip, config)])
    return float(np.median(misfits[:, 1]) / np.median(misfits[:, 0]))


def pool_counts(pool: str, scenes: int) -> None:
    config, counts, ratios = SGCConfig(), collections.Counter(), []
    for px, noisy in protocol.check_pool_clips(pool, scenes):
        for reading, clip in (("as given", noisy), ("disparity stored", as_disparity(noisy))):
            rho_alone = disparity_line(clip, config, rho_alone=True)
            counts[reading, px, "rho alone"] += rho_alone
            counts[reading, px, "rule D2"] += disparity_line(clip, config)
            counts[reading, px, "clips"] += 1
            if rho_alone and reading != "as given":
                ratios.append(misfit_ratio(clip, config))
    print(f"{pool} pool, {scenes} scenes, 1,000 tracks, {', '.join(protocol.CHECK_POOL_MODELS)}")
    print("| reading | px | clips | rho alone | rule D2 |\n|---|---|---|---|---|")
    for reading in ("as given", "disparity stored"):
        for px in protocol.CHECK_POOL_LEVELS_PX:
            print(f"| {reading} | {px} | {counts[reading, px, 'clips']} | {counts[reading, px, 'rho alone']} | "
                  f"{counts[reading, px, 'rule D2']} |")
    print("misfit ratios (1/z : z) where rho alone finds disparity stored, the largest:",
          np.round(np.sort(ratios)[-12:], 3))


def real_windows(realdata: Path) -> None:
    config, found, windows = SGCConfig(), collections.Counter(), collections.Counter()
    for path in sorted(realdata.glob("*.npz")):
        with np.load(path) as stored:
            arrays = {name: stored[name] for name in stored.files if name != "meta"}
        for frames in WINDOW_FRAMES:
            for start in range(0, arrays["depth"].shape[0] - frames + 1, 2):
                window = {name: (value[start:start + frames - 1] if name.startswith("track_") else
                                 value[start:start + frames]) for name, value in arrays.items()}
                clip = clip_from_arrays(window, clip_id=f"{path.stem}[{start}:{start + frames}]", validate=False)
                windows[frames] += 1
                lines = [p for p in validate.check_clip(clip, config) if p.severity in ("warning", "error")]
                for problem in lines:
                    found[frames, problem.code] += 1
                    print(f"{clip.clip_id}: {problem.line()}")
    print("windows:", dict(windows), "lines:", dict(found))


def main() -> None:
    parser = pool_parser(__doc__, real="--real-windows")
    args = parser.parse_args()
    if args.pool:
        pool_counts(args.pool, args.scenes)
    if args.real_windows:
        real_windows(args.realdata)
    need_one(parser, args, real="real_windows")


if __name__ == "__main__":
    main()
