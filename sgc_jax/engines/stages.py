"""The traced computation of the JAX engine (docs/semantics.md §3, §7.1): each stage as a function
of padded arrays with static shapes and validity masks. ``vmap`` lifts the pose kernels over the
pairs of a clip, ``lax.map`` runs clips, and the pixel kernels (regions, depth warp) over all frames
of a bucket, one at a time, where batching costs more on CPU than it saves. Padding (extra frames,
tracks, pixels) is marked invalid and never changes a clip's numbers. Imported only to trace
(``jax_engine`` loads kept programs without it).
"""

from __future__ import annotations

import functools
from typing import Any, Mapping, NamedTuple

import jax
import jax.numpy as jnp

from ..codes import EXCLUDED_STATUSES, PAIR_REASON_CODE, REGION_EMPTY, REGION_OK
from ..config import STATIC_FIELDS, SGCConfig
from ..kernels.components import mean_pose, pair_pose_components
from ..kernels.geometry import back_project, nearest_rotation, rotation_angle_deg
from ..kernels.kmeans import depth_partition, depth_regions, grid_regions, kmeans_1d, region_of_depth
from ..kernels.partition import spatial_regions
from ..kernels.ransac import ransac_pnp_regions
from ..kernels.uncertainty import region_quality
from ..kernels.warp import depth_error, warp_depth
from .buckets import STAGE_FIELDS, STAGES, PaddedClips, PixelInputs, PoseInputs, stage_inputs
from .units import PERCENT, translation_factor

class LocalPoses(NamedTuple):
    """Stage A of a pair: regions and their PnP-RANSAC poses (k region slots)."""

    R_local: jax.Array  # (k, 3, 3)
    t_local: jax.Array  # (k, 3)
    region_status: jax.Array  # (k,) int32, codes.REGION_STATUS
    region_points: jax.Array  # (k,) int32
    region_reproj: jax.Array  # (k,) px
    region_rot_std: jax.Array  # (k,) deg, RMS rotation uncertainty of the pose
    region_trans_std: jax.Array  # (k,) depth units
    n_tracks: jax.Array  # () usable tracks
    n_regions: jax.Array  # ()
    region_pixels: jax.Array  # () pixels of S_i


def _pair_regions(depth_curr, region_mask, config: SGCConfig):
    if config.partition == "grid":
        return grid_regions(region_mask, k=config.k_seg, min_region_pixels=config.min_region_pixels)
    if config.partition == "depth":
        return depth_regions(depth_curr, region_mask, k=config.k_seg, bins=config.kmeans_bins,
                             min_region_pixels=config.min_region_pixels)
    cluster = kmeans_1d(depth_curr.reshape(-1), region_mask.reshape(-1), k=config.k_seg, bins=config.kmeans_bins)
    return spatial_regions(cluster.reshape(depth_curr.shape), k=config.k_seg,
                           min_region_pixels=config.min_region_pixels)


def frame_regions(depth_curr, static_curr, track_curr, image_hw, config: SGCConfig):
    """docs/semantics.md §3.2 steps 1-2 and 5 for frames i (F, H, W), their pairs' points in them (F, P, 2) and
    true image sizes (F, 2) -> (region at each point's floor pixel (F, P) int32, 0 = none or
    outside the image; N_s (F,); |S_i| (F,)).

    Scatter-heavy pixel work one frame at a time (``lax.map``): unbatched scatters run several
    times faster on CPU than one batched scatter over all frames. The depth partition labels only
    the points, from its per-bin regions, never whole label maps.
    """
    region_mask = static_curr if config.compat == "authors" else static_curr & (depth_curr > 0)
    H_pad, W_pad = depth_curr.shape[1:]
    col, row = jnp.floor(track_curr[..., 0]).astype(jnp.int32), jnp.floor(track_curr[..., 1]).astype(jnp.int32)
    inside = (col >= 0) & (col < image_hw[:, 1:]) & (row >= 0) & (row < image_hw[:, :1])
    pixel = jnp.clip(row, 0, H_pad - 1) * W_pad + jnp.clip(col, 0, W_pad - 1)  # (F, P)
    at_points = jax.vmap(lambda image, p: image.reshape(-1)[p])
    if config.partition == "depth":
        partition = depth_partition(depth_curr, region_mask, k=config.k_seg, bins=config.kmeans_bins,
                                    min_region_pixels=config.min_region_pixels)
        labels = jax.vmap(region_of_depth)(partition, at_points(depth_curr, pixel), at_points(region_mask, pixel))
        n_regions = partition.n_regions
    else:
        labels, n_regions = jax.lax.map(lambda frame: _pair_regions(*frame, config), (depth_curr, region_mask))
        labels = at_points(labels, pixel)
    return (jnp.where(inside, labels, 0).astype(jnp.int32), n_regions.astype(jnp.int32),
            jnp.sum(region_mask, axis=(1, 2)).astype(jnp.int32))


def depth_at_tracks(depth_prev, track_prev, image_hw):
    """Depth (P,) of frame i-1 (H, W) at each track's floor pixel, clamped to the true image
    (``image_hw`` (2,)). docs/semantics.md §3.2."""
    H, W = image_hw[0], image_hw[1]
    col = jnp.clip(jnp.floor(track_prev[:, 0]).astype(jnp.int32), 0, W - 1)
    row = jnp.clip(jnp.floor(track_prev[:, 1]).astype(jnp.int32), 0, H - 1)
    return depth_prev[row, col]


def points_prev(Z, K_prev, track_prev, usable):
    """Tracks (P, 2) of frame i-1 back-projected at their pixel's depth Z (P,) (``depth_at_tracks``)
    -> (X (P, 3) in camera i-1, (P,) bool usable with depth > 0). docs/semantics.md §3.2."""
    return back_project(K_prev, track_prev, Z), usable & (Z > 0)


def local_poses_pair(Z_prev, track_label, n_regions, region_pixels, K_prev, K_curr, track_prev, track_curr,
                     usable, image_hw, key, rival_R, global_t, config: SGCConfig) -> LocalPoses:
    """docs/semantics.md §3.2 steps 3-7 for one pair (frames i-1 -> i), given frame i's regions at the points
    (``frame_regions``), then the region-quality rule (``uncertainty.region_quality``) when the
    config applies it. rival_R (3, 3), global_t (3,): the camera's motion R_g, s t_g (units of D),
    a start of every region's search, R_g that of its rival (§3.3); the identity and None without
    a global pose."""
    H, W = image_hw[0], image_hw[1]
    X, has_depth = points_prev(Z_prev, K_prev, track_prev, usable)

    point_region = jnp.where(has_depth, track_label, 0)
    n_tracks = jnp.sum(usable)
    enough_tracks = n_tracks >= 4
    regions = jnp.arange(1, config.k_seg + 1)
    point_region = jnp.where((point_region <= n_regions) & enough_tracks, point_region, 0)

    keys = jax.vmap(lambda r: jax.random.fold_in(key, r))(regions)
    fit = ransac_pnp_regions(X, track_curr, point_region, K_curr, keys, rival_R, global_t=global_t,
                             hypotheses=config.ransac_hypotheses,
                             inlier_px=config.inlier_px, min_inlier_frac=config.min_inlier_frac,
                             min_points=config.min_points, steps=config.gn_steps, confidence=config.confidence,
                             ambiguous_rot_deg=config.ambiguous_rot_deg,
                             ambiguous_inlier_frac=config.ambiguous_inlier_frac,
                             borrow=config.borrow_region_poses)
    exists = regions <= n_regions
    status = jnp.where(exists & enough_tracks, fit.status, REGION_EMPTY)
    if config.applies_quality_rule:
        diagonal = jnp.hypot(H.astype(X.dtype), W.astype(X.dtype))
        focal = 0.5 * (K_curr[0, 0] + K_curr[1, 1])
        status = region_quality(status, fit.n_inliers, fit.uncertainty, fit.ambiguous, diagonal, focal,
                                min_region_points=config.min_region_points,
                                max_rot_std_deg=config.max_rot_std_deg,
                                max_rot_std_px=config.max_rot_std_px,
                                min_region_extent=config.min_region_extent,
                                quality_noise_px=config.quality_noise_px)
    return LocalPoses(fit.R, fit.t, status.astype(jnp.int32), fit.n_members, fit.reproj_px,
                      fit.uncertainty.rot_std_deg, fit.uncertainty.trans_std,
                      n_tracks.astype(jnp.int32), n_regions.astype(jnp.int32), region_pixels)


def global_relative_pose(R_prev, t_prev, R_curr, t_curr, config: SGCConfig):
    """(R_g, t_g) from camera i-1 to camera i (docs/semantics.md §3.4); authors: t from the raw product."""
    product = R_curr @ R_prev.T
    R_g = nearest_rotation(product)
    R_for_t = product if config.compat == "authors" else R_g
    return R_g, t_curr - R_for_t @ t_prev


def pair_depth_errors(depth_prev, static_prev, depth_curr, static_curr, K_prev, K_curr, R_g, t_g,
                      config: SGCConfig):
    """The depth error of pairs (F, ...) -> (F,) (docs/semantics.md §3): under spec the static,
    valid pixels of frame i-1 warped (AbsRel in percent), under authors every valid one (depth
    units). One pair at a time (``lax.map``), for the unbatched z-buffer scatter."""
    authors = config.compat == "authors"

    def one(pair):
        depth_prev, static_prev, depth_curr, static_curr, K_prev, K_curr, R_g, t_g = pair
        source = depth_prev > 0 if authors else (depth_prev > 0) & static_prev
        warped, hit = warp_depth(depth_prev, source, K_prev, K_curr, R_g, t_g, nearest=not authors,
                                 mask_holes=not authors)
        return depth_error(warped, hit, depth_curr, depth_curr > 0, static_curr, relative=config.scale_free)[0]

    errors = jax.lax.map(one, (depth_prev, static_prev, depth_curr, static_curr, K_prev, K_curr, R_g, t_g))
    return errors * (PERCENT if config.scale_free else 1.0)


def _excluded(status):
    """Regions whose pose the quality rule left out (``codes.EXCLUDED_STATUSES``)."""
    return jnp.any(status[..., None] == jnp.asarray(EXCLUDED_STATUSES, status.dtype), axis=-1)


def pair_components(poses: LocalPoses, R_g, t_g, err, config: SGCConfig):
    """docs/semantics.md §3.5-3.7 for one pair: pose variances, diagnostics, reason code; ``err`` is its depth
    error (``pair_depth_errors``)."""
    accepted = poses.region_status == REGION_OK
    comps = pair_pose_components(poses.R_local, poses.t_local, accepted, R_g, t_g, compat=config.compat)
    f2 = translation_factor(config) ** 2
    if not config.global_pose:  # the mean local pose is no independent reference
        comps["global_rot_var"] = comps["global_trans_var"] = jnp.float32(jnp.nan)
    n_poses = jnp.sum(accepted)
    n_excluded = jnp.sum(_excluded(poses.region_status))
    reproj = jnp.sum(jnp.where(accepted, poses.region_reproj, 0.0)) / jnp.maximum(n_poses, 1)
    reason = jnp.select(
        [poses.n_tracks < 4, poses.region_pixels == 0, poses.n_regions == 0, (n_poses == 0) & (n_excluded > 0),
         n_poses == 0, jnp.isnan(err)],
        [PAIR_REASON_CODE[r] for r in ("too_few_tracks", "no_static", "no_region", "ill_conditioned", "no_pose",
                                       "no_depth_overlap")],
        PAIR_REASON_CODE["ok"])
    return dict(
        local_rot_var=comps["local_rot_var"], local_trans_var=comps["local_trans_var"] * f2,
        global_rot_var=comps["global_rot_var"], global_trans_var=comps["global_trans_var"] * f2,
        depth_error=err, reproj_error=jnp.where(n_poses > 0, reproj, jnp.nan), n_poses=n_poses.astype(jnp.int32),
        n_ill_conditioned=n_excluded.astype(jnp.int32),
        t_g_norm=jnp.linalg.norm(t_g), R_g_angle_deg=rotation_angle_deg(jnp.eye(3, dtype=R_g.dtype), R_g),
        reason=reason.astype(jnp.int32))


# ----------------------------------------------------------------------------- per clip


def scale_equations(Z_prev, track_label, K_prev, K_curr, track_prev, track_curr, usable, R_g, t_g):
    """One pair's equations for the translation scale s (docs/semantics.md §3.4): a static point
    X of camera i-1 seen at normalised n in frame i gives, per image axis k, a_k s = b_k with
    a_k = n_k t_3 - t_k and b_k = Y_k - n_k Y_3 (Y = R_g X) -> (ratios b / a, weights |a| f_k / Y_3),
    each (P, 2); the weight is the reprojection change in pixels per unit of s, 0 for an unused point."""
    X, has_depth = points_prev(Z_prev, K_prev, track_prev, usable)
    use = has_depth & (track_label > 0)
    Y = X @ R_g.T
    n = back_project(K_curr, track_curr, jnp.ones_like(track_curr[:, 0]))  # (P, 3), n_3 = 1
    a = n[:, :2] * t_g[2] - t_g[:2]
    b = Y[:, :2] - n[:, :2] * Y[:, 2:3]
    focal = jnp.stack([K_curr[0, 0], K_curr[1, 1]])
    ok = use[:, None] & (Y[:, 2:3] > 0) & (a != 0)
    weight = jnp.where(ok, jnp.abs(a) * focal / jnp.where(ok, Y[:, 2:3], 1.0), 0.0)
    return jnp.where(ok, b / jnp.where(ok, a, 1.0), 0.0), weight


def weighted_median(values, weights, fallback):
    """The first value (sorted) whose cumulative weight reaches half the total, i.e. the smallest
    value whose weight at or below it does; ``fallback`` when the total is 0. Any shape,
    flattened; weight 0 marks an unused entry. Found by bisection over the values' order-keeping
    uint32 keys (32 masked sums; a sort of the values costs ten times more on CPU)."""
    values, weights = values.reshape(-1).astype(jnp.float32), weights.reshape(-1)
    sign = jnp.uint32(0x80000000)
    bits = jax.lax.bitcast_convert_type(values, jnp.uint32)
    keys = jnp.where(bits & sign, ~bits, bits | sign)  # negative floats reversed, below the positive ones
    total = jnp.sum(weights)

    def halve(_, bounds):  # the smallest key whose weight at or below it reaches half the total is in [lo, hi]
        lo, hi = bounds
        mid = lo + (hi - lo) // 2
        enough = jnp.sum(jnp.where(keys <= mid, weights, 0.0)) >= 0.5 * total
        return jnp.where(enough, lo, mid + 1), jnp.where(enough, mid, hi)

    key, _ = jax.lax.fori_loop(0, 32, halve, (jnp.uint32(0), jnp.uint32(0xFFFFFFFF)))
    median = jax.lax.bitcast_convert_type(jnp.where(key & sign, key ^ sign, ~key), jnp.float32)
    return jnp.where(total > 0, median, fallback)


# Pairs posed at once (vmapped) at most. Every RANSAC and least-squares loop of a vmapped group
# runs until its slowest pair is done, so fewer pairs at once waste fewer steps; fewer than ~4
# pay more per-op overhead than they save (bench/RESULTS.md: a clip's 15 pairs in three groups of
# 5 take ~20% less CPU than all at once).
PAIRS_AT_ONCE = 5


def pair_groups(pose_pair, args, n_pairs: int):
    """``pose_pair`` over the pairs (leading axis ``n_pairs`` of every leaf of ``args``), vmapped in
    ceil(n_pairs / PAIRS_AT_ONCE) groups of equal size, one group after another (``lax.map``); the
    last group is filled up with copies of the last pair, whose results are dropped."""
    groups = -(-n_pairs // PAIRS_AT_ONCE)
    if groups <= 1:
        return jax.vmap(pose_pair)(args)
    size = -(-n_pairs // groups)
    pair = jnp.minimum(jnp.arange(groups * size), n_pairs - 1)
    grouped = jax.tree.map(lambda a: a[pair].reshape((groups, size) + a.shape[1:]), args)
    out = jax.lax.map(jax.vmap(pose_pair), grouped)
    return jax.tree.map(lambda a: a.reshape((groups * size,) + a.shape[2:])[:n_pairs], out)


def clip_poses(x: PoseInputs, key, config: SGCConfig):
    """Local poses of all pairs of one padded clip (no leading B axis), the reference poses and
    the translation scale -> (LocalPoses (T-1, ...), R_g (T-1, 3, 3), t_g (T-1, 3), scale). The
    reference pose is the global relative pose, or each pair's mean local pose (NaN without one)
    when ``config.global_pose`` is off."""
    n_pairs = x.pair_valid.shape[0]
    pair_keys = jax.vmap(lambda p: jax.random.fold_in(key, p))(jnp.arange(n_pairs) + 1)
    prev, curr = slice(None, -1), slice(1, None)
    usable = x.usable & x.pair_valid[:, None]
    if config.global_pose:
        R_g, t_g = jax.vmap(functools.partial(global_relative_pose, config=config))(
            x.R_wc[prev], x.t_wc[prev], x.R_wc[curr], x.t_wc[curr])
        # the rivals' rotation (docs/semantics.md §3.3): the camera's, the identity where it is not finite
        rival_R = jnp.where(jnp.all(jnp.isfinite(R_g), axis=(1, 2))[:, None, None], R_g, jnp.eye(3, dtype=R_g.dtype))
    else:
        rival_R = jnp.broadcast_to(jnp.eye(3, dtype=x.K.dtype), (n_pairs, 3, 3))
    if config.global_pose:
        # s maps pose units to units of D; undefined, the units are taken as shared (s = 1 / D).
        # It does not depend on the local poses, which start from the camera's pose (R_g, s t_g).
        scale = 1.0 / x.depth_unit
        if config.fits_translation_scale:
            ratios, weights = jax.vmap(scale_equations)(x.Z_prev, x.track_labels, x.K[prev], x.K[curr], x.track_prev,
                                                        x.track_curr, usable, R_g, t_g)
            scale = weighted_median(ratios, weights, fallback=scale)
        global_t = scale * t_g
    else:
        global_t = None  # no camera start (an empty pytree under vmap)
    poses = pair_groups(lambda a: local_poses_pair(*a[:9], x.image_hw, *a[9:], config=config),
                        (x.Z_prev, x.track_labels, x.n_regions, x.region_pixels, x.K[prev], x.K[curr], x.track_prev,
                         x.track_curr, usable, pair_keys, rival_R, global_t), n_pairs)
    accepted = poses.region_status == REGION_OK
    if not config.global_pose:
        R_g, t_g = jax.vmap(mean_pose)(poses.R_local, poses.t_local, accepted)
        return poses, R_g, t_g, jnp.float32(1.0)
    return poses, R_g, t_g, scale


# ----------------------------------------------------------------------------- stages


def _pairs_flat(B, T):
    """(flat, unflat): (B, T-1, ...) <-> (B (T-1), ...)."""
    return (lambda x: x.reshape((B * (T - 1),) + x.shape[2:]),
            lambda x: x.reshape((B, T - 1) + x.shape[1:]))


def pixel_stage(x: PixelInputs, config: SGCConfig) -> dict:
    """Regions at the tracks of every pair of the clips (leading axis B): frame i's region of each
    track, N_s and |S_i| (``frame_regions``), and frame i-1's depth at each track (``Z_prev``),
    frame by frame over the flattened B (T-1) frames."""
    B, T = x.depth.shape[:2]
    flat, unflat = _pairs_flat(B, T)
    image_hw = flat(jnp.broadcast_to(x.image_hw[:, None], (B, T - 1, 2)))
    labels, n_regions, region_pixels = map(unflat, frame_regions(
        flat(x.depth[:, 1:]), flat(x.static[:, 1:]), flat(x.track_curr), image_hw, config))
    Z_prev = unflat(jax.vmap(depth_at_tracks)(flat(x.depth[:, :-1]), flat(x.track_prev), image_hw))
    return dict(track_labels=labels, n_regions=n_regions, region_pixels=region_pixels, Z_prev=Z_prev)


def pose_stage(x: PoseInputs, key, config: SGCConfig) -> dict:
    """Local poses, reference poses and the scale of the clips (leading axis B), clip by clip,
    each clip's pairs in groups of at most PAIRS_AT_ONCE (``pair_groups``): RANSAC's loops run
    until their slowest lane is done, so vmapping many pairs at once costs more than it saves."""
    poses, R_g, t_g, scale = jax.lax.map(lambda clip: clip_poses(PoseInputs(*clip), key, config), tuple(x))
    return dict(poses._asdict(), R_g=R_g, t_g=t_g, scale=scale)


def finish_stage(pose: dict, depth, static, K, config: SGCConfig) -> dict:
    """Depth errors and per-pair components from the pose stage's output and the clips' depth
    (B, T, H, W), masks and K -> dict of per-clip, per-pair and per-region arrays (leading axes
    B, T-1)."""
    B, T = depth.shape[:2]
    flat, unflat = _pairs_flat(B, T)
    poses = LocalPoses(**{name: pose[name] for name in LocalPoses._fields})
    R_g, t_g, scale = pose["R_g"], pose["t_g"], pose["scale"]
    t_g_scaled = scale[:, None, None] * t_g
    err = unflat(pair_depth_errors(flat(depth[:, :-1]), flat(static[:, :-1]), flat(depth[:, 1:]),
                                   flat(static[:, 1:]), flat(K[:, :-1]), flat(K[:, 1:]), flat(R_g),
                                   flat(t_g_scaled), config))
    comps = jax.vmap(jax.vmap(functools.partial(pair_components, config=config)))(poses, R_g, t_g_scaled, err)
    # ECD input: the camera's translation in the reported unit (s t_g in % of D under spec, raw t_g under authors)
    t_g_ecd = t_g_scaled if config.scale_free else t_g
    comps["t_g_norm"] = jnp.linalg.norm(t_g_ecd, axis=-1) * translation_factor(config)
    return dict(comps, **poses._asdict(), scale=scale)


def run_stage(stage: str, inputs: tuple, key, config: SGCConfig):
    """One stage on its flat inputs (``stage_inputs``)."""
    if stage == "pixel":
        return pixel_stage(PixelInputs(*inputs), config)
    if stage == "pose":
        return pose_stage(PoseInputs(*inputs), key, config)
    return finish_stage(*inputs, config)


def score_padded(batch: PaddedClips, key, config: SGCConfig):
    """All pairs of the clips of a bucket (leading axis B) -> dict of per-clip, per-pair and
    per-region arrays (leading axes B, T-1): the three stages in one trace."""
    out = None
    for stage in STAGES:
        out = run_stage(stage, stage_inputs(stage, batch, out), key, config)
    return out


# ----------------------------------------------------------------------------- programs


class ProgramConfig:
    """The config as a compiled stage sees it: its static fields (and the config's properties) as
    Python values, ``VALUE_FIELDS`` as traced scalars from ``values``; reading another stage's
    static field is an error (it would not be part of the program's key)."""

    def __init__(self, static: SGCConfig, values: Mapping[str, Any], stage: str):
        self._static, self._values, self._stage = static, values, stage

    def __getattr__(self, name: str):
        values, stage = self.__dict__["_values"], self.__dict__["_stage"]
        if name in values:
            return values[name]
        if name in STATIC_FIELDS and name not in STAGE_FIELDS[stage]:
            raise AttributeError(f"the {stage} stage reads config.{name}, which is not in STAGE_FIELDS[{stage!r}]")
        return getattr(self.__dict__["_static"], name)


def stage_program(inputs: tuple, key, values, stage: str, static: SGCConfig):
    """A stage as a compiled program sees it: flat inputs (``stage_inputs``), the RANSAC key, the
    value fields (``jax_engine.program_values``), and the static config ``static`` (a jit-static
    argument)."""
    return run_stage(stage, inputs, key, ProgramConfig(static, values, stage))
