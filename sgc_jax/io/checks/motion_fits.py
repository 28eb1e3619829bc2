"""How well a clip's tracks fit its cameras' motion at its depth, with the poses, tracks or depth read
one way or another: the measure every reading test of the checks compares (misfits in px)."""

from __future__ import annotations

import dataclasses
from typing import Sequence

import numpy as np

from ...config import SGCConfig
from ..clip import Clip

MIN_POINTS_FOR_STATS = 30
RHO_PAIRS, RHO_POINTS = 6, 256  # pairs and points per pair the depth/disparity test looks at (cost cap)
# The reading tests speak only where the tracks miss the camera's motion by more than this as given
# (median, px): the floor of the camera->world line's rule, which the other readings' rules kept
# (bench/history/issue-58.md "Poses given camera to world").
POSE_MISFIT_MIN_PX = 1.0
# How a pose file may hold the cameras: as §1.1 asks (world->camera, OpenCV's axes: x right, y down,
# looking along +z), camera->world, and either with OpenGL's camera axes (y up, looking along -z:
# Blender's, nerfstudio's and NeRF's transforms.json are camera->world so). The same ratio and floor
# tell the OpenGL readings (rule G1, bench/history/issue-58.md "Poses with OpenGL's camera axes"), and
# two conversions' slips: each camera's centre stored as its translation, and each rotation transposed
# beside its translation (rule C1, "Poses whose translation is stored as the cameras' centres"), and
# the poses stored in reverse order of the frames (rules T1, T2, "Poses reversed in time").
# The poses stored in the text order of the frames' numbers, counted from 0 or from 1 (frame_10 before
# frame_2: VGGT's demos read sorted(glob(...))): rule TO2 (bench/history/issue-58.md "Poses in the text
# order of the frames' names").
REVERSED_IN_TIME = "reversed in time"
POSE_READINGS = ("given", "camera->world", "opengl", "opengl camera->world", "translation as centres",
                 "rotation transposed", REVERSED_IN_TIME)
TEXT_ORDERS = {"text order from 0": 0, "text order from 1": 1}  # outside POSE_READINGS: read on their seams
OPENGL_AXES = np.diag([1.0, -1.0, -1.0])  # an OpenGL camera's coordinates -> OpenCV's, and back


def track_samples(clip: Clip, config: SGCConfig, on_static: bool = True, visible: bool = True,
                  pairs: np.ndarray | None = None):
    """Per sampled pair (at most RHO_PAIRS, spread over the clip): (pair, frame i-1 and frame i
    positions (n, 2) float64, depth at the frame i-1 position (n,)) of at most RHO_POINTS usable
    static tracks (``on_static`` False: those off the static mask; ``visible`` False: the hidden ones
    that would otherwise be usable) with valid depth, evenly spread; pairs with fewer than
    MIN_POINTS_FOR_STATS are left out. ``pairs`` (1-based): those in place of the spread."""
    H, W = clip.image_size
    pairs = sampled_pairs(clip) if pairs is None else np.asarray(pairs, np.int64)
    usable = (clip.usable_tracks(config.min_track_conf, pairs=pairs) if visible
              else ~clip.track_vis[pairs - 1] & clip.candidate_tracks(config.min_track_conf, pairs=pairs))
    for pair, usable_of_pair in zip(pairs, usable):
        index = np.flatnonzero(usable_of_pair)
        if index.size > 4 * RHO_POINTS:  # a deterministic spread-out subset keeps the cost flat
            index = index[np.linspace(0, index.size - 1, 4 * RHO_POINTS).astype(np.int64)]
        prev, curr = clip.track_prev[pair - 1][index], clip.track_curr[pair - 1][index]
        col = np.clip(np.floor(prev[:, 0]).astype(np.int64), 0, W - 1)
        row = np.clip(np.floor(prev[:, 1]).astype(np.int64), 0, H - 1)
        z = clip.depth[pair - 1][row, col]
        keep = np.flatnonzero(np.isfinite(z) & (z > 0) & (clip.static_mask[pair - 1][row, col] == on_static))
        if keep.size < MIN_POINTS_FOR_STATS:
            continue
        keep = keep[np.linspace(0, keep.size - 1, min(keep.size, RHO_POINTS)).astype(np.int64)]
        yield pair, prev[keep].astype(np.float64), curr[keep].astype(np.float64), z[keep].astype(np.float64)


def sampled_pairs(clip: Clip) -> np.ndarray:
    """The pairs (1-based) the reading tests look at: at most RHO_PAIRS, spread over the clip."""
    return np.unique(np.linspace(1, clip.n_frames - 1, min(RHO_PAIRS, clip.n_pairs)).round().astype(np.int64))


def relative_pose(clip: Clip, pair: int, reading: str = "given") -> tuple[np.ndarray, np.ndarray]:
    """(R, t) moving camera pair-1's points into camera pair, from the stored poses read as one of
    POSE_READINGS: as given, world->camera with OpenCV's axes (docs/semantics.md §1.1); as
    camera->world (R_wc holding R_cw, t_wc the camera centre); either of OpenGL's camera (y up,
    looking along -z), whose axes differ from OpenCV's by OPENGL_AXES; world->camera rotations with
    each camera's centre as its translation; each rotation transposed, its translation as given;
    frame j's pose stored at T - 1 - j (reversed in time), or in the text order of the frames' numbers
    (``text_order_places``)."""
    if reading not in POSE_READINGS and reading not in TEXT_ORDERS:
        raise ValueError(f"unknown pose reading {reading!r}; one of {POSE_READINGS + tuple(TEXT_ORDERS)}")
    frames = [pair - 1, pair]
    if reading == REVERSED_IN_TIME:
        frames = [clip.n_frames - pair, clip.n_frames - 1 - pair]
    elif reading in TEXT_ORDERS:
        frames = list(text_order_places(clip.n_frames, TEXT_ORDERS[reading])[frames])
    R, t = clip.R_wc[frames], clip.t_wc[frames]
    if reading.endswith("camera->world") or reading == "rotation transposed":
        R = np.swapaxes(R, 1, 2)
    if reading.endswith("camera->world") or reading == "translation as centres":
        t = -np.einsum("fij,fj->fi", R, t)
    R_rel = R[1] @ R[0].T
    t_rel = t[1] - R_rel @ t[0]
    if reading.startswith("opengl"):  # each camera's axes flipped: the relative pose conjugated
        return OPENGL_AXES @ R_rel @ OPENGL_AXES, OPENGL_AXES @ t_rel
    return R_rel, t_rel


def text_order_places(n_frames: int, first: int) -> np.ndarray:
    """(n_frames,) where frame j's pose lies in a file that lists the frames by their numbers (counted
    from ``first``) sorted as text: frame 10 before frame 2."""
    return np.argsort(sorted(range(first, first + n_frames), key=str)) if n_frames else np.zeros(0, np.int64)


def text_order_seams(n_frames: int, first: int) -> np.ndarray:
    """The pairs (1-based) whose two frames' poses do not lie next to each other, in that order, in a
    file listed in the text order of the frames' numbers from ``first``: where it and the frames' order
    tell apart."""
    places = text_order_places(n_frames, first)
    return np.flatnonzero(np.diff(places) != 1) + 1


def rotation_parallax(clip: Clip, pair: int, prev: np.ndarray, curr: np.ndarray, R_rel: np.ndarray) -> np.ndarray:
    """(n,) px: each track's motion left once the camera rotation R_rel is taken out (the rotation's
    homography K[pair] R_rel K[pair-1]^-1 applied to its frame i-1 position): its parallax."""
    homography = clip.K[pair] @ R_rel @ np.linalg.inv(clip.K[pair - 1])
    rotated = np.c_[prev, np.ones(len(prev))] @ homography.T
    with np.errstate(divide="ignore", invalid="ignore"):
        rotated = rotated[:, :2] / rotated[:, 2:3]
    return np.linalg.norm(curr - rotated, axis=1)


def pose_residual_px(clip: Clip, pair: int, prev: np.ndarray, curr: np.ndarray, z: np.ndarray,
                     reading: str) -> float:
    """Median px by which the tracks of one pair miss the camera's motion (``relative_pose``): each
    frame i-1 point back-projected at its depth, moved by (R, s t) and projected, with the
    translation's scale s >= 0 fitted to the tracks (depth and poses may have different units), to
    first order in s."""
    return track_fit(clip, pair, prev, curr, z, reading)[0]


def track_fit(clip: Clip, pair: int, prev: np.ndarray, curr: np.ndarray, z: np.ndarray,
              reading: str) -> tuple[float, float]:
    """(``pose_residual_px``'s median misfit [px], the translation's scale s it fitted); NaN, NaN
    where a point does not project."""
    return track_fits(clip, pair, prev, curr, z, (reading,))[0]


def track_fits(clip: Clip, pair: int, prev: np.ndarray, curr: np.ndarray, z: np.ndarray,
               readings: Sequence[str]) -> list[tuple[float, float]]:
    """``track_fit`` under each of ``readings``, the readings stacked on a leading axis (the loader
    fits a pair's tracks under seven)."""
    poses = [relative_pose(clip, pair, reading) for reading in readings]
    R, t = np.stack([pose[0] for pose in poses]), np.stack([pose[1] for pose in poses])  # (r, 3, 3), (r, 3)
    rays = np.c_[prev, np.ones(len(prev))] @ np.linalg.inv(clip.K[pair - 1]).T
    Y = (rays * z[:, None]) @ np.swapaxes(R, 1, 2)  # (r, n, 3): camera pair's coordinates before the translation
    K = clip.K[pair]
    with np.errstate(divide="ignore", invalid="ignore"):
        projected = (Y @ K.T)[..., :2] / Y[..., 2:3]
        # d projection / d Y along t: (K t)_xy / Y_z - projection * (t_z / Y_z)
        flow = ((t @ K.T)[:, None, :2] - projected * t[:, None, 2:3]) / Y[..., 2:3]
        moved = curr - projected
        # a reading whose points do not all project is NaN: its sums below are computed and dropped
        finite = np.isfinite(flow).all(axis=(1, 2)) & np.isfinite(moved).all(axis=(1, 2))
        scale = np.maximum(0.0, np.sum(moved * flow, axis=(1, 2)) / np.maximum(np.sum(flow * flow, axis=(1, 2)), 1e-12))
        misfit = np.median(np.linalg.norm(moved - scale[:, None, None] * flow, axis=2), axis=1)
    return [(float(m), float(s)) if ok else (float("nan"), float("nan")) for m, s, ok in zip(misfit, scale, finite)]


def pair_track_fits(clip: Clip, config: SGCConfig, readings: Sequence[str] = POSE_READINGS[:2]
                    ) -> dict[int, dict[str, tuple[float, float]]]:
    """Per sampled pair (``track_samples``), per pose reading: ``track_fit``'s (misfit [px], scale),
    fitted once for the pose, mask and range tests that read them."""
    return {pair: dict(zip(readings, track_fits(clip, pair, prev, curr, z, readings)))
            for pair, prev, curr, z in track_samples(clip, config)}


def side_residuals(clip: Clip, config: SGCConfig, fits: dict[int, dict[str, tuple[float, float]]] | None = None,
                   **other_side: bool) -> tuple[float, float]:
    """(the usable static tracks, the tracks ``track_samples(**other_side)`` gives: off the static mask,
    or hidden): the median over the sampled pairs where both hold tracks of ``pose_residual_px`` of
    each side's tracks, the poses as given (the first side's from ``fits``, ``pair_track_fits``,
    where given); NaN where no pair has both."""
    fits = pair_track_fits(clip, config, ("given",)) if fits is None else fits
    usable = {pair: by_reading["given"][0] for pair, by_reading in fits.items()}
    both = [(usable[pair], pose_residual_px(clip, pair, prev, curr, z, "given"))
            for pair, prev, curr, z in track_samples(clip, config, **other_side) if pair in usable]
    both = [b for b in both if np.isfinite(b).all()]
    if not both:
        return float("nan"), float("nan")
    first, other = np.median(np.array(both), axis=0)
    return float(first), float(other)


def pose_convention_residuals(clip: Clip, config: SGCConfig, readings: Sequence[str] = POSE_READINGS[:2],
                              fits: dict[int, dict[str, tuple[float, float]]] | None = None) -> dict[str, float]:
    """Per pose reading (``relative_pose``): the median over sampled pairs of ``pose_residual_px``
    (from ``fits``, ``pair_track_fits`` of the same readings, where given); NaN where no pair has
    the tracks to tell."""
    fits = pair_track_fits(clip, config, readings) if fits is None else fits
    residuals = [[by_reading[reading][0] for reading in readings] for by_reading in fits.values()]
    residuals = [r for r in residuals if np.isfinite(r).all()]
    medians = np.median(np.array(residuals), axis=0) if residuals else np.full(len(readings), np.nan)
    return {reading: float(m) for reading, m in zip(readings, medians)}


def track_readings(clip: Clip) -> dict[str, Clip]:
    """The clip's tracks read three ways: as given, each position as (y, x), and each pair's ends
    swapped (track_prev holding frame i)."""
    return {"given": clip,
            "yx": dataclasses.replace(clip, track_prev=clip.track_prev[..., ::-1], track_curr=clip.track_curr[..., ::-1]),
            "reversed": dataclasses.replace(clip, track_prev=clip.track_curr, track_curr=clip.track_prev)}


def track_reading_residuals(clip: Clip, config: SGCConfig, names: Sequence[str] = ("given", "yx", "reversed"),
                            fits: dict[int, dict[str, tuple[float, float]]] | None = None
                            ) -> dict[str, dict[str, float]]:
    """Per reading ``names`` of ``track_readings``: ``pose_convention_residuals``, the tracks' misfit
    to the camera's motion [px] under each pose reading (every one of POSE_READINGS for the tracks as
    given, from ``fits`` where given, world->camera and camera->world for the others)."""
    return {name: pose_convention_residuals(read, config, POSE_READINGS if name == "given" else POSE_READINGS[:2],
                                            fits if name == "given" else None)
            for name, read in track_readings(clip).items() if name in names}


def scaled_tracks(clip: Clip, factor: float) -> Clip:
    """The clip with every track position scaled by ``factor`` about the image's corner (pixel centres
    at integers: (x + 0.5) factor - 0.5), as tracks of a frame 1 / ``factor`` the size are rescaled."""
    scale = lambda track: ((track.astype(np.float64) + 0.5) * factor - 0.5).astype(track.dtype)  # noqa: E731
    return dataclasses.replace(clip, track_prev=scale(clip.track_prev), track_curr=scale(clip.track_curr))
