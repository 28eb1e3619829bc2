"""Plausibility checks of a clip's content, shared by the loader and ``sgc-jax validate``.

Structural problems (shapes, ranks, non-finite cameras) are found by :mod:`sgc_jax.io.loading`. The
checks here look for inputs whose units or resolutions do not fit together: intrinsics made for
another image size, depth that is really disparity, poses that are not rotations, tracks on another
pixel grid, masks that look inverted. Each problem is one actionable line. ``error`` problems make
the loader raise :class:`ClipValidationError`; ``warning`` problems are issued as
:class:`ClipWarning`; ``info`` lines (what the clip holds, deliberate reference-compat choices)
are only shown by ``sgc-jax validate``.
"""

from __future__ import annotations

import dataclasses
import sys
import warnings
from typing import Any, Sequence

import numpy as np

from ..config import SGCConfig
from ..stats import spearman
from .clip import Clip, ClipFormatError, no_reading, repeated_tracks
from .depth_edges import DEPTH_EDGE_RATIO, RAMP_SHARE, edges_are_ramps, hole_border_counts, holes_blended, ramp_counts
from .depth_range import depth_reading_misfits

SEVERITIES = ("error", "warning", "info")

# Thresholds, each with where it comes from.
FOCAL_RATIO_MAX = 3.0  # focal length off by more than 3x from the image size is an error
PRINCIPAL_OFFSET_WARN = 0.25  # principal point this far from the centre (fraction of the side) is suspicious
ROTATION_ERROR_TOL = 1e-2  # max |R R^T - I| beyond which R is not a rotation (float32 VGGT R: ~1e-7)
ROTATION_WARN_TOL = 1e-4  # ... and beyond which it is used as is but reported
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
CONF_OUTSIDE_WARN = 0.01  # share of the visible tracks' confidences outside [0, 1]: logits or percentages
CONF_LOW_WARN = 0.5  # share of the visible tracks below min_track_conf: the score cannot use most of them
# share of a float track_vis strictly between 0 and 1 (all of it within [0, 1], some of it below 0.5):
# probabilities, whose hidden tracks the reading "visible where > 0" keeps (docs/semantics.md §1.2)
VIS_FRACTIONAL_WARN = 0.01
STATIC_COVERAGE_WARN = 0.05  # static mask below this fraction of a frame: inverted mask?
NEGATIVE_DEPTH_WARN = 0.01  # negative depth on this share of the pixels with a depth: a sign convention
DISPARITY_RHO_WARN = 0.3  # Spearman(depth, parallax) above this: larger "depth" moves faster = disparity
# ... and the tracks fit the camera's motion better with the depth read as its inverse, below this share
# of the misfit as given (rule D2 on FIT's random pool, bench/history/issue-58.md "Depth like disparity
# on short clips"): where the translation cannot tell (ratio 1, its scale fitted at 0 both ways), the
# image position alone can set rho (a short real clip's one pair)
DISPARITY_FIT_RATIO = 1.0
MIN_PARALLAX_PX = 0.5  # pairs whose median parallax is below this say nothing about depth vs disparity
MIN_POINTS_FOR_STATS = 30
RHO_PAIRS, RHO_POINTS = 6, 256  # pairs and points per pair the depth/disparity test looks at (cost cap)
PARALLAX_OUTLIER = 4.0  # parallax above this multiple of the pair's median: a wrong track, ignored
# The poses read as camera->world leave the tracks at most this fraction of the misfit they leave as
# given (both with the translation's scale fitted), and the misfit as given is above this many px:
# camera->world poses. As given, the ratio is >= 1.10 on 86 synthetic clips and >= 5.4 on the six
# real ones, but 0.51-0.94 where the depth is disparity; the same poses inverted read 0.06-0.18 on
# the real clips (bench/history/issue-58.md "Poses given camera to world").
POSE_CONVENTION_RATIO = 0.4
POSE_MISFIT_MIN_PX = 1.0
# How a pose file may hold the cameras: as §1.1 asks (world->camera, OpenCV's axes: x right, y down,
# looking along +z), camera->world, and either with OpenGL's camera axes (y up, looking along -z:
# Blender's, nerfstudio's and NeRF's transforms.json are camera->world so). The same ratio and floor
# tell the OpenGL readings (rule G1, bench/history/issue-58.md "Poses with OpenGL's camera axes"), and
# two conversions' slips: each camera's centre stored as its translation, and each rotation transposed
# beside its translation (rule C1, "Poses whose translation is stored as the cameras' centres").
POSE_READINGS = ("given", "camera->world", "opengl", "opengl camera->world", "translation as centres",
                 "rotation transposed")
# ... named only where they fit below this fraction of the best of the four readings before them: where a
# clip's translation moves its tracks too little to tell a transposed rotation from a camera->world
# file (a real clip: 0.878 against 0.881 px), the commoner file is named (rule C2).
SLIP_READINGS, SLIP_MARGIN = POSE_READINGS[4:], 0.8
OPENGL_AXES = np.diag([1.0, -1.0, -1.0])  # an OpenGL camera's coordinates -> OpenCV's, and back
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
}
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
# Depth given as range (each pixel's distance from the camera centre; sgc_jax/io/depth_range.py): read
# as range it warps onto the next frame with at most RANGE_READING_RATIO of the misfit it leaves read
# as z, which is above RANGE_MISFIT_MIN (relative; below it the depth warps onto itself as well as
# float32 and a renderer allow, and neither reading is worse), and within RANGE_FIT_MAX: a clean range
# map, where range maps come from (renderers, Hypersim). Under an estimator's depth errors neither
# reading warps well and none is told. Rules R1 and R2 on FIT's random pool (bench/history/issue-58.md,
# "Depth given as range"): RANGE_MISFIT_MIN written first; the ratio min(0.5, 0.67 x the least of its
# z depth under five noise models, 0.752); RANGE_FIT_MAX half the least range reading of its z depth
# under depth errors (0.271 %), added after R1 alone told one held-out clip of 120, with a 2 %
# per-frame depth scale error, range.
RANGE_READING_RATIO = 0.5
RANGE_MISFIT_MIN = 5e-4
RANGE_FIT_MAX = 1.35e-3
# A motion mask given as the static one: the tracks off the static mask miss the camera's motion by at
# most this fraction of what those on it miss (over POSE_MISFIT_MIN_PX), the poses as given. Rule M1
# (bench/history/issue-58.md "A motion mask given as the static one").
MASK_SIDE_RATIO = 0.4
# Clips longer than this many frames get an info line: the splits the score was validated on hold 6-12
# frames, the standard clip 16, and a slow inconsistency shows each consecutive pair less the more
# frames it is spread over (docs/semantics.md §1.5, "Long clips"; bench/clip_length.py).
LONG_CLIP_FRAMES = 16
FRAMES_AFTER_STEP = 12  # about what a frame step should leave of a long clip (§1.5)
# A far backdrop read as depth (a sky at VGGT's or a metric model's far depth): at least this share of the
# valid depth lies beyond this multiple of its 10th percentile. It sets the depth unit D (§3.1) once it is
# half the frame, and a pose's error at its edge reads as a depth error without bound (docs/semantics.md
# §3.1, "A sky"). Of the splits' scenes, the demo's and the unseen pool's first 60, one holds depth beyond
# 20x (8 %: unseen-48, a dolly 0.6 units from a surface, its wall at 12); the real clips at most 1.6 %
# (tartan_000020's window); a backdrop 25-40x away lifts consistent clips (bench/history/issue-58.md
# "A sky read as depth").
FAR_DEPTH_RATIO = 20.0
FAR_DEPTH_SHARE_WARN = 0.10
# Focal lengths that spread more than this over the frames (RMS of their log): a camera estimator's per-frame
# scatter, which the depth check reads as depth disagreement. On 12 unseen scenes 0.5 % RMS left 0-1 of 12
# consistent clips above 0.10 and 1 % 5-7 (bench/history/issue-58.md "A sky read as depth").
FOCAL_SPREAD_WARN = 0.005
# Content problems that the scorer already reports per pair with a reason code (docs/semantics.md §1.4): shown by
# ``sgc-jax validate``, not repeated as loader warnings.
SCORER_REPORTED = ("too_few_tracks", "no_valid_depth")


class ClipValidationError(ClipFormatError):
    """A clip whose content cannot be right (units or resolutions that do not fit)."""


class ClipWarning(UserWarning):
    """A clip that loads but looks wrong in a way that changes its score."""


def clip_warnings_as_lines(prefix: str, show_other=None):
    """A ``warnings.showwarning`` that prints a :class:`ClipWarning` as one line on stderr,
    "{prefix}: clip 'a': warning: ...", not Python's form with the file and source line that raised
    it; other warnings go to ``show_other`` (default: the current ``warnings.showwarning``)."""
    show_other = warnings.showwarning if show_other is None else show_other

    def show(message, category, filename, lineno, file=None, line=None):
        if issubclass(category, ClipWarning):
            print(f"{prefix}: {message}", file=sys.stderr if file is None else file)
        else:
            show_other(message, category, filename, lineno, file, line)
    return show


@dataclasses.dataclass(frozen=True)
class Problem:
    """One finding: ``array`` is the clip array concerned; ``message`` says what and how to fix it."""

    severity: str  # "error" | "warning" | "info"
    code: str
    array: str
    expected: str
    found: str
    fix: str = ""

    @property
    def message(self) -> str:
        text = f"expected {self.expected}, found {self.found}" if self.expected else self.found
        return text + (f"; {self.fix}" if self.fix else "")

    def line(self) -> str:
        return f"{self.severity}: {self.array}: {self.message}"


def _frames_list(index: np.ndarray, total: int) -> str:
    shown = ", ".join(str(int(i)) for i in index[:5])
    return f"{len(index)}/{total} ({shown}{', ...' if len(index) > 5 else ''})"


def _is_reference_compat(clip: Clip) -> bool:
    record = clip.meta.get("import")
    return isinstance(record, dict) and bool(record.get("reference_compat"))


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
    compat = _is_reference_compat(clip)
    severe = "info" if compat else "error"
    note = " (deliberate: reference-compat keeps VGGT's 518-px intrinsics)" if compat else ""
    problems = []
    bad = np.flatnonzero((fx <= 0) | (fy <= 0))
    if bad.size:
        t = bad[0]
        problems.append(Problem("error", "focal_not_positive", "K", "positive focal lengths fx, fy",
                                f"fx={fx[t]:.4g}, fy={fy[t]:.4g} in frames {_frames_list(bad, T)}",
                                "K must be a pinhole matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] in pixels"))
        return problems
    outside = np.flatnonzero((cx < -0.5) | (cx > W - 0.5) | (cy < -0.5) | (cy > H - 0.5))
    if outside.size:
        t = outside[0]
        problems.append(Problem(severe, "principal_point_outside", "K", f"principal point inside the {H}x{W} image",
                                f"cx={cx[t]:.1f}, cy={cy[t]:.1f} in frames {_frames_list(outside, T)}",
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
            f"fx={fx[t]:.1f}, fy={fy[t]:.1f} in frames {_frames_list(off, T)}",
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
                f"cx={cx[t]:.1f}, cy={cy[t]:.1f} in frames {_frames_list(far, T)}",
                _k_hint(cx[t], cy[t], H, W) + note))
    return problems


def focal_spread(K: np.ndarray) -> float:
    """The RMS over frames of the log focal lengths fx, fy of K (T, 3, 3) about their mean: 0.01 is a
    1 % scatter; NaN where a focal length is not positive."""
    focal = np.concatenate([K[:, 0, 0], K[:, 1, 1]]).astype(np.float64)
    return float(np.std(np.log(focal))) if np.all(focal > 0) else float("nan")


def check_focal_spread(clip: Clip) -> list[Problem]:
    """A warning where the per-frame focal lengths scatter beyond FOCAL_SPREAD_WARN (a zoom, or an
    estimator's per-frame K)."""
    spread = focal_spread(clip.K)
    if not spread > FOCAL_SPREAD_WARN:  # NaN: check_intrinsics' error
        return []
    return [Problem(
        "info" if _is_reference_compat(clip) else "warning", "focal_spread", "K",
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
                        f"max |R R^T - I| = {deviation[t]:.3g}, det = {det[t]:.3g} in frames {_frames_list(bad, T)}",
                        "give world->camera rotations (OpenCV); a scaled or reflected matrix, or a camera->world "
                        "pose with scale, gives this")]
    mild = np.flatnonzero(deviation > ROTATION_WARN_TOL)
    if mild.size:
        t = mild[0]
        return [Problem("warning", "rotation_not_orthonormal", "R_wc", "orthonormal rotations",
                        f"max |R R^T - I| = {deviation[t]:.3g} in frames {_frames_list(mild, T)}",
                        "used as given; re-orthonormalise (nearest rotation by SVD) if they come from a fit")]
    return []


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
                                f"fewer in pairs {_frames_list(few + 1, clip.n_pairs)}",
                                "those pairs will score NaN (reason too_few_tracks)"))
    problems.append(Problem("info", "track_coverage", "track_vis/track_conf", "",
                            f"{clip.n_tracks} tracks per pair, usable per pair: min {usable.min()}, "
                            f"median {int(np.median(usable))}"))
    return problems


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
    TRACKS_OUTSIDE_ERROR of them lie outside, tracks of another grid) and their extent."""
    H, W = clip.image_size
    problems = []
    # visible and finite, however far outside: tracks of a larger grid are what this check finds
    visible, x_max, y_max, low = _visible_reach(clip)
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
            if severity == "warning" and _is_reference_compat(clip):
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


def check_dtypes(arrays: Any) -> list[Problem]:
    """Stored dtypes and value sets that load fine but usually mean a unit or format mix-up."""
    problems = []
    depth = np.asarray(arrays["depth"]) if "depth" in arrays else None
    if depth is not None and not np.issubdtype(depth.dtype, np.floating):
        holes = np.count_nonzero(no_reading(depth))
        read = (f"; its {holes} pixels at {np.iinfo(depth.dtype).max}, the no-reading code of such PNGs (7-Scenes, "
                "Kinect), are read as invalid") if holes else ""
        problems.append(Problem("warning", "depth_dtype", "depth", "float depth",
                                f"dtype {depth.dtype}",
                                "integer depth is often a 16-bit PNG in millimetres: convert to float (e.g. / 1000)"
                                + read))
    frames = arrays.get("frames") if hasattr(arrays, "get") else None
    if frames is not None and np.asarray(frames).dtype != np.uint8:
        problems.append(Problem("warning", "frames_dtype", "frames", "uint8 RGB in 0..255",
                                f"dtype {np.asarray(frames).dtype}",
                                "frames are for plots only: store (frames * 255).astype(np.uint8)"))
    for name in ("static_mask", "dynamic_mask"):
        if name in arrays:
            mask = np.asarray(arrays[name])
            if mask.dtype.kind == "f":  # a network's probabilities or logits, read at even odds (§1.2)
                values = mask[:, ::4, ::4] if mask.ndim == 3 else mask
                between = np.count_nonzero((values > 0) & (values < 1))
                if between or np.any(values < 0):
                    problems.append(Problem(
                        "info", "mask_float", name, "a boolean mask",
                        f"floats in [{np.nanmin(values):.3g}, {np.nanmax(values):.3g}], {100 * between / values.size:.0f}% "
                        "strictly between 0 and 1", f"read as {'static' if name == 'static_mask' else 'moving'} where "
                        "above 0.5 (probabilities at even odds; logits at a probability of 0.62): store a boolean "
                        "mask of your own threshold to read it otherwise"))
            elif mask.dtype != bool:
                values = np.unique(mask[:, ::4, ::4]) if mask.ndim == 3 else np.unique(mask)
                if values.size > 2:
                    shown = ", ".join(str(v) for v in values[:6]) + (", ..." if values.size > 6 else "")
                    problems.append(Problem(
                        "warning", "mask_labels", name, "a boolean mask", f"{values.size} distinct values ({shown})",
                        f"every non-zero value counts as {'static' if name == 'static_mask' else 'moving'}; "
                        "object ids (0 = background) belong in dynamic_mask"))
    return problems




def _track_samples(clip: Clip, config: SGCConfig, on_static: bool = True):
    """Per sampled pair (at most RHO_PAIRS, spread over the clip): (pair, frame i-1 and frame i
    positions (n, 2) float64, depth at the frame i-1 position (n,)) of at most RHO_POINTS usable
    static tracks (``on_static`` False: those off the static mask) with valid depth, evenly spread;
    pairs with fewer than MIN_POINTS_FOR_STATS are left out."""
    H, W = clip.image_size
    usable = clip.usable_tracks(config.min_track_conf)
    pairs = np.unique(np.linspace(1, clip.n_frames - 1, min(RHO_PAIRS, clip.n_pairs)).round().astype(np.int64))
    for pair in pairs:
        index = np.flatnonzero(usable[pair - 1])
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


def relative_pose(clip: Clip, pair: int, reading: str = "given") -> tuple[np.ndarray, np.ndarray]:
    """(R, t) moving camera pair-1's points into camera pair, from the stored poses read as one of
    POSE_READINGS: as given, world->camera with OpenCV's axes (docs/semantics.md §1.1); as
    camera->world (R_wc holding R_cw, t_wc the camera centre); either of OpenGL's camera (y up,
    looking along -z), whose axes differ from OpenCV's by OPENGL_AXES; world->camera rotations with
    each camera's centre as its translation; each rotation transposed, its translation as given."""
    if reading not in POSE_READINGS:
        raise ValueError(f"unknown pose reading {reading!r}; one of {POSE_READINGS}")
    R, t = clip.R_wc[[pair - 1, pair]], clip.t_wc[[pair - 1, pair]]
    if reading.endswith("camera->world") or reading == "rotation transposed":
        R = np.swapaxes(R, 1, 2)
    if reading.endswith("camera->world") or reading == "translation as centres":
        t = -np.einsum("fij,fj->fi", R, t)
    R_rel = R[1] @ R[0].T
    t_rel = t[1] - R_rel @ t[0]
    if reading.startswith("opengl"):  # each camera's axes flipped: the relative pose conjugated
        return OPENGL_AXES @ R_rel @ OPENGL_AXES, OPENGL_AXES @ t_rel
    return R_rel, t_rel


def rotation_parallax(clip: Clip, pair: int, prev: np.ndarray, curr: np.ndarray, R_rel: np.ndarray) -> np.ndarray:
    """(n,) px: each track's motion left once the camera rotation R_rel is taken out (the rotation's
    homography K[pair] R_rel K[pair-1]^-1 applied to its frame i-1 position): its parallax."""
    homography = clip.K[pair] @ R_rel @ np.linalg.inv(clip.K[pair - 1])
    rotated = np.c_[prev, np.ones(len(prev))] @ homography.T
    with np.errstate(divide="ignore", invalid="ignore"):
        rotated = rotated[:, :2] / rotated[:, 2:3]
    return np.linalg.norm(curr - rotated, axis=1)


def depth_parallax_rho(clip: Clip, config: SGCConfig, reading: str = "given") -> float:
    """Median over pairs of Spearman(depth at the track, rotation-compensated track motion), the
    rotation read as ``relative_pose`` reads it.

    With true depth, nearer points move more (rho < 0); with disparity the larger values move more
    (rho > 0). NaN when no pair has enough parallax to tell.
    """
    rhos = []
    for pair, prev, curr, z in _track_samples(clip, config):
        parallax = rotation_parallax(clip, pair, prev, curr, relative_pose(clip, pair, reading)[0])
        if not np.isfinite(parallax).all():
            continue
        median = np.median(parallax)
        inlier = parallax <= PARALLAX_OUTLIER * median
        if median < MIN_PARALLAX_PX or inlier.sum() < MIN_POINTS_FOR_STATS:
            continue
        rho = spearman(z[inlier], parallax[inlier])
        if np.isfinite(rho):
            rhos.append(rho)
    return float(np.median(rhos)) if rhos else float("nan")


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
    R, t = relative_pose(clip, pair, reading)
    rays = np.c_[prev, np.ones(len(prev))] @ np.linalg.inv(clip.K[pair - 1]).T
    Y = (rays * z[:, None]) @ R.T  # camera pair's coordinates before the translation
    K = clip.K[pair]
    with np.errstate(divide="ignore", invalid="ignore"):
        projected = (Y @ K.T)[:, :2] / Y[:, 2:3]
        # d projection / d Y along t: (K t)_xy / Y_z - projection * (t_z / Y_z)
        flow = ((K @ t)[:2][None, :] - projected * t[2]) / Y[:, 2:3]
    moved = curr - projected
    if not (np.isfinite(flow).all() and np.isfinite(moved).all()):
        return float("nan"), float("nan")
    scale = max(0.0, float(np.sum(moved * flow)) / max(float(np.sum(flow * flow)), 1e-12))
    return float(np.median(np.linalg.norm(moved - scale * flow, axis=1))), scale


def pair_track_fits(clip: Clip, config: SGCConfig, readings: Sequence[str] = POSE_READINGS[:2]
                    ) -> dict[int, dict[str, tuple[float, float]]]:
    """Per sampled pair (``_track_samples``), per pose reading: ``track_fit``'s (misfit [px], scale),
    fitted once for the pose, mask and range tests that read them."""
    return {pair: {reading: track_fit(clip, pair, prev, curr, z, reading) for reading in readings}
            for pair, prev, curr, z in _track_samples(clip, config)}


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


def visible_track_extent(clip: Clip) -> float:
    """The share of the frame the visible, finite track positions reach from its top-left corner: the
    larger of (x_max + 0.5) / W and (y_max + 0.5) / H over both ends of every pair; NaN without any."""
    H, W = clip.image_size
    visible, x_max, y_max, _ = _visible_reach(clip)
    return max((x_max + 0.5) / W, (y_max + 0.5) / H) if visible.any() else float("nan")


def scaled_tracks(clip: Clip, factor: float) -> Clip:
    """The clip with every track position scaled by ``factor`` about the image's corner (pixel centres
    at integers: (x + 0.5) factor - 0.5), as tracks of a frame 1 / ``factor`` the size are rescaled."""
    scale = lambda track: ((track.astype(np.float64) + 0.5) * factor - 0.5).astype(track.dtype)  # noqa: E731
    return dataclasses.replace(clip, track_prev=scale(clip.track_prev), track_curr=scale(clip.track_curr))


def check_track_scale(clip: Clip, config: SGCConfig, given: dict[str, float]) -> list[Problem]:
    """A warning where the visible tracks reach less than TRACK_SCALE_EXTENT of the frame and, scaled to
    reach all of it, fit the camera's motion far better (``check_track_axes``' ratio and floor; the
    tracks as given under the best of every pose reading, ``given``): tracks of a smaller frame."""
    extent = visible_track_extent(clip)
    if not (np.isfinite(extent) and TRACK_EXTENT_WARN <= extent < TRACK_SCALE_EXTENT):
        return []
    misfit = float(np.min(list(given.values())))
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
    better; the two under their better of world->camera and camera->world, the tracks as given
    under the best of every pose reading, so a pose file's convention or slip does not decide it):
    positions stored row first, on a frame where both readings fall inside the
    image. (Swapped ends get no line of their own: they read like camera->world poses, and like
    cameras that do not translate.)"""
    misfit = {name: min(by_pose[reading] for reading in POSE_READINGS[:2]) for name, by_pose in residuals.items()}
    # the tracks as given under every pose reading fitted: a pose file's slip is not the tracks' (rule C2)
    given, yx = float(np.min(list(residuals["given"].values()))), misfit["yx"]
    if not (np.isfinite(given) and given > POSE_MISFIT_MIN_PX and yx < TRACK_READING_RATIO * min(given, misfit["reversed"])):
        return []
    return [Problem(
        "warning", "tracks_yx", "track_prev/track_curr", "positions as (x, y) = (column, row)",
        f"the tracks miss the camera's motion by {given:.2g} px (median) as given and by {yx:.2g} px read as (y, x)",
        "these look like (row, column) positions: swap the last axis (tracks[..., ::-1])")]


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


def check_depth(clip: Clip, config: SGCConfig, reading: str = "given", read_tracks: bool = True,
                fits: dict[int, dict[str, tuple[float, float]]] | None = None, k_usable: bool = True) -> list[Problem]:
    """Valid depth per frame, its range, and (``read_tracks``) whether it behaves like depth or like
    disparity (the camera rotation read as ``relative_pose`` reads it: a rotation read the wrong way
    round leaves a motion that can look like disparity's). Where K is refused (``k_usable`` False),
    no reading fits the camera's motion: the rank test alone speaks, as its line then comes after K's."""
    problems = []
    T = clip.n_frames
    sample = clip.depth[:, ::4, ::4]  # depth statistics on a strided sample keep loading fast
    valid_count = np.count_nonzero(((sample > 0) & (sample < np.inf)).reshape(T, -1), axis=1)
    empty = np.flatnonzero(valid_count == 0)
    if empty.size:
        problems.append(Problem("warning", "no_valid_depth", "depth", "some depth > 0 in every frame",
                                f"no valid depth in frames {_frames_list(empty, clip.n_frames)}",
                                "pairs touching these frames will score NaN"))
    problems += check_negative_depth(sample)
    values = sample[(sample > 0) & (sample < np.inf)]
    if values.size:
        lo, mid, hi = np.percentile(values, [2, 50, 98])
        problems.append(Problem("info", "depth_range", "depth", "",
                                f"median {mid:.4g}, 2-98% range [{lo:.4g}, {hi:.4g}], "
                                f"{100 * valid_count.sum() / sample.size:.0f}% of pixels valid"))
        problems += check_far_backdrop(values)
    rho = depth_parallax_rho(clip, config, reading) if read_tracks else float("nan")
    moves_like_disparity = np.isfinite(rho) and rho > DISPARITY_RHO_WARN
    if moves_like_disparity and (not k_usable or inverse_depth_fits_better(clip, config, reading, fits)):
        compat = _is_reference_compat(clip)
        problems.append(Problem(
            "info" if compat else "warning", "depth_like_disparity", "depth",
            "depth (nearer points, smaller values, move more between frames)",
            f"larger values move more (Spearman rho = {rho:+.2f} between depth and track parallax)"
            + (", and the tracks fit the camera's motion better with its inverse" if k_usable else ""),
            "deliberate: reference-compat uses VDA output / 1000 directly" if compat else
            "this looks like disparity (inverse depth): convert it, e.g. `sgc-jax import --depth-kind disparity`"))
    elif read_tracks and not moves_like_disparity and not _is_reference_compat(clip):  # disparity read as range says nothing
        problems += check_depth_range(depth_range_misfits(clip, config, reading, fits))
    return problems


def inverse_depth_fits_better(clip: Clip, config: SGCConfig, reading: str = "given",
                              fits: dict[int, dict[str, tuple[float, float]]] | None = None) -> bool:
    """Whether the tracks miss the camera's motion (``track_fit``, the median over sampled pairs) with
    the depth read as its inverse by less than DISPARITY_FIT_RATIO of what they miss with it as given
    (``fits``, ``pair_track_fits`` holding ``reading``, where given). A pair whose translation's scale
    is fitted at 0 both ways (the same misfit, up to rounding) cannot tell the two readings apart and
    is left out."""
    fits = pair_track_fits(clip, config, (reading,)) if fits is None else fits
    pairs = [(fits[pair][reading], track_fit(clip, pair, prev, curr, 1.0 / z, reading))
             for pair, prev, curr, z in _track_samples(clip, config)]
    misfits = np.array([(depth[0], inverse[0]) for depth, inverse in pairs
                        if np.isfinite(depth + inverse).all() and max(depth[1], inverse[1]) > 0]).reshape(-1, 2)
    return bool(misfits.size) and bool(np.median(misfits[:, 1]) < DISPARITY_FIT_RATIO * np.median(misfits[:, 0]))


def depth_range_misfits(clip: Clip, config: SGCConfig, reading: str = "given",
                        fits: dict[int, dict[str, tuple[float, float]]] | None = None) -> tuple[float, float]:
    """``depth_range.depth_reading_misfits`` (as z, as range) with the camera's poses read as
    ``relative_pose`` reads them and each pair's translation scale fitted to its tracks (``fits``,
    ``pair_track_fits`` holding ``reading``, where given)."""
    fits = pair_track_fits(clip, config, (reading,)) if fits is None else fits
    return depth_reading_misfits(clip, [(pair, *relative_pose(clip, pair, reading), by_reading[reading][1])
                                        for pair, by_reading in fits.items()])


def check_depth_range(misfits: tuple[float, float]) -> list[Problem]:
    """From ``depth_range_misfits``: a warning where the depth, read as each pixel's distance from
    the camera centre, warps onto the next frame's far better than read as z (RANGE_READING_RATIO),
    and well (RANGE_FIT_MAX): a clean range map, as a renderer or a dataset's ground truth gives it."""
    as_z, as_range = misfits
    if not (np.isfinite(as_z) and as_z > RANGE_MISFIT_MIN and as_range < min(RANGE_READING_RATIO * as_z,
                                                                            RANGE_FIT_MAX)):
        return []
    return [Problem(
        "warning", "depth_like_range", "depth", "z depth (each point's coordinate along the optical axis)",
        f"the depth misses the camera's motion by {100 * as_z:.2g} % (median) read as z and by "
        f"{100 * as_range:.2g} % read as each pixel's distance from the camera centre",
        "this looks like range (ray length: Hypersim's depth, a renderer's distance pass): convert it, "
        "depth = sgc_jax.depth_from_range(depth, K)")]


def check_negative_depth(sample: np.ndarray) -> list[Problem]:
    """Negative depth on more than NEGATIVE_DEPTH_WARN of the pixels that have one (``sample`` (T, h, w)):
    read as invalid, as every value <= 0 is (§1.1), but no estimator outputs it by accident."""
    negative = sample < 0
    given = np.count_nonzero(np.isfinite(sample) & (sample != 0))
    if given == 0 or np.count_nonzero(negative) <= NEGATIVE_DEPTH_WARN * given:
        return []
    frames = np.flatnonzero(negative.reshape(len(sample), -1).any(axis=1))
    return [Problem("warning", "negative_depth", "depth", "depth > 0 (values <= 0 are invalid)",
                    f"negative values on {100 * np.count_nonzero(negative) / given:.0f}% of the pixels with a depth, "
                    f"in frames {_frames_list(frames, len(sample))}",
                    "they are read as invalid; a camera looking along -z (OpenGL, Blender) gives negative z: "
                    "negate the depth")]


def check_far_backdrop(values: np.ndarray) -> list[Problem]:
    """A warning where a share of the valid depth ``values`` lies far beyond the rest: a sky."""
    near = np.percentile(values, 10)
    far_share = np.count_nonzero(values > FAR_DEPTH_RATIO * near) / values.size
    if far_share < FAR_DEPTH_SHARE_WARN:
        return []
    limit = FAR_DEPTH_RATIO * near
    return [Problem("warning", "far_backdrop", "depth",
                    f"static surfaces in view (under {100 * FAR_DEPTH_SHARE_WARN:.0f}% of the valid depth "
                    f"beyond {FAR_DEPTH_RATIO:.0f}x its 10th percentile)",
                    f"{100 * far_share:.0f}% of the valid depth lies beyond {limit:.4g} ({FAR_DEPTH_RATIO:.0f}x the "
                    f"10th percentile, {near:.4g}): a sky read as depth sets the depth unit and the depth error "
                    "at its edges (docs/semantics.md §3.1, \"A sky\")",
                    f"if it is sky, mark it invalid: depth 0 there (`sgc-jax import ... --max-depth {limit:.3g}`)")]


def check_depth_ramps(clip: Clip, config: SGCConfig) -> list[Problem]:
    """Where the depth's edges are ramps of mixed depths, as a network's enlarged output: a line saying
    they are left out before scoring (``config.smooth_depth_edges``), or a warning where they are kept."""
    valid, n_edges, n_ramps = ramp_counts(clip.depth)
    if not edges_are_ramps(valid, n_edges, n_ramps):
        return []
    found = (f"{100 * n_ramps / n_edges:.0f}% of the edge pixels ({100 * n_edges / valid:.1f}% of the valid depth) lie "
             "between their neighbours' depths: a depth network's enlarged output, whose edge points lie on no surface "
             "and read as depth error (docs/semantics.md §3.6, \"Smooth depth edges\")")
    if config.leaves_out_depth_ramps:
        return [Problem("info", "smooth_depth_edges", "depth", "", found + "; their ramps are left out before scoring "
                        "(smooth_depth_edges='leave_out', the default)")]
    return [Problem("warning", "smooth_depth_edges", "depth",
                    f"depth edges as steps (under {100 * RAMP_SHARE:.0f}% of the edge pixels between their "
                    "neighbours' depths)", found,
                    "leave the ramps out before scoring: drop `--smooth-depth-edges keep` (not under --compat authors), "
                    f"or `sgc-jax import ... --depth-edge-ratio {DEPTH_EDGE_RATIO:g}` or "
                    "sgc_jax.adapters.leave_out_depth_ramps(clip)")]


def check_depth_holes(clip: Clip) -> list[Problem]:
    """A warning where the pixels around the depth's holes are blends of their surface and 0: depth
    resized (interpolated) with its holes read as depth 0 (:func:`~sgc_jax.io.depth_edges.holes_blended`)."""
    valid, n_border, n_sunk = hole_border_counts(clip.depth)
    if not holes_blended(valid, n_border, n_sunk):
        return []
    return [Problem("warning", "depth_holes_blended", "depth",
                    "holes (invalid depth) bordered by their surfaces' depths",
                    f"{100 * n_sunk / n_border:.0f}% of the pixels beside a hole ({100 * n_sunk / valid:.1f}% of the "
                    f"valid depth) lie over {DEPTH_EDGE_RATIO:g}x below their neighbours: depth resized with its holes "
                    "read as 0, whose blends lie on no surface and read as depth error (docs/semantics.md §1.6)",
                    "resize depth by nearest neighbour (cv2.INTER_NEAREST), or mark the holes NaN before "
                    "interpolating and leave the NaN invalid")]


def static_coverage(clip: Clip) -> np.ndarray:
    """(T,) the share of each frame the static mask covers."""
    return np.count_nonzero(clip.static_mask.reshape(clip.n_frames, -1), axis=1) / clip.static_mask[0].size


def mask_side_residuals(clip: Clip, config: SGCConfig,
                        fits: dict[int, dict[str, tuple[float, float]]] | None = None) -> tuple[float, float]:
    """(on the static mask, off it): the median over the sampled pairs where both sides hold tracks of
    ``pose_residual_px`` of each side's tracks, the poses as given (the static side's from ``fits``,
    ``pair_track_fits``, where given); NaN where no pair has both."""
    fits = pair_track_fits(clip, config, ("given",)) if fits is None else fits
    static = {pair: by_reading["given"][0] for pair, by_reading in fits.items()}
    both = [(static[pair], pose_residual_px(clip, pair, prev, curr, z, "given"))
            for pair, prev, curr, z in _track_samples(clip, config, on_static=False) if pair in static]
    both = [b for b in both if np.isfinite(b).all()]
    if not both:
        return float("nan"), float("nan")
    on, off = np.median(np.array(both), axis=0)
    return float(on), float(off)


def check_mask_inverted(residuals: tuple[float, float], mask_source: str = "static_mask") -> list[Problem]:
    """From ``mask_side_residuals``: a warning where the tracks off the static mask fit the camera's
    motion far better (MASK_SIDE_RATIO) than those on it, which miss it by over POSE_MISFIT_MIN_PX:
    a motion mask given as the static one (or, from ``dynamic_mask``, a static mask given as that)."""
    on, off = residuals
    if not (np.isfinite(on) and on > POSE_MISFIT_MIN_PX and off < MASK_SIDE_RATIO * on):
        return []
    dynamic = mask_source == "dynamic_mask"
    return [Problem(
        "warning", "static_mask_inverted", mask_source,
        "dynamic_mask true on the moving objects" if dynamic else "static_mask true on the static background",
        f"the tracks on the static part miss the camera's motion by {on:.2g} px (median), those on the moving "
        f"part by {off:.2g} px",
        "this looks like a static mask: give it as static_mask" if dynamic else
        "this looks like a motion mask: give it as dynamic_mask, or invert it (static_mask = ~mask)")]


def check_mask(clip: Clip) -> list[Problem]:
    """Static-mask coverage per frame (an inverted mask leaves almost nothing static)."""
    if clip.mask_source == "none":
        return [Problem("info", "no_mask", "static_mask", "",
                        "no static_mask or dynamic_mask: the whole frame counts as static (nothing moves)")]
    coverage = static_coverage(clip)
    low = np.flatnonzero(coverage < STATIC_COVERAGE_WARN)
    problems = []
    if low.size:
        problems.append(Problem("warning", "static_mask_tiny", clip.mask_source,
                                f"static background on at least {100 * STATIC_COVERAGE_WARN:.0f}% of each frame",
                                f"{100 * coverage[low[0]]:.1f}% static in frames {_frames_list(low, clip.n_frames)}",
                                "an inverted mask? static_mask is true on the static background; "
                                "moving-object masks go in dynamic_mask"))
    problems.append(Problem("info", "mask_coverage", clip.mask_source, "",
                            f"static on {100 * coverage.mean():.0f}% of pixels (min {100 * coverage.min():.0f}% "
                            "in one frame)"))
    return problems


def check_length(clip: Clip) -> list[Problem]:
    """An info line for a clip longer than the score was validated on (:data:`LONG_CLIP_FRAMES`)."""
    if clip.n_frames <= LONG_CLIP_FRAMES:
        return []
    step = max(2, round((clip.n_frames - 1) / (FRAMES_AFTER_STEP - 1)))
    return [Problem("info", "long_clip", "track_prev/track_curr", "",
                    f"{clip.n_frames} frames: an inconsistency that grows slowly over the clip shows each "
                    "consecutive pair only its increment (docs/semantics.md §1.5, \"Long clips\")",
                    f"with long-range tracks, `sgc-jax import ... --frame-step {step}` pairs frames {step} apart")]


# Track problems after which the tests that read the tracks' motion say nothing: positions of another
# grid or in other units, hidden tracks counted as visible
TRACKS_NOT_OF_THE_IMAGE = ("tracks_outside", "tracks_normalised", "tracks_small_extent", "track_vis_probabilities")


def check_clip(clip: Clip, config: SGCConfig | None = None, arrays: Any = None) -> list[Problem]:
    """Every content check of one clip, errors first; ``arrays``: the stored arrays, for dtype checks."""
    config = config or SGCConfig()
    poses, tracks = check_poses(clip), check_tracks(clip, config)
    if arrays is not None:
        tracks = check_track_vis_values(arrays, _is_reference_compat(clip)) + tracks
    # the pose and depth tests read the tracks' motion: not where the tracks do not fit the image or
    # hidden ones count as visible, nor for a reference-compat clip, whose K and depth are
    # deliberately off (VGGT's grid, VDA / 1000)
    tracks_fit = not any(p.code in TRACKS_NOT_OF_THE_IMAGE and p.severity != "info" for p in tracks)
    test_poses = tracks_fit and not poses and not _is_reference_compat(clip)
    test_axes = test_poses and np.median(static_coverage(clip)) >= TRACK_READING_MIN_STATIC
    read_as = ("given", "yx", "reversed") if test_axes else ("given",)  # the other readings only where tested
    # the tracks as given fitted once under every pose reading: the pose, mask and range tests read them
    fits = (pair_track_fits(clip, config, POSE_READINGS if test_poses else ("given",))
            if tracks_fit and not _is_reference_compat(clip) else None)
    readings = track_reading_residuals(clip, config, read_as, fits) if test_poses else None
    axes = check_track_axes(readings) if test_axes else []
    axes = axes or (check_track_scale(clip, config, readings["given"]) if test_axes else [])
    # a motion mask given as the static one leaves the other tests only the movers' tracks
    inverted = (check_mask_inverted(mask_side_residuals(clip, config, fits), clip.mask_source)
                if test_poses and not axes else [])
    # tracks read the wrong way round or at the wrong size say nothing about the poses' convention or
    # the depth's kind
    test_convention = test_poses and not axes and not inverted
    convention, reading = check_pose_convention(readings["given"]) if test_convention else ([], "given")
    intrinsics = check_intrinsics(clip)
    k_usable = not any(p.severity == "error" for p in intrinsics)
    problems = (intrinsics + check_focal_spread(clip) + poses + convention + tracks + axes + inverted
                + check_depth(clip, config, reading, read_tracks=tracks_fit and not axes and not inverted, fits=fits,
                              k_usable=k_usable)
                + check_depth_ramps(clip, config)
                + check_depth_holes(clip) + check_mask(clip) + check_length(clip))
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
