"""Content checks shared by the loader and `sgc-jax validate`; one actionable line each."""

import dataclasses
import json
import warnings

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from estimator_fixtures import vggt_intrinsics
from scenes import IMPORT_SCENE

from sgc_jax import (
    ClipFormatError,
    SGCConfig,
    clip_from_arrays,
    depth_without_ramps,
    load_clip,
    save_batch,
    save_clip,
    score_batch,
)
from sgc_jax.adapters import DEPTH_EDGE_RATIO, leave_out_depth_ramps, resize_depth
from sgc_jax.adapters.common import resize_nearest
from sgc_jax.engines.jax_engine import device_prepare
from sgc_jax.io.checks import cameras as camera_checks, depth as depth_checks
from sgc_jax.io.checks.depth import check_depth_mirrored, depth_range_misfits, inverse_depth_fits_better, mirrored_flip
from sgc_jax.io.clip import clip_to_arrays
from sgc_jax.io.depth_edges import RAMP_SHARE, edges_and_ramps, has_smooth_edges, ramp_share, ramps_left_out
from sgc_jax.io.depth_range import depth_from_range, range_from_depth
from sgc_jax.io.loading import validate_paths
from sgc_jax.io.validate import ClipValidationError, ClipWarning, check_clip
from sgc_jax.research.noise import enlarged_depth, letterboxed
from sgc_jax.research.synth import synth_clip

SMALL = dict(IMPORT_SCENE, with_frames=False)


@pytest.fixture(scope="module")
def clip():
    return synth_clip(seed=4, clip_id="good", **SMALL)


def arrays_of(clip, **changes):
    arrays = clip_to_arrays(clip)
    arrays.update(changes)
    return arrays


def problems_of(arrays):
    return check_clip(clip_from_arrays(arrays, validate=False))


def codes(problems, severity):
    return sorted(p.code for p in problems if p.severity == severity)


def test_a_consistent_clip_has_no_problem(clip):
    problems = problems_of(arrays_of(clip))
    assert codes(problems, "error") == [] and codes(problems, "warning") == []
    assert codes(problems, "info") == ["depth_range", "mask_coverage", "track_coverage"]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        clip_from_arrays(arrays_of(clip))


def test_a_clip_longer_than_the_validated_lengths_gets_an_info_line_naming_a_frame_step():
    long_clip = synth_clip(seed=4, clip_id="long", **{**SMALL, "n_frames": 49})
    [line] = [p for p in check_clip(long_clip) if p.code == "long_clip"]
    assert line.severity == "info" and "49 frames" in line.found and "--frame-step 4" in line.fix


def test_a_sky_read_as_depth_gets_a_warning_naming_a_depth_limit_and_none_once_it_is_invalid():
    sky = synth_clip(seed=4, clip_id="sky", back_wall_depth=1000.0, **SMALL)
    [line] = [p for p in check_clip(sky) if p.code == "far_backdrop"]
    assert line.severity == "warning" and "--max-depth" in line.fix
    masked = dataclasses.replace(sky, depth=np.where(sky.depth > 100.0, 0.0, sky.depth).astype(np.float32))
    assert not [p for p in check_clip(masked) if p.code == "far_backdrop"]


def test_negative_depth_gets_a_warning_naming_the_sign_convention_and_a_few_stray_values_none(clip):
    flipped = clip.depth.copy()
    flipped[:, : flipped.shape[1] // 2] *= -1.0  # half of every frame given as -z
    [line] = [p for p in problems_of(arrays_of(clip, depth=flipped)) if p.code == "negative_depth"]
    assert line.severity == "warning" and "50%" in line.found and "negate" in line.fix
    strays = clip.depth.copy()
    strays[:, 0, :4] = -1.0  # below NEGATIVE_DEPTH_WARN of the pixels: an estimator's invalid marker
    assert not [p for p in problems_of(arrays_of(clip, depth=strays)) if p.code == "negative_depth"]


def network_depth(clip, factor=2):
    """The clip with its depth as a network at 1/factor of the frame's size leaves it."""
    return dataclasses.replace(clip, depth=enlarged_depth(clip.depth, factor))


def test_depth_edges_as_ramps_are_said_to_be_left_out_warned_of_where_kept_and_quiet_once_left_out(clip):
    smooth = network_depth(clip)
    [line] = [p for p in check_clip(smooth) if p.code == "smooth_depth_edges"]
    assert line.severity == "info" and "left out before scoring" in line.message
    for config in (SGCConfig(smooth_depth_edges="keep"), SGCConfig(compat="authors")):
        [line] = [p for p in check_clip(smooth, config) if p.code == "smooth_depth_edges"]
        assert line.severity == "warning" and f"--depth-edge-ratio {DEPTH_EDGE_RATIO:g}" in line.fix
    left_out = leave_out_depth_ramps(smooth)
    assert 0 < left_out.meta["depth_ramps"]["invalid_frac"] < 0.5
    assert not (left_out.depth[edges_and_ramps(smooth.depth)[1]] > 0).any()
    assert not [p for p in check_clip(left_out) if p.code == "smooth_depth_edges"]
    assert ramp_share(clip.depth)[1] < RAMP_SHARE / 10 < ramp_share(smooth.depth)[1] / 10
    assert has_smooth_edges(smooth.depth) and not has_smooth_edges(clip.depth)
    with pytest.raises(ValueError, match="must be > 1"):
        leave_out_depth_ramps(clip, 1.0)


def test_confidences_outside_zero_to_one_are_warned_of_as_logits_or_percentages(clip):
    warned = lambda conf: [p for p in check_clip(dataclasses.replace(clip, track_conf=conf))  # noqa: E731
                           if p.code == "track_conf_range"]
    inside = np.random.default_rng(0).uniform(0.0, 1.0, clip.track_conf.shape).astype(np.float32)
    assert not warned(inside) and not warned(clip.track_conf)
    for given in (100.0 * inside, np.log(inside / (1.0 - inside))):  # percentages; logits
        [line] = warned(given.astype(np.float32))
        assert line.severity == "warning" and "sigmoid" in line.fix


def with_holes(clip):
    """The clip with invalid blocks (0) in its depth, as a sensor's shadows and dropouts leave them."""
    depth = clip.depth.copy()
    H, W = clip.image_size
    for y, x in ((H // 5, W // 6), (H // 2, W // 2), (3 * H // 4, W // 5)):
        depth[:, y:y + H // 8, x:x + W // 8] = 0.0
    return dataclasses.replace(clip, depth=depth)


def resized_from_half(depth, interpolation):
    """Depth shrunk to half its size by nearest neighbour and enlarged back by ``interpolation``, its 0s read as values."""
    T, H, W = depth.shape
    return np.stack([cv2.resize(cv2.resize(frame, (W // 2, H // 2), interpolation=cv2.INTER_NEAREST), (W, H),
                                interpolation=interpolation) for frame in depth])


def test_depth_resized_with_its_holes_read_as_zero_is_warned_of_and_nearest_neighbour_is_not(clip):
    holed = with_holes(clip)
    warned = lambda depth: [p for p in check_clip(dataclasses.replace(holed, depth=depth))  # noqa: E731
                            if p.code == "depth_holes_blended"]
    assert not warned(holed.depth) and not warned(resized_from_half(holed.depth, cv2.INTER_NEAREST))
    [line] = warned(resized_from_half(holed.depth, cv2.INTER_LINEAR))
    assert line.severity == "warning" and "INTER_NEAREST" in line.fix
    assert not warned(resized_from_half(clip.depth, cv2.INTER_LINEAR))  # no holes: nothing blended with 0


def test_letterbox_bars_left_out_of_the_static_mask_or_of_the_depth_get_no_line(clip):
    boxed = letterboxed(clip, 0.1)
    bars = np.r_[0:10, 86:96]
    unmasked, invalid = boxed.static_mask.copy(), boxed.depth.copy()
    unmasked[:, bars], invalid[:, bars] = False, 0.0
    warned = lambda c: [p.code for p in check_clip(c) if p.code == "letterbox_bars"]  # noqa: E731
    assert warned(boxed) == ["letterbox_bars"]
    assert not warned(dataclasses.replace(boxed, static_mask=unmasked))
    assert not warned(dataclasses.replace(boxed, depth=invalid))
    assert not warned(letterboxed(clip, 0.01))  # one row: under 2 % of the frame's


def test_the_devices_ramp_step_leaves_the_same_depth_as_the_hosts_inside_a_jit(clip):
    smooth = network_depth(clip)
    holes = smooth.depth.copy()
    holes[:, :5, :7] = 0  # invalid depth is no neighbour
    on_host = leave_out_depth_ramps(dataclasses.replace(smooth, depth=holes)).depth
    on_device = np.asarray(jax.jit(depth_without_ramps)(jnp.asarray(holes), DEPTH_EDGE_RATIO))
    assert (on_host == 0).sum() > (holes == 0).sum()
    np.testing.assert_array_equal(on_device, on_host)


@pytest.mark.parametrize("n_frames", [2, 3, 4])
def test_the_device_decides_which_clips_have_smooth_edges_and_leaves_out_their_ramps_as_the_host(clip, n_frames):
    T, (H, W) = n_frames, clip.image_size

    @jax.jit
    def on_device(arrays):
        smooth = device_prepare.has_smooth_edges(arrays)
        return smooth, device_prepare.ramps_left_out(arrays, smooth, True)

    for depth in (clip.depth[:T], network_depth(clip).depth[:T]):
        padded = np.full((T + 2, H + 8, W + 8), 3.0, np.float32)  # the padding's depth is no neighbour
        padded[:T, :H, :W] = depth
        arrays = device_prepare.ClipArrays(*[None] * 9, n_frames=jnp.int32(T), n_tracks=None, heights=jnp.int32(H),
                                           widths=jnp.int32(W))._replace(depth=jnp.asarray(padded))
        smooth, left_out = on_device(arrays)
        assert bool(smooth) == has_smooth_edges(depth)
        np.testing.assert_array_equal(np.asarray(left_out)[:T, :H, :W], ramps_left_out(depth))


def test_focal_lengths_that_scatter_over_the_frames_get_a_warning_and_one_k_none(clip):
    scatter = np.array([1.0, 1.012, 0.99, 1.006])[:clip.n_frames, None, None]  # 0.8 % RMS over 4 frames
    jittered = clip.K.astype(np.float64).copy()
    jittered[:, :2, :2] *= scatter
    [line] = [p for p in check_clip(dataclasses.replace(clip, K=jittered)) if p.code == "focal_spread"]
    assert line.severity == "warning" and "--per-frame-intrinsics" in line.fix
    one_K = np.repeat(np.median(jittered, axis=0, keepdims=True), clip.n_frames, axis=0)
    assert not [p for p in check_clip(dataclasses.replace(clip, K=one_K)) if p.code == "focal_spread"]


def test_pixels_that_are_not_square_are_no_focal_spread(clip):
    wide = clip.K.astype(np.float64) * np.array([1.3, 1.0, 1.0])[:, None]  # fx 30 % above fy in every frame
    assert not [p for p in check_clip(dataclasses.replace(clip, K=wide)) if p.code == "focal_spread"]


def test_tracks_given_twice_get_a_warning_and_a_few_repeats_none(clip):
    def repeated(count):
        extra = lambda a: np.concatenate([a, a[:, :count]], axis=1)  # noqa: E731
        return dataclasses.replace(clip, track_prev=extra(clip.track_prev), track_curr=extra(clip.track_curr),
                                   track_vis=extra(clip.track_vis), track_conf=extra(clip.track_conf))

    [line] = [p for p in check_clip(repeated(clip.n_tracks)) if p.code == "duplicate_tracks"]
    assert line.severity == "warning" and "50% of pair" in line.found and "leaves the repeats out" in line.fix
    assert not [p for p in check_clip(repeated(clip.n_tracks // 50)) if p.code == "duplicate_tracks"]


def vggt_K(clip):
    return vggt_intrinsics(clip.K, *clip.image_size, "crop")[0]


def camera_to_world(clip):
    """The clip's poses as a camera->world file holds them (R_cw = R_wc^T, the camera centre)."""
    R = np.swapaxes(clip.R_wc, 1, 2)
    return {"R_wc": R, "t_wc": -np.einsum("tij,tj->ti", R, clip.t_wc)}


def opengl(clip, camera_to_world=False):
    """The clip's poses as a file of an OpenGL camera (y up, looking along -z) holds them, world->camera
    or camera->world (a transforms.json)."""
    flip = np.diag([1.0, -1.0, -1.0])
    R, t = np.einsum("ij,tjk->tik", flip, clip.R_wc), clip.t_wc @ flip
    if camera_to_world:
        R = np.swapaxes(R, 1, 2)
        t = -np.einsum("tij,tj->ti", R, t)
    return {"R_wc": R.astype(np.float32), "t_wc": t.astype(np.float32)}


def centres_as_translation(clip):
    """The clip's poses with each camera's centre stored as its translation (a camera->world file
    whose rotation alone was transposed)."""
    return {"t_wc": camera_to_world(clip)["t_wc"].astype(np.float32)}


def as_range(clip):
    """The clip's depth as a range map: each pixel's distance from the camera centre."""
    return range_from_depth(clip.depth, clip.K)


def yx_inside(clip):
    """The tracks stored as (y, x), those whose (y, x) reading would leave the frame made invisible:
    row-first tracks on a frame where both readings fall inside it, as on a square frame."""
    H, W = clip.image_size
    inside = (clip.track_prev[..., 0] < H - 1) & (clip.track_curr[..., 0] < H - 1)
    return {"track_prev": clip.track_prev[..., ::-1], "track_curr": clip.track_curr[..., ::-1],
            "track_vis": clip.track_vis & inside}


def far_origin(clip, steps_away=2.0**17.5, dtype=np.float32):
    """t_wc (T, 3) of ``clip``'s cameras in a world whose origin lies ``steps_away`` median camera steps
    away (2^17.5: steps of ~2^-18.5 of the cameras' distance from it, FAR_ORIGIN_STEP_RANGE)."""
    centres = -np.einsum("tji,tj->ti", clip.R_wc, clip.t_wc)
    step = float(np.median(np.linalg.norm(np.diff(centres, axis=0), axis=1)))
    shift = steps_away * step * np.array([0.6, -0.64, 0.48])
    return (clip.t_wc.astype(np.float64) + np.einsum("tij,j->ti", clip.R_wc, shift)).astype(dtype)


def failed_hidden(clip, share=0.3):
    """``clip`` with ``share`` more of its tracks hidden, and every hidden track's frame-i position drawn
    over the image: a tracker whose hidden points failed (as LK's do)."""
    H, W = clip.image_size
    hidden = ~clip.track_vis | (np.arange(clip.n_tracks) % 10 < 10 * share)[None]
    drawn = np.random.default_rng(0).uniform([0, 0], [W - 1, H - 1], clip.track_curr.shape)
    return dataclasses.replace(clip, track_curr=np.where(hidden[..., None], drawn, clip.track_curr).astype(np.float32),
                               track_vis=~hidden)


# (changes to the clip, severity, code, array, words the line must contain)
CASES = {
    "K at VGGT's 518-px scale": (lambda c: {"K": vggt_K(c)}, "error", "principal_point_outside", "K",
                                 ["inside the 96x128 image", "cx=258.5", "518-px preprocessed grid"]),
    "focal off by more than 3x": (lambda c: {"K": np.array([[20.0, 0, 63.5], [0, 20.0, 47.5], [0, 0, 1]])},
                                  "error", "focal_implausible", "K", ["within 3x", "fx=20.0"]),
    "principal point off centre": (lambda c: {"K": np.array([[110.0, 0, 110.0], [0, 110.0, 47.5], [0, 0, 1]])},
                                   "warning", "principal_point_off_centre", "K", ["cx=110.0", "rescale K"]),
    "K of a half-size grid": (lambda c: {"K": c.K * np.array([0.5, 0.5, 1.0])[:, None]}, "warning",
                              "principal_point_off_centre", "K", ["a ~48x64 image", "rescale K"]),
    "poses that are not rotations": (lambda c: {"R_wc": 2.0 * c.R_wc}, "error", "not_rotation", "R_wc",
                                     ["det = 8", "world->camera rotations"]),
    "tracks at twice the resolution": (lambda c: {"track_prev": 2 * c.track_prev, "track_curr": 2 * c.track_curr},
                                       "error", "tracks_outside", "track_prev/track_curr",
                                       ["74% outside", "at least 191x255", "--track-size"]),
    "tracks of a slightly larger frame": (lambda c: {name: (getattr(c, name) + 0.5) * 1.1 - 0.5
                                                     for name in ("track_prev", "track_curr")},
                                          "warning", "tracks_outside", "track_prev/track_curr",
                                          ["check the visibility threshold", "none lies left of or above it",
                                           "--track-size"]),
    "tracks stored as (y, x)": (lambda c: {"track_prev": c.track_prev[..., ::-1], "track_curr": c.track_curr[..., ::-1]},
                                "warning", "tracks_outside", "track_prev/track_curr",
                                ["outside", "read as (y, x) the positions fit the image", "(x, y) = (column, row)"]),
    "tracks stored as (y, x) on a frame they fit": (lambda c: yx_inside(c), "warning", "tracks_yx",
                                                    "track_prev/track_curr",
                                                    ["read as (y, x)", "(row, column)", "tracks[..., ::-1]"]),
    "tracks at half the resolution": (lambda c: {"track_prev": c.track_prev / 2, "track_curr": c.track_curr / 2},
                                      "warning", "tracks_small_extent", "track_prev/track_curr",
                                      ["smaller grid", "--track-size"]),
    "occlusion probabilities stored as confidence": (
        lambda c: {"track_conf": np.where(c.track_vis & (np.arange(c.track_vis.shape[1]) % 8 > 0), 0.1, 0.9)
                   .astype(np.float32)},  # an eighth of the visible tracks confident, so no pair is empty
        "warning", "track_conf_low", "track_conf",
        ["% of the visible tracks below it (median 0.1, the hidden tracks' 0.9)", "store 1 - p"]),
    "tracks of a smaller frame": (lambda c: {name: (getattr(c, name) + 0.5) * 2 / 3 - 0.5
                                             for name in ("track_prev", "track_curr")},
                                  "warning", "tracks_of_a_smaller_frame", "track_prev/track_curr",
                                  ["visible tracks within its top-left 66%", "scaled by 1.5", "(x + 0.5) 128 / W_tracks - 0.5"]),
    "tracks in normalised coordinates": (lambda c: {"track_prev": c.track_prev / 128, "track_curr": c.track_curr / 128},
                                         "error", "tracks_normalised", "track_prev/track_curr",
                                         ["in pixels of the 96x128 image", "normalised coordinates?", "x W - 0.5"]),
    "disparity stored as depth": (lambda c: {"depth": np.where(c.depth > 0, 1.0 / c.depth, 0.0).astype(np.float32)},
                                  "warning", "depth_like_disparity", "depth",
                                  ["larger values move more", "--depth-kind disparity"]),
    "range stored as depth": (lambda c: {"depth": as_range(c)}, "warning", "depth_like_range", "depth",
                              ["read as each pixel's distance from the camera centre", "depth_from_range(depth, K)"]),
    "camera->world poses": (lambda c: camera_to_world(c), "warning", "camera_to_world_poses", "R_wc/t_wc",
                            ["read as camera->world", "R_wc = R^T, t_wc = -R^T t", "swap track_prev and track_curr"]),
    "OpenGL world->camera poses": (lambda c: opengl(c), "warning", "opengl_poses", "R_wc/t_wc",
                                   ["world->camera of an OpenGL camera", "R_wc = F R, t_wc = F t"]),
    "OpenGL camera->world poses": (lambda c: opengl(c, camera_to_world=True), "warning", "opengl_poses", "R_wc/t_wc",
                                   ["camera->world of an OpenGL camera", "R_wc = F R^T, t_wc = -F R^T t"]),
    "the cameras' centres stored as the translation": (
        centres_as_translation, "warning", "translation_as_centres", "R_wc/t_wc",
        ["with each camera's centre c as its translation", "t_wc = -R_wc c"]),
    "rotations transposed beside their translation": (
        lambda c: {"R_wc": np.swapaxes(c.R_wc, 1, 2)}, "warning", "rotation_transposed", "R_wc/t_wc",
        ["camera->world rotations beside world->camera translations", "R_wc = R^T and keep t_wc"]),
    "cameras far from the world's origin": (
        lambda c: {"t_wc": far_origin(c)}, "warning", "cameras_far_from_origin", "t_wc",
        ["of the cameras' distance from the origin", "counts as no translation", "t_wc <- t_wc + R_wc c"]),
    "one pose for every frame (placeholders)": (
        lambda c: {"R_wc": np.tile(np.eye(3, dtype=np.float32), (c.n_frames, 1, 1)),
                   "t_wc": np.zeros((c.n_frames, 3), np.float32)},
        "warning", "cameras_frozen", "R_wc/t_wc", ["one pose in all 4 frames while the tracks move", "placeholder poses"]),
    "poses at half the frame rate given again": (
        lambda c: {"R_wc": c.R_wc[[0, 0, 2, 2]], "t_wc": c.t_wc[[0, 0, 2, 2]]}, "warning", "cameras_held", "R_wc/t_wc",
        ["frame i's pose equal to frame i-1's in pairs 2/3 (1, 3)", "lower frame rate"]),
    "visible tracks at NaN": (
        lambda c: {"track_curr": np.where(c.track_vis[..., None] & (np.arange(c.n_tracks) % 10 == 0)[None, :, None],
                                          np.nan, c.track_curr).astype(np.float32)},
        "warning", "tracks_nonfinite", "track_prev/track_curr", ["of them NaN or infinite", "mark them hidden"]),
    "tracks with their ends swapped": (lambda c: {"track_prev": c.track_curr, "track_curr": c.track_prev}, "warning",
                                       "camera_to_world_poses", "R_wc/t_wc",
                                       ["read as camera->world", "swap track_prev and track_curr"]),
    "letterbox bars": (lambda c: {name: getattr(letterboxed(c, 0.1), name) for name in ("depth", "static_mask", "track_vis")},
                       "warning", "letterbox_bars", "depth",
                       ["rows 0-9 at the top and rows 86-95 at the bottom", "no track", "crop the bars away"]),
    "an occlusion flag stored as visibility": (
        lambda c: {"track_curr": failed_hidden(c).track_curr, "track_vis": ~failed_hidden(c).track_vis},
        "warning", "track_vis_inverted", "track_vis",
        ["35% of the tracks visible", "the hidden ones by 0.012 px", "store track_vis = ~occluded"]),
    "depth brought up from half its size by nearest neighbour": (
        lambda c: {"depth": resize_nearest(resize_nearest(c.depth, (c.image_size[0] // 2, c.image_size[1] // 2)),
                                           c.image_size)},
        "warning", "depth_in_blocks", "depth", ["100% (rows) and 100% (columns)", "--depth-resize bilinear"]),
    "depth stored bottom-up": (lambda c: {"depth": np.ascontiguousarray(c.depth[:, ::-1])}, "warning", "depth_mirrored",
                               "depth", ["each map's rows read in reverse order", "depth[:, ::-1]"]),
    "depth stored mirrored left to right": (lambda c: {"depth": np.ascontiguousarray(c.depth[:, :, ::-1])}, "warning",
                                            "depth_mirrored", "depth", ["columns read in reverse order", "depth[:, :, ::-1]"]),
    "depth turned 180°": (lambda c: {"depth": np.ascontiguousarray(c.depth[:, ::-1, ::-1])}, "warning", "depth_mirrored",
                          "depth", ["rows and columns read in reverse order", "depth[:, ::-1, ::-1]", "orientation tag"]),
    "inverted static mask": (lambda c: {"static_mask": ~c.static_mask}, "warning", "static_mask_tiny",
                             "static_mask", ["0.0% static", "inverted mask"]),
}


@pytest.mark.parametrize("name", list(CASES))
def test_each_problem_gives_one_actionable_line(clip, name):
    change, severity, code, array, words = CASES[name]
    problems = problems_of(arrays_of(clip, **change(clip)))
    found = [p for p in problems if p.code == code]
    assert len(found) == 1 and found[0].severity == severity and found[0].array == array, problems
    line = found[0].line()
    assert "\n" not in line and line.startswith(f"{severity}: {array}: ")
    for word in words:
        assert word in line, line
    others = [p.code for p in problems if p.severity in ("error", "warning") and p.code != code]
    assert others in ([], ["focal_implausible"]), others  # VGGT-scale K is also 3.5x the image size


@pytest.mark.parametrize("name", [n for n in CASES if CASES[n][1] == "error"])
def test_the_loader_refuses_errors_naming_clip_and_array(clip, name):
    change, _, _, array, _ = CASES[name]
    with pytest.raises(ClipValidationError) as info:
        clip_from_arrays(arrays_of(clip, **change(clip)))
    assert isinstance(info.value, ClipFormatError) and info.value.array == array
    assert str(info.value).startswith(f"clip 'good': array '{array}': expected ")


@pytest.mark.parametrize("name", [n for n in CASES if CASES[n][1] == "warning"])
def test_the_loader_warns_on_warnings(clip, name):
    change, _, code, array, words = CASES[name]
    with pytest.warns(ClipWarning, match=rf"clip 'good': warning: {array}: ") as record:
        loaded = clip_from_arrays(arrays_of(clip, **change(clip)))
    assert any(words[-1] in str(w.message) for w in record)
    assert code in loaded.warnings


def test_a_mirrored_depth_line_needs_the_map_read_back_to_move_like_depth(clip):
    disparity = np.where(clip.depth > 0, 1.0 / clip.depth, 0.0).astype(np.float32)
    mirrored_disparity = dataclasses.replace(clip, depth=np.ascontiguousarray(disparity[:, ::-1]))
    readings = depth_range_misfits(mirrored_disparity, SGCConfig())
    assert mirrored_flip(readings) is not None  # the warp alone would call it mirrored
    assert check_depth_mirrored(mirrored_disparity, SGCConfig(), readings) == []


def test_depth_from_range_gives_back_the_z_depth_of_a_range_map(clip):
    back = depth_from_range(as_range(clip), clip.K)
    assert back.dtype == np.float32 and back.shape == clip.depth.shape
    np.testing.assert_allclose(back, clip.depth, rtol=2e-7)  # float32 rounding of the range map, twice
    np.testing.assert_allclose(depth_from_range(as_range(clip)[0], clip.K[0]), clip.depth[0], rtol=2e-7)
    np.testing.assert_allclose(depth_from_range(as_range(clip), clip.K[0]), clip.depth, rtol=2e-7)  # one K, every frame


def test_depth_is_called_disparity_only_where_its_inverse_fits_the_camera_better(clip, monkeypatch):
    disparity = {"depth": np.where(clip.depth > 0, 1.0 / clip.depth, 0.0).astype(np.float32)}
    assert inverse_depth_fits_better(clip_from_arrays(arrays_of(clip, **disparity), validate=False), SGCConfig())
    assert not inverse_depth_fits_better(clip, SGCConfig())
    # a still camera's translation cannot tell depth from disparity: a rank correlation alone (here
    # forced) does not call the depth disparity
    still = arrays_of(clip, t_wc=np.zeros_like(clip.t_wc))
    monkeypatch.setattr(depth_checks, "depth_parallax_rho", lambda *args, **kwargs: 0.8)
    assert "depth_like_disparity" in [p.code for p in problems_of(arrays_of(clip, **disparity))]
    assert "depth_like_disparity" not in [p.code for p in problems_of(still)]


def test_poses_stored_in_reverse_order_of_the_frames_are_named():
    # six frames: on the fixture's four, the camera turns too little for the reversed poses to miss
    # the tracks by the lines' 1 px floor
    clip = synth_clip(seed=4, clip_id="six", **dict(SMALL, n_frames=6))
    assert codes(check_clip(clip), "warning") == []
    problems = problems_of(arrays_of(clip, R_wc=clip.R_wc[::-1].copy(), t_wc=clip.t_wc[::-1].copy()))
    assert codes(problems, "warning") == ["poses_reversed_in_time"]
    line = next(p for p in problems if p.code == "poses_reversed_in_time").line()
    assert "with the poses read as reversed in time" in line and "R_wc[::-1], t_wc[::-1]" in line


def test_one_pose_for_every_frame_is_named_only_where_the_tracks_move(clip):
    frozen = {"R_wc": np.tile(clip.R_wc[:1], (clip.n_frames, 1, 1)), "t_wc": np.tile(clip.t_wc[:1], (clip.n_frames, 1))}
    assert "cameras_frozen" in codes(problems_of(arrays_of(clip, **frozen)), "warning")
    tripod = dict(frozen, track_curr=clip.track_prev + np.float32(0.3))  # a still camera's tracker jitter
    assert "cameras_frozen" not in codes(problems_of(arrays_of(clip, **tripod)), "warning")
    assert "cameras_frozen" not in codes(problems_of(arrays_of(clip)), "warning")


def test_cameras_far_from_the_origin_are_named_below_float32s_rounding_only_where_stored_in_float64(clip):
    # a geographic frame: steps of ~2^-23.5 of the distance, below a float32 held centre's rounding
    geographic = {"t_wc": far_origin(clip, 2.0**22.5, np.float64), "R_wc": clip.R_wc.astype(np.float64)}
    assert "cameras_far_from_origin" in codes(problems_of(arrays_of(clip, **geographic)), "warning")
    in_float32 = {"t_wc": far_origin(clip, 2.0**22.5), "R_wc": clip.R_wc.astype(np.float32)}
    assert "cameras_far_from_origin" not in codes(problems_of(arrays_of(clip, **in_float32)), "warning")


def test_a_pose_files_slip_is_named_only_where_it_fits_clearly_better_than_the_commoner_files():
    # 7scenes_000800 with camera->world poses stored: its translation barely moves the tracks, and the
    # transposed rotation beside the wrong translation fit as well (bench/history/issue-58.md "Poses
    # whose translation is stored as the cameras' centres")
    misfits = {"given": 5.70, "camera->world": 0.881, "opengl": 1.40, "opengl camera->world": 4.43,
               "translation as centres": 9.62, "rotation transposed": 0.878}
    assert [p.code for p in camera_checks.check_pose_convention(misfits)[0]] == ["camera_to_world_poses"]
    clearly = dict(misfits, **{"rotation transposed": 0.6})
    problems, reading = camera_checks.check_pose_convention(clearly)
    assert [p.code for p in problems] == ["rotation_transposed"] and reading == "rotation transposed"


def test_tracks_read_as_y_x_are_not_judged_where_most_of_the_frame_is_masked_as_moving(clip):
    changes = yx_inside(clip)
    assert "tracks_yx" in [p.code for p in problems_of(arrays_of(clip, **changes))]
    static = np.zeros_like(clip.static_mask)
    static[:, : int(0.4 * clip.image_size[0])] = True  # an inverted mask's share: its tracks sit on movers
    problems = problems_of(arrays_of(clip, **changes, static_mask=static))
    assert "tracks_yx" not in [p.code for p in problems]


def test_the_tables_carry_the_loaders_warnings_also_for_a_loaded_clip_given_in_memory(clip, tmp_path):
    percent = dataclasses.replace(clip, clip_id="percent", track_conf=100.0 * clip.track_conf)
    path = save_clip(tmp_path / "percent.npz", percent)
    with pytest.warns(ClipWarning, match="track_conf"):
        loaded = clip_from_arrays(arrays_of(percent), clip_id="loaded")
        rows = score_batch([path, loaded, dataclasses.replace(percent, clip_id="built")], engine="reference",
                           progress=False).to_pandas()
    assert list(rows["warnings"]) == ["track_conf_range", "track_conf_range", ""]  # built in code: not checked


@pytest.mark.parametrize("change, code, array, words", [
    (lambda c: {"depth": (1000 * c.depth).astype(np.uint16)}, "depth_dtype", "depth", ["uint16", "millimetres"]),
    (lambda c: {"frames": np.zeros((4, 96, 128, 3), np.float32)}, "frames_dtype", "frames", ["uint8", "float32"]),
    (lambda c: {"static_mask": np.broadcast_to((np.arange(128) // 43).astype(np.uint8), (4, 96, 128)).copy()},
     "mask_labels", "static_mask", ["3 distinct values (0, 1, 2)", "dynamic_mask"]),
])
def test_stored_dtypes_that_suggest_a_mix_up_warn(clip, change, code, array, words):
    arrays = arrays_of(clip, **change(clip))
    problems = check_clip(clip_from_arrays(arrays, validate=False), arrays=arrays)
    found = [p for p in problems if p.code == code]
    assert len(found) == 1 and found[0].severity == "warning" and found[0].array == array
    assert all(word in found[0].line() for word in words), found[0].line()
    with pytest.warns(ClipWarning, match=code.split("_")[0]):
        clip_from_arrays(arrays)


def test_a_float_mask_of_probabilities_gets_an_info_line_naming_its_threshold_not_a_labels_warning(clip):
    probabilities = np.where(clip.static_mask, 0.9, 0.1).astype(np.float32)
    probabilities[:, :, :5] = np.linspace(0.2, 0.8, 96)[None, :, None]  # a network's soft edge
    arrays = arrays_of(clip, static_mask=probabilities)
    problems = check_clip(clip_from_arrays(arrays, validate=False), arrays=arrays)
    found = [p for p in problems if p.array == "static_mask" and p.code != "mask_coverage"]
    assert [(p.code, p.severity) for p in found] == [("mask_float", "info")], found
    assert "static where above 0.5" in found[0].line()


def test_integer_depth_at_its_largest_value_is_no_reading_and_the_warning_says_so(clip):
    millimetres = np.round(1000 * clip.depth).astype(np.uint16)
    millimetres[:, :8, :8] = np.iinfo(np.uint16).max  # 7-Scenes' and Kinect's PNGs mark no reading so
    arrays = arrays_of(clip, depth=millimetres)
    with pytest.warns(ClipWarning, match="its 256 pixels at 65535") as record:
        loaded = clip_from_arrays(arrays)
    assert not any("sky" in str(w.message) for w in record)
    assert np.all(loaded.depth[:, :8, :8] == 0) and np.array_equal(loaded.depth[:, 8:], millimetres[:, 8:])
    picture = np.full(clip.depth.shape, 255, np.uint8)  # 8 bits: a picture, whose 255 is its nearest surface
    assert np.all(clip_from_arrays(arrays_of(clip, depth=picture), validate=False).depth == 255)


def test_visibility_given_as_probabilities_warns_and_leaves_the_motion_tests_out(clip):
    hidden = np.arange(clip.n_tracks) % 4 == 0
    as_given = lambda low, high: np.where(hidden, low, high) * np.ones_like(clip.track_vis, np.float32)  # noqa: E731
    arrays = arrays_of(clip, track_vis=as_given(0.2, 0.9))
    problems = check_clip(clip_from_arrays(arrays, validate=False), arrays=arrays)
    [found] = [p for p in problems if p.code == "track_vis_probabilities"]
    assert found.severity == "warning" and found.array == "track_vis"
    assert all(words in found.line() for words in ("100% of its values strictly between 0 and 1",
                                                   "25% above 0 but below 0.5", "track_vis > 0.5")), found.line()
    assert [p.code for p in problems if p.severity in ("error", "warning")] == ["track_vis_probabilities"]
    with pytest.warns(ClipWarning, match="track_vis: expected visibility as booleans"):
        clip_from_arrays(arrays)
    for low, high in ((0.0, 1.0), (-2.0, 3.0)):  # booleans as floats, logits: read as meant
        arrays = arrays_of(clip, track_vis=as_given(low, high))
        problems = check_clip(clip_from_arrays(arrays, validate=False), arrays=arrays)
        assert "track_vis_probabilities" not in [p.code for p in problems]


def test_content_problems_the_scorer_reports_are_not_loader_warnings(clip):
    vis = clip.track_vis.copy()
    vis[1] = False
    assert codes(problems_of(arrays_of(clip, track_vis=vis)), "warning") == ["too_few_tracks"]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        loaded = clip_from_arrays(arrays_of(clip, track_vis=vis))  # the pair is reported as too_few_tracks when scored
    assert loaded.warnings == ()


def test_reference_compat_choices_are_info_not_errors(clip):
    meta = {"clip_id": "compat", "import": {"reference_compat": True}}
    depth = np.where(clip.depth > 0, 1.0 / clip.depth, 0.0).astype(np.float32)
    arrays = arrays_of(clip, K=vggt_K(clip), depth=depth, meta=np.asarray(json.dumps(meta)))
    problems = problems_of(arrays)
    assert codes(problems, "error") == [] and codes(problems, "warning") == []
    assert {"principal_point_outside", "focal_implausible", "depth_like_disparity"} <= set(codes(problems, "info"))
    summaries = ("depth_range", "mask_coverage", "track_coverage")
    assert all("reference-compat" in p.line() for p in problems if p.code not in summaries)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert clip_from_arrays(arrays).clip_id == "compat"


def test_validate_paths_reports_every_clip_of_files_directories_and_batches(tmp_path, clip):
    good = save_clip(tmp_path / "good.npz", clip)
    bad = clip_from_arrays(arrays_of(clip, K=vggt_K(clip)), validate=False)
    save_clip(tmp_path / "bad_k.npz", bad)
    broken = arrays_of(clip)
    broken.pop("track_vis")
    np.savez(tmp_path / "broken.npz", **broken)
    (tmp_path / "junk.npz").write_bytes(b"not an npz")
    # the batch's good clip has its own id: one id for two clip files is a duplicate (docs/semantics.md §1.4)
    batch = save_batch(tmp_path / "sub" / "batch.npz", [dataclasses.replace(clip, clip_id="good_packed"), bad])
    reports = validate_paths([tmp_path, batch])
    by_origin = {r.origin: r for r in reports}
    assert by_origin[str(good)].ok and by_origin[f"{batch}[0]"].ok
    for origin, code in ((str(tmp_path / "bad_k.npz"), "principal_point_outside"), (f"{batch}[1]", "principal_point_outside"),
                         (str(tmp_path / "broken.npz"), "structure"), (str(tmp_path / "junk.npz"), "unreadable")):
        report = by_origin[origin]
        assert not report.ok and report.problems[0].code == code, report
        assert all(line.startswith(f"{origin}: ") for line in report.lines())
    assert "track_vis: expected shape (3, 512), found no such array" in by_origin[str(tmp_path / "broken.npz")].lines()[0]


def test_a_clip_failing_validation_is_one_error_in_a_scored_batch(tmp_path, clip):
    save_clip(tmp_path / "a_good.npz", clip)
    save_clip(tmp_path / "b_bad.npz", clip_from_arrays(arrays_of(clip, R_wc=2.0 * clip.R_wc), validate=False))
    with pytest.raises(ClipValidationError):
        load_clip(tmp_path / "b_bad.npz")
    result = score_batch(tmp_path, engine="reference")
    assert [c.status for c in result.clips] == ["ok", "error"]
    assert "'R_wc'" in result.clips[1].reason and "rotation" in result.clips[1].reason


def test_a_motion_mask_given_as_the_static_one_warns_and_the_right_mask_does_not():
    movers = synth_clip(seed=0, clip_id="movers", **dict(SMALL, moving_objects=6))
    assert "static_mask_inverted" not in codes(check_clip(movers), "warning")
    inverted = check_clip(dataclasses.replace(movers, static_mask=~movers.static_mask))
    found = [p for p in inverted if p.code == "static_mask_inverted"]
    assert len(found) == 1 and found[0].severity == "warning" and "give it as dynamic_mask" in found[0].line()
    assert not {"camera_to_world_poses", "opengl_poses", "depth_like_disparity", "depth_like_range"} & {
        p.code for p in inverted}  # the tests that read the static tracks are not run on the movers' tracks
    arrays = arrays_of(movers)
    arrays["dynamic_mask"] = arrays.pop("static_mask")  # the static mask given as the motion mask
    found = [p for p in problems_of(arrays) if p.code == "static_mask_inverted"]
    assert len(found) == 1 and found[0].array == "dynamic_mask" and "give it as static_mask" in found[0].line()


@pytest.mark.parametrize("first", [0, 1])
def test_poses_listed_in_the_text_order_of_the_frames_numbers_are_named(first):
    long_clip = synth_clip(seed=4, clip_id="long", **dict(SMALL, n_frames=12))
    assert "poses_in_text_order" not in codes(check_clip(long_clip), "warning")
    order = np.array(sorted(range(first, first + 12), key=str)) - first  # frame 10 before frame 2
    stored = dataclasses.replace(long_clip, R_wc=long_clip.R_wc[order], t_wc=long_clip.t_wc[order])
    found = [p for p in check_clip(stored) if p.code == "poses_in_text_order"]
    assert len(found) == 1 and f"counted from {first}" in found[0].line() and "np.argsort(order)" in found[0].line()
    assert codes(check_clip(stored), "warning") == ["poses_in_text_order"]


def test_poses_given_again_are_named_only_where_the_video_moves_in_those_pairs(clip):
    held = dataclasses.replace(clip, R_wc=clip.R_wc[[0, 0, 2, 2]], t_wc=clip.t_wc[[0, 0, 2, 2]])
    assert "cameras_held" in codes(check_clip(held), "warning")
    rng = np.random.default_rng(0)  # a camera that held while its video held: tracks move by noise and outliers
    still = held.track_prev + rng.normal(0.0, 1.5, held.track_prev.shape)
    outliers = rng.random(held.track_vis.shape) < 0.1
    still[outliers] = rng.uniform([0, 0], [127, 95], (np.count_nonzero(outliers), 2))
    curr = held.track_curr.copy()
    curr[[0, 2]] = still[[0, 2]]
    assert "cameras_held" not in codes(check_clip(dataclasses.replace(held, track_curr=curr.astype(np.float32))),
                                       "warning")


def test_visibility_is_called_inverted_only_where_most_tracks_are_hidden_and_they_fit_far_better(clip):
    mostly_hidden = np.random.default_rng(1).random(clip.track_vis.shape) >= 0.6  # their positions kept
    for kept in (failed_hidden(clip), dataclasses.replace(clip, track_vis=clip.track_vis & mostly_hidden),
                 dataclasses.replace(clip, track_vis=~clip.track_vis)):  # the synthetic hidden tracks are exact
        assert "track_vis_inverted" not in codes(check_clip(kept), "warning")
    flagged = check_clip(dataclasses.replace(failed_hidden(clip), track_vis=~failed_hidden(clip).track_vis))
    assert "track_vis_inverted" in codes(flagged, "warning")
    assert not {"camera_to_world_poses", "opengl_poses", "depth_like_disparity", "static_mask_inverted"} & {
        p.code for p in flagged}  # the tests that read the visible tracks are not run on the failed ones


def test_depth_brought_up_bilinearly_or_at_its_own_size_has_no_blocks(clip):
    H, W = clip.image_size
    half = resize_nearest(clip.depth, (H // 2, W // 2))
    for depth in (clip.depth, resize_depth(half, (H, W))):
        assert "depth_in_blocks" not in codes(problems_of(arrays_of(clip, depth=depth)), "warning")


def test_a_homogeneous_extrinsic_is_read_as_its_top_rows_and_a_wrong_last_row_is_refused(clip):
    arrays = arrays_of(clip)
    extrinsic = np.zeros((clip.n_frames, 4, 4))
    extrinsic[:, :3, :3], extrinsic[:, :3, 3], extrinsic[:, 3, 3] = arrays.pop("R_wc"), arrays.pop("t_wc"), 1.0
    loaded, as_rotations = clip_from_arrays({**arrays, "extrinsic": extrinsic}), clip_from_arrays(arrays_of(clip))
    np.testing.assert_array_equal(loaded.R_wc, as_rotations.R_wc)
    np.testing.assert_array_equal(loaded.t_wc, as_rotations.t_wc)
    extrinsic[2, 3, 0] = 0.5
    with pytest.raises(ClipFormatError, match=r"array 'extrinsic'.*last row \(0, 0, 0, 1\).*frame 2"):
        clip_from_arrays({**arrays, "extrinsic": extrinsic})
