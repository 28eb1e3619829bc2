"""The finish stage (docs/semantics.md §3.5-3.7): every pair's depth error and pose components,
from the pose stage's output."""

from __future__ import annotations

import functools
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp

from ...codes import EXCLUDED_STATUSES, PAIR_REASON_CODE, REGION_OK
from ...config import SGCConfig
from ...kernels.pose_variances import pair_pose_components
from ...kernels.so3 import rotation_angle_deg
from ...kernels.warp import depth_error, has_magnified, spec_depth_error, warp_depth
from ..units import translation_factor
from .buckets import Bucket, PaddedClips
from .pixel_stage import frames_in_place, pairs_flat
from .pose_stage import LocalPoses
from .stages import POSE_PER_TRACK, Stage, each


def pair_frames(depth, static, previous):
    """(depth_prev, static_prev, depth_curr, static_curr) (H, W) of the pair whose frame i-1 is
    ``previous`` (an index into the frames (n, H, W)), read by index: no stack of pairs is copied."""
    at = lambda stack, i: jax.lax.dynamic_index_in_dim(stack, i, keepdims=False)  # noqa: E731
    return at(depth, previous), at(static, previous), at(depth, previous + 1), at(static, previous + 1)


def warp_source(depth, static, previous, authors: bool):
    """Frame i-1's depth (H, W) and the pixels the warp moves (H, W): every valid one under
    authors, the static valid ones under spec."""
    depth_prev, static_prev = pair_frames(depth, static, previous)[:2]
    return depth_prev, depth_prev > 0 if authors else (depth_prev > 0) & static_prev


def has_magnified_surface(depth, static, pairs, pair_valid, vectorized: bool):
    """() bool under spec, for a batch of pairs (``pair_depth_errors``'s frames and pairs): whether
    any pair has a surface coming 2x nearer (the hole rule's larger squares). A padded pair
    (``pair_valid`` False) is no part of it: the last frame warped by a padded frame's camera could
    ask for them, and they cost every pair of the batch."""
    def needs(pair_valid):
        pair, valid = pair_valid
        return valid & has_magnified(*warp_source(depth, static, pair[0], authors=False), *pair[1:5])

    return jnp.any(each(needs, (pairs, pair_valid), vectorized))


def pair_depth_errors(depth, static, previous, K_prev, K_curr, R_g, t_g, image_hw, pair_valid, stage: FinishStage,
                      active=None):
    """Frames (n, H, W) of depth and static masks, each pair's frame i-1 as an index into them
    (F,) int32 (frame i is the next), the pairs' (F, ...) cameras and true sizes, and which pairs
    are the clip's, not padding (F,) bool -> depth errors (F,); with ``active`` (F,) bool only those
    pairs' (the others NaN; a CPU program skips their work). Under spec the static valid pixels
    of frame i-1 warped (AbsRel in %) and compared where frame i-1 could see (within the true size
    ``image_hw`` (F, 2), on a pixel it warped, not behind a nearer surface), looked up in frame i-1
    where the warp put a surface 10x farther (``spec_depth_error``);
    under authors every valid one (depth units). One pair at a time on CPU, for the unbatched
    z-buffer scatter."""
    authors = stage.compat == "authors"
    skips = active is not None and not stage.vectorized
    active = jnp.ones_like(pair_valid) if active is None else active
    pairs = (previous, K_prev, K_curr, R_g, t_g, image_hw, active)

    def compared_frame(previous):  # frame i's depth and the pixels it is compared on, for a read at the point
        depth_curr, static_curr = pair_frames(depth, static, previous)[2:]
        return (depth_curr, (depth_curr > 0) & static_curr) if stage.depth_at_point else None

    def only_active(compute, pair, skipped):  # each pair alone on a CPU: the inactive ones cost nothing
        return jax.lax.cond(pair[6], compute, lambda: skipped) if skips else compute()

    def warps(magnified: bool):  # the warped depth alone: a pixel is hit where it is > 0 (z > MIN_WARP_Z)
        def one(pair):
            return only_active(lambda: warp_depth(*warp_source(depth, static, pair[0], authors), *pair[1:5],
                                                  nearest=not authors, mask_holes=not authors,
                                                  magnified=magnified, at_point=compared_frame(pair[0]))[0],
                               pair, jnp.zeros(depth.shape[1:], depth.dtype))

        return each(one, pairs, stage.vectorized)

    def errors_of(warped):
        def one(pair_warp):
            return only_active(lambda: error_of(*pair_warp), pair_warp[0], jnp.full((), jnp.nan, depth.dtype))

        def error_of(pair, warped):
            _, _, depth_curr, static_curr = pair_frames(depth, static, pair[0])
            hit = warped > 0
            valid = depth_curr > 0
            if authors:
                return depth_error(warped, hit, depth_curr, valid, static_curr, relative=stage.scale_free)[0]
            return spec_depth_error(warped, hit, depth_curr, valid, static_curr,
                                    warp_source(depth, static, pair[0], authors), *pair[1:6],
                                    relative=stage.scale_free)[0]

        return each(one, (pairs, warped), stage.vectorized)

    if authors:
        errors = errors_of(warps(False))
    else:
        magnified = has_magnified_surface(depth, static, pairs[:6], pair_valid & active, stage.vectorized)
        errors = errors_of(jax.lax.cond(magnified, lambda: warps(True), lambda: warps(False)))
    return jnp.where(active, errors, jnp.nan) * translation_factor(stage)


def depth_errors_checked(depth, static, previous, K_prev, K_curr, R_g, t_g, image_hw, pair_valid, refit,
                         stage: FinishStage):
    """``pair_depth_errors`` with the camera's poses, and under spec, for the pairs where the pose
    stage found the camera fits their tracks worse than its refit to them (``refit``: R (F, 3, 3),
    t (F, 3), gate (F,) bool; ``kernels.depth_pose.refit_camera``), the lesser of that and the
    error warped with the refit (docs/semantics.md §3.6 step 6) -> (errors (F,), whether the refit
    gave it (F,) bool, the pose each error was warped with (F, 3, 3), (F, 3))."""
    errors = pair_depth_errors(depth, static, previous, K_prev, K_curr, R_g, t_g, image_hw, pair_valid, stage)
    if stage.compat == "authors" or not stage.global_pose:
        return errors, jnp.zeros_like(pair_valid), R_g, t_g
    R_refit, t_refit, refit_gate = refit
    R_refit = jnp.where(refit_gate[:, None, None], R_refit, R_g)  # finite wherever it is read
    t_refit = jnp.where(refit_gate[:, None], t_refit, t_g)
    by_refit = jax.lax.cond(
        jnp.any(refit_gate),
        lambda: pair_depth_errors(depth, static, previous, K_prev, K_curr, R_refit, t_refit, image_hw, pair_valid,
                                  stage, active=refit_gate),
        lambda: jnp.full_like(errors, jnp.nan))
    refit_lower = refit_gate & ((by_refit < errors) | (jnp.isnan(errors) & ~jnp.isnan(by_refit)))
    return (jnp.where(refit_lower, by_refit, errors), refit_lower,
            jnp.where(refit_lower[:, None, None], R_refit, R_g), jnp.where(refit_lower[:, None], t_refit, t_g))


def pair_components(poses: LocalPoses, R_g, t_g, err, stage: FinishStage) -> dict:
    """One pair's pose variances, diagnostics and reason code; ``err`` its depth error."""
    accepted = poses.region_status == REGION_OK
    comps = pair_pose_components(poses.R_local, poses.t_local, accepted, R_g, t_g, poses.region_rot_per_px,
                                 poses.region_trans_per_px, compat=stage.compat)
    f2 = translation_factor(stage) ** 2
    if not stage.global_pose:  # the mean local pose is no independent reference
        comps["global_rot_var"] = comps["global_trans_var"] = jnp.float32(jnp.nan)
    n_poses = jnp.sum(accepted)
    excluded = jnp.any(poses.region_status[..., None] == jnp.asarray(EXCLUDED_STATUSES, poses.region_status.dtype),
                       axis=-1)
    n_excluded = jnp.sum(excluded)
    reproj = jnp.sum(jnp.where(accepted, poses.region_reproj, 0.0)) / jnp.maximum(n_poses, 1)
    one_pose = (n_poses == 1) & (stage.compat != "authors")
    reason = jnp.select(
        [poses.n_tracks < 4, poses.region_pixels == 0, poses.n_regions == 0, (n_poses == 0) & (n_excluded > 0),
         n_poses == 0, one_pose, jnp.isnan(err)],
        [PAIR_REASON_CODE[r] for r in ("too_few_tracks", "no_static", "no_region", "ill_conditioned", "no_pose",
                                       "one_pose", "no_depth_overlap")],
        PAIR_REASON_CODE["ok"])
    return dict(
        local_rot_var=comps["local_rot_var"], local_trans_var=comps["local_trans_var"] * f2,
        global_rot_var=comps["global_rot_var"], global_trans_var=comps["global_trans_var"] * f2,
        depth_error=err, reproj_error=jnp.where(n_poses > 0, reproj, jnp.nan), n_poses=n_poses.astype(jnp.int32),
        n_ill_conditioned=n_excluded.astype(jnp.int32),
        R_g_angle_deg=rotation_angle_deg(jnp.eye(3, dtype=R_g.dtype), R_g),
        reason=reason.astype(jnp.int32))


class FinishStage(Stage):
    """Every pair's depth error and pose components (``finish_stage``)."""

    name: ClassVar[str] = "finish"
    k_seg: int = eqx.field(static=True)  # the region slots of its inputs
    compat: str = eqx.field(static=True)
    scale_free: bool = eqx.field(static=True)
    global_pose: bool = eqx.field(static=True)
    vectorized: bool = eqx.field(static=True)
    depth_at_point: bool = eqx.field(static=True, default=False)  # SGCConfig.depth_at_point

    @classmethod
    def of(cls, config: SGCConfig, vectorized: bool = False) -> FinishStage:
        return cls(k_seg=config.k_seg, compat=config.compat, scale_free=config.scale_free,
                   global_pose=config.global_pose, vectorized=vectorized, depth_at_point=config.depth_at_point)

    def sizes(self, bucket: Bucket) -> tuple[int, ...]:
        return bucket.T, bucket.H, bucket.W

    def inputs(self, batch: PaddedClips, previous: dict | None) -> tuple:
        regions = {name: value for name, value in previous.items() if name not in POSE_PER_TRACK}
        return (regions, batch.depth, batch.static, batch.K, batch.image_hw, batch.pair_valid)

    def __call__(self, inputs: tuple, key) -> dict:
        return finish_stage(*inputs, self)


def finish_stage(pose: dict, depth, static, K, image_hw, pair_valid, stage: FinishStage) -> dict:
    """The pose stage's per-region output and the clips' depth (B, T, H, W), masks, K, true sizes
    (B, 2) and the pairs that are not padding (B, T-1) -> per-clip, per-pair and per-region arrays
    (leading axes B, T-1)."""
    B, T = depth.shape[:2]
    flat, unflat = pairs_flat(B, T)
    regions = {name: pose[name] for name in LocalPoses._fields if name not in POSE_PER_TRACK}
    # FinishStage.inputs keeps the per-track fields back
    poses = LocalPoses(**regions, **dict.fromkeys(name for name in LocalPoses._fields if name in POSE_PER_TRACK))
    R_g, t_g, scale = pose["R_g"], pose["t_g"], pose["scale"]
    t_g_scaled = scale[:, None, None] * t_g
    (depth_frames, static_frames), previous = frames_in_place(depth, static)
    pairs = (depth_frames, static_frames, previous, flat(K[:, :-1]), flat(K[:, 1:]), flat(R_g), flat(t_g_scaled),
             flat(jnp.repeat(image_hw[:, None], T - 1, axis=1)), flat(pair_valid))
    refit = (flat(pose["R_refit"]), flat(pose["t_refit"]), flat(pose["refit_gate"]))
    checked = depth_errors_checked(*pairs, refit, stage)
    err, depth_by_refit, R_depth, t_depth = (unflat(x) for x in checked)
    comps = jax.vmap(jax.vmap(functools.partial(pair_components, stage=stage)))(poses, R_g, t_g_scaled, err)
    # ECD's input: the camera's translation in the reported unit (s t_g in % of D under spec, raw t_g under authors)
    t_g_ecd = t_g_scaled if stage.scale_free else t_g
    comps["t_g_norm"] = jnp.linalg.norm(t_g_ecd, axis=-1) * translation_factor(stage)
    # the motion the tracks show (§3.11), in the camera's units: [deg] and % of D
    comps["tracks_rot_deg"], comps["tracks_trans"] = pose["tracks_rot_deg"], pose["tracks_trans"] * translation_factor(stage)
    # which pose each depth error was warped with, for sgc_smooth's held choices
    return dict(comps, **regions, scale=scale, depth_by_refit=depth_by_refit, R_depth=R_depth, t_depth=t_depth)
