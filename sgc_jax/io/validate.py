"""Plausibility checks of a clip's content, shared by the loader and ``sgc-jax validate``.

Structural problems (shapes, ranks, non-finite cameras) are found by :mod:`sgc_jax.io.arrays`. The
checks (:mod:`sgc_jax.io.checks`, a module per array: cameras, tracks, depth, masks, stored dtypes)
look for inputs whose units or resolutions do not fit together: intrinsics made for another image
size, depth that is really disparity, poses that are not rotations, tracks on another pixel grid,
masks that look inverted. Each problem is one actionable line. ``error`` problems make the loader
raise :class:`ClipValidationError`; ``warning`` problems are issued as :class:`ClipWarning`;
``info`` lines (what the clip holds, deliberate reference-compat choices) are only shown by
``sgc-jax validate``. This module runs them in order: which tests may read the tracks' motion
depends on what the earlier ones found.
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np

from ..config import SGCConfig
from .checks.bars import check_bars
from .checks.cameras import (
    check_far_origin,
    check_focal_spread,
    check_frozen_cameras,
    check_held_cameras,
    check_intrinsics,
    check_pose_convention,
    check_poses,
    check_text_order,
)
from .checks.depth import check_depth, check_depth_blocks, check_depth_edges
from .checks.masks import check_mask, check_mask_inverted, mask_side_residuals, static_coverage
from .checks.motion_fits import POSE_READINGS, pair_track_fits, track_reading_residuals
from .checks.problems import SEVERITIES, ClipValidationError, ClipWarning, Problem, is_reference_compat
from .checks.stored import check_dtypes
from .checks.tracks import (
    TRACK_READING_MIN_STATIC,
    check_length,
    check_track_axes,
    check_track_scale,
    check_track_vis_values,
    check_tracks,
)
from .checks.visibility import check_vis_inverted
from .clip import Clip

__all__ = ["ClipValidationError", "ClipWarning", "Problem", "check_clip", "enforce", "raise_first_error"]

# Content problems that the scorer already reports per pair with a reason code (docs/semantics.md §1.4): shown by
# ``sgc-jax validate``, not repeated as loader warnings.
SCORER_REPORTED = ("too_few_tracks", "no_valid_depth")
# Track problems after which the tests that read the tracks' motion say nothing: positions of another
# grid or in other units, hidden tracks counted as visible
TRACKS_NOT_OF_THE_IMAGE = ("tracks_outside", "tracks_normalised", "tracks_small_extent", "track_vis_probabilities")


def check_clip(clip: Clip, config: SGCConfig | None = None, arrays: Any = None) -> list[Problem]:
    """Every content check of one clip, errors first; ``arrays``: the stored arrays, for dtype checks."""
    config = config or SGCConfig()
    poses, tracks = check_poses(clip), check_tracks(clip, config)
    # one pose for every frame: no camera motion for the tests that read the tracks' motion against it
    frozen = [] if poses else check_frozen_cameras(clip, config)
    held = [] if poses or frozen else check_held_cameras(clip, config)
    if arrays is not None:
        tracks = check_track_vis_values(arrays, is_reference_compat(clip)) + tracks
    # the pose and depth tests read the tracks' motion: not where the tracks do not fit the image or
    # hidden ones count as visible, nor for a reference-compat clip, whose K and depth are
    # deliberately off (VGGT's grid, VDA / 1000)
    tracks_fit = not any(p.code in TRACKS_NOT_OF_THE_IMAGE and p.severity != "info" for p in tracks)
    test_poses = tracks_fit and not poses and not frozen and not is_reference_compat(clip)
    test_axes = test_poses and np.median(static_coverage(clip)) >= TRACK_READING_MIN_STATIC
    read_as = ("given", "yx", "reversed") if test_axes else ("given",)  # the other readings only where tested
    # the tracks as given fitted once under every pose reading: the pose, mask and range tests read them
    fits = (pair_track_fits(clip, config, POSE_READINGS if test_poses else ("given",))
            if tracks_fit and not frozen and not is_reference_compat(clip) else None)
    readings = track_reading_residuals(clip, config, read_as, fits) if test_poses else None
    axes = check_track_axes(readings) if test_axes else []
    axes = axes or (check_track_scale(clip, config, readings["given"]) if test_axes else [])
    # visibility stored the other way round, or a motion mask given as the static one, leaves the
    # other tests only the failed or the movers' tracks
    inverted = check_vis_inverted(clip, config, fits) if test_poses and not axes else []
    inverted = inverted or (check_mask_inverted(mask_side_residuals(clip, config, fits), clip.mask_source)
                            if test_poses and not axes else [])
    # tracks read the wrong way round or at the wrong size say nothing about the poses' convention or
    # the depth's kind
    test_convention = test_poses and not axes and not inverted
    # poses listed in the text order of the frames' numbers: read on the pairs where the orders differ
    text_order = check_text_order(clip, config) if test_convention else []
    convention, reading = (check_pose_convention(readings["given"]) if test_convention and not text_order
                           else ([], "given"))
    intrinsics = check_intrinsics(clip)
    k_usable = not any(p.severity == "error" for p in intrinsics)
    far_origin = [] if poses or frozen else check_far_origin(clip)
    problems = (intrinsics + check_focal_spread(clip) + poses + frozen + held + far_origin + text_order + convention + tracks + axes + inverted
                + check_depth(clip, config, reading, read_tracks=tracks_fit and not frozen and not axes and not inverted and not text_order,
                              fits=fits, k_usable=k_usable)
                + check_depth_edges(clip, config) + check_depth_blocks(clip) + check_bars(clip, config) + check_mask(clip) + check_length(clip))
    if arrays is not None:
        problems += check_dtypes(arrays)
    return sorted(problems, key=lambda p: SEVERITIES.index(p.severity))


def raise_first_error(clip_id: str, problems: list[Problem]) -> None:
    """Raise :class:`ClipValidationError` for the first problem of severity "error", if any."""
    for problem in problems:
        if problem.severity == "error":
            raise ClipValidationError(clip_id, problem.array, problem.expected, problem.found, problem.fix)


def enforce(clip: Clip, config: SGCConfig | None = None, arrays: Any = None) -> tuple[str, ...]:
    """Raise :class:`ClipValidationError` on the first error; warn (:class:`ClipWarning`) on warnings
    and return their codes (those the scorer reports per pair left out)."""
    problems = check_clip(clip, config, arrays)
    raise_first_error(clip.clip_id, problems)
    codes = []
    for problem in problems:
        if problem.severity == "warning" and problem.code not in SCORER_REPORTED:
            warnings.warn(ClipWarning(f"clip {clip.clip_id!r}: {problem.line()}"), stacklevel=3)
            codes.append(problem.code)
    return tuple(dict.fromkeys(codes))
