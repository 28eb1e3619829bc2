"""The JAX program's three stages, wired: what each takes, which static config fields shape it,
the key of its compiled program, and the traced function a program runs.

A clip is scored by three programs, each compiled for the sizes it touches: the pixel stage
(regions at the tracks; T, H, W, P), the pose stage (RANSAC, the scale; T, P: most of the
compile, shared by clips of every image size) and the finish (depth warp, components; T, H, W).
Their inputs and outputs are flat tuples and dicts (what ``jax.export`` keeps). Each stage is
traced from its own module (``trace``); only tracing imports those and the kernels, so programs
loaded from the cache need neither.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Mapping, NamedTuple

import jax
import numpy as np

from ...config import STATIC_FIELDS, VALUE_FIELDS, SGCConfig
from .buckets import Bucket, PaddedClips

STAGES = ("pixel", "pose", "finish")
# The pose stage's per-track outputs (P axis): read by the differentiable score, not passed to the
# finish stage, whose program must not depend on the track count (its key holds T, H, W only).
POSE_PER_TRACK = ("track_fitted",)

# The static config fields each stage reads (ProgramConfig refuses the others), so a stage's
# program is shared by configs that differ elsewhere. Properties of the config used in a stage
# must derive from these (scale_free and fits_translation_scale do).
STAGE_FIELDS = {
    "pixel": ("k_seg", "kmeans_bins", "partition", "region_frame", "compat"),
    "pose": ("k_seg", "ransac_hypotheses", "lm_steps", "compat", "global_pose", "align_scale", "borrow_region_poses"),
    "finish": ("k_seg", "compat", "global_pose"),
}


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


def stage_inputs(stage: str, batch: PaddedClips, previous: dict | None) -> tuple:
    """The flat inputs of ``stage`` for a padded batch, given the previous stage's output."""
    if stage == "pixel":
        return tuple(PixelInputs(batch.depth, batch.static, batch.track_prev, batch.track_curr, batch.usable,
                                 batch.image_hw))
    if stage == "pose":
        return tuple(PoseInputs(previous["Z_prev"], previous["track_labels"], previous["n_regions"],
                                previous["region_pixels"], batch.K, batch.R_wc, batch.t_wc, batch.track_prev,
                                batch.track_curr, batch.usable, batch.pair_valid, batch.image_hw, batch.depth_unit))
    regions = {name: value for name, value in previous.items() if name not in POSE_PER_TRACK}
    return (regions, batch.depth, batch.static, batch.K)


@dataclasses.dataclass(frozen=True)
class StageKey:
    """One compiled program: a stage, its static config (``stage_config``), the bucket sizes it
    reads (pixel: T, H, W, P; pose: T, P; finish: T, H, W) and whether it is ``vectorized``."""

    stage: str
    static: SGCConfig
    shape: tuple[int, ...]
    vectorized: bool = False

    def __str__(self) -> str:
        return f"{self.stage} {'x'.join(map(str, self.shape))}{' vectorized' if self.vectorized else ''}"


def stage_config(config: SGCConfig, stage: str) -> SGCConfig:
    """``config`` with every field but the stage's static ones at its default."""
    defaults, keep = SGCConfig(), set(STAGE_FIELDS[stage])
    return config.replace(**{f.name: getattr(defaults, f.name) for f in dataclasses.fields(SGCConfig)
                             if f.name not in keep})


def stage_key(config: SGCConfig, stage: str, bucket: Bucket, vectorized: bool = False) -> StageKey:
    """The program that runs ``stage`` for clips of ``bucket`` under ``config``."""
    T, H, W, P = bucket.T, bucket.H, bucket.W, bucket.P
    shape = {"pixel": (T, H, W, P), "pose": (T, P), "finish": (T, H, W)}[stage]
    return StageKey(stage, stage_config(config, stage), shape, vectorized)


def program_values(config: SGCConfig) -> dict[str, np.ndarray]:
    """The value fields a program takes as arguments (int32 or float32 scalars; the seed enters as the key)."""
    return {name: np.asarray(getattr(config, name), np.int32 if isinstance(getattr(config, name), int) else np.float32)
            for name in VALUE_FIELDS if name != "seed"}


class ProgramConfig:
    """The config as a stage's trace sees it: its static fields (and properties) as Python values,
    VALUE_FIELDS as traced scalars; reading another stage's static field raises (it would not be
    part of the program's key). ``vectorized``: how the program runs its clips, frames and pairs
    (``each``)."""

    def __init__(self, static: SGCConfig, values: Mapping[str, Any], stage: str, vectorized: bool = False):
        self._static, self._values, self._stage = static, values, stage
        self.vectorized = vectorized

    def __getattr__(self, name: str):
        values, stage = self.__dict__["_values"], self.__dict__["_stage"]
        if name in values:
            return values[name]
        if name in STATIC_FIELDS and name not in STAGE_FIELDS[stage]:
            raise AttributeError(f"the {stage} stage reads config.{name}, which is not in STAGE_FIELDS[{stage!r}]")
        return getattr(self.__dict__["_static"], name)


def each(fn, items, config: ProgramConfig):
    """``fn`` over the leading axis of ``items``: in one wide vmapped step in a vectorized program
    (accelerators, where lanes are plentiful), else one item after another (``lax.map``: on CPU,
    unbatched scatters run faster and each item's loops stop at its own end; docs/semantics.md §9.3)."""
    return jax.vmap(fn)(items) if config.vectorized else jax.lax.map(fn, items)
