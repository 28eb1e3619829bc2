"""The hole rule of the depth check (docs/semantics.md §3.6 step 3) on the calibration's clean scenes.

    python bench/hole_rule.py

For each clean scene of ``sgc-spec-2026``'s corpus (``research.spec_calibration.clean_scenes``,
exact depth), every pair warped with the exact relative pose by the reference engine: the clip's
depth error (mean over pairs, %) and the share of warped pixels the rule discards (pixels that a
nearer surface covers). Prints the range and median of each over the scenes. Exact poses and depth:
what remains is the warp's own rounding at depth edges.
"""

from __future__ import annotations

import numpy as np

from sgc_jax.config import SGCConfig
from sgc_jax.engines import reference
from sgc_jax.io.clip import relative_poses
from sgc_jax.research.spec_calibration import clean_scenes


def scene_figures(clip, config: SGCConfig) -> tuple[float, float]:
    """(depth error %, share of warped pixels discarded) of one clip, means over its pairs."""
    R, t = relative_poses(clip)
    errors, discarded = [], []
    for pair in range(1, clip.depth.shape[0]):
        source = reference.warp_source(clip, pair, config)
        warp = [reference.warp_depth(source, clip.K[pair - 1], clip.K[pair], R[pair - 1], t[pair - 1],
                                     mask_holes=holes) for holes in (False, True)]
        discarded.append(np.sum((warp[0] > 0) & (warp[1] == 0)) / max(np.sum(warp[0] > 0), 1))
        errors.append(reference.pair_depth_error(clip, pair, R[pair - 1], t[pair - 1], config)[1])
    return float(np.mean(errors)), float(np.mean(discarded))


def main() -> None:
    figures = np.array([scene_figures(clip, SGCConfig()) for clip in clean_scenes()])
    for name, values, unit in (("depth error", figures[:, 0], "%"), ("discarded", 100 * figures[:, 1], "% of warped")):
        print(f"{name}: {values.min():.2f}-{values.max():.2f} {unit}, median {np.median(values):.2f} "
              f"({len(values)} clean scenes, exact poses)")


if __name__ == "__main__":
    main()
