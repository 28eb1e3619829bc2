"""The JAX program's three stages as values (docs/semantics.md §7.1): each a frozen equinox module
holding exactly the options its function reads. Static fields (array sizes, loop counts,
branches) shape its compiled program; the others are 0-d arrays the program takes as arguments,
so one program serves every value of them.

A clip is scored by three programs, each compiled for the sizes it touches: the pixel stage
(regions at the tracks; T, H, W, P), the pose stage (RANSAC, the scale; T, P: most of the compile,
shared by clips of every image size) and the finish (depth warp, components; T, H, W). Their
inputs and outputs are flat tuples and dicts (what ``jax.export`` keeps). Building a stage imports
no kernel: its function is imported when it is traced, so programs loaded from the cache need
neither.
"""

from __future__ import annotations

from typing import Any, ClassVar, NamedTuple

import equinox as eqx
import jax
import numpy as np

from ...config import SGCConfig
from ...kernels.ransac_options import QualityRule, RansacOptions
from .buckets import Bucket, PaddedClips

# The pose stage's per-track outputs (P axis): read by the differentiable score, not passed to the
# finish stage, whose program must not depend on the track count (its key holds T, H, W only).
POSE_PER_TRACK = ("track_fitted",)


class PixelInputs(NamedTuple):
    depth: jax.Array  # (B, T, H, W)
    static: jax.Array  # (B, T, H, W)
    track_prev: jax.Array  # (B, T-1, P, 2)
    track_curr: jax.Array  # (B, T-1, P, 2)
    usable: jax.Array  # (B, T-1, P)
    image_hw: jax.Array  # (B, 2)


class PoseInputs(NamedTuple):
    Z_prev: jax.Array  # (B, T-1, P) depth of frame i-1 at the tracks
    track_labels: jax.Array  # (B, T-1, P) region of each track in the region frame (§3.2 step 5)
    n_regions: jax.Array  # (B, T-1)
    region_pixels: jax.Array  # (B, T-1)
    K: jax.Array  # (B, T, 3, 3)
    R_wc: jax.Array  # (B, T, 3, 3)
    t_wc: jax.Array  # (B, T, 3)
    track_prev: jax.Array  # (B, T-1, P, 2)
    track_curr: jax.Array
    usable: jax.Array  # (B, T-1, P)
    pair_valid: jax.Array  # (B, T-1)
    image_hw: jax.Array  # (B, 2)
    depth_unit: jax.Array  # (B,)


def _int(value) -> np.ndarray:
    return np.asarray(value, np.int32)


def _float(value) -> np.ndarray:
    return np.asarray(value, np.float32)


class Stage(eqx.Module):
    """One stage: ``stage(inputs, key)`` -> its output dict; ``inputs(batch, previous)`` its flat
    inputs from the padded clips and the previous stage's output; ``sizes(bucket)`` the bucket
    sizes its program is compiled for. ``vectorized``: how the program runs its clips, frames
    and pairs (``each``)."""

    name: ClassVar[str]
    vectorized: eqx.AbstractVar[bool]

    def sizes(self, bucket: Bucket) -> tuple[int, ...]:
        raise NotImplementedError

    def inputs(self, batch: PaddedClips, previous: dict | None) -> tuple:
        raise NotImplementedError

    def __call__(self, inputs: tuple, key) -> dict:
        raise NotImplementedError


class PixelStage(Stage):
    """The region of every track and frame i-1's depth there (``pixel_stage``)."""

    name: ClassVar[str] = "pixel"
    k_seg: int = eqx.field(static=True)
    kmeans_bins: int = eqx.field(static=True)
    partition: str = eqx.field(static=True)
    reads_previous_frame: bool = eqx.field(static=True)
    compat: str = eqx.field(static=True)
    vectorized: bool = eqx.field(static=True)
    min_region_pixels: Any  # int32 ()
    tracks_per_layer: Any  # int32 ()

    @classmethod
    def of(cls, config: SGCConfig, vectorized: bool = False) -> PixelStage:
        return cls(k_seg=config.k_seg, kmeans_bins=config.kmeans_bins, partition=config.partition,
                   reads_previous_frame=config.reads_previous_frame, compat=config.compat, vectorized=vectorized,
                   min_region_pixels=_int(config.min_region_pixels), tracks_per_layer=_int(config.tracks_per_layer))

    def sizes(self, bucket: Bucket) -> tuple[int, ...]:
        return bucket.T, bucket.H, bucket.W, bucket.P

    def inputs(self, batch: PaddedClips, previous: dict | None) -> tuple:
        return tuple(PixelInputs(batch.depth, batch.static, batch.track_prev, batch.track_curr, batch.usable,
                                 batch.image_hw))

    def __call__(self, inputs: tuple, key) -> dict:
        from .pixel_stage import pixel_stage  # the kernels, only when traced

        return pixel_stage(PixelInputs(*inputs), self)


class PoseStage(Stage):
    """Every pair's local poses, the camera's relative poses and the clip's translation scale
    (``pose_stage``)."""

    name: ClassVar[str] = "pose"
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
            inlier_px=_float(config.inlier_px), min_inlier_frac=_float(config.min_inlier_frac),
            min_points=_int(config.min_points), confidence=_float(config.confidence),
            ambiguous_rot_deg=_float(config.ambiguous_rot_deg),
            ambiguous_inlier_frac=_float(config.ambiguous_inlier_frac),
            hypotheses=config.ransac_hypotheses, lm_steps=config.lm_steps, borrow=config.borrow_region_poses)
        quality = QualityRule(
            min_region_points=_int(config.min_region_points), max_rot_std_deg=_float(config.max_rot_std_deg),
            max_rot_std_px=_float(config.max_rot_std_px), min_region_extent=_float(config.min_region_extent),
            quality_noise_px=_float(config.quality_noise_px))
        return cls(k_seg=config.k_seg, compat=config.compat, global_pose=config.global_pose,
                   fits_translation_scale=config.fits_translation_scale, vectorized=vectorized, ransac=ransac,
                   quality=quality, quality_rule=_int(config.quality_rule))

    def sizes(self, bucket: Bucket) -> tuple[int, ...]:
        return bucket.T, bucket.P

    def inputs(self, batch: PaddedClips, previous: dict | None) -> tuple:
        return tuple(PoseInputs(previous["Z_prev"], previous["track_labels"], previous["n_regions"],
                                previous["region_pixels"], batch.K, batch.R_wc, batch.t_wc, batch.track_prev,
                                batch.track_curr, batch.usable, batch.pair_valid, batch.image_hw, batch.depth_unit))

    def __call__(self, inputs: tuple, key) -> dict:
        from .pose_stage import pose_stage

        return pose_stage(PoseInputs(*inputs), key, self)


class FinishStage(Stage):
    """Every pair's depth error and pose components (``finish_stage``)."""

    name: ClassVar[str] = "finish"
    k_seg: int = eqx.field(static=True)  # the region slots of its inputs
    compat: str = eqx.field(static=True)
    scale_free: bool = eqx.field(static=True)
    global_pose: bool = eqx.field(static=True)
    vectorized: bool = eqx.field(static=True)

    @classmethod
    def of(cls, config: SGCConfig, vectorized: bool = False) -> FinishStage:
        return cls(k_seg=config.k_seg, compat=config.compat, scale_free=config.scale_free,
                   global_pose=config.global_pose, vectorized=vectorized)

    def sizes(self, bucket: Bucket) -> tuple[int, ...]:
        return bucket.T, bucket.H, bucket.W

    def inputs(self, batch: PaddedClips, previous: dict | None) -> tuple:
        regions = {name: value for name, value in previous.items() if name not in POSE_PER_TRACK}
        return (regions, batch.depth, batch.static, batch.K)

    def __call__(self, inputs: tuple, key) -> dict:
        from .finish_stage import finish_stage

        return finish_stage(*inputs, self)


def stages_of(config: SGCConfig, vectorized: bool = False) -> tuple[PixelStage, PoseStage, FinishStage]:
    """The three stages that score clips under ``config``, in the order they run."""
    return PixelStage.of(config, vectorized), PoseStage.of(config, vectorized), FinishStage.of(config, vectorized)


def each(fn, items, vectorized: bool):
    """``fn`` over the leading axis of ``items``: in one wide vmapped step in a vectorized program
    (accelerators, where lanes are plentiful), else one item after another (``lax.map``: on CPU,
    unbatched scatters run faster and each item's loops stop at its own end; docs/semantics.md §9.3)."""
    return jax.vmap(fn)(items) if vectorized else jax.lax.map(fn, items)
