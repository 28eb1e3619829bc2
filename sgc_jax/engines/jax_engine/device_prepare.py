"""The host's clip preparation written for the device (docs/semantics.md §9.2): a network's ramps at
depth edges left out, absurd depth made invalid, depth in units of D, usable tracks, the
``max_tracks`` selection and padding to the bucket, with the numbers of ``units.in_depth_units``,
``arrays.subsample_tracks`` and ``buckets.pad_clip``. Traceable: no host round-trip, so a user's
``jax.jit`` can hold it."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from ...config import SGCConfig
from ...io.arrays import evenly_spaced_ranks
from ...io.clip import DEPTH_RATIO_LIMIT, within_reach
from ...io.depth_edges import DEPTH_EDGE_RATIO, RAMP_MARGIN, edges_are_ramps, ramp_frames
from ...kernels.double_float import df_div, df_mul, df_sub, two_sum
from ...kernels.medians import order_statistics
from .buckets import Bucket, PaddedClips


class ClipArrays(NamedTuple):
    """B clips as the caller gives them, one shape for all (T, H, W, P); the true sizes say how
    much of it each clip fills (the rest is padding)."""

    depth: jax.Array  # (B, T, H, W) float32, input depth units
    K: jax.Array  # (B, T, 3, 3)
    R_wc: jax.Array  # (B, T, 3, 3)
    t_wc: jax.Array  # (B, T, 3)
    static_mask: jax.Array  # (B, T, H, W) bool
    track_prev: jax.Array  # (B, T-1, P, 2) px
    track_curr: jax.Array  # (B, T-1, P, 2) px
    track_vis: jax.Array  # (B, T-1, P) bool
    track_conf: jax.Array  # (B, T-1, P) float32
    n_frames: jax.Array  # (B,) int32
    n_tracks: jax.Array  # (B,) int32
    heights: jax.Array  # (B,) int32
    widths: jax.Array  # (B,) int32


def _ramps(depth, valid, ratio):
    """(..., H, W) bool: the ``valid`` pixels on a ramp at a depth edge (``io.depth_edges.edges_and_ramps``),
    and (..., H, W) bool: those at an edge."""
    window, strides = (1,) * (depth.ndim - 2) + (3, 3), (1,) * depth.ndim
    inf, zero = jnp.array(jnp.inf, depth.dtype), jnp.array(0, depth.dtype)  # the depth's dtype, x64 or not
    low = jax.lax.reduce_window(jnp.where(valid, depth, inf), inf, jax.lax.min, window, strides, "SAME")
    high = jax.lax.reduce_window(jnp.where(valid, depth, zero), zero, jax.lax.max, window, strides, "SAME")
    edges = valid & (high > ratio * low)
    return edges & (depth > (1 + RAMP_MARGIN) * low) & ((1 + RAMP_MARGIN) * depth < high), edges


def depth_without_ramps(depth: jax.Array, ratio: float = DEPTH_EDGE_RATIO, inside=True) -> jax.Array:
    """``depth`` (..., H, W) with 0 on the ramps at its edges, as ``adapters.leave_out_depth_ramps``
    does on the host (the same numbers; docs/semantics.md §3.6, "Smooth depth edges"): for a training
    loop whose depth network's output goes to the Scorer. Traceable; ``ratio`` may be traced.
    ``inside``: where the pixels are the clip's (the rest is no neighbour)."""
    ramps, _ = _ramps(depth, inside & jnp.isfinite(depth) & (depth > 0), ratio)
    return jnp.where(ramps, jnp.zeros_like(depth), depth)


def has_smooth_edges(clip: ClipArrays):
    """() bool: the clip's depth edges are ramps (``io.depth_edges.has_smooth_edges``: read on the
    same frames, decided alike)."""
    frames = ramp_frames(clip.n_frames, xp=jnp)  # ascending; a repeat is read once
    once = jnp.concatenate([jnp.ones(1, bool), frames[1:] != frames[:-1]])
    _, inside = true_extent(clip)
    depth = clip.depth[frames]
    valid = inside[frames] & once[:, None, None] & jnp.isfinite(depth) & (depth > 0)
    ramps, edges = _ramps(depth, valid, DEPTH_EDGE_RATIO)
    count = lambda mask: jnp.sum(mask, dtype=jnp.int32)  # noqa: E731
    return edges_are_ramps(count(valid), count(edges), count(ramps), xp=jnp)


def ramps_left_out(clip: ClipArrays, smooth, check) -> jax.Array:
    """The clip's depth (T, H, W), its ramps 0 where ``smooth`` (() bool: ``has_smooth_edges``);
    computed where ``check`` (() bool, any clip of the batch smooth; a conditional, so a batch
    without such depth skips it)."""
    def left_out():
        _, inside = true_extent(clip)
        return jnp.where(smooth, depth_without_ramps(clip.depth, DEPTH_EDGE_RATIO, inside), clip.depth)

    return jax.lax.cond(check, left_out, lambda: clip.depth)


def masked_median(values, mask):
    """The median of the positive finite values[mask] as a double-float (hi, lo): the middle value,
    or the two middle values averaged exactly (as ``stats.exact_median`` does in float64); (1, 0)
    when mask is empty."""
    n = jnp.sum(mask, dtype=jnp.int32)
    lower, upper = order_statistics(values, mask)
    total, error = two_sum(lower, upper)  # lower + upper exactly; halving is exact
    hi, lo = jnp.where(n % 2 == 1, upper, 0.5 * total), jnp.where(n % 2 == 1, 0.0, 0.5 * error)
    return jnp.where(n > 0, hi, 1.0), jnp.where(n > 0, lo, 0.0)


def pixel_median(values, mask):
    """The median of values[mask] (what ``masked_median`` gives, to float rounding) as the value
    of its one or two middle pixels, so that its gradient reaches them; 1 when mask is empty. The
    pixels are chosen on the values as float32, held fixed."""
    n = jnp.sum(mask, dtype=jnp.int32)
    chosen = jax.lax.stop_gradient(values).astype(jnp.float32)
    lower, upper = order_statistics(chosen, mask)
    flat, pick = values.reshape(-1), mask.reshape(-1)
    at_lower = flat[jnp.argmax(pick & (chosen.reshape(-1) == lower))]
    at_upper = flat[jnp.argmax(pick & (chosen.reshape(-1) == upper))]
    return jnp.where(n > 0, jnp.where(n % 2 == 1, at_upper, 0.5 * (at_lower + at_upper)), 1.0)


def greater_than(x, df):
    """x > hi + lo exactly, for float32 x and a double-float with |lo| below half an ulp of hi."""
    return (x > df[0]) | ((x == df[0]) & (df[1] < 0))


def divide_rounded(x, divisor):
    """float32(x / (hi + lo)) correctly rounded (what float64 division then rounding to float32
    gives), for a double-float divisor > 0: of the floats within 2 ulps of x / hi, the one whose
    product with the divisor lies nearest x."""
    q = x / divisor[0]
    steps = [jnp.nextafter(q, -jnp.inf), q, jnp.nextafter(q, jnp.inf)]
    candidates = [jnp.nextafter(steps[0], -jnp.inf), *steps, jnp.nextafter(steps[2], jnp.inf)]
    miss = lambda c: jnp.abs(df_sub((x, jnp.zeros_like(x)), df_mul((c, jnp.zeros_like(c)), divisor))[0])  # noqa: E731
    # a running minimum (the first candidate on ties), elementwise: XLA fuses it into one pass over
    # the pixels, where stacked candidates and an argmin took ~20x longer
    rounded, least = candidates[0], miss(candidates[0])
    for c in candidates[1:]:
        m = miss(c)
        rounded, least = jnp.where(m < least, c, rounded), jnp.minimum(m, least)
    return jnp.where(jnp.isfinite(q), rounded, q)


def true_extent(clip: ClipArrays):
    """(frame (T,), inside (T, H, W)) bool: the clip's true frames, and its true image in them."""
    T, H, W = clip.depth.shape
    frame = jnp.arange(T) < clip.n_frames
    return frame, frame[:, None, None] & (jnp.arange(H) < clip.heights)[:, None] & (jnp.arange(W) < clip.widths)


def positive_depth(clip: ClipArrays):
    """(T, H, W) bool: the clip's finite, positive depth inside its true extent."""
    return true_extent(clip)[1] & jnp.isfinite(clip.depth) & (clip.depth > 0)


def may_hold_absurd_depth(depth, positive):
    """Whether some positive depth can lie beyond DEPTH_RATIO_LIMIT of their median: the largest
    beyond the smallest times it, in float32, as ``io.clip.without_absurd_depth`` decides."""
    lo = jnp.min(jnp.where(positive, depth, jnp.inf))
    hi = jnp.max(jnp.where(positive, depth, -jnp.inf))
    return hi > lo * jnp.float32(DEPTH_RATIO_LIMIT)


def valid_without_absurd_depth(depth, positive, check=True):
    """``positive`` less the absurd depth (beyond DEPTH_RATIO_LIMIT of the median of the positive
    values; docs/semantics.md §1.2), compared as float64 would; ``check`` (traced bool) False:
    ``positive``, without the median, where ``may_hold_absurd_depth`` says none can be."""

    def without_absurd():
        median = masked_median(depth, positive)
        too_far = greater_than(depth, df_mul(median, (jnp.float32(DEPTH_RATIO_LIMIT), jnp.float32(0.0))))
        low = df_div(median, jnp.float32(DEPTH_RATIO_LIMIT))
        too_near = (depth < low[0]) | ((depth == low[0]) & (low[1] > 0))
        return positive & ~too_far & ~too_near

    return jax.lax.cond(check, without_absurd, lambda: positive)


def first_usable_tracks(clip: ClipArrays, config: SGCConfig):
    """(T-1, P) bool: visible, confident, within reach, of a true pair and track (§1.2), repeats
    not yet left out."""
    T, P = clip.track_prev.shape[0] + 1, clip.track_prev.shape[1]
    pair = jnp.arange(T - 1) < clip.n_frames - 1
    return (clip.track_vis & (jnp.nan_to_num(clip.track_conf, nan=0.0) >= config.min_track_conf)
            & within_reach(clip.track_prev, clip.heights, clip.widths)
            & within_reach(clip.track_curr, clip.heights, clip.widths)
            & pair[:, None] & (jnp.arange(P) < clip.n_tracks))


def _coordinates(track_prev, track_curr) -> list:
    """The four coordinates (..., P) of each track's two positions, -0.0 made 0.0 (== holds them equal)."""
    return [jnp.where(c == 0, 0.0, c) for c in (track_prev[..., 0], track_prev[..., 1], track_curr[..., 0],
                                                  track_curr[..., 1])]


def _mixed(h):
    """A 32-bit integer finaliser (each input bit moves about half of the output's)."""
    h = (h ^ (h >> 16)) * jnp.uint32(0x7FEB352D)
    h = (h ^ (h >> 15)) * jnp.uint32(0x846CA68B)
    return h ^ (h >> 16)


def may_hold_repeats(track_prev, track_curr, usable):
    """() bool, False only where no pair holds a repeat: two usable tracks whose positions agree
    share both of two 32-bit hashes of them, so each hash sorted (one operand, the cheap sort)
    shows them side by side. Unrelated tracks share both in ~1e-3 of standard clips."""
    # hashed in float32 whatever the dtype (float64 under gradient checks): equal values stay equal
    bits = [jax.lax.bitcast_convert_type(c.astype(jnp.float32), jnp.uint32) for c in _coordinates(track_prev, track_curr)]
    adjacent_equal = []
    for seed, step in ((0x9E3779B9, 0x85EBCA77), (0xC2B2AE3D, 0x27D4EB2F)):
        h = jnp.full(usable.shape, seed, jnp.uint32)
        for word in bits:
            h = _mixed(h ^ (word * jnp.uint32(step)))
        ordered = jnp.sort(jnp.where(usable, h | 1, 0), axis=-1)  # unusable: 0, never a match
        adjacent_equal.append(jnp.any((ordered[..., 1:] == ordered[..., :-1]) & (ordered[..., 1:] > 0)))
    return adjacent_equal[0] & adjacent_equal[1]


def repeated_tracks(track_prev, track_curr, usable):
    """(P,) bool: the ``usable`` (P,) tracks of one pair whose positions (P, 2) at frame i-1 and i both
    equal (==) a usable track's of lower index (``io.clip.repeated_tracks``): one sort of the usable
    tracks by their four coordinates, then by index."""
    P = usable.shape[0]
    coords = _coordinates(track_prev, track_curr)
    unusable, *coords, index = jax.lax.sort(((~usable).astype(jnp.int32), *coords, jnp.arange(P)), num_keys=6)
    same = (unusable[1:] == 0) & (unusable[:-1] == 0)
    for c in coords:
        same &= c[1:] == c[:-1]
    return jnp.zeros(P, bool).at[index[1:]].set(same)


def without_repeats(clip: ClipArrays, usable, check_repeats):
    """``usable`` (T-1, P) less the repeats (``repeated_tracks``), looked for where ``check_repeats``
    (() bool; a conditional, so a batch without any skips the sort by coordinates)."""
    repeated = jax.lax.cond(check_repeats, lambda: jax.vmap(repeated_tracks)(clip.track_prev, clip.track_curr, usable),
                            lambda: jnp.zeros(usable.shape, bool))
    return usable & ~repeated


def select_tracks(usable, limit: int):
    """(P,) usable -> (limit,) indices of the kept tracks (``arrays.subsample_tracks``): usable
    ones first in their order, evenly spaced when more than ``limit``; then unusable ones."""
    order = jnp.argsort(~usable, stable=True)
    n = jnp.sum(usable, dtype=jnp.int32)
    spaced = order[evenly_spaced_ranks(n, limit, xp=jnp)]
    return jnp.where(n > limit, spaced, order[:limit])


def prepare_one(clip: ClipArrays, bucket: Bucket, config: SGCConfig, check_absurd=None,
                check_repeats=None, smooth_edges=None, check_ramps=None) -> PaddedClips:
    """One clip (no B axis) -> its padded arrays (no B axis), as ``dispatch.prepare_clip`` makes them.
    ``check_absurd``, ``check_repeats``, ``check_ramps``: whether to look for absurd depth, for
    repeated tracks and for ramps to leave out (default: ``may_hold_absurd_depth``,
    ``may_hold_repeats``, ``smooth_edges``); ``smooth_edges``: ``has_smooth_edges`` of the clip
    (computed when not given)."""
    if config.leaves_out_depth_ramps:
        smooth_edges = has_smooth_edges(clip) if smooth_edges is None else smooth_edges
        clip = clip._replace(depth=ramps_left_out(clip, smooth_edges,
                                                  smooth_edges if check_ramps is None else check_ramps))
    T = clip.depth.shape[0]
    P = clip.track_prev.shape[1]
    frame, inside = true_extent(clip)
    positive = positive_depth(clip)
    if check_absurd is None:
        check_absurd = may_hold_absurd_depth(clip.depth, positive)
    valid = valid_without_absurd_depth(clip.depth, positive, check_absurd)
    static = clip.static_mask if config.use_mos else jnp.ones_like(clip.static_mask)
    depth = clip.depth
    if config.scale_free:  # D: the median static valid depth, of all valid depth when none is static
        chosen = valid & static
        unit = masked_median(depth, jnp.where(jnp.any(chosen), chosen, valid))
        depth = jnp.where(valid, divide_rounded(jnp.where(valid, depth, 1.0), unit), 0.0)
        depth_unit = unit[0] + unit[1]  # float32(D): hi, as lo is below half its ulp
    else:
        depth_unit = jnp.float32(1.0)
    depth = jnp.where(valid & jnp.isfinite(depth) & (depth > 0), depth, 0.0)

    last = jnp.maximum(clip.n_frames - 1, 0)
    K = jnp.where(frame[:, None, None], clip.K, clip.K[last])
    R_wc = jnp.where(frame[:, None, None], clip.R_wc, jnp.eye(3, dtype=clip.R_wc.dtype))
    t_wc = jnp.where(frame[:, None], clip.t_wc, 0.0)

    usable = first_usable_tracks(clip, config)
    if not config.counts_repeated_tracks:
        if check_repeats is None:
            check_repeats = may_hold_repeats(clip.track_prev, clip.track_curr, usable)
        usable = without_repeats(clip, usable, check_repeats)
    track_prev, track_curr = clip.track_prev, clip.track_curr
    if P > config.max_tracks:
        index = jax.vmap(lambda row: select_tracks(row, config.max_tracks))(usable)
        keep = jnp.where(clip.n_tracks > config.max_tracks, index, jnp.arange(config.max_tracks))
        usable = jnp.take_along_axis(usable, keep, axis=1)
        track_prev = jnp.take_along_axis(track_prev, keep[..., None], axis=1)
        track_curr = jnp.take_along_axis(track_curr, keep[..., None], axis=1)
    track_prev = jnp.where(usable[..., None], track_prev, 0.0)
    track_curr = jnp.where(usable[..., None], track_curr, 0.0)

    grow = lambda a, sizes: jnp.pad(a, [(0, s - n) for s, n in zip(sizes, a.shape)])  # noqa: E731
    Tb, Hb, Wb, Pb = bucket.T, bucket.H, bucket.W, bucket.P
    pad_frames = jnp.arange(Tb) >= T
    return PaddedClips(
        depth=grow(depth, (Tb, Hb, Wb)), static=grow(static & inside, (Tb, Hb, Wb)),
        K=jnp.where(pad_frames[:, None, None], K[last], grow(K, (Tb, 3, 3))),
        R_wc=jnp.where(pad_frames[:, None, None], jnp.eye(3, dtype=R_wc.dtype), grow(R_wc, (Tb, 3, 3))),
        t_wc=grow(t_wc, (Tb, 3)), track_prev=grow(track_prev, (Tb - 1, Pb, 2)),
        track_curr=grow(track_curr, (Tb - 1, Pb, 2)), usable=grow(usable, (Tb - 1, Pb)),
        pair_valid=jnp.arange(Tb - 1) < clip.n_frames - 1,
        image_hw=jnp.stack([clip.heights, clip.widths]).astype(jnp.int32), depth_unit=depth_unit)


def prepare_differentiable(clip: ClipArrays, bucket: Bucket, config: SGCConfig) -> tuple[PaddedClips, PaddedClips]:
    """``prepare_one`` with gradients (docs/semantics.md §10.1) -> (the padded clip with gradients,
    the forward pass's padded clip). Every choice (valid depth, usable and kept tracks) is made on
    the float32 depth as ``prepare_one`` makes it; the depth is divided by a D that is the value of
    its median pixels, the rest gathered from the live arrays."""
    depth32 = jax.lax.stop_gradient(clip.depth).astype(jnp.float32)
    fixed = prepare_one(clip._replace(depth=depth32), bucket, config)
    T, H, W = clip.depth.shape
    valid = fixed.depth[:T, :H, :W] > 0
    depth = clip.depth
    if config.scale_free:
        chosen = valid & fixed.static[:T, :H, :W]
        unit = pixel_median(depth, jnp.where(jnp.any(chosen), chosen, valid))
        depth = jnp.where(valid, jnp.where(valid, depth, 1.0) / unit, 0.0)
    else:
        unit = jnp.ones((), depth.dtype)
        depth = jnp.where(valid, depth, 0.0)
    grown = jnp.pad(depth, [(0, s - n) for s, n in zip(fixed.depth.shape, depth.shape)])
    return fixed._replace(depth=grown, depth_unit=unit), jax.lax.stop_gradient(fixed)


def prepare_on_device(clips: ClipArrays, bucket: Bucket, config: SGCConfig) -> PaddedClips:
    """B clips -> the padded batch (leading axis B) the stages take. Absurd depth is looked for
    in every clip when any clip may hold some: one decision for the batch stays a conditional
    under the vmap, where each clip's own would compute both branches (the median's passes); so
    are repeated tracks (the sort by coordinates) and smooth depth edges (the ramps left out)."""
    smooth = jax.vmap(has_smooth_edges)(clips) if config.leaves_out_depth_ramps else None
    ramps = jnp.any(smooth) if config.leaves_out_depth_ramps else None
    check = jnp.any(jax.vmap(lambda clip: may_hold_absurd_depth(clip.depth, positive_depth(clip)))(clips))
    repeats = None
    if not config.counts_repeated_tracks:
        repeats = jnp.any(jax.vmap(lambda clip: may_hold_repeats(clip.track_prev, clip.track_curr,
                                                                  first_usable_tracks(clip, config)))(clips))
    return jax.vmap(lambda clip, smooth_edges: prepare_one(clip, bucket, config, check, repeats, smooth_edges, ramps)
                    )(clips, smooth)
