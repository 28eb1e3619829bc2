"""Forward depth warp with a z-buffer, and the depth error of docs/semantics.md §3.6. Pixels and
poses as in ``camera``."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from ..config import HOLE_DEPTH_MARGIN, HOLE_LEVELS
from .camera import back_project_xyz, project_xyz, transform_xyz

MIN_WARP_Z = 1e-5  # points at or behind this depth in the target camera are dropped


def _valid_depth(depth, valid):
    """(H, W) depth, (H, W) bool -> valid & depth > 0 & finite."""
    return valid & (depth > 0) & jnp.isfinite(depth)


class Splat(NamedTuple):
    """Frame i-1's pixels moved into frame i, flattened (H W,)."""

    target: jax.Array  # int32 pixel of frame i each lands on, H W where it is dropped
    z: jax.Array  # its depth in camera i
    u: jax.Array  # its pixel coordinates in frame i, unrounded
    v: jax.Array
    front: jax.Array  # bool: valid and z > MIN_WARP_Z
    magnification: jax.Array  # how many times larger its pixel is in frame i: depth i-1 / z, focal-scaled


def _moved_pixels(depth, valid, K_from, K_to, R, t, image_hw=None):
    """Valid pixels (H, W) of one frame back-projected at ``depth`` with K_from, moved by (R, t) and
    projected with K_to -> (Z, their depth before; z, after; u, v unrounded; iu, iv rounded half
    up; front: valid and z > MIN_WARP_Z; inside: front and (iu, iv) in the image), all (H, W).
    ``image_hw`` (2,): the true image size within a padded (H, W), which ``inside`` keeps to."""
    H, W = depth.shape
    depth = depth.astype(jnp.float32)
    valid = _valid_depth(depth, valid)
    K_from, K_to, R, t = (a.astype(jnp.float32) for a in (K_from, K_to, R, t))
    # Coordinate arrays, not (H, W, 3) stacks: back-project, R X + t and project fuse into one
    # elementwise pass over the pixels (a (H W, 3) @ (3, 3) matmul and stacks cost more on CPU).
    v = jnp.arange(H, dtype=jnp.float32)[:, None]
    u = jnp.arange(W, dtype=jnp.float32)[None, :]
    X, Y, Z = back_project_xyz(K_from, u, v, jnp.where(valid, depth, 1.0))
    Xc, Yc, z = transform_xyz(R, t, X, Y, Z)
    front = valid & (z > MIN_WARP_Z)
    u_c, v_c = project_xyz(K_to, Xc, Yc, jnp.where(front, z, 1.0))
    iu, iv = jnp.floor(u_c + 0.5), jnp.floor(v_c + 0.5)
    height, width = (H, W) if image_hw is None else (image_hw[0].astype(jnp.float32), image_hw[1].astype(jnp.float32))
    inside = front & (iu >= 0) & (iu < width) & (iv >= 0) & (iv < height)  # False for NaN coordinates too
    return Z, z, u_c, v_c, iu, iv, front, inside


def splat(depth_prev, valid_prev, K_prev, K_curr, R, t) -> Splat:
    """Valid pixels of frame i-1 (H, W) back-projected, moved by (R, t), projected into frame i and
    rounded half up; those with z > MIN_WARP_Z inside the image keep their target."""
    H, W = depth_prev.shape
    Z, z, u_c, v_c, iu, iv, front, keep = _moved_pixels(depth_prev, valid_prev, K_prev, K_curr, R, t)
    target = jnp.where(keep, iv.astype(jnp.int32) * W + iu.astype(jnp.int32), H * W).reshape(-1)
    focal_ratio = jnp.sqrt(K_curr[0, 0] * K_curr[1, 1] / (K_prev[0, 0] * K_prev[1, 1])).astype(jnp.float32)
    magnification = jnp.where(front, Z * focal_ratio / jnp.where(front, z, 1.0), 0.0)
    return Splat(target, z.reshape(-1), u_c.reshape(-1), v_c.reshape(-1), front.reshape(-1),
                 magnification.reshape(-1))


def nearest_hits(points: Splat, H: int, W: int, mask_holes: bool):
    """The z-buffer (H W,) of the nearest z landing on each pixel (inf where none) and hit (H W,)."""
    buffer = jnp.full(H * W, jnp.inf, jnp.float32).at[points.target].min(points.z, mode="drop")
    hit = buffer < jnp.inf
    if mask_holes:
        cover = jnp.minimum(_footprint_cover(points.u, points.v, points.z, points.front, H, W),
                            _magnified_cover(points, H, W))
        hit = hit & (buffer <= (1.0 + HOLE_DEPTH_MARGIN) * cover)
    return buffer, hit


def warp_depth(depth_prev, valid_prev, K_prev, K_curr, R, t, *, nearest: bool = True, mask_holes: bool = False):
    """Depth (H, W) of frame i-1 warped into frame i -> (z (H, W) float32, 0 where nothing lands;
    hit (H, W) bool) (``splat``). Collisions keep the nearest z (``nearest``, a z-buffer) or the
    farthest (the authors' code). ``mask_holes`` (spec): no hit where a point nearer by more than
    HOLE_DEPTH_MARGIN lands within one pixel (within its square of side 2^l when magnified
    2^l to 2^(l+1) times, ``_magnified_cover``), since what reached it is seen through a gap between
    a magnified nearer surface's splats."""
    H, W = depth_prev.shape
    points = splat(depth_prev, valid_prev, K_prev, K_curr, R, t)
    if nearest:
        buffer, hit = nearest_hits(points, H, W, mask_holes)
    else:
        buffer = jnp.full(H * W, -jnp.inf, jnp.float32).at[points.target].max(points.z, mode="drop")
        hit = buffer > -jnp.inf
    warped = jnp.where(hit, buffer, 0.0)
    return warped.reshape(H, W), hit.reshape(H, W)


def warp_sources(depth_prev, valid_prev, K_prev, K_curr, R, t, *, mask_holes: bool = True):
    """The nearest-z warp's choice: (source (H W,) int32, the pixel of frame i-1 whose point each
    pixel of frame i keeps (the first of equal z), H W where none; hit (H, W) bool)."""
    H, W = depth_prev.shape
    points = splat(depth_prev, valid_prev, K_prev, K_curr, R, t)
    buffer, hit = nearest_hits(points, H, W, mask_holes)
    won = points.target < H * W
    won = won & (points.z == buffer[jnp.minimum(points.target, H * W - 1)])
    index = jnp.arange(H * W, dtype=jnp.int32)
    source = jnp.full(H * W, H * W, jnp.int32).at[jnp.where(won, points.target, H * W)].min(index, mode="drop")
    return jnp.where(hit, source, H * W), hit.reshape(H, W)


def _footprint_cover(u_c, v_c, z, front, H, W):
    """(H W,) nearest z of the points whose 2x2 footprint (floor(u) + {0, 1}, floor(v) + {0, 1})
    covers each pixel, inf where none does: holes up to a magnification of 2 are covered."""
    # one scatter to each footprint's corner on a grid with a row and column before the image's,
    # then the minimum over the 2x2 corners that reach a pixel: four scatters' minimum, for one
    u0, v0 = jnp.floor(u_c), jnp.floor(v_c)
    inside = front & (u0 >= -1) & (u0 < W) & (v0 >= -1) & (v0 < H)  # in float: no int overflow
    corner = jnp.where(inside, (v0.astype(jnp.int32) + 1) * (W + 1) + u0.astype(jnp.int32) + 1, (H + 1) * (W + 1))
    nearest = jnp.full((H + 1) * (W + 1), jnp.inf, jnp.float32).at[corner.reshape(-1)].min(z.reshape(-1), mode="drop")
    nearest = nearest.reshape(H + 1, W + 1)  # [1 + floor(v), 1 + floor(u)]
    cover = jnp.minimum(jnp.minimum(nearest[1:, 1:], nearest[1:, :-1]), jnp.minimum(nearest[:-1, 1:], nearest[:-1, :-1]))
    return cover.reshape(-1)


def _magnified_cover(points: Splat, H: int, W: int):
    """(H W,) nearest z of the points magnified m >= 2 times whose footprint on the grid of side
    s = 2^l, 2^l <= m < 2^(l+1) (cells floor(u / s) + {0, 1}, floor(v / s) + {0, 1}) covers each
    pixel, inf where none does: their splats lie less than 2 s apart, so each window of 2 s holds
    one. A pair without such a point skips the grids (on a CPU, where pairs run one by one)."""
    magnified = points.front & (points.magnification >= 2.0)
    none = jnp.full(H * W, jnp.inf, jnp.float32)
    return jax.lax.cond(jnp.any(magnified), lambda: _level_cover(points, magnified, H, W), lambda: none)


def _level_cover(points: Splat, magnified, H: int, W: int):
    """``_magnified_cover``'s grids: one scatter into all of them, then each level's 2x2 minimum,
    carried from the coarsest grid to the pixels by doubling (each pixel's cell at side s / 2 lies
    in its cell at side s)."""
    sides = [2**lv for lv in range(1, HOLE_LEVELS + 1)]
    cells = [(-(-H // s), -(-W // s)) for s in sides]
    shapes = [(h + 1, w + 1) for h, w in cells]  # a row and column before the image's
    starts = [sum(h * w for h, w in shapes[:lv]) for lv in range(len(shapes) + 1)]
    level = jnp.clip(jnp.floor(jnp.log2(jnp.maximum(points.magnification, 1.0))), 1, HOLE_LEVELS).astype(jnp.int32)
    pick = lambda values: jnp.array(values, jnp.int32)[level - 1]  # noqa: E731
    width, height, start = pick([w for _, w in shapes]), pick([h for h, _ in shapes]), pick(starts[:-1])
    side = jnp.exp2(level.astype(jnp.float32))
    u0, v0 = jnp.floor(points.u / side), jnp.floor(points.v / side)  # in float: no int overflow
    inside = magnified & (u0 >= -1) & (u0 < width - 1) & (v0 >= -1) & (v0 < height - 1)
    cell = start + (v0.astype(jnp.int32) + 1) * width + u0.astype(jnp.int32) + 1
    total = starts[-1]
    nearest = jnp.full(total, jnp.inf, jnp.float32).at[jnp.where(inside, cell, total)].min(points.z, mode="drop")
    cover = None
    for (h, w), first, (ch, cw) in reversed(list(zip(shapes, starts, cells))):  # static: coarsest first
        grid = nearest[first:first + h * w].reshape(h, w)
        coarse = jnp.minimum(jnp.minimum(grid[1:, 1:], grid[1:, :-1]), jnp.minimum(grid[:-1, 1:], grid[:-1, :-1]))
        cover = coarse if cover is None else jnp.minimum(coarse, cover[:ch, :cw])
        cover = jnp.repeat(jnp.repeat(cover, 2, axis=0), 2, axis=1)  # to the next finer grid's cells
    return cover[:H, :W].reshape(-1)


def seen_from_previous(depth_curr, valid_curr, K_prev, K_curr, R, t, image_hw=None):
    """(H, W) bool: valid pixels of frame i whose point at depth_curr lies in front of camera i-1
    (z > MIN_WARP_Z) and inside its image when rounded half up, (R, t) moving camera i-1's points
    into camera i; ``image_hw`` (2,): the frames' true size when (H, W) is padded (the padding is no
    part of frame i-1's image). What frame i-1 could not see, nothing warped from it can be compared
    with: a nearer surface entering the view covers background frame i-1 saw."""
    R, t = R.astype(jnp.float32), t.astype(jnp.float32)
    return _moved_pixels(depth_curr, valid_curr, K_curr, K_prev, R.T, -(R.T @ t), image_hw)[-1]


def depth_error(warped, hit, depth_curr, valid_curr, static_curr, *, relative: bool = False):
    """Mean |warped - depth_curr| over hit & valid (depth > 0, finite) & static (H, W) -> (float32,
    int32 count): in depth units, or relative to depth_curr (AbsRel, a fraction); NaN with no overlap."""
    both = hit & _valid_depth(depth_curr, valid_curr) & static_curr
    n = jnp.sum(both).astype(jnp.int32)
    error = jnp.abs(warped - depth_curr)
    if relative:
        error = error / jnp.where(both, depth_curr, 1.0)
    total = jnp.sum(jnp.where(both, error, 0.0).astype(jnp.float32))
    mean = jnp.where(n > 0, total / jnp.maximum(n, 1).astype(jnp.float32), jnp.nan)
    return mean.astype(jnp.float32), n
