"""Shape buckets and padding (docs/semantics.md §7.1): a clip's arrays padded on the host to the
next bucket's (T, H, W, P), so clips of nearby shapes share one compiled program. NumPy only."""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import numpy as np

from ...config import SGCConfig
from ...io.clip import Clip

SHORT_FRAME_BUCKETS = (2, 4, 8, 12, 16)
# Beyond 16 frames a bucket's pair count (T - 1) is m * 2**k with m in 4..7: a quarter octave apart,
# so padding adds under a quarter of a clip's pairs (a padded pair costs about what a real one does),
# and none to video generators' 4n + 1 frame counts (17, 25, 33, 49, 65, 81, 97, 129, 161, 257).
BUCKET_PAIR_MANTISSAS = (4, 5, 6, 7)
PIXEL_MULTIPLE = 64  # H and W are rounded up to a multiple of this
MIN_TRACK_BUCKET = 64


@dataclasses.dataclass(frozen=True, order=True)
class Bucket:
    """Padded (T frames, H x W pixels, P tracks); each stage compiles once per the sizes it reads."""

    T: int
    H: int
    W: int
    P: int


def _round_up(value: int, multiple: int) -> int:
    return -(-value // multiple) * multiple


def bucket_for(clip: Clip) -> Bucket:
    """The bucket a clip is padded to (``bucket_for_shape``)."""
    return bucket_for_shape(clip.n_frames, *clip.image_size, clip.n_tracks)


def frame_bucket(T: int) -> int:
    """T frames padded to: the next of SHORT_FRAME_BUCKETS, beyond them 1 + the next pair count of
    the form m * 2**k, m in BUCKET_PAIR_MANTISSAS."""
    if T <= SHORT_FRAME_BUCKETS[-1]:
        return next(b for b in SHORT_FRAME_BUCKETS if b >= T)
    pairs = T - 1
    octave = 1 << max(pairs.bit_length() - 3, 0)  # 4 * octave <= pairs < 8 * octave
    return 1 + min(m * octave for m in (*BUCKET_PAIR_MANTISSAS, 8) if m * octave >= pairs)  # 8: the next octave's 4


def bucket_for_shape(T: int, H: int, W: int, P: int) -> Bucket:
    """The bucket of clips of T frames, H x W pixels and P tracks per pair: T to ``frame_bucket(T)``,
    H and W to a multiple of 64, P to the next power of two (at least 64)."""
    T = frame_bucket(T)
    H, W = (_round_up(s, PIXEL_MULTIPLE) for s in (H, W))
    P = max(MIN_TRACK_BUCKET, 1 << max(P - 1, 0).bit_length())
    return Bucket(T, H, W, P)


class PaddedClips(NamedTuple):
    """Clips of one bucket stacked on a leading axis B (1 in a scoring call); pairs index p =
    frames p -> p+1."""

    depth: np.ndarray  # (B, T, H, W) float32, 0 = invalid (and in padding)
    static: np.ndarray  # (B, T, H, W) bool, False in padding
    K: np.ndarray  # (B, T, 3, 3) float32
    R_wc: np.ndarray  # (B, T, 3, 3) float32
    t_wc: np.ndarray  # (B, T, 3) float32
    track_prev: np.ndarray  # (B, T-1, P, 2) float32
    track_curr: np.ndarray  # (B, T-1, P, 2) float32
    usable: np.ndarray  # (B, T-1, P) bool: visible, confident, finite; False in padding
    pair_valid: np.ndarray  # (B, T-1) bool
    image_hw: np.ndarray  # (B, 2) int32 true image size
    depth_unit: np.ndarray  # (B,) float32 D in input depth units (depth above is depth / D)


# jax.device_put takes a host array aligned to this many bytes as it is, where it copies others
# (a standard clip's 14 MB: ~4 ms of CPU time, and fresh pages to fault in).
HOST_ALIGN = 64


def host_zeros(shape: tuple[int, ...], dtype) -> np.ndarray:
    """``np.zeros(shape, dtype)`` starting on a HOST_ALIGN-byte boundary."""
    dtype = np.dtype(dtype)
    size = int(np.prod(shape)) * dtype.itemsize
    raw = np.zeros(size + HOST_ALIGN, np.uint8)
    start = -raw.ctypes.data % HOST_ALIGN
    return raw[start:start + size].view(dtype).reshape(shape)


def pad_clip(clip: Clip, bucket: Bucket, config: SGCConfig, depth_unit: float = 1.0) -> PaddedClips:
    """One clip padded to ``bucket`` (leading axis B = 1); ``depth_unit``: the D its depth was
    divided by (``units.in_depth_units``)."""
    T, H, W, P = clip.n_frames, *clip.image_size, clip.n_tracks
    if (T > bucket.T) or (H > bucket.H) or (W > bucket.W) or (P > bucket.P):
        raise ValueError(f"clip {clip.clip_id!r} of shape {(T, H, W, P)} does not fit bucket {bucket}")
    depth = host_zeros((bucket.T, bucket.H, bucket.W), np.float32)
    for frame, source in zip(depth, clip.depth):  # a frame at a time: no clip-sized temporaries
        view = frame[:H, :W]
        np.copyto(view, source)
        np.copyto(view, 0.0, where=~((view > 0) & (view < np.inf)))  # NaN, inf and depth <= 0 invalid
    static = host_zeros((bucket.T, bucket.H, bucket.W), bool)
    static[:T, :H, :W] = clip.static_mask if config.use_mos else True
    K = host_zeros((bucket.T, 3, 3), np.float32)
    K[:] = clip.K[-1]
    K[:T] = clip.K
    R_wc = host_zeros((bucket.T, 3, 3), np.float32)
    R_wc[:] = np.eye(3)
    R_wc[:T] = clip.R_wc
    t_wc = host_zeros((bucket.T, 3), np.float32)
    t_wc[:T] = clip.t_wc
    track_prev = host_zeros((bucket.T - 1, bucket.P, 2), np.float32)
    track_curr = host_zeros((bucket.T - 1, bucket.P, 2), np.float32)
    usable = host_zeros((bucket.T - 1, bucket.P), bool)
    usable[: T - 1, :P] = clip.usable_tracks(config.min_track_conf, repeats=config.counts_repeated_tracks)
    track_prev[: T - 1, :P] = np.where(usable[: T - 1, :P, None], clip.track_prev, 0.0)
    track_curr[: T - 1, :P] = np.where(usable[: T - 1, :P, None], clip.track_curr, 0.0)
    pair_valid = np.arange(bucket.T - 1) < T - 1
    return PaddedClips(depth[None], static[None], K[None], R_wc[None], t_wc[None], track_prev[None],
                       track_curr[None], usable[None], pair_valid[None], np.array([[H, W]], np.int32),
                       np.array([depth_unit], np.float32))
