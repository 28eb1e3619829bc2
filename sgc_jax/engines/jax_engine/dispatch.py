"""Scoring clips with the compiled programs: a clip prepared on the host (``prepare_clip``), its
program called without waiting (``dispatch``, or ``dispatch_group`` for many clips at once), and
its outputs turned into per-pair arrays (``collect``)."""

from __future__ import annotations

from typing import Callable, NamedTuple

import jax
import numpy as np

from ...codes import EXCLUDED_STATUSES, PAIR_REASONS, REGION_OK
from ...config import SGCConfig
from ...io.clip import Clip
from ..evidence import parallax_px
from ..pairs import PairArrays
from ..units import in_depth_units
from .buckets import Bucket, PaddedClips, bucket_for, pad_clip
from .programs import pipeline

COMPONENT_OUTPUTS = ("local_rot_var", "local_trans_var", "global_rot_var", "global_trans_var", "depth_error",
                     "reproj_error", "t_g_norm", "R_g_angle_deg", "tracks_rot_deg", "tracks_trans")


class PreparedClip(NamedTuple):
    """A clip ready for the device: padded to its bucket (host arrays)."""

    n_pairs: int
    bucket: Bucket
    batch: PaddedClips
    depth_unit: float
    image_pixels: int  # H W of the clip's true frames
    K_curr: np.ndarray  # (n_pairs, 3, 3) frame i's intrinsics of each pair, float64


def prepare_clip(clip: Clip, config: SGCConfig) -> PreparedClip:
    """The host side of scoring a clip: depth units and padding (NumPy only, safe in a thread)."""
    clip, unit = in_depth_units(clip, config)
    bucket = bucket_for(clip)
    H, W = clip.image_size
    return PreparedClip(clip.n_pairs, bucket, pad_clip(clip, bucket, config, unit), unit, H * W,
                        clip.K[1:].astype(np.float64))


class Dispatched(NamedTuple):
    """Clips whose program has been called: ``out`` holds device arrays still being computed, clip b at index b."""

    prepared: list[PreparedClip]
    out: dict


def dispatch(prepared: PreparedClip, config: SGCConfig) -> Dispatched:
    """Start scoring a prepared clip on the default device; returns without waiting (a bucket's
    first clip compiles its program first)."""
    score = pipeline(config, prepared.bucket, prepared.batch)
    batch = PaddedClips(*jax.device_put(tuple(prepared.batch)))  # once, not per stage
    return Dispatched([prepared], score(batch))


def dispatch_group(group: list[PreparedClip], config: SGCConfig, devices: list, size: int,
                   vectorized: bool) -> Dispatched:
    """Start scoring up to ``size`` (a multiple of len(devices)) prepared clips of one bucket in one
    program sharded over ``devices``, ``vectorized`` or one clip after another (docs/semantics.md
    §9.3); a short group is filled with copies of its last clip, which ``collect`` leaves out."""
    fill = [group[-1].batch] * (size - len(group))
    stacked = PaddedClips(*(np.concatenate(arrays) for arrays in zip(*[p.batch for p in group], *fill)))
    score = pipeline(config, group[0].bucket, stacked, devices, vectorized)
    return Dispatched(group, score(PaddedClips(*jax.device_put(tuple(stacked), score.sharding))))


def device_steps(config: SGCConfig, devices: list, size: int, vectorized: bool) -> tuple[Callable, Callable]:
    """(start, collect) of ``scoring.engine_steps``: start a group of prepared clips (one clip per
    program call on the default device when ``size`` is 1, else up to ``size`` at once over
    ``devices``), and wait for its per-pair arrays."""
    if size == 1:
        return lambda group: dispatch(group[0], config), lambda dispatched: collect(dispatched, config)
    return (lambda group: dispatch_group(group, config, devices, size, vectorized),
            lambda dispatched: collect(dispatched, config))


def pair_arrays(out: dict, b: int, prepared: PreparedClip, scale: float, config: SGCConfig) -> PairArrays:
    """Clip b's per-pair arrays, with the scale to report (depth units per pose unit)."""
    take = lambda name: np.asarray(out[name][b, :prepared.n_pairs])  # noqa: E731
    t_g_norm = take("t_g_norm").astype(np.float64)
    status = take("region_status")
    posed = (status == REGION_OK) | np.isin(status, EXCLUDED_STATUSES)
    per_region = lambda name: np.where(posed, take(name), np.nan).astype(np.float64)  # noqa: E731
    return PairArrays(
        **{name: take(name).astype(np.float64) for name in COMPONENT_OUTPUTS},
        static_frac=take("region_pixels") / prepared.image_pixels,
        parallax_px=parallax_px(prepared.K_curr, t_g_norm, config.scale_free),
        n_tracks=take("n_tracks"), n_regions=take("n_regions"), n_poses=take("n_poses"),
        n_ill_conditioned=take("n_ill_conditioned"),
        reason=np.array([PAIR_REASONS[c] for c in take("reason")], dtype=object),
        R_local=np.where(posed[..., None, None], take("R_local"), np.nan).astype(np.float64),
        t_local=np.where(posed[..., None], take("t_local"), np.nan).astype(np.float64),
        region_status=status, region_points=take("region_points"), region_reproj=per_region("region_reproj"),
        region_rot_std=per_region("region_rot_std"), region_trans_std=per_region("region_trans_std"),
        region_rot_noise=per_region("region_rot_noise"), region_trans_noise=per_region("region_trans_noise"),
        region_sigma_px=per_region("region_sigma_px"), region_rot_per_px=per_region("region_rot_per_px"),
        region_trans_per_px=per_region("region_trans_per_px"), scale=scale, depth_unit=prepared.depth_unit)


def collect(dispatched: Dispatched, config: SGCConfig) -> list[PairArrays]:
    """Wait for dispatched clips -> their per-pair arrays, in order (a filled group's copies dropped)."""
    out = jax.device_get(dispatched.out)
    results = []
    for b, prepared in enumerate(dispatched.prepared):
        # s (per unit of D inside) reported in depth units per pose unit; 1 without a global translation
        scale = float(np.asarray(out["scale"][b])) * prepared.depth_unit if config.global_pose else 1.0
        results.append(pair_arrays(out, b, prepared, scale, config))
    return results


def score_pairs_batch(clips: list[Clip], config: SGCConfig | None = None) -> list[PairArrays]:
    """Per-pair arrays of every clip, one program call per clip on the default device, the next
    clip dispatched before the previous one's outputs are fetched."""
    config = config or SGCConfig()
    results, pending = [], None
    for clip in clips:
        current = dispatch(prepare_clip(clip, config), config)
        if pending is not None:
            results.extend(collect(pending, config))
        pending = current
    if pending is not None:
        results.extend(collect(pending, config))
    return results
