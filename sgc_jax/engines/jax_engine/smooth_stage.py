"""The differentiable score (docs/semantics.md §10): ``sgc_smooth`` of B clips as a function of
their depth, tracks, cameras and intrinsics, with every discrete choice of the forward pass held
fixed (regions, the points each local pose was fitted on, the region statuses, the scale fit's
equation, which pose the depth warp took and the points its refit was fitted on, the depth warp's
z-buffer winners, the median pixels of D) and everything continuous
recomputed so that ``jax.grad`` reaches the inputs."""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp

from ...calibration import COMPONENTS, Calibration
from ...calibration.formula import sgc_smooth_score
from ...codes import REGION_OK
from ...config import SGCConfig
from ...io.tables import FLOOR_COLUMNS
from ...kernels.camera import back_project, back_project_xyz, project_xyz, transform_xyz
from ...kernels.depth_map import pair_depth_map
from ...kernels.implicit_pose import least_squares_pose
from ...kernels.pose_variances import pair_pose_components
from ...kernels.scale import scale_equations
from ...kernels.so3 import polar_rotation, so3_exp, so3_log
from ...kernels.warp import (
    MIN_WARP_Z,
    at_pixel_centre,
    depth_at_landing,
    has_magnified,
    looked_back_depth,
    occluded_in_previous,
    previous_view,
    warp_sources,
)
from ...stats import nanmean
from ..units import PERCENT, resolved_translation
from .buckets import Bucket, PaddedClips
from .device_prepare import ClipArrays, pixel_median, prepare_differentiable
from .pixel_stage import depth_at_tracks


class Frozen(NamedTuple):
    """What the forward pass chose for one clip (leading axis T-1), held fixed."""

    track_labels: jax.Array  # (T-1, P) int32 region of each track in the region frame (pixel stage)
    track_fitted: jax.Array  # (T-1, P) bool: the tracks its region's pose was fitted on
    region_status: jax.Array  # (T-1, k) int32
    R_local: jax.Array  # (T-1, k, 3, 3) the local poses, where their Newton polish starts
    t_local: jax.Array  # (T-1, k, 3) units of D
    rot_per_px: jax.Array  # (T-1, k) deg / px; with trans_per_px (units of D / px), each pose's weight
    trans_per_px: jax.Array
    R_g: jax.Array  # (T-1, 3, 3) the camera's relative poses, for the depth warp's and the scale's choices
    t_g: jax.Array  # (T-1, 3) pose units
    scale: jax.Array  # () s, units of D per pose unit
    present: jax.Array  # (T-1, 5) bool: the pair has the component (COMPONENTS' order)
    floors: jax.Array  # (4,) the clip's noise floors (FLOOR_COLUMNS' order), for an excess calibration
    depth_by_refit: jax.Array  # (T-1,) bool: the depth error is the camera's refit's warp's (§3.6 step 6)
    refit_fitted_on: jax.Array  # (T-1, P) bool: the points that refit is the least-squares fit of
    R_depth: jax.Array  # (T-1, 3, 3) the pose the depth check warped with, for the warp's choices
    t_depth: jax.Array  # (T-1, 3) units of D


def frozen_choices(pixel: dict, pose: dict, finish: dict, pair_valid, summary: dict) -> Frozen:
    """The stage outputs of B clips (leading axis B) and their summary (``scoring.summary.summarize_on_device``, whose
    noise floors they reuse) -> their Frozen (leading axis B)."""
    present = jnp.stack([pair_valid & ~jnp.isnan(finish[k]) for k in COMPONENTS], axis=-1)
    floors = jnp.stack([summary[name] for name in FLOOR_COLUMNS], axis=-1)
    return jax.lax.stop_gradient(Frozen(pixel["track_labels"], pose["track_fitted"], pose["region_status"],
                                        pose["R_local"], pose["t_local"], pose["region_rot_per_px"],
                                        pose["region_trans_per_px"], pose["R_g"], pose["t_g"],
                                        pose["scale"], present, floors, finish["depth_by_refit"],
                                        pose["refit_fitted_on"], finish["R_depth"], finish["t_depth"]))


def check_differentiable(config: SGCConfig) -> None:
    """The differentiable form is defined for the default semantics with a camera pose."""
    if config.compat != "spec" or not config.global_pose:
        raise ValueError("the differentiable score needs compat='spec' and global_pose=True "
                         f"(got compat={config.compat!r}, global_pose={config.global_pose})")


def camera_poses(R_wc, t_wc):
    """(R_g, t_g) of each pair (T-1, ...) from the cameras (T, ...), as ``global_relative_pose``
    under spec, the nearest rotation by ``polar_rotation``."""
    R_g = polar_rotation(R_wc[1:] @ jnp.swapaxes(R_wc[:-1], -1, -2))
    return R_g, resolved_translation(t_wc[1:] - jnp.einsum("pij,pj->pi", R_g, t_wc[:-1]), t_wc[:-1], t_wc[1:],
                                     xp=jnp)


def pair_points(clip: PaddedClips, track_labels, config: SGCConfig):
    """Every pair's tracks of frame i-1 back-projected (T-1, P, 3) and which have depth and a
    region (T-1, P) (the pose stage's points)."""
    pairs = clip.track_prev.shape[0]
    Z = jax.vmap(depth_at_tracks, in_axes=(None, 0, 0, None, None))(clip.depth, jnp.arange(pairs), clip.track_prev,
                                                                    clip.image_hw, config.track_pixel_offset)
    X = jax.vmap(back_project)(clip.K[:-1], clip.track_prev, Z)
    return X, clip.usable & clip.pair_valid[:, None] & (Z > 0) & (track_labels > 0)


def held_translation_scale(clip: PaddedClips, X, used, fixed: PaddedClips, frozen: Frozen, R_g, t_g,
                           config: SGCConfig):
    """s from the clip's points X, used (T-1, P, ...; ``pair_points``): the equation the forward
    weighted median chose (of the forward's equations, the one whose ratio lies nearest the forward
    s), recomputed; 0 where the forward s was held at 0; 1 / D where the scale is not fitted or had
    none."""
    fallback = 1.0 / clip.depth_unit
    if not config.fits_translation_scale:
        return fallback
    X_fixed, used_fixed = pair_points(fixed, frozen.track_labels, config)
    ratios, weights = jax.vmap(scale_equations)(X_fixed, used_fixed, fixed.K[1:], fixed.track_curr, frozen.R_g,
                                                frozen.t_g)
    chosen = jnp.argmin(jnp.where(weights > 0, jnp.abs(ratios - frozen.scale), jnp.inf).reshape(-1))
    ratios, _ = jax.vmap(scale_equations)(X, used, clip.K[1:], clip.track_curr, R_g, t_g)
    held = jnp.where(frozen.scale > 0, ratios.reshape(-1)[chosen], 0.0)
    return jnp.where(jnp.any(weights > 0), held, fallback)


def local_poses(clip: PaddedClips, X, frozen: Frozen):
    """Every region's pose (T-1, k, 3, 3), (T-1, k, 3), its least-squares optimum on the tracks it
    was fitted on (``least_squares_pose``); the identity where it was not accepted."""
    k = frozen.region_status.shape[-1]
    accepted = frozen.region_status == REGION_OK
    pose0 = jnp.concatenate([so3_log(frozen.R_local), frozen.t_local], axis=-1)
    pose0 = jnp.where(accepted[..., None] & jnp.isfinite(pose0), pose0, 0.0).astype(X.dtype)
    region = jnp.where(frozen.track_fitted, frozen.track_labels, 0)
    weight = (region[:, None, :] == jnp.arange(1, k + 1)[None, :, None]).astype(X.dtype)  # (T-1, k, P)

    def pair(pose0, X, uv, K, weight, accepted):
        return jax.vmap(least_squares_pose, in_axes=(0, None, None, None, 0, 0))(pose0, X, uv, K, weight, accepted)

    poses = jax.vmap(pair)(pose0, X, clip.track_curr, clip.K[1:], weight, accepted)
    return so3_exp(poses[..., :3]), poses[..., 3:], accepted


def depth_check_pose(clip: PaddedClips, X, frozen: Frozen, R_g, t_scaled):
    """Each pair's depth-check pose (T-1, 3, 3), (T-1, 3): the camera's (R_g, t_scaled), or where
    the forward pass warped with the camera's refit to the tracks (§3.6 step 6), that refit's
    least-squares optimum on the points it was fitted on (``least_squares_pose``)."""
    pose0 = jnp.concatenate([so3_log(frozen.R_depth), frozen.t_depth], axis=-1).astype(X.dtype)
    by_refit = frozen.depth_by_refit
    pose0 = jnp.where(by_refit[:, None] & jnp.isfinite(pose0), pose0, 0.0)
    refit = jax.vmap(least_squares_pose)(pose0, X, clip.track_curr, clip.K[1:],
                                         frozen.refit_fitted_on.astype(X.dtype), by_refit)
    return (jnp.where(by_refit[:, None, None], so3_exp(refit[:, :3]), R_g),
            jnp.where(by_refit[:, None], refit[:, 3:], t_scaled))


def held_warped_depth(depth_prev, K_prev, K_curr, R, t, source, depth_curr, comparable, *, at_point: bool):
    """(H W,) each pixel's warped depth with the nearest-z warp's winners held fixed (``source``
    (H W,) from ``warp_sources``): the z in camera i of the pixel of frame i-1 that won it; with
    ``at_point`` read at the pixel's centre on frame i's depth (``at_pixel_centre``; ``comparable``
    (H, W))."""
    H, W = depth_prev.shape
    source = jnp.minimum(source, H * W - 1)
    x, y, z = back_project_xyz(K_prev, (source % W).astype(depth_prev.dtype), (source // W).astype(depth_prev.dtype),
                               depth_prev.reshape(-1)[source])
    x, y, z = transform_xyz(R, t, x, y, z)
    if not at_point:
        return z
    front = z > MIN_WARP_Z
    u, v = project_xyz(K_curr, x, y, jnp.where(front, z, 1.0))
    return at_pixel_centre(u, v, z, front, depth_curr, comparable)


def held_warp_depth_error(depth_prev, depth_curr, K_prev, K_curr, R, t, source, hit, static_curr, landing, read, *,
                          at_point: bool):
    """One pair's depth error [% AbsRel] with the nearest-z warp's winners held fixed (``source``
    (H W,), ``hit`` (H, W) from ``warp_sources``), and the look back into frame i-1 where the
    forward pass read it (``read`` (H, W), at the held pixel ``landing`` (H, W) of frame i-1), up to
    the pair's depth map (``pair_depth_map``, §3.6 step 7)."""
    H, W = depth_prev.shape
    both = (hit & (depth_curr > 0) & static_curr).reshape(-1)
    warped = held_warped_depth(depth_prev, K_prev, K_curr, R, t, source, depth_curr, (depth_curr > 0) & static_curr,
                               at_point=at_point)
    target = jnp.where(both, depth_curr.reshape(-1), 1.0)
    scale, offset = pair_depth_map(warped.reshape(H, W), target.reshape(H, W), both.reshape(H, W), median=pixel_median)
    warped = scale * warped + offset
    error = jnp.abs(warped - target) / target
    # frame i's point in camera i-1: the depth row of R^T (X - t)
    x, y, z = back_project_xyz(K_curr, jnp.tile(jnp.arange(W, dtype=depth_curr.dtype), H),
                               jnp.repeat(jnp.arange(H, dtype=depth_curr.dtype), W), target)
    read = both & read.reshape(-1)
    z_back = jnp.where(read, R[0, 2] * (x - t[0]) + R[1, 2] * (y - t[1]) + R[2, 2] * (z - t[2]), 1.0)
    back = jnp.abs(scale * depth_prev.reshape(-1)[landing.reshape(-1)] + offset - z_back) / z_back
    error = jnp.where(both, jnp.where(read, jnp.minimum(error, back), error), 0.0)
    n = jnp.sum(both)
    return PERCENT * jnp.sum(error) / jnp.maximum(n, 1)


def clip_components(clip: PaddedClips, fixed: PaddedClips, frozen: Frozen, config: SGCConfig) -> dict:
    """One padded clip's per-pair components (T-1,) in the units of docs/semantics.md §4; ``fixed``:
    the forward pass's padded clip, on which the depth warp's and the scale's choices are made."""
    R_g, t_g = camera_poses(clip.R_wc, clip.t_wc)
    X, used = pair_points(clip, frozen.track_labels, config)
    t_scaled = held_translation_scale(clip, X, used, fixed, frozen, R_g, t_g, config) * t_g
    R_local, t_local, accepted = local_poses(clip, X, frozen)
    comps = jax.vmap(pair_pose_components)(R_local, t_local, accepted, R_g, t_scaled, frozen.rot_per_px,
                                           frozen.trans_per_px)
    R_depth, t_depth = depth_check_pose(clip, X, frozen, R_g, t_scaled)
    frames = (fixed.depth[:-1], (fixed.depth[:-1] > 0) & fixed.static[:-1], fixed.K[:-1], fixed.K[1:], frozen.R_depth,
              frozen.t_depth)
    compared_curr = (fixed.depth[1:], (fixed.depth[1:] > 0) & fixed.static[1:])
    at_point = config.depth_at_point

    def warp_all(magnified: bool):
        def one(*pair):
            return warp_sources(*pair[:6], mask_holes=True, magnified=magnified,
                                at_point=pair[6:] if at_point else None)

        return jax.vmap(one)(*frames, *compared_curr)

    # the hole rule's larger squares only for a clip with a surface coming 2x nearer (the forward's
    # choice, padded pairs no part of it)
    magnified = jnp.any(jax.vmap(has_magnified)(*frames) & fixed.pair_valid)
    source, hit = jax.lax.cond(magnified, lambda: warp_all(True), lambda: warp_all(False))
    view = jax.vmap(previous_view, in_axes=(0, 0, 0, 0, 0, 0, None))(
        fixed.depth[1:], fixed.depth[1:] > 0, fixed.K[:-1], fixed.K[1:], frozen.R_depth, frozen.t_depth, fixed.image_hw)
    at_landing = jax.vmap(depth_at_landing)(*frames[:2], view)
    # where the forward pass looked frame i-1 up (``looked_back_depth``) and what it left out as
    # frame i-1's occlusions are held too
    warped = jax.vmap(functools.partial(held_warped_depth, at_point=at_point))(
        fixed.depth[:-1], fixed.K[:-1], fixed.K[1:], frozen.R_depth, frozen.t_depth, source, *compared_curr)
    warped = warped.reshape(hit.shape)
    occluded = jax.vmap(occluded_in_previous)(warped, fixed.depth[1:], view, at_landing)
    hit = hit & (at_landing > 0) & ~occluded  # seen, on a pixel frame i-1 warped, not behind a nearer surface
    compared = hit & (fixed.depth[1:] > 0) & fixed.static[1:]
    read = jax.vmap(looked_back_depth)(warped, compared, fixed.depth[1:], at_landing) > 0
    errors = jax.vmap(functools.partial(held_warp_depth_error, at_point=at_point))(
        clip.depth[:-1], clip.depth[1:], clip.K[:-1], clip.K[1:], R_depth, t_depth, source, hit, fixed.static[1:],
        view.landing, read)
    return dict(local_rot_var=comps["local_rot_var"], local_trans_var=comps["local_trans_var"] * PERCENT**2,
                global_rot_var=comps["global_rot_var"], global_trans_var=comps["global_trans_var"] * PERCENT**2,
                depth_error=errors)


def smooth_components(clip: ClipArrays, frozen: Frozen, bucket: Bucket, config: SGCConfig) -> tuple[dict, dict]:
    """One clip (no B axis) -> (its components (), each the mean over the pairs that have it; whether
    it has any ()), differentiable."""
    per_pair = clip_components(*prepare_differentiable(clip, bucket, config), frozen, config)
    components = {name: nanmean(per_pair[name], frozen.present[:, i], jnp) for i, name in enumerate(COMPONENTS)}
    return components, {name: jnp.any(frozen.present[:, i]) for i, name in enumerate(COMPONENTS)}


def smooth_stage(clips: ClipArrays, frozen: Frozen, bucket: Bucket, config: SGCConfig,
                 calibration: Calibration):
    """B clips (leading axis B) and their Frozen -> sgc_smooth (B,) (``sgc_smooth_score`` of
    ``smooth_components``)."""
    check_differentiable(config)

    def one(clip, choices):
        floors = {name: choices.floors[i] for i, name in enumerate(FLOOR_COLUMNS)}
        return sgc_smooth_score(*smooth_components(clip, choices, bucket, config), calibration, xp=jnp, floors=floors)

    return jax.vmap(one)(clips, frozen)
