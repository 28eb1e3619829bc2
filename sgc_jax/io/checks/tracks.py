"""The tracks: positions against the pixel grid, their extent and axes, confidences and visibility,
repeats, usable tracks per pair, and the clip's length (docs/semantics.md §1.1, §1.2, §1.6)."""

from __future__ import annotations

from typing import Any

import numpy as np

from ...config import SGCConfig
from ..clip import Clip, repeated_tracks
from .motion_fits import (
    MIN_POINTS_FOR_STATS,
    POSE_MISFIT_MIN_PX,
    POSE_READINGS,
    REVERSED_IN_TIME,
    pose_convention_residuals,
    scaled_tracks,
)
from .problems import Problem, frames_list, is_reference_compat

TRACK_MARGIN_PX = 1.0  # tracker positions this far outside the image still count as inside
TRACKS_OUTSIDE_ERROR = 0.25  # fraction of visible track positions outside: another pixel grid
TRACKS_OUTSIDE_WARN = 0.05
TRACK_EXTENT_WARN = 0.6  # visible tracks all within this fraction of W and H: computed on a smaller grid
# Visible tracks all within TRACKS_NORMALISED_PX of the origin on a frame at least TRACKS_NORMALISED_MIN_SIZE
# a side: coordinates in [0, 1] or [-1, 1] (a little past 1 where tracks leave the frame), not pixels; no
# tracker's pixel output fits a 2x2 corner of a 16x16 frame
TRACKS_NORMALISED_PX, TRACKS_NORMALISED_MIN_SIZE = 2.0, 16
# A pair whose usable tracks repeat another usable track's positions at both ends this often: a track set
# merged with itself, which the user may not have meant to give. The score leaves repeats out (§1.2). No
# split's scene nor real clip repeats a track.
DUPLICATE_TRACKS_WARN = 0.05
# Share of the visible tracks with a non-finite position at either end, which the score cannot use (§1.2):
# a tracker's failed points left visible. No split's scene, battery clip or real clip holds one.
NONFINITE_TRACKS_WARN = 0.01
CONF_OUTSIDE_WARN = 0.01  # share of the visible tracks' confidences outside [0, 1]: logits or percentages
CONF_LOW_WARN = 0.5  # share of the visible tracks below min_track_conf: the score cannot use most of them
# share of a float track_vis strictly between 0 and 1 (all of it within [0, 1], some of it below 0.5):
# probabilities, whose hidden tracks the reading "visible where > 0" keeps (docs/semantics.md §1.2)
VIS_FRACTIONAL_WARN = 0.01
# Tracks stored as (y, x): read so, with the poses read either way, they miss the camera's motion by at
# most this fraction of what they miss as given or with their ends swapped (and by over
# POSE_MISFIT_MIN_PX as given). Chosen on FIT's random pool (24 scenes, four noise models at 0.5 and
# 2 px: as given the ratio >= 1.13, kept 1.5x above this); held out, as given 0 of 192 fire, FIT's
# and TEST's batteries 0 of 888, the real clips 0 of 6; stored as (y, x) the real clips read 0.08-0.20
# (bench/history/issue-58.md "Tracks stored as (y, x) on a frame they fit").
TRACK_READING_RATIO = 0.7
# ... tested only where the static mask covers at least this share of a frame (median over frames): an
# inverted motion mask (static on the movers, 3-7 % of the frame on 8 unseen scenes) leaves tracks that
# fit no camera reading, and the (y, x) reading fitted them better by chance on 5 of 8. Masks with a
# mover in the splits and the unseen pool cover 91-100 %, the real clips 100 %.
TRACK_READING_MIN_STATIC = 0.5
# Tracks of a smaller frame (a tracker run at its own resolution): where the visible positions stay within
# the top-left TRACK_SCALE_EXTENT of the frame (below TRACK_EXTENT_WARN the small-extent line speaks), they
# are read scaled by 1 / extent and judged by the (y, x) line's ratio and floor (rule S1,
# bench/history/issue-58.md "Tracks of a smaller frame").
TRACK_SCALE_EXTENT = 0.9
# Clips longer than this many frames get an info line: the splits the score was validated on hold 6-12
# frames, the standard clip 16, and a slow inconsistency shows each consecutive pair less the more
# frames it is spread over (docs/semantics.md §1.5, "Long clips"; bench/clip_length.py).
LONG_CLIP_FRAMES = 16
FRAMES_AFTER_STEP = 12  # about what a frame step should leave of a long clip (§1.5)


def _outside(x: np.ndarray, y: np.ndarray, H: int, W: int) -> np.ndarray:
    """Positions (x, y) beyond TRACK_MARGIN_PX of an H x W image."""
    return (x < -TRACK_MARGIN_PX) | (x > W - 1 + TRACK_MARGIN_PX) | (y < -TRACK_MARGIN_PX) | (y > H - 1 + TRACK_MARGIN_PX)


def check_tracks(clip: Clip, config: SGCConfig) -> list[Problem]:
    """Visible track positions against the grid, their extent, and usable tracks per pair."""
    problems = check_track_positions(clip)
    usable_tracks = clip.usable_tracks(config.min_track_conf)
    repeated = repeated_track_share(clip, usable_tracks)
    if repeated.max(initial=0.0) > DUPLICATE_TRACKS_WARN:
        worst = int(np.argmax(repeated))
        problems.append(Problem("warning", "duplicate_tracks", "track_prev/track_curr",
                                "each track once", f"{100 * repeated[worst]:.0f}% of pair {worst + 1}'s usable tracks "
                                "repeat another's positions at both ends",
                                "the score leaves the repeats out (docs/semantics.md §1.2; compat='authors' counts "
                                "them); a tracker queried twice at one point usually makes them"))
    problems += check_track_conf(clip, config)
    usable = np.count_nonzero(usable_tracks, axis=1)
    few = np.flatnonzero(usable < 4)
    if few.size:
        problems.append(Problem("warning", "too_few_tracks", "track_vis/track_conf",
                                "at least 4 usable tracks (visible, confidence >= "
                                f"{config.min_track_conf:g}) per pair",
                                f"fewer in pairs {frames_list(few + 1, clip.n_pairs)}",
                                "those pairs will score NaN (reason too_few_tracks)"))
    problems.append(Problem("info", "track_coverage", "track_vis/track_conf", "",
                            f"{clip.n_tracks} tracks per pair, usable per pair: min {usable.min()}, "
                            f"median {int(np.median(usable))}"))
    return problems


def check_track_finite(clip: Clip, visible_finite: np.ndarray) -> list[Problem]:
    """A warning where over NONFINITE_TRACKS_WARN of the visible tracks have a non-finite position at
    either end (those ``visible_finite`` (T-1, P), ``_visible_reach``'s, leaves out): the score cannot use
    them (docs/semantics.md §1.2)."""
    bad = clip.track_vis.astype(bool) & ~visible_finite
    n_visible, n_bad = int(np.count_nonzero(clip.track_vis)), int(np.count_nonzero(bad))
    if n_bad <= NONFINITE_TRACKS_WARN * n_visible:
        return []
    pairs = np.flatnonzero(bad.any(axis=1)) + 1
    return [Problem("warning", "tracks_nonfinite", "track_prev/track_curr", "finite positions of the visible tracks",
                    f"{100 * n_bad / n_visible:.0f}% of them NaN or infinite, in pairs {frames_list(pairs, clip.n_pairs)}",
                    "the score cannot use them (docs/semantics.md §1.2): a tracker's failed points left visible? "
                    "mark them hidden (track_vis False), or check the tracker's visibility output")]


def check_track_conf(clip: Clip, config: SGCConfig) -> list[Problem]:
    """A warning where over CONF_OUTSIDE_WARN of the visible tracks' confidences lie outside [0, 1]:
    logits or percentages, which the threshold ``min_track_conf`` does not read as meant."""
    conf = clip.track_conf[clip.track_vis]
    outside = np.count_nonzero((conf < 0) | (conf > 1))
    if conf.size == 0:
        return []
    if outside <= CONF_OUTSIDE_WARN * conf.size:
        return check_track_conf_low(clip, config, conf)
    return [Problem("warning", "track_conf_range", "track_conf", "confidences in [0, 1]",
                    f"{100 * outside / conf.size:.0f}% of the visible tracks' confidences outside it (range "
                    f"[{conf.min():.3g}, {conf.max():.3g}]); a track is usable at confidence >= "
                    f"{config.min_track_conf:g} (docs/semantics.md §1.2)",
                    "logits: store their sigmoid, 1 / (1 + exp(-x)); percentages: divide by 100")]


def check_track_conf_low(clip: Clip, config: SGCConfig, conf: np.ndarray) -> list[Problem]:
    """A warning where over CONF_LOW_WARN of the visible tracks' confidences (``conf``, in [0, 1]) lie
    below ``min_track_conf``, so that the score cannot use them; where the hidden tracks are the more
    confident, the line names an occlusion probability stored as confidence."""
    low = np.count_nonzero(conf < config.min_track_conf)
    if low <= CONF_LOW_WARN * conf.size:
        return []
    hidden = clip.track_conf[~clip.track_vis.astype(bool)]
    inverted = hidden.size > 0 and np.median(hidden) > np.median(conf)
    return [Problem("warning", "track_conf_low", "track_conf",
                    f"most visible tracks usable (confidence >= min_track_conf {config.min_track_conf:g})",
                    f"{100 * low / conf.size:.0f}% of the visible tracks below it (median {np.median(conf):.3g}"
                    + (f", the hidden tracks' {np.median(hidden):.3g})" if inverted else ")"),
                    "these look like occlusion probabilities: store 1 - p" if inverted else
                    "the score cannot use them: check what the tracker's confidence means (an occlusion "
                    "probability? store 1 - p), or lower min_track_conf for a tracker whose confidences run low")]


def check_track_vis_values(arrays: Any, reference_compat: bool = False) -> list[Problem]:
    """A warning (info for a reference-compat import, whose raw values are the authors' reading)
    where a float ``track_vis`` reads like probabilities: within [0, 1], over VIS_FRACTIONAL_WARN of
    it strictly between, some of it below 0.5. Read as visible where > 0, its hidden tracks count."""
    vis = np.asarray(arrays["track_vis"]) if "track_vis" in arrays else None
    if vis is None or vis.dtype.kind != "f":
        return []
    vis = vis[np.isfinite(vis)]
    if vis.size == 0 or vis.min() < 0 or vis.max() > 1:  # logits (hidden below 0) are read as meant
        return []
    fractional = np.count_nonzero((vis > 0) & (vis < 1))
    below_half = np.count_nonzero((vis > 0) & (vis < 0.5))
    if fractional <= VIS_FRACTIONAL_WARN * vis.size or below_half == 0:
        return []
    return [Problem("info" if reference_compat else "warning", "track_vis_probabilities", "track_vis",
                    "visibility as booleans (a float is read as visible where > 0, docs/semantics.md §1.2)",
                    f"{100 * fractional / vis.size:.0f}% of its values strictly between 0 and 1 (probabilities?), "
                    f"{100 * below_half / vis.size:.0f}% above 0 but below 0.5, which are read as visible",
                    "store a threshold of them, e.g. track_vis > 0.5 (DELTA's own is 0.8): hidden tracks read as "
                    "visible lifted the real clips from 0.13-0.21 to 0.48-0.65")]


def _visible_reach(clip: Clip) -> tuple[np.ndarray, float, float, float]:
    """(visible (T-1, P): visible with both ends finite, however far outside, x_max, y_max, the least
    coordinate) over both ends of every pair's visible tracks; -inf, -inf, inf without any."""
    visible = clip.track_vis.astype(bool)
    for track in (clip.track_prev, clip.track_curr):
        visible &= np.isfinite(track[..., 0]) & np.isfinite(track[..., 1])
    x_max, y_max, low = -np.inf, -np.inf, np.inf
    for track in (clip.track_prev, clip.track_curr):
        x, y = track[..., 0], track[..., 1]
        x_max = max(x_max, float(np.max(x, where=visible, initial=-np.inf)))
        y_max = max(y_max, float(np.max(y, where=visible, initial=-np.inf)))
        low = min(low, float(np.min(np.minimum(x, y), where=visible, initial=np.inf)))
    return visible, x_max, y_max, low


def check_track_positions(clip: Clip) -> list[Problem]:
    """Visible track positions against the H x W grid (``tracks_outside``: an error where over
    TRACKS_OUTSIDE_ERROR of them lie outside, tracks of another grid), non-finite ones, and their extent."""
    H, W = clip.image_size
    # visible and finite, however far outside: tracks of a larger grid are what this check finds
    visible, x_max, y_max, low = _visible_reach(clip)
    problems = check_track_finite(clip, visible)
    n_points = 2 * int(visible.sum())
    if n_points:
        n_out, n_out_swapped = 0, 0
        for track in (clip.track_prev, clip.track_curr):
            x, y = track[..., 0], track[..., 1]
            n_out += int((_outside(x, y, H, W) & visible).sum())
            n_out_swapped += int((_outside(y, x, H, W) & visible).sum())
        frac = n_out / n_points
        if frac > TRACKS_OUTSIDE_WARN:
            severity = "error" if frac > TRACKS_OUTSIDE_ERROR else "warning"
            larger = (f"tracks computed on a grid of at least {np.ceil(y_max + 1):.0f}x{np.ceil(x_max + 1):.0f}? rescale "
                      f"them to {H}x{W} (`sgc-jax import --track-size HxW`)")
            fix = larger if severity == "error" else (
                "positions outside the image are usually tracks marked visible after leaving the frame: check the "
                "visibility threshold" + (f"; none lies left of or above it, so maybe {larger}" if low >= -TRACK_MARGIN_PX
                                          else ""))
            if n_out_swapped / n_points <= TRACKS_OUTSIDE_WARN:
                fix = ("read as (y, x) the positions fit the image: store each position as (x, y) = (column, row) "
                       "(docs/semantics.md §1.1)")
            if severity == "warning" and is_reference_compat(clip):
                severity, fix = "info", "deliberate: reference-compat does not threshold DELTA visibility"
            problems.append(Problem(severity, "tracks_outside", "track_prev/track_curr",
                                    f"visible positions inside the {H}x{W} image",
                                    f"{100 * frac:.0f}% outside (x up to {x_max:.1f}, y up to {y_max:.1f})", fix))
        elif n_points >= MIN_POINTS_FOR_STATS:
            if max(x_max, y_max) <= TRACKS_NORMALISED_PX and min(H, W) >= TRACKS_NORMALISED_MIN_SIZE:
                problems.append(Problem("error", "tracks_normalised", "track_prev/track_curr",
                                        f"visible positions in pixels of the {H}x{W} image",
                                        f"all within x <= {x_max:.2f}, y <= {y_max:.2f}",
                                        "normalised coordinates? store pixels with their centres at integers "
                                        "(docs/semantics.md §1.1): x W - 0.5, y H - 0.5 from [0, 1] with the "
                                        "image's edges at 0 and 1; from [-1, 1], map to [0, 1] first"))
            elif x_max < TRACK_EXTENT_WARN * (W - 1) and y_max < TRACK_EXTENT_WARN * (H - 1):
                problems.append(Problem("warning", "tracks_small_extent", "track_prev/track_curr",
                                        f"visible tracks spread over the {H}x{W} image",
                                        f"all within x <= {x_max:.1f}, y <= {y_max:.1f}",
                                        f"tracks computed on a smaller grid? rescale them to {H}x{W} "
                                        "(`sgc-jax import --track-size HxW`)"))
    return problems


def repeated_track_share(clip: Clip, usable: np.ndarray) -> np.ndarray:
    """(T-1,) share of each pair's ``usable`` tracks that repeat an earlier one's positions at both
    ends (``io.clip.repeated_tracks``)."""
    repeats = np.count_nonzero(repeated_tracks(clip.track_prev, clip.track_curr, usable), axis=-1)
    return repeats / np.maximum(np.count_nonzero(usable, axis=-1), 1)


def visible_track_extent(clip: Clip) -> float:
    """The share of the frame the visible, finite track positions reach from its top-left corner: the
    larger of (x_max + 0.5) / W and (y_max + 0.5) / H over both ends of every pair; NaN without any."""
    H, W = clip.image_size
    visible, x_max, y_max, _ = _visible_reach(clip)
    return max((x_max + 0.5) / W, (y_max + 0.5) / H) if visible.any() else float("nan")


def misfit_as_given(by_reading: dict[str, float]) -> float:
    """The tracks' misfit as given [px] for the (y, x) and smaller-frame lines, from
    ``pose_convention_residuals``: the best of every pose reading but the poses reversed in time, whose
    chance fit of garbled tracks hid their misfit (rule T2, bench/history/issue-58.md "Poses reversed in
    time")."""
    return float(np.min([value for reading, value in by_reading.items() if reading != REVERSED_IN_TIME]))


def check_track_scale(clip: Clip, config: SGCConfig, given: dict[str, float]) -> list[Problem]:
    """A warning where the visible tracks reach less than TRACK_SCALE_EXTENT of the frame and, scaled to
    reach all of it, fit the camera's motion far better (``check_track_axes``' ratio and floor; the
    tracks as given from ``given`` by ``misfit_as_given``): tracks of a smaller frame."""
    extent = visible_track_extent(clip)
    if not (np.isfinite(extent) and TRACK_EXTENT_WARN <= extent < TRACK_SCALE_EXTENT):
        return []
    misfit = misfit_as_given(given)
    scaled = min(pose_convention_residuals(scaled_tracks(clip, 1.0 / extent), config).values())
    if not (np.isfinite(misfit) and misfit > POSE_MISFIT_MIN_PX and scaled < TRACK_READING_RATIO * misfit):
        return []
    H, W = clip.image_size
    return [Problem(
        "warning", "tracks_of_a_smaller_frame", "track_prev/track_curr", f"positions in pixels of the {H}x{W} image",
        f"visible tracks within its top-left {100 * extent:.0f}%, which miss the camera's motion by {misfit:.2g} px "
        f"(median) as given and by {scaled:.2g} px scaled by {1 / extent:.3g}",
        f"tracks computed on a smaller copy of the video? rescale them to {H}x{W}: (x + 0.5) {W} / W_tracks - 0.5 "
        "(`sgc-jax import --track-size HxW`)")]


def check_track_axes(residuals: dict[str, dict[str, float]]) -> list[Problem]:
    """From ``track_reading_residuals``: a warning where the tracks fit the camera's motion far
    better read as (y, x) than as given or with their ends swapped (TRACK_READING_RATIO of the
    better; the two under their better of world->camera and camera->world, the tracks as given by
    ``misfit_as_given``, so a pose file's convention or slip does not decide it):
    positions stored row first, on a frame where both readings fall inside the
    image. (Swapped ends get no line of their own: they read like camera->world poses, and like
    cameras that do not translate.)"""
    misfit = {name: min(by_pose[reading] for reading in POSE_READINGS[:2]) for name, by_pose in residuals.items()}
    # the tracks as given under the pose readings fitted: a pose file's slip is not the tracks' (rules C2, T2)
    given = misfit_as_given(residuals["given"])
    yx = misfit["yx"]
    if not (np.isfinite(given) and given > POSE_MISFIT_MIN_PX and yx < TRACK_READING_RATIO * min(given, misfit["reversed"])):
        return []
    return [Problem(
        "warning", "tracks_yx", "track_prev/track_curr", "positions as (x, y) = (column, row)",
        f"the tracks miss the camera's motion by {given:.2g} px (median) as given and by {yx:.2g} px read as (y, x)",
        "these look like (row, column) positions: swap the last axis (tracks[..., ::-1])")]


def check_length(clip: Clip) -> list[Problem]:
    """An info line for a clip longer than the score was validated on (:data:`LONG_CLIP_FRAMES`)."""
    if clip.n_frames <= LONG_CLIP_FRAMES:
        return []
    step = max(2, round((clip.n_frames - 1) / (FRAMES_AFTER_STEP - 1)))
    return [Problem("info", "long_clip", "track_prev/track_curr", "",
                    f"{clip.n_frames} frames: an inconsistency that grows slowly over the clip shows each "
                    "consecutive pair only its increment (docs/semantics.md §1.5, \"Long clips\")",
                    f"with long-range tracks, `sgc-jax import ... --frame-step {step}` pairs frames {step} apart")]
