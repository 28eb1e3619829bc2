"""The cameras: intrinsics against the pixel grid, focal lengths over the frames, rotations, and the
pose file's convention as the tracks read it (docs/semantics.md §1.1, §1.6)."""

from __future__ import annotations

import numpy as np

from ...config import CAMERA_TRANSLATION_RESOLUTION, SGCConfig
from ..clip import Clip, relative_poses
from .motion_fits import (
    POSE_MISFIT_MIN_PX,
    POSE_READINGS,
    RHO_PAIRS,
    TEXT_ORDERS,
    text_order_seams,
    track_fits,
    track_samples,
)
from .problems import Problem, frames_list, is_reference_compat

# Thresholds, each with where it comes from.
FOCAL_RATIO_MAX = 3.0  # focal length off by more than 3x from the image size is an error
# Principal point this far from the centre (fraction of the side) is suspicious: K of a grid f times the frame's
# puts it |f - 1| / 2 off, so a half-size grid's K (0.249 on the real clips, scoring them 0.12-0.27) is named;
# every split's scene and real clip has it within 0.002.
PRINCIPAL_OFFSET_WARN = 0.2
ROTATION_ERROR_TOL = 1e-2  # max |R R^T - I| beyond which R is not a rotation (float32 VGGT R: ~1e-7)
ROTATION_WARN_TOL = 1e-4  # ... and beyond which it is used as is but reported
# Every frame's pose the same within this (R's entries; t's relative to its largest entry): one pose for the
# whole video, as placeholders (identity) give it; no estimator gives a moving video one pose to float32's
# rounding, and no split's scene, battery clip or real clip holds one.
FROZEN_POSE_TOL = 1e-6
# A pair's coherent motion is read where at least this many usable tracks give it (an affine flow's 6 numbers),
# refitted on the tracks within this multiple of the first fit's median residual (rule CH4)
MIN_FLOW_TRACKS, FLOW_INLIER_RATIO = 30, 3.0
# The poses read as camera->world leave the tracks at most this fraction of the misfit they leave as
# given (both with the translation's scale fitted), and the misfit as given is above POSE_MISFIT_MIN_PX:
# camera->world poses. As given, the ratio is >= 1.10 on 86 synthetic clips and >= 5.4 on the six
# real ones, but 0.51-0.94 where the depth is disparity; the same poses inverted read 0.06-0.18 on
# the real clips (bench/history/issue-58.md "Poses given camera to world").
POSE_CONVENTION_RATIO = 0.4
# ... named only where they fit below this fraction of the best of the four readings before them: where a
# clip's translation moves its tracks too little to tell a transposed rotation from a camera->world
# file (a real clip: 0.878 against 0.881 px), the commoner file is named (rule C2).
SLIP_READINGS, SLIP_MARGIN = POSE_READINGS[4:], 0.8
POSE_FIXES = {  # reading -> (code, what the poses read as, the fix)
    "camera->world": (
        "camera_to_world_poses", "camera->world",
        "these look like camera->world poses: invert them (R_wc = R^T, t_wc = -R^T t); or, where the poses are "
        "right, like tracks whose ends are swapped, which read alike: swap track_prev and track_curr; where the "
        "camera barely translates, also like rotations alone transposed: then transpose R_wc and keep t_wc"),
    "opengl": (
        "opengl_poses", "world->camera of an OpenGL camera (y up, looking along -z)",
        "these look like an OpenGL camera's world->camera poses: flip its y and z axes (F = diag(1, -1, -1): "
        "R_wc = F R, t_wc = F t)"),
    "opengl camera->world": (
        "opengl_poses", "camera->world of an OpenGL camera (y up, looking along -z; Blender's and nerfstudio's "
        "transforms)",
        "these look like an OpenGL camera's camera->world poses (a transforms.json): invert them and flip the "
        "camera's y and z axes (F = diag(1, -1, -1): R_wc = F R^T, t_wc = -F R^T t)"),
    "translation as centres": (
        "translation_as_centres", "world->camera rotations with each camera's centre c as its translation",
        "t_wc looks like the cameras' centres (a camera->world pose's position kept when its rotation was "
        "transposed): store t_wc = -R_wc c"),
    "rotation transposed": (
        "rotation_transposed", "camera->world rotations beside world->camera translations",
        "R_wc looks transposed (a camera->world rotation, or a quaternion read in the other convention, "
        "JPL's against Hamilton's): store R_wc = R^T and keep t_wc"),
    "reversed in time": (
        "poses_reversed_in_time", "reversed in time (frame j's pose stored at T - 1 - j)",
        "the poses look stored in reverse order of the frames: store R_wc[::-1], t_wc[::-1] (or check that the "
        "poses' frames and the video's are listed in one order)"),
} | {reading: (
    "poses_in_text_order", f"listed in the text order of the frames' numbers counted from {first} (10 before 2)",
    "the pose estimator read the frames sorted as text (VGGT's demos: sorted(glob(...)) of unpadded names): "
    f"reorder with order = sorted(range({first}, {first} + T), key=str); R_wc = R_wc[np.argsort(order)] (and "
    "t_wc, K), or name the frames with leading zeros") for reading, first in TEXT_ORDERS.items()}
# Focal lengths that spread more than this over the frames (RMS of their log): a camera estimator's per-frame
# scatter, which the depth check reads as depth disagreement. On 12 unseen scenes 0.5 % RMS left 0-1 of 12
# consistent clips above 0.10 and 1 % 5-7 (bench/history/issue-58.md "A sky read as depth").
FOCAL_SPREAD_WARN = 0.005


# Camera steps this small against the cameras' distance from the world's origin (|t_g| / (|t_wc[i]| +
# |t_wc[i-1]|)) but above a held centre's float32 rounding (at most 1.7e-7, 2^-22.5, on FIT's held cameras and
# the real clips'): within 4x of CAMERA_TRANSLATION_RESOLUTION, below which a step counts as none (§3.4), and
# float32 keeps them to a few percent. Derived, not fitted: the six real clips with their origin 1,000 units
# away fire (their least ratios 8.7e-7 to 4.8e-6); as given, 10 or 100 units away, and no clip of FIT's or
# TEST's scenes and battery, FIT's random pool or the unseen pool does (bench/history/issue-59.md, "A world
# whose origin lies far from its cameras").
FAR_ORIGIN_STEP_RANGE = (2.0**-21, 4 * CAMERA_TRANSLATION_RESOLUTION)
# ... from this instead of 2^-21 where R_wc and t_wc hold more than float32 does (a float64 SLAM or geographic
# file): their held centres' rounding is float64's, and a metre's step 5,000 km from the origin (2e-7) is real.
FAR_ORIGIN_STEP_MIN_FLOAT64 = 2.0**-40


def _k_hint(cx: float, cy: float, H: int, W: int) -> str:
    implied_w, implied_h = 2.0 * cx + 1.0, 2.0 * cy + 1.0
    hint = (f"K looks made for a ~{implied_h:.0f}x{implied_w:.0f} image (principal point at its centre), "
            f"not this {H}x{W} grid: rescale K to the grid")
    if 500 <= max(implied_w, implied_h) <= 540:
        hint += " (VGGT intrinsics are on its 518-px preprocessed grid: `sgc-jax import --cameras` rescales them)"
    return hint


def check_intrinsics(clip: Clip) -> list[Problem]:
    """Focal lengths and principal points against the H x W grid."""
    H, W = clip.image_size
    T = clip.n_frames
    fx, fy, cx, cy = clip.K[:, 0, 0], clip.K[:, 1, 1], clip.K[:, 0, 2], clip.K[:, 1, 2]
    compat = is_reference_compat(clip)
    severe = "info" if compat else "error"
    note = " (deliberate: reference-compat keeps VGGT's 518-px intrinsics)" if compat else ""
    problems = []
    bad = np.flatnonzero((fx <= 0) | (fy <= 0))
    if bad.size:
        t = bad[0]
        problems.append(Problem("error", "focal_not_positive", "K", "positive focal lengths fx, fy",
                                f"fx={fx[t]:.4g}, fy={fy[t]:.4g} in frames {frames_list(bad, T)}",
                                "K must be a pinhole matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] in pixels"))
        return problems
    outside = np.flatnonzero((cx < -0.5) | (cx > W - 0.5) | (cy < -0.5) | (cy > H - 0.5))
    if outside.size:
        t = outside[0]
        problems.append(Problem(severe, "principal_point_outside", "K", f"principal point inside the {H}x{W} image",
                                f"cx={cx[t]:.1f}, cy={cy[t]:.1f} in frames {frames_list(outside, T)}",
                                _k_hint(cx[t], cy[t], H, W) + note))
    side = max(H, W)
    ratio = np.maximum(fx, fy) / side
    ratio_low = np.minimum(fx, fy) / side
    off = np.flatnonzero((ratio > FOCAL_RATIO_MAX) | (ratio_low < 1.0 / FOCAL_RATIO_MAX))
    if off.size:
        t = off[0]
        problems.append(Problem(
            severe, "focal_implausible", "K",
            f"focal lengths within {FOCAL_RATIO_MAX:g}x of the image size {side} px "
            f"({side / FOCAL_RATIO_MAX:.0f}..{side * FOCAL_RATIO_MAX:.0f})",
            f"fx={fx[t]:.1f}, fy={fy[t]:.1f} in frames {frames_list(off, T)}",
            "K is probably for another resolution (or in normalised units): scale fx, cx by W'/W and fy, cy by "
            "H'/H" + note))
    if not outside.size:
        offset = np.maximum(np.abs(cx - (W - 1) / 2) / W, np.abs(cy - (H - 1) / 2) / H)
        far = np.flatnonzero(offset > PRINCIPAL_OFFSET_WARN)
        if far.size:
            t = far[0]
            problems.append(Problem(
                "info" if compat else "warning", "principal_point_off_centre", "K",
                f"principal point near the centre ({(W - 1) / 2:.1f}, {(H - 1) / 2:.1f})",
                f"cx={cx[t]:.1f}, cy={cy[t]:.1f} in frames {frames_list(far, T)}",
                _k_hint(cx[t], cy[t], H, W) + note))
    return problems


def focal_spread(K: np.ndarray) -> float:
    """The RMS over frames of the log focal lengths of K (T, 3, 3), fx and fy each about its own mean (pixels
    that are not square, fx != fy, are no spread): 0.01 is a 1 % scatter; NaN where one is not positive."""
    focal = np.stack([K[:, 0, 0], K[:, 1, 1]]).astype(np.float64)
    return float(np.sqrt(np.mean(np.var(np.log(focal), axis=1)))) if np.all(focal > 0) else float("nan")


def check_focal_spread(clip: Clip) -> list[Problem]:
    """A warning where the per-frame focal lengths scatter beyond FOCAL_SPREAD_WARN (a zoom, or an
    estimator's per-frame K)."""
    spread = focal_spread(clip.K)
    if not spread > FOCAL_SPREAD_WARN:  # NaN: check_intrinsics' error
        return []
    return [Problem(
        "info" if is_reference_compat(clip) else "warning", "focal_spread", "K",
        f"one camera's focal lengths in every frame (within {100 * FOCAL_SPREAD_WARN:g} % RMS), unless the video zooms",
        f"fx, fy spread {100 * spread:.2f} % RMS over the frames: the depth check reads a focal change between "
        "two frames as depth disagreement (docs/semantics.md §1.5, \"One K for a clip\")",
        "if the video does not zoom, give every frame one K, the median of the frames' (`sgc-jax import` does, "
        "unless --per-frame-intrinsics)")]


def check_poses(clip: Clip) -> list[Problem]:
    """R_wc must be rotations: orthonormal with determinant +1."""
    R = clip.R_wc
    deviation = np.abs(R @ np.swapaxes(R, 1, 2) - np.eye(3)).max(axis=(1, 2))
    det = np.linalg.det(R)
    bad = np.flatnonzero((deviation > ROTATION_ERROR_TOL) | (det < 0))
    T = clip.n_frames
    if bad.size:
        t = bad[0]
        return [Problem("error", "not_rotation", "R_wc", "rotation matrices (R R^T = I, det = +1)",
                        f"max |R R^T - I| = {deviation[t]:.3g}, det = {det[t]:.3g} in frames {frames_list(bad, T)}",
                        "give world->camera rotations (OpenCV); a scaled or reflected matrix, or a camera->world "
                        "pose with scale, gives this")]
    mild = np.flatnonzero(deviation > ROTATION_WARN_TOL)
    if mild.size:
        t = mild[0]
        return [Problem("warning", "rotation_not_orthonormal", "R_wc", "orthonormal rotations",
                        f"max |R R^T - I| = {deviation[t]:.3g} in frames {frames_list(mild, T)}",
                        "used as given; re-orthonormalise (nearest rotation by SVD) if they come from a fit")]
    return []


def frozen_cameras(clip: Clip) -> bool:
    """Whether every frame's pose is the first one's, within FROZEN_POSE_TOL."""
    R, t = clip.R_wc.astype(np.float64), clip.t_wc.astype(np.float64)
    return bool(np.abs(R - R[0]).max() <= FROZEN_POSE_TOL
                and np.abs(t - t[0]).max() <= FROZEN_POSE_TOL * np.abs(t).max())


def held_pairs(clip: Clip) -> np.ndarray:
    """(T-1,) bool: the pairs whose two poses are equal within FROZEN_POSE_TOL (as ``frozen_cameras``)."""
    R, t = clip.R_wc.astype(np.float64), clip.t_wc.astype(np.float64)
    return ((np.abs(np.diff(R, axis=0)).max(axis=(1, 2)) <= FROZEN_POSE_TOL)
            & (np.abs(np.diff(t, axis=0)).max(axis=1) <= FROZEN_POSE_TOL * np.abs(t).max()))


def coherent_motion_px(clip: Clip, config: SGCConfig, pairs: np.ndarray) -> np.ndarray:
    """(len(pairs),) [px]: the median length over a pair's usable tracks of the displacement an affine
    flow (x, y, 1) -> (dx, dy) gives them, fitted to theirs by least squares and refitted on those
    within FLOW_INLIER_RATIO of the median residual: a video's motion, which the flow follows to first
    order, without the tracker's independent noise and outliers; NaN below MIN_FLOW_TRACKS tracks."""
    usable = clip.usable_tracks(config.min_track_conf, pairs=pairs)
    out = np.full(len(pairs), np.nan)
    for k, (pair, use) in enumerate(zip(pairs, usable)):
        prev = clip.track_prev[pair - 1][use].astype(np.float64)
        moved = clip.track_curr[pair - 1][use].astype(np.float64) - prev
        keep = np.isfinite(moved).all(axis=1)
        if np.count_nonzero(keep) < MIN_FLOW_TRACKS:
            continue
        design, moved = np.c_[prev[keep], np.ones(np.count_nonzero(keep))], moved[keep]
        for _ in range(2):  # fitted, then refitted on the tracks it fits (a tracker's outliers left out)
            flow = design @ np.linalg.lstsq(design, moved, rcond=None)[0]
            residual = np.linalg.norm(moved - flow, axis=1)
            inliers = residual <= FLOW_INLIER_RATIO * np.median(residual)
            design, moved = design[inliers], moved[inliers]
        out[k] = np.median(np.linalg.norm(flow, axis=1))
    return out


def check_held_cameras(clip: Clip, config: SGCConfig) -> list[Problem]:
    """A warning naming the pairs whose two poses are equal (``held_pairs``) while their usable tracks
    move coherently by over POSE_MISFIT_MIN_PX (``coherent_motion_px``), where not every frame shares
    one pose (rule CH4; every frame: ``check_frozen_cameras``, and all pairs held: nothing)."""
    held = np.flatnonzero(held_pairs(clip)) + 1
    if held.size == 0 or held.size == clip.n_pairs:
        return []
    motion = coherent_motion_px(clip, config, held)
    pairs = held[motion > POSE_MISFIT_MIN_PX]
    if pairs.size == 0:
        return []
    return [Problem(
        "warning", "cameras_held", "R_wc/t_wc", "each frame's camera pose",
        f"frame i's pose equal to frame i-1's in pairs {frames_list(pairs, clip.n_pairs)} while their tracks "
        f"move {np.median(motion[motion > POSE_MISFIT_MIN_PX]):.2g} px (median, an affine flow fitted to them)",
        "poses at a lower frame rate given again, or a missing pose filled with its neighbour? give each frame's "
        "own pose; where they are the cameras a video was asked to follow, it moved where told to hold still. "
        "Such a pair reads a camera that holds still, which measures little (docs/semantics.md §3.11)")]


def check_frozen_cameras(clip: Clip, config: SGCConfig) -> list[Problem]:
    """A warning where every frame has one pose while the usable tracks move by over POSE_MISFIT_MIN_PX a
    pair (the median over pairs of each pair's median): placeholder poses, or a video that moved where
    the cameras it was asked to follow hold still; the score reads a camera that holds still."""
    if not frozen_cameras(clip):
        return []
    usable = clip.usable_tracks(config.min_track_conf)
    motion = np.linalg.norm(clip.track_curr.astype(np.float64) - clip.track_prev, axis=-1)
    per_pair = [np.median(m[u & np.isfinite(m)]) for m, u in zip(motion, usable) if np.any(u & np.isfinite(m))]
    moved = float(np.median(per_pair)) if per_pair else float("nan")
    if not moved > POSE_MISFIT_MIN_PX:
        return []
    return [Problem(
        "warning", "cameras_frozen", "R_wc/t_wc", "each frame's camera pose",
        f"one pose in all {clip.n_frames} frames while the tracks move {moved:.2g} px a pair (median)",
        "placeholder poses (identity)? give the camera's pose in each frame, e.g. VGGT's (`sgc-jax import "
        "--cameras`); where they are the cameras a video was asked to follow, it moved where told to hold still. "
        "The score reads a camera that holds still, which measures nothing (no evidence, docs/semantics.md §3.11)")]


def camera_step_ratios(clip: Clip) -> np.ndarray:
    """(T-1,) each pair's camera step |t_g| (t_g = t_wc[i] - R_g t_wc[i-1]) over |t_wc[i]| + |t_wc[i-1]|,
    in float64; 0 where both are 0."""
    step = np.linalg.norm(relative_poses(clip)[1], axis=1)
    t = clip.t_wc.astype(np.float64)
    size = np.linalg.norm(t[1:], axis=1) + np.linalg.norm(t[:-1], axis=1)
    return np.where(size > 0, step / np.where(size > 0, size, 1.0), 0.0)


def check_far_origin(clip: Clip) -> list[Problem]:
    """A warning where some pair's camera step lies in FAR_ORIGIN_STEP_RANGE of the cameras' distance from
    the world's origin: a moving camera whose steps the resolution bound takes, or nearly takes, for none."""
    ratios = camera_step_ratios(clip)
    low, high = FAR_ORIGIN_STEP_RANGE
    if not all(np.array_equal(a.astype(np.float32), a) for a in (clip.R_wc, clip.t_wc)):
        low = FAR_ORIGIN_STEP_MIN_FLOAT64
    near = np.flatnonzero((ratios > low) & (ratios <= high))
    if not near.size:
        return []
    distance = float(np.median(np.linalg.norm(clip.t_wc.astype(np.float64), axis=1)))
    held = int(np.sum(ratios[near] <= CAMERA_TRANSLATION_RESOLUTION))
    return [Problem(
        "info" if is_reference_compat(clip) else "warning", "cameras_far_from_origin", "t_wc",
        "cameras whose steps are large against their distance from the world's origin",
        f"{near.size} of {ratios.size} pairs step {ratios[near].min():.2g}-{ratios[near].max():.2g} of the cameras' "
        f"distance from the origin (|t_wc| ~{distance:.3g}); {held} of them below {CAMERA_TRANSLATION_RESOLUTION:.2g}, "
        "which counts as no translation (docs/semantics.md §3.4), and float32 keeps the others to a few percent",
        "give the cameras in a world whose origin lies near them: move it to the first camera's centre "
        "c = -R_wc[0]^T t_wc[0] (t_wc <- t_wc + R_wc c, in float64), as a SLAM or geographic frame needs")]


def text_order_residuals(clip: Clip, config: SGCConfig) -> dict[str, tuple[float, float]]:
    """Per text order of TEXT_ORDERS: (as given, read in that order), the median over its seams
    (``text_order_seams``, at most RHO_PAIRS spread over them) of the tracks' misfit [px]; NaN without
    a seam that holds tracks. The orders' seams share their samples and their fit as given."""
    seams = {}
    for reading, first in TEXT_ORDERS.items():
        pairs = text_order_seams(clip.n_frames, first)
        seams[reading] = pairs[np.linspace(0, pairs.size - 1, RHO_PAIRS).round().astype(np.int64)] \
            if pairs.size > RHO_PAIRS else pairs
    union = np.unique(np.concatenate(list(seams.values())))
    readings = ("given", *TEXT_ORDERS)
    fits = {pair: [misfit for misfit, _ in track_fits(clip, pair, prev, curr, z, readings)]
            for pair, prev, curr, z in track_samples(clip, config, pairs=union)}
    out = {}
    for k, reading in enumerate(TEXT_ORDERS, start=1):
        both = [(fits[pair][0], fits[pair][k]) for pair in seams[reading] if pair in fits]
        both = [b for b in both if np.isfinite(b).all()]
        out[reading] = tuple(float(v) for v in np.median(np.array(both), axis=0)) if both else (np.nan, np.nan)
    return out


def check_text_order(clip: Clip, config: SGCConfig) -> list[Problem]:
    """A warning where, on its seams, a text order of the frames' numbers leaves the tracks at most
    POSE_CONVENTION_RATIO of the misfit as given, which is over POSE_MISFIT_MIN_PX (rule TO2)."""
    for reading, (given, ordered) in text_order_residuals(clip, config).items():
        if np.isfinite(given) and given > POSE_MISFIT_MIN_PX and ordered <= POSE_CONVENTION_RATIO * given:
            code, meaning, fix = POSE_FIXES[reading]
            return [Problem(
                "warning", code, "R_wc/t_wc", "each frame's pose at its frame's place",
                f"where the two orders differ, the tracks miss the camera's motion by {given:.2g} px (median) as "
                f"given and by {ordered:.2g} px with the poses read as {meaning}", fix)]
    return []


def check_pose_convention(residuals: dict[str, float]) -> tuple[list[Problem], str]:
    """Whether the poses are world->camera with OpenCV's axes, as the tracks and depth see them, from
    ``pose_convention_residuals`` over POSE_READINGS -> (problems, the reading the tests of the depth
    use): a warning where another reading leaves the tracks POSE_CONVENTION_RATIO or less of the
    misfit the stored reading leaves (the best such reading named)."""
    stored = residuals["given"]
    others = {reading: residuals[reading] for reading in POSE_READINGS[1:] if reading in residuals}
    best = min(others, key=others.get)
    commoner = [reading for reading in others if reading not in SLIP_READINGS]
    if best in SLIP_READINGS and commoner and not others[best] < SLIP_MARGIN * min(others[r] for r in commoner):
        best = min(commoner, key=others.get)
    if not (np.isfinite(stored) and stored > POSE_MISFIT_MIN_PX and others[best] < POSE_CONVENTION_RATIO * stored):
        return [], "given"
    code, meaning, fix = POSE_FIXES[best]
    return [Problem(
        "warning", code, "R_wc/t_wc", "world->camera poses with OpenCV's axes (x_cam = R_wc x_world + t_wc, y down, "
        "looking along +z)",
        f"the tracks miss the camera's motion by {stored:.2g} px (median) as given and by {others[best]:.2g} px "
        f"with the poses read as {meaning}", fix)], best
