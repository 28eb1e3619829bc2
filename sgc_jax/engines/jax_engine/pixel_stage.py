"""The pixel stage (docs/semantics.md §3.2 steps 1-2 and 5): the region of every track (in frame i's
partition, or frame i-1's under ``region_frame="previous"``), and frame i-1's depth at every track,
for every pair of the clips of a bucket."""

from __future__ import annotations

from typing import Any, ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp

from ...config import SGCConfig
from ...kernels.partitions import depth_partition_of, depth_spatial_regions, grid_regions, region_of_depth
from .buckets import Bucket, PaddedClips
from .stages import PixelInputs, Stage, as_float, as_int, each


def layer_count(tracks_on_mask, stage: PixelStage):
    """Depth layers (F,) int32 of frames whose backgrounds hold ``tracks_on_mask`` (F,) of their
    pairs' tracks: one per ``tracks_per_layer`` of them and two from that many on, 1..k_seg; k_seg
    when it is 0 or under compat="authors"."""
    if stage.compat == "authors":
        return jnp.full(tracks_on_mask.shape, stage.k_seg, jnp.int32)
    per_layer = jnp.maximum(stage.tracks_per_layer, 1)
    # two layers as soon as one is full: a pair's two poses are what its local components need (§3.5)
    count = jnp.maximum(tracks_on_mask // per_layer, 2 * (tracks_on_mask >= per_layer))
    return jnp.where(stage.tracks_per_layer > 0, jnp.clip(count, 1, stage.k_seg), stage.k_seg).astype(jnp.int32)


def region_mask(depth, static, compat: str):
    """S_i's pixels (...) bool: the static ones, with a depth unless compat="authors"."""
    return static if compat == "authors" else static & (depth > 0)


def frame_regions(depth, static, frame, points, counted, image_hw, stage: PixelStage):
    """The clips' frames (B T, H, W), the frame (F,) of each pair's partition among them, the pairs'
    points in it (F, P, 2), the points that count towards the layer count (F, P) and true sizes (F, 2)
    -> (region at each point's pixel (F, P) int32 (``track_pixel``), 0 = none or outside; N_s (F,);
    |S| (F,)).
    Each frame is read where it lies: the pairs' frames sliced out first would be a copy of the
    clip's depth and mask, which at video generators' sizes costs a quarter to a third of the stage."""
    H_pad, W_pad = depth.shape[1:]
    col, row = track_pixels(points, stage.track_pixel_offset)
    inside = (col >= 0) & (col < image_hw[:, 1:]) & (row >= 0) & (row < image_hw[:, :1])
    pixel = jnp.clip(row, 0, H_pad - 1) * W_pad + jnp.clip(col, 0, W_pad - 1)  # (F, P)
    at_points = lambda image: image.reshape(image.shape[0], -1)[frame[:, None], pixel]  # noqa: E731
    regions = dict(k=stage.k_seg, min_region_pixels=stage.min_region_pixels)
    if stage.partition == "depth":  # the points labelled from each bin's region, never whole label maps
        depth_at = at_points(depth)
        on_mask = region_mask(depth_at, at_points(static), stage.compat)
        layers = layer_count(jnp.sum(counted & inside & on_mask, axis=1), stage)
        def read_frame(i):
            frame_depth = depth[frame[i]]
            return frame_depth, region_mask(frame_depth, static[frame[i]], stage.compat)

        partition = depth_partition_of(read_frame, frame.shape[0], bins=stage.kmeans_bins, **regions, layers=layers,
                                       frames_at_once=stage.vectorized)
        labels = jax.vmap(region_of_depth)(partition, depth_at, on_mask)
        n_regions, n_pixels = partition.n_regions, partition.n_pixels
    else:  # frame by frame on CPU: unbatched scatters run several times faster there
        frames = depth[frame]
        mask = region_mask(frames, static[frame], stage.compat)
        if stage.partition == "grid":
            label_frame = lambda frame: grid_regions(frame[1], **regions)  # noqa: E731
        else:
            label_frame = lambda frame: depth_spatial_regions(*frame, bins=stage.kmeans_bins, **regions,  # noqa: E731
                                                              cpu_form=not stage.vectorized)
        labels, n_regions = each(label_frame, (frames, mask), stage.vectorized)
        labels = jax.vmap(lambda image, p: image.reshape(-1)[p])(labels, pixel)
        n_pixels = jnp.sum(mask, axis=(1, 2))
    return jnp.where(inside, labels, 0).astype(jnp.int32), n_regions.astype(jnp.int32), n_pixels.astype(jnp.int32)


def track_pixels(points, offset):
    """(column, row) int32 (...) of the pixels points (..., 2) are read at: floor(x + offset),
    floor(y + offset); offset 0.5 reads the nearest pixel, 0 the floor pixel
    (``SGCConfig.track_pixel_offset``)."""
    return tuple(jnp.floor(points[..., axis] + offset).astype(jnp.int32) for axis in (0, 1))


def depth_at_tracks(depth, frame, track_prev, image_hw, offset):
    """Depth (P,) of frame i-1 (``depth[frame]``, frames (N, H, W)) at each track's pixel
    (``track_pixels`` at ``offset``), clamped to the true image (2,)."""
    col, row = track_pixels(track_prev, offset)
    return depth[frame, jnp.clip(row, 0, image_hw[0] - 1), jnp.clip(col, 0, image_hw[1] - 1)]


def pairs_flat(B, T):
    """(flat, unflat): (B, T-1, ...) <-> (B (T-1), ...)."""
    return (lambda x: x.reshape((B * (T - 1),) + x.shape[2:]),
            lambda x: x.reshape((B, T - 1) + x.shape[1:]))


def frames_in_place(*stacks):
    """Clips' frames (B, T, ...) -> (each stack as (B T, ...), a reshape that copies nothing; the
    index (B (T-1),) int32 of every pair's frame i-1 among them, frame i the next)."""
    B, T = stacks[0].shape[:2]
    previous = pairs_flat(B, T)[0](jnp.arange(B, dtype=jnp.int32)[:, None] * T + jnp.arange(T - 1, dtype=jnp.int32))
    return tuple(s.reshape((B * T,) + s.shape[2:]) for s in stacks), previous


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
    track_pixel_offset: Any  # float32 (): 0 reads a track's floor pixel, 0.5 its nearest

    @classmethod
    def of(cls, config: SGCConfig, vectorized: bool = False) -> PixelStage:
        return cls(k_seg=config.k_seg, kmeans_bins=config.kmeans_bins, partition=config.partition,
                   reads_previous_frame=config.reads_previous_frame, compat=config.compat, vectorized=vectorized,
                   min_region_pixels=as_int(config.min_region_pixels), tracks_per_layer=as_int(config.tracks_per_layer),
                   track_pixel_offset=as_float(config.track_pixel_offset))

    def sizes(self, bucket: Bucket) -> tuple[int, ...]:
        return bucket.T, bucket.H, bucket.W, bucket.P

    def inputs(self, batch: PaddedClips, previous: dict | None) -> tuple:
        return tuple(PixelInputs(batch.depth, batch.static, batch.track_prev, batch.track_curr, batch.usable,
                                 batch.image_hw))

    def __call__(self, inputs: tuple, key) -> dict:
        return pixel_stage(PixelInputs(*inputs), self)


def pixel_stage(x: PixelInputs, stage: PixelStage) -> dict:
    """Clips (leading axis B) -> track_labels (B, T-1, P), n_regions, region_pixels (B, T-1) and
    Z_prev (B, T-1, P), frame by frame over the B (T-1) frames."""
    B, T = x.depth.shape[:2]
    flat, unflat = pairs_flat(B, T)
    image_hw = flat(jnp.broadcast_to(x.image_hw[:, None], (B, T - 1, 2)))
    (depth, static), previous = frames_in_place(x.depth, x.static)
    # frame i-1 and the tracks' query points, or frame i and where the tracker put them
    frame, points = (previous, x.track_prev) if stage.reads_previous_frame else (previous + 1, x.track_curr)
    Z_prev = jax.vmap(depth_at_tracks, (None, 0, 0, 0, None))(depth, previous, flat(x.track_prev), image_hw,
                                                              stage.track_pixel_offset)
    counted = flat(x.usable) & (Z_prev > 0)  # the tracks a local pose can use (pose stage)
    labels, n_regions, region_pixels = map(unflat, frame_regions(depth, static, frame, flat(points), counted,
                                                                 image_hw, stage))
    Z_prev = unflat(Z_prev)
    return dict(track_labels=labels, n_regions=n_regions, region_pixels=region_pixels, Z_prev=Z_prev)
