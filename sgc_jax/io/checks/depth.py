"""The depth: valid pixels, sign, a far backdrop, ramps and blended holes at its edges, and whether it
moves like depth, disparity or range (docs/semantics.md §1.1, §1.6)."""

from __future__ import annotations

import dataclasses

import numpy as np

from ...config import SGCConfig
from ...stats import spearman
from ..clip import Clip
from ..depth_edges import DEPTH_EDGE_RATIO, RAMP_SHARE, edge_counts, edges_are_ramps, holes_blended
from ..depth_range import FLIPS, DepthReadings, depth_reading_misfits
from .motion_fits import (
    MIN_POINTS_FOR_STATS,
    pair_track_fits,
    relative_pose,
    rotation_parallax,
    track_fit,
    track_samples,
)
from .problems import Problem, frames_list, is_reference_compat

NEGATIVE_DEPTH_WARN = 0.01  # negative depth on this share of the pixels with a depth: a sign convention
DISPARITY_RHO_WARN = 0.3  # Spearman(depth, parallax) above this: larger "depth" moves faster = disparity
# ... and the tracks fit the camera's motion better with the depth read as its inverse, below this share
# of the misfit as given (rule D2 on FIT's random pool, bench/history/issue-58.md "Depth like disparity
# on short clips"): where the translation cannot tell (ratio 1, its scale fitted at 0 both ways), the
# image position alone can set rho (a short real clip's one pair)
DISPARITY_FIT_RATIO = 1.0
MIN_PARALLAX_PX = 0.5  # pairs whose median parallax is below this say nothing about depth vs disparity
PARALLAX_OUTLIER = 4.0  # parallax above this multiple of the pair's median: a wrong track, ignored
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
# A depth map stored mirrored against its frame (rows bottom-up, as OpenGL and Blender's image buffers
# hold them, columns reversed, or both: turned 180°): read so back it warps onto the next frame's with under
# this share of its misfit as given (the pose readings' ratio, cameras.POSE_CONVENTION_RATIO), where that is
# above RANGE_MISFIT_MIN, and so read its nearer points move more (rho below -DISPARITY_RHO_WARN).
# Rules FL7 and FT2 on FIT's random pool and battery (bench/history/issue-58.md "Depth stored mirrored",
# "Depth turned 180°").
MIRRORED_READING_RATIO = 0.4
# A far backdrop read as depth (a sky at VGGT's or a metric model's far depth): at least this share of the
# valid depth lies beyond this multiple of its 10th percentile. It sets the depth unit D (§3.1) once it is
# half the frame, and a pose's error at its edge reads as a depth error without bound (docs/semantics.md
# §3.1, "A sky"). Of the splits' scenes, the demo's and the unseen pool's first 60, one holds depth beyond
# 20x (8 %: unseen-48, a dolly 0.6 units from a surface, its wall at 12); the real clips at most 1.6 %
# (tartan_000020's window); a backdrop 25-40x away lifts consistent clips (bench/history/issue-58.md
# "A sky read as depth").
FAR_DEPTH_RATIO = 20.0
FAR_DEPTH_SHARE_WARN = 0.10
# Depth in blocks (a smaller map brought up by nearest neighbour): of the pixel triples along a row, and
# along a column, with valid depth whose ends differ, at least this share has a middle equal to an end,
# on each of BLOCK_FRAMES frames. Blocks of 2 px or more give 1.0; float depth ~0 (FIT's random pool
# 0.000), a sensor's millimetres up to 0.68 (7-Scenes). Rule K1 (bench/history/issue-58.md "Depth maps
# smaller than the clip grid").
BLOCK_SHARE_WARN = 0.9
BLOCK_FRAMES, BLOCK_STRIDE = 4, 4


def depth_parallax_rho(clip: Clip, config: SGCConfig, reading: str = "given") -> float:
    """Median over pairs of Spearman(depth at the track, rotation-compensated track motion), the
    rotation read as ``relative_pose`` reads it.

    With true depth, nearer points move more (rho < 0); with disparity the larger values move more
    (rho > 0). NaN when no pair has enough parallax to tell.
    """
    rhos = []
    for pair, prev, curr, z in track_samples(clip, config):
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
                                f"no valid depth in frames {frames_list(empty, clip.n_frames)}",
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
        compat = is_reference_compat(clip)
        problems.append(Problem(
            "info" if compat else "warning", "depth_like_disparity", "depth",
            "depth (nearer points, smaller values, move more between frames)",
            f"larger values move more (Spearman rho = {rho:+.2f} between depth and track parallax)"
            + (", and the tracks fit the camera's motion better with its inverse" if k_usable else ""),
            "deliberate: reference-compat uses VDA output / 1000 directly" if compat else
            "this looks like disparity (inverse depth): convert it, e.g. `sgc-jax import --depth-kind disparity`"))
    elif read_tracks and not is_reference_compat(clip):
        # without parallax (rho NaN) every depth reading warps alike, and a mirrored one tells nothing;
        # under another pose reading the tracks may be what was misread (ends swapped read as
        # camera->world poses), and the warp then moves the depth by the wrong cameras, which a half
        # turn can meet halfway: the mirrored readings only where neither holds
        read_mirrored = bool(np.isfinite(rho)) and reading == "given"
        readings = depth_range_misfits(clip, config, reading, fits, mirrored=read_mirrored)
        mirrored = check_depth_mirrored(clip, config, readings, reading) if read_mirrored else []
        # a mirrored map read as range says nothing, nor disparity read as range
        problems += mirrored or ([] if moves_like_disparity else check_depth_range(readings))
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
             for pair, prev, curr, z in track_samples(clip, config)]
    misfits = np.array([(depth[0], inverse[0]) for depth, inverse in pairs
                        if np.isfinite(depth + inverse).all() and max(depth[1], inverse[1]) > 0]).reshape(-1, 2)
    return bool(misfits.size) and bool(np.median(misfits[:, 1]) < DISPARITY_FIT_RATIO * np.median(misfits[:, 0]))


def depth_range_misfits(clip: Clip, config: SGCConfig, reading: str = "given",
                        fits: dict[int, dict[str, tuple[float, float]]] | None = None,
                        mirrored: bool = True) -> DepthReadings:
    """``depth_range.depth_reading_misfits`` (as z, as range, and, where ``mirrored``, mirrored where
    the as-z misfit is above RANGE_MISFIT_MIN or NaN) with the camera's poses read as ``relative_pose``
    reads them and each pair's translation scale fitted to its tracks (``fits``, ``pair_track_fits``
    holding ``reading``, where given)."""
    fits = pair_track_fits(clip, config, (reading,)) if fits is None else fits
    return depth_reading_misfits(clip, [(pair, *relative_pose(clip, pair, reading), by_reading[reading][1])
                                        for pair, by_reading in fits.items()],
                                 mirrored_above=RANGE_MISFIT_MIN if mirrored else None)


# Per flip of FLIPS: the reversed axes, how the maps look, the undoing slice, and where such maps come from.
MIRROR_WORDS = {
    "up-down": ("rows", "mirrored up-down", "depth[:, ::-1]", "OpenGL's and Blender's image buffers run bottom-up"),
    "left-right": ("columns", "mirrored left-right", "depth[:, :, ::-1]",
                   "a mirrored selfie video, or depth estimated on flipped frames"),
    "turned 180°": ("rows and columns", "turned 180°", "depth[:, ::-1, ::-1]",
                    "a video whose orientation tag turns it upside down, its depth estimated on the frames as stored "
                    "and its tracks on the frames as shown, or the other way round"),
}


def mirrored_flip(readings: DepthReadings) -> str | None:
    """From ``depth_range_misfits``: the flip of FLIPS under which the depth warps onto the next
    frame's far better than as given (MIRRORED_READING_RATIO), or None."""
    flipped = readings.flipped or {}
    if not flipped:
        return None
    flip = min(flipped, key=lambda name: flipped[name] if np.isfinite(flipped[name]) else np.inf)
    as_z = readings.mirrored_as_z
    return flip if np.isfinite(as_z) and as_z > RANGE_MISFIT_MIN and flipped[flip] < MIRRORED_READING_RATIO * as_z else None


def check_depth_mirrored(clip: Clip, config: SGCConfig, readings: DepthReadings, reading: str = "given") -> list[Problem]:
    """A warning where the depth, each map read mirrored (``mirrored_flip``), warps far better than as
    given, and so read, nearer points move more (``depth_parallax_rho`` below -DISPARITY_RHO_WARN):
    a map stored mirrored, not one whose every reading warps alike (no parallax, disparity)."""
    flip = mirrored_flip(readings)
    if flip is None:
        return []
    reversed_axes = tuple(axis for axis, reverse in zip((1, 2), FLIPS[flip]) if reverse)
    flipped = np.flip(clip.depth, axis=reversed_axes)
    if not depth_parallax_rho(dataclasses.replace(clip, depth=flipped), config, reading) < -DISPARITY_RHO_WARN:
        return []
    axes, look, undo, source = MIRROR_WORDS[flip]
    return [Problem(
        "warning", "depth_mirrored", "depth", "depth maps stored as the frames are (row 0 at the top, column 0 at the left)",
        f"the depth misses the camera's motion by {100 * readings.mirrored_as_z:.2g} % (median) as given and by "
        f"{100 * readings.flipped[flip]:.2g} % with each map's {axes} read in reverse order, and so read nearer points move more",
        f"the maps look {look} against their frames ({source}): "
        f"flip them, {undo}")]


def check_depth_range(misfits: DepthReadings) -> list[Problem]:
    """From ``depth_range_misfits``: a warning where the depth, read as each pixel's distance from
    the camera centre, warps onto the next frame's far better than read as z (RANGE_READING_RATIO),
    and well (RANGE_FIT_MAX): a clean range map, as a renderer or a dataset's ground truth gives it."""
    as_z, as_range = misfits[:2]
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
                    f"in frames {frames_list(frames, len(sample))}",
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


def check_depth_edges(clip: Clip, config: SGCConfig) -> list[Problem]:
    """The depth's edges, read once on its ramp frames (``depth_edges.edge_counts``): ramps of mixed
    depths and holes blended with 0."""
    ramps, holes = edge_counts(clip.depth)
    return ramp_problems(*ramps, config) + hole_problems(*holes)


def block_shares(depth: np.ndarray) -> tuple[float, float]:
    """(along rows, along columns): the least over BLOCK_FRAMES frames of the share of pixel triples
    (a, b, c) with valid depth and a != c whose middle b equals a or c exactly, on every BLOCK_STRIDE-th
    row (column); NaN without any."""
    shares = []
    for frame in np.unique(np.linspace(0, len(depth) - 1, BLOCK_FRAMES).round().astype(np.int64)):
        # every BLOCK_STRIDE-th row (column) read along itself: a block spans whole rows and columns
        for z in (depth[frame, ::BLOCK_STRIDE], np.ascontiguousarray(depth[frame, :, ::BLOCK_STRIDE].T)):
            a, b, c = z[:, :-2], z[:, 1:-1], z[:, 2:]
            valid = z > 0  # NaN compares false; an infinite depth counts here, and makes no block
            ok = valid[:, :-2] & valid[:, 1:-1] & valid[:, 2:] & (a != c)
            n = np.count_nonzero(ok)
            shares.append(np.count_nonzero(ok & ((b == a) | (b == c))) / n if n else np.nan)
    rows, columns = np.array(shares).reshape(-1, 2).T
    least = lambda x: float(np.min(x)) if np.isfinite(x).all() else float("nan")  # noqa: E731
    return least(rows), least(columns)


def check_depth_blocks(clip: Clip) -> list[Problem]:
    """A warning where the depth lies in blocks along rows and columns (``block_shares`` at least
    BLOCK_SHARE_WARN both ways): a smaller map brought up by nearest neighbour (rule K1)."""
    rows, columns = block_shares(clip.depth)
    if not (rows >= BLOCK_SHARE_WARN and columns >= BLOCK_SHARE_WARN):
        return []
    return [Problem("warning", "depth_in_blocks", "depth", "depth that varies from pixel to pixel on sloping surfaces",
                    f"blocks: {100 * rows:.0f}% (rows) and {100 * columns:.0f}% (columns) of the pixels between "
                    "two different depths equal one of them: a smaller map brought up by nearest neighbour, whose "
                    "steps on every sloping surface read as depth error (docs/semantics.md §1.5, \"Depth maps of "
                    "another size\")",
                    "bring it up bilinearly within valid depth (sgc_jax.adapters.resize_depth, `sgc-jax import "
                    "... --depth-resize bilinear`), or score the clip at the depth's resolution")]


def ramp_problems(valid: int, n_edges: int, n_ramps: int, config: SGCConfig) -> list[Problem]:
    """Where the depth's edges are ramps of mixed depths, as a network's enlarged output: a line saying
    they are left out before scoring (``config.smooth_depth_edges``), or a warning where they are kept."""
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


def hole_problems(valid: int, n_border: int, n_sunk: int) -> list[Problem]:
    """A warning where the pixels around the depth's holes are blends of their surface and 0: depth
    resized (interpolated) with its holes read as depth 0 (:func:`~sgc_jax.io.depth_edges.holes_blended`)."""
    if not holes_blended(valid, n_border, n_sunk):
        return []
    return [Problem("warning", "depth_holes_blended", "depth",
                    "holes (invalid depth) bordered by their surfaces' depths",
                    f"{100 * n_sunk / n_border:.0f}% of the pixels beside a hole ({100 * n_sunk / valid:.1f}% of the "
                    f"valid depth) lie over {DEPTH_EDGE_RATIO:g}x below their neighbours: depth resized with its holes "
                    "read as 0, whose blends lie on no surface and read as depth error (docs/semantics.md §1.6)",
                    "resize depth within its valid pixels (sgc_jax.adapters.resize_depth), by nearest neighbour "
                    "(cv2.INTER_NEAREST; from a smaller map it leaves blocks), or mark the holes NaN before "
                    "interpolating and leave the NaN invalid")]
