"""What the JAX program's three stages share (docs/semantics.md §7.1): each stage is a value, a
frozen equinox module holding exactly the options its function reads (``PixelStage`` in
pixel_stage.py, ``PoseStage``, ``FinishStage``). Static fields (array sizes, loop counts,
branches) shape its compiled program; the others are 0-d arrays the program takes as arguments,
so one program serves every value of them.

A clip is scored by three programs, each compiled for the sizes it touches: the pixel stage
(regions at the tracks; T, H, W, P), the pose stage (RANSAC, the scale; T, P: most of the compile,
shared by clips of every image size) and the finish (depth warp, components; T, H, W). Their
inputs and outputs are flat tuples and dicts (what ``jax.export`` keeps).
"""

from __future__ import annotations

import abc
from typing import ClassVar, NamedTuple

import equinox as eqx
import jax
import numpy as np

from .buckets import Bucket, PaddedClips

# The pose stage's per-track outputs (P axis): read by the differentiable score, not passed to the
# finish stage, whose program must not depend on the track count (its key holds T, H, W only).
POSE_PER_TRACK = ("track_fitted", "refit_fitted_on")


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


def as_int(value) -> np.ndarray:
    """A value field: an int32 0-d array (a leaf the program takes)."""
    return np.asarray(value, np.int32)


def as_float(value) -> np.ndarray:
    """A value field: a float32 0-d array."""
    return np.asarray(value, np.float32)


# XLA:CPU vectorises loops 256 bits wide by default; on a CPU with AVX-512, 512 bits run a warm
# standard clip ~8 % faster (AMD EPYC; bench/history/issue-61.md, "Loops vectorised 512 bits wide").
# A CPU without AVX-512 keeps its widest vectors; a flag set in XLA_FLAGS wins (stage_compiler_options).
CPU_COMPILER_OPTIONS = {"xla_cpu_prefer_vector_width": "512"}


class Stage(eqx.Module):
    """One stage: ``stage(inputs, key)`` -> its output dict; ``inputs(batch, previous)`` its flat
    inputs from the padded clips and the previous stage's output; ``sizes(bucket)`` the bucket
    sizes its program is compiled for. ``vectorized``: how the program runs its clips, frames
    and pairs (``each``)."""

    name: ClassVar[str]
    cpu_compiler_options: ClassVar[dict[str, str]] = CPU_COMPILER_OPTIONS  # XLA options for its program on CPU devices
    vectorized: eqx.AbstractVar[bool]

    @abc.abstractmethod
    def sizes(self, bucket: Bucket) -> tuple[int, ...]:
        """The bucket sizes its program reads."""

    @abc.abstractmethod
    def inputs(self, batch: PaddedClips, previous: dict | None) -> tuple:
        """Its flat inputs from the padded clips and the previous stage's output."""

    @abc.abstractmethod
    def __call__(self, inputs: tuple, key) -> dict:
        """Its output dict from its flat inputs and RANSAC's key."""


def each(fn, items, vectorized: bool):
    """``fn`` over the leading axis of ``items``: in one wide vmapped step in a vectorized program
    (accelerators, where lanes are plentiful), else one item after another (``lax.map``: on CPU,
    unbatched scatters run faster and each item's loops stop at its own end; docs/semantics.md §9.3)."""
    return jax.vmap(fn)(items) if vectorized else jax.lax.map(fn, items)
