"""The pose stage (docs/semantics.md §3.2 steps 3-7, §3.3, §3.4): every pair's local poses, the
camera's relative poses and the clip's translation scale."""

from __future__ import annotations

import functools
from typing import Any, ClassVar, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp

from ...codes import REGION_EMPTY, REGION_OK
from ...config import NOISE_BLOCK_FRAC, SGCConfig
from ...kernels.camera import back_project
from ...kernels.depth_pose import CameraRefit, refit_camera
from ...kernels.pose_variances import mean_pose
from ...kernels.ransac import ransac_pnp_regions
from ...kernels.ransac_options import QualityRule, RansacOptions
from ...kernels.scale import robust_scale, scale_equations
from ...kernels.so3 import nearest_rotation
from ...kernels.uncertainty import region_quality
from ..units import resolved_translation
from .buckets import Bucket, PaddedClips
from .stages import CPU_COMPILER_OPTIONS, PoseInputs, Stage, as_float, as_int, each

# Pairs posed at once (vmapped), at most: every loop of a vmapped group runs until its slowest pair
# is done, and fewer than ~4 pay more per-op overhead than they save (bench/history/issue-21.md,
# "Fewer pairs in lockstep").
PAIRS_AT_ONCE = 5


class LocalPoses(NamedTuple):
    """A pair's regions and their poses (k region slots)."""

    R_local: jax.Array  # (k, 3, 3)
    t_local: jax.Array  # (k, 3) units of D
    region_status: jax.Array  # (k,) int32, codes.REGION_STATUS
    region_points: jax.Array  # (k,) int32
    region_reproj: jax.Array  # (k,) px
    region_rot_std: jax.Array  # (k,) deg, RMS rotation uncertainty
    region_trans_std: jax.Array  # (k,) units of D
    region_rot_noise: jax.Array  # (k,) deg, the RMS rotation error the noise floors count
    region_trans_noise: jax.Array  # (k,) units of D
    region_sigma_px: jax.Array  # (k,) px, the residual sigma of its fit's inliers
    region_rot_per_px: jax.Array  # (k,) deg / px, RMS rotation error per px of tracking error: its weight's geometry
    region_trans_per_px: jax.Array  # (k,) units of D / px
    n_tracks: jax.Array  # () usable tracks
    n_regions: jax.Array  # ()
    region_pixels: jax.Array  # () pixels of S_i
    track_fitted: jax.Array  # (P,) bool: the tracks its region's pose is the least-squares fit of


class PairInputs(NamedTuple):
    """One pair's share of the pose stage's inputs (frames i-1 -> i)."""

    Z_prev: jax.Array  # (P,) depth of frame i-1 at the tracks
    track_label: jax.Array  # (P,) region of each track in the region frame (§3.2 step 5)
    n_regions: jax.Array  # ()
    region_pixels: jax.Array  # ()
    K_prev: jax.Array  # (3, 3)
    K_curr: jax.Array
    track_prev: jax.Array  # (P, 2)
    track_curr: jax.Array
    usable: jax.Array  # (P,) bool
    key: jax.Array  # RANSAC's key of the pair
    rival_R: jax.Array  # (3, 3) R_g, the identity without a global pose
    global_t: jax.Array | None  # (3,) s t_g in units of D; None without a global pose


def points_prev(Z, K_prev, track_prev, usable):
    """Tracks (P, 2) of frame i-1 back-projected at their pixel's depth Z (P,) -> (X (P, 3) in
    camera i-1, usable with depth > 0 (P,))."""
    return back_project(K_prev, track_prev, Z), usable & (Z > 0)


def local_poses_pair(pair: PairInputs, image_hw, stage: PoseStage) -> LocalPoses:
    """One pair's local poses, then the region-quality rule where the config applies it."""
    H, W = image_hw[0], image_hw[1]
    X, has_depth = points_prev(pair.Z_prev, pair.K_prev, pair.track_prev, pair.usable)
    n_tracks = jnp.sum(pair.usable)
    enough_tracks = n_tracks >= 4
    regions = jnp.arange(1, stage.k_seg + 1)
    point_region = jnp.where(has_depth, pair.track_label, 0)
    point_region = jnp.where((point_region <= pair.n_regions) & enough_tracks, point_region, 0)
    keys = jax.vmap(lambda r: jax.random.fold_in(pair.key, r))(regions)
    diagonal = jnp.hypot(H.astype(X.dtype), W.astype(X.dtype))
    fit = ransac_pnp_regions(X, pair.track_curr, point_region, pair.K_curr, keys, stage.ransac,
                             pair.rival_R, global_t=pair.global_t, noise_block_px=NOISE_BLOCK_FRAC * diagonal)
    status = jnp.where((regions <= pair.n_regions) & enough_tracks, fit.status, REGION_EMPTY)
    nan = jnp.full(stage.k_seg, jnp.nan, X.dtype)
    rot_noise, trans_noise = nan, nan  # no floors under compat="authors"
    if stage.compat != "authors":  # the rule is never applied there; on or off is a value, one program for both
        focal = 0.5 * (pair.K_curr[0, 0] + pair.K_curr[1, 1])
        judged = region_quality(status, fit.n_inliers, fit.uncertainty, fit.ambiguous, diagonal, focal,
                                stage.quality)
        status = jnp.where(stage.quality_rule != 0, judged, status)
        rot_noise, trans_noise = fit.uncertainty.rot_noise_deg, fit.uncertainty.trans_noise
    return LocalPoses(fit.R, fit.t, status.astype(jnp.int32), fit.n_members, fit.reproj_px,
                      fit.uncertainty.rot_std_deg, fit.uncertainty.trans_std, rot_noise, trans_noise,
                      fit.uncertainty.sigma_px, fit.uncertainty.rot_per_px_deg, fit.uncertainty.trans_per_px,
                      n_tracks.astype(jnp.int32), pair.n_regions.astype(jnp.int32),
                      pair.region_pixels, fit.fitted)


def global_relative_pose(R_prev, t_prev, R_curr, t_curr, compat: str):
    """(R_g, t_g) from camera i-1 to camera i; authors: t from the raw product; spec: t_g within
    float32's resolution of the cameras is 0 (``resolved_translation``)."""
    product = R_curr @ R_prev.T
    R_g = nearest_rotation(product)
    if compat == "authors":
        return R_g, t_curr - product @ t_prev
    return R_g, resolved_translation(t_curr - R_g @ t_prev, t_prev, t_curr, xp=jnp)


def pair_groups(pose_pair, args, n_pairs: int, vectorized: bool):
    """``pose_pair`` over the pairs (leading axis n_pairs of every leaf of ``args``): all at once
    in a vectorized program, else vmapped in ceil(n_pairs / PAIRS_AT_ONCE) equal groups one after
    another, the last group filled with copies of the last pair, whose results are dropped."""
    groups = -(-n_pairs // PAIRS_AT_ONCE)
    if groups <= 1 or vectorized:
        return jax.vmap(pose_pair)(args)
    size = -(-n_pairs // groups)
    pair = jnp.minimum(jnp.arange(groups * size), n_pairs - 1)
    grouped = jax.tree.map(lambda a: a[pair].reshape((groups, size) + a.shape[1:]), args)
    out = jax.lax.map(jax.vmap(pose_pair), grouped)
    return jax.tree.map(lambda a: a.reshape((groups * size,) + a.shape[2:])[:n_pairs], out)


def translation_scale(x: PoseInputs, usable, R_g, t_g, stage: PoseStage):
    """s (units of D per pose unit): the robust weighted median of every pair's scale equations
    (``robust_scale``, cut at RANSAC's inlier_px), or 1 / D (the units taken as shared) where it is
    not fitted or undefined."""
    scale = 1.0 / x.depth_unit
    if not stage.fits_translation_scale:
        return scale

    def equations(Z_prev, label, K_prev, K_curr, track_prev, track_curr, usable, R_g, t_g):
        X, has_depth = points_prev(Z_prev, K_prev, track_prev, usable)
        return scale_equations(X, has_depth & (label > 0), K_curr, track_curr, R_g, t_g)

    ratios, weights = jax.vmap(equations)(x.Z_prev, x.track_labels, x.K[:-1], x.K[1:], x.track_prev, x.track_curr,
                                          usable, R_g, t_g)
    return robust_scale(ratios, weights, stage.ransac.inlier_px, fallback=scale)


def camera_refits(x: PoseInputs, poses: LocalPoses, usable, R_g, t_g, stage: PoseStage) -> CameraRefit:
    """Per pair (T-1, ...) of one clip: the camera's pose (t_g in units of D) refitted to the points
    of its regions and whether that refit also warps the depth check (``refit_camera``, at RANSAC's
    inlier_px; only in pairs with an accepted local pose; §3.6 step 6)."""
    def pair(has_pose, Z_prev, label, K_prev, K_curr, track_prev, track_curr, usable, R_g, t_g):
        X, has_depth = points_prev(Z_prev, K_prev, track_prev, usable)
        return refit_camera(X, track_curr, has_depth & (label > 0), K_curr, R_g, t_g, has_pose,
                            stage.ransac.inlier_px)

    has_pose = jnp.any(poses.region_status == REGION_OK, axis=-1)
    return jax.vmap(pair)(has_pose, x.Z_prev, x.track_labels, x.K[:-1], x.K[1:], x.track_prev, x.track_curr, usable,
                          R_g, t_g)


def no_refit(R_g, t_g, usable) -> CameraRefit:
    """Per pair: the camera's pose unchanged, nothing refitted, no tracks' motion (NaN)."""
    n_pairs = R_g.shape[0]
    nan = jnp.full(n_pairs, jnp.nan, R_g.dtype)
    return CameraRefit(R_g, t_g, jnp.zeros(n_pairs, bool), jnp.zeros_like(usable), nan, nan)


def clip_poses(x: PoseInputs, key, stage: PoseStage):
    """One padded clip (no B axis) -> (LocalPoses (T-1, ...), R_g (T-1, 3, 3), t_g (T-1, 3), s, and
    per pair the camera's refit to its tracks, CameraRefit (T-1, ...)).
    Without a global pose each pair's mean local pose (NaN without one) stands for the camera's."""
    n_pairs = x.pair_valid.shape[0]
    pair_keys = jax.vmap(lambda p: jax.random.fold_in(key, p))(jnp.arange(n_pairs) + 1)
    usable = x.usable & x.pair_valid[:, None]
    if stage.global_pose:
        R_g, t_g = jax.vmap(functools.partial(global_relative_pose, compat=stage.compat))(
            x.R_wc[:-1], x.t_wc[:-1], x.R_wc[1:], x.t_wc[1:])
        # the rivals' rotation (docs/semantics.md §3.3): the camera's, the identity where it is not finite
        rival_R = jnp.where(jnp.all(jnp.isfinite(R_g), axis=(1, 2))[:, None, None], R_g, jnp.eye(3, dtype=R_g.dtype))
        # s does not depend on the local poses, which start from the camera's pose (R_g, s t_g)
        scale = translation_scale(x, usable, R_g, t_g, stage)
        global_t = scale * t_g
    else:
        rival_R = jnp.broadcast_to(jnp.eye(3, dtype=x.K.dtype), (n_pairs, 3, 3))
        global_t = None  # no camera start (an empty pytree under vmap)
    pairs = PairInputs(x.Z_prev, x.track_labels, x.n_regions, x.region_pixels, x.K[:-1], x.K[1:], x.track_prev,
                       x.track_curr, usable, pair_keys, rival_R, global_t)
    poses = pair_groups(lambda pair: local_poses_pair(pair, x.image_hw, stage), pairs, n_pairs, stage.vectorized)
    if not stage.global_pose:
        R_g, t_g = jax.vmap(mean_pose)(poses.R_local, poses.t_local, poses.region_status == REGION_OK)
        return poses, R_g, t_g, jnp.float32(1.0), no_refit(R_g, t_g, usable)
    if stage.compat == "authors":  # the camera alone warps there
        return poses, R_g, t_g, scale, no_refit(R_g, global_t, usable)
    return poses, R_g, t_g, scale, camera_refits(x, poses, usable, R_g, global_t, stage)


class PoseStage(Stage):
    """Every pair's local poses, the camera's relative poses and the clip's translation scale
    (``pose_stage``)."""

    name: ClassVar[str] = "pose"
    # XLA CPU's YNNPACK fusions run this stage's many small reductions slower than its own loops
    # (~175 against ~220 ms per standard clip, bench/history/issue-21.md, "The pose stage without
    # YNNPACK fusions")
    cpu_compiler_options: ClassVar[dict[str, str]] = {**CPU_COMPILER_OPTIONS, "xla_cpu_experimental_ynn_fusion_type": ""}
    k_seg: int = eqx.field(static=True)
    compat: str = eqx.field(static=True)
    global_pose: bool = eqx.field(static=True)
    fits_translation_scale: bool = eqx.field(static=True)
    vectorized: bool = eqx.field(static=True)
    ransac: RansacOptions
    quality: QualityRule
    quality_rule: Any  # int32 (): the region-quality rule on (1) or off (0), one program for both

    @classmethod
    def of(cls, config: SGCConfig, vectorized: bool = False) -> PoseStage:
        ransac = RansacOptions(
            inlier_px=as_float(config.inlier_px), min_inlier_frac=as_float(config.min_inlier_frac),
            min_points=as_int(config.min_points), confidence=as_float(config.confidence),
            ambiguous_rot_deg=as_float(config.ambiguous_rot_deg),
            ambiguous_inlier_frac=as_float(config.ambiguous_inlier_frac),
            hypotheses=config.ransac_hypotheses, lm_steps=config.lm_steps, borrow=config.borrow_region_poses)
        quality = QualityRule(
            min_region_points=as_int(config.min_region_points), max_rot_std_deg=as_float(config.max_rot_std_deg),
            max_rot_std_px=as_float(config.max_rot_std_px), min_region_extent=as_float(config.min_region_extent),
            quality_noise_px=as_float(config.quality_noise_px))
        return cls(k_seg=config.k_seg, compat=config.compat, global_pose=config.global_pose,
                   fits_translation_scale=config.fits_translation_scale, vectorized=vectorized, ransac=ransac,
                   quality=quality, quality_rule=as_int(config.quality_rule))

    def sizes(self, bucket: Bucket) -> tuple[int, ...]:
        return bucket.T, bucket.P

    def inputs(self, batch: PaddedClips, previous: dict | None) -> tuple:
        return tuple(PoseInputs(previous["Z_prev"], previous["track_labels"], previous["n_regions"],
                                previous["region_pixels"], batch.K, batch.R_wc, batch.t_wc, batch.track_prev,
                                batch.track_curr, batch.usable, batch.pair_valid, batch.image_hw, batch.depth_unit))

    def __call__(self, inputs: tuple, key) -> dict:
        return pose_stage(PoseInputs(*inputs), key, self)


def pose_stage(x: PoseInputs, key, stage: PoseStage) -> dict:
    """Clips (leading axis B). On CPU one after another, each clip's pairs in groups of at most
    PAIRS_AT_ONCE: RANSAC's loops run until their slowest lane is done, so vmapping many pairs at
    once costs more than it saves there. Vectorized (accelerators): every pair of every clip at once."""
    poses, R_g, t_g, scale, refit = each(lambda clip: clip_poses(PoseInputs(*clip), key, stage), tuple(x),
                                         stage.vectorized)
    return dict(poses._asdict(), R_g=R_g, t_g=t_g, scale=scale, R_refit=refit.R, t_refit=refit.t,
                refit_gate=refit.warps, refit_fitted_on=refit.fitted_on, tracks_rot_deg=refit.tracks_rot_deg,
                tracks_trans=refit.tracks_trans)
