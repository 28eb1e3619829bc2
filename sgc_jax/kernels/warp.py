"""Forward depth warp with a z-buffer, and the depth error of docs/semantics.md §3.6. Pixels and
poses as in ``camera``."""

from __future__ import annotations

import functools
import itertools
from typing import NamedTuple

import jax
import jax.numpy as jnp

from ..config import DEPTH_EDGE_RATIO, HOLE_DEPTH_MARGIN, HOLE_LEVELS, LOOK_BACK_RATIO, MAX_HOLE_REACH_PX
from .camera import back_project_xyz, project_xyz, transform_xyz
from .depth_map import pair_depth_map
from .fence import gather_apart

MIN_WARP_Z = 1e-5  # points at or behind this depth in the target camera are dropped


def _valid_depth(depth, valid):
    """(H, W) depth, (H, W) bool -> valid & depth > 0 & finite."""
    return valid & (depth > 0) & jnp.isfinite(depth)


def source_pixels(depth_prev, valid_prev):
    """(H, W) bool: the pixels of frame i-1 the warp moves (valid depth where ``valid_prev``)."""
    return _valid_depth(depth_prev, valid_prev)


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


def at_pixel_centre(u, v, z, front, depth_curr, comparable):
    """Each point's depth z (N,) at (u, v) (N,) in frame i carried to its rounded pixel's centre along
    frame i's surface: z d_i(pixel) / d_i(u, v), with 1 / d_i(u, v) frame i's inverse depth
    interpolated bilinearly over the four pixels around (u, v) (exact on a plane), where those four
    are ``comparable`` (H, W) and lie on one surface (largest / smallest <= DEPTH_EDGE_RATIO); z
    elsewhere. Compared at the pixel, its error is then its own position's: the rounding to the
    nearest pixel moves no depth (docs/semantics.md §3.6 step 2)."""
    H, W = depth_curr.shape
    d = jnp.where(comparable, depth_curr.astype(jnp.float32), 0.0).reshape(-1)
    u0, v0 = jnp.floor(u), jnp.floor(v)
    inside = front & (u0 >= 0) & (u0 < W - 1) & (v0 >= 0) & (v0 < H - 1)  # False for NaN coordinates too
    fu, fv = jnp.where(inside, u - u0, 0.0), jnp.where(inside, v - v0, 0.0)
    first = jnp.where(inside, v0, 0.0).astype(jnp.int32) * W + jnp.where(inside, u0, 0.0).astype(jnp.int32)
    # (4, N): the pixels (u0, v0), (u0 + 1, v0), (u0, v0 + 1), (u0 + 1, v0 + 1)
    corners = gather_apart(d, jnp.stack([first, first + 1, first + W, first + W + 1]))
    lowest, highest = jnp.min(corners, axis=0), jnp.max(corners, axis=0)
    one_surface = inside & (lowest > 0) & (highest <= DEPTH_EDGE_RATIO * lowest)
    d00, d10, d01, d11 = jnp.where(one_surface, corners, 1.0)
    inverse = (1.0 - fv) * ((1.0 - fu) / d00 + fu / d10) + fv * ((1.0 - fu) / d01 + fu / d11)
    right, below = fu >= 0.5, fv >= 0.5  # which of the four the point rounds to
    at_pixel = jnp.where(below, jnp.where(right, d11, d01), jnp.where(right, d10, d00))
    return jnp.where(one_surface, z * (at_pixel * inverse), z)


def _compared_z(points: Splat, at_point):
    """The z each point offers the z-buffer: its own, or with ``at_point`` (frame i's depth (H, W),
    the pixels it is compared on (H, W)) read at its pixel's centre (``at_pixel_centre``)."""
    if at_point is None:
        return points.z
    return at_pixel_centre(points.u, points.v, points.z, points.front, *at_point)


def nearest_hits(points: Splat, H: int, W: int, mask_holes: bool, magnified: bool = True, z=None):
    """The z-buffer (H W,) of the nearest z landing on each pixel (inf where none) and hit (H W,);
    ``z``: the value each point offers (its own z by default; ``_compared_z``); ``mask_holes``: the
    hole rule (``_hole_cover``; ``magnified``: for points magnified 2x or more too, which may be left
    out only where there are none, ``has_magnified``)."""
    z = points.z if z is None else z
    buffer = jnp.full(H * W, jnp.inf, jnp.float32).at[points.target].min(z, mode="drop")
    hit = buffer < jnp.inf
    if mask_holes:
        cover = _hole_cover(points, H, W) if magnified else _ordinary_cover(points, H, W)
        hit = hit & (buffer <= (1.0 + HOLE_DEPTH_MARGIN) * cover)
    return buffer, hit


def has_magnified(depth_prev, valid_prev, K_prev, K_curr, R, t):
    """bool: some valid pixel of frame i-1 comes 2x or more nearer in frame i (``splat``): only then
    does the hole rule need its larger squares, which cost a pair several times the rest."""
    points = splat(depth_prev, valid_prev, K_prev, K_curr, R, t)
    return jnp.any(points.front & (points.magnification >= 2.0))


def warp_depth(depth_prev, valid_prev, K_prev, K_curr, R, t, *, nearest: bool = True, mask_holes: bool = False,
               magnified: bool = True, at_point=None):
    """Depth (H, W) of frame i-1 warped into frame i -> (z (H, W) float32, 0 where nothing lands;
    hit (H, W) bool) (``splat``). Collisions keep the nearest z (``nearest``, a z-buffer) or the
    farthest (the authors' code). ``mask_holes`` (spec): no hit where a point nearer by more than
    HOLE_DEPTH_MARGIN lies within its reach (``hole_reach``, ``_hole_cover``), since what reached
    it is seen through a gap between a nearer surface's splats or past its last one;
    ``magnified``: as in ``nearest_hits``; ``at_point`` (spec, with ``nearest``): frame i's depth
    and compared pixels (H, W), each point's z read at its pixel's centre (``at_pixel_centre``)."""
    H, W = depth_prev.shape
    points = splat(depth_prev, valid_prev, K_prev, K_curr, R, t)
    if nearest:
        buffer, hit = nearest_hits(points, H, W, mask_holes, magnified, _compared_z(points, at_point))
    else:
        buffer = jnp.full(H * W, -jnp.inf, jnp.float32).at[points.target].max(points.z, mode="drop")
        hit = buffer > -jnp.inf
    warped = jnp.where(hit, buffer, 0.0)
    return warped.reshape(H, W), hit.reshape(H, W)


def warp_sources(depth_prev, valid_prev, K_prev, K_curr, R, t, *, mask_holes: bool = True, magnified: bool = True,
                 at_point=None):
    """The nearest-z warp's choice (``warp_depth``'s arguments): (source (H W,) int32, the pixel of
    frame i-1 whose point each pixel of frame i keeps (the first of equal z), H W where none; hit
    (H, W) bool)."""
    H, W = depth_prev.shape
    points = splat(depth_prev, valid_prev, K_prev, K_curr, R, t)
    z = _compared_z(points, at_point)
    buffer, hit = nearest_hits(points, H, W, mask_holes, magnified, z)
    won = points.target < H * W
    won = won & (z == buffer[jnp.minimum(points.target, H * W - 1)])
    index = jnp.arange(H * W, dtype=jnp.int32)
    source = jnp.full(H * W, H * W, jnp.int32).at[jnp.where(won, points.target, H * W)].min(index, mode="drop")
    return jnp.where(hit, source, H * W), hit.reshape(H, W)


def hole_reach(magnification):
    """A point's reach r [px] in the hole rule (docs/semantics.md §3.6 step 3): its magnification
    m, at least 1 (a pixel's neighbours) and at most MAX_HOLE_REACH_PX."""
    return jnp.clip(magnification, 1.0, MAX_HOLE_REACH_PX)


def _hole_cover(points: Splat, H: int, W: int):
    """(H W,) nearest z of the front points whose square covers each pixel, inf where none does:
    a point of reach r (``hole_reach``) at (u, v) covers the pixels (k, j) with u - r < k <= u + r
    and v - r < j <= v + r."""
    return jnp.minimum(_ordinary_cover(points, H, W), _magnified_cover(points, H, W))


def _ordinary_cover(points: Splat, H: int, W: int):
    """``_hole_cover`` for the points magnified less than 2x (level 0: squares of 2 to 4 pixels)."""
    return _level_squares(points, points.front & (points.magnification < 2.0), (0,), H, W)


def _magnified_cover(points: Splat, H: int, W: int):
    """``_hole_cover`` for the points magnified 2x or more (levels 1 .. HOLE_LEVELS)."""
    return _level_squares(points, points.front & (points.magnification >= 2.0), tuple(range(1, HOLE_LEVELS + 1)), H, W)


def _level_squares(points: Splat, on, levels: tuple[int, ...], H: int, W: int):
    """``_hole_cover`` for the points ``on`` (H W,), all of reach 2^l <= r < 2^(l+1) for some l in
    ``levels`` -> (H W,). Per level a grid of the first pixels of P = 2^(l+1) wide squares, then its
    sliding P x P minimum: a point's square (P to 2 P a side) is the union of the four P-squares
    anchored at its corners, one scatter each."""
    reach = hole_reach(points.magnification)
    level = jnp.clip(jnp.floor(jnp.log2(reach)), levels[0], levels[-1]).astype(jnp.int32)
    sides = [2 ** (lv + 1) for lv in levels]
    shapes = [(H + side - 1, W + side - 1) for side in sides]  # a square's first pixel, from 1 - P on
    starts = [sum(h * w for h, w in shapes[:k]) for k in range(len(shapes) + 1)]
    of_level = [level == lv for lv in levels]
    pick = lambda values: jnp.select(of_level, [jnp.asarray(x) for x in values], values[0])  # noqa: E731
    side, width, start = pick(sides), pick([w for _, w in shapes]), pick(starts[:-1])
    firsts = []
    for centre, extent in ((points.v, H), (points.u, W)):  # per axis, in float: no int overflow
        firsts.append([(first + (side - 1), (first > -side) & (first < extent))
                       for first in (jnp.floor(centre - reach) + 1.0, jnp.floor(centre + reach) + 1.0 - side)])
    total = starts[-1]
    grids = jnp.full(total, jnp.inf, jnp.float32)
    for (row, row_in), (col, col_in) in itertools.product(*firsts):
        cell = jnp.where(on & row_in & col_in, start + row.astype(jnp.int32) * width + col.astype(jnp.int32), total)
        # four scatters of n points, each apart from the computation of its cells: one scatter of
        # 4 n, or the cells fused into it, runs several times slower on a CPU
        cell, z = jax.lax.optimization_barrier((cell, points.z))
        grids = grids.at[cell].min(z, mode="drop")
    covers = [_sliding_min(grids[first:first + h * w].reshape(h, w), side)
              for (h, w), first, side in zip(shapes, starts, sides)]
    return functools.reduce(jnp.minimum, covers).reshape(-1)


def _sliding_min(grid, side: int):
    """(h - side + 1, w - side + 1): the minimum over each side x side window of ``grid`` (h, w),
    ``side`` a power of two, by doubling the window along each axis."""
    for axis in (0, 1):
        width = 1
        while width < side:
            n = grid.shape[axis]
            grid = jnp.minimum(jax.lax.slice_in_dim(grid, 0, n - width, axis=axis),
                               jax.lax.slice_in_dim(grid, width, n, axis=axis))
            width *= 2
    return grid


class PreviousView(NamedTuple):
    """Frame i's pixels (H, W) as camera i-1 sees them (``previous_view``)."""

    # bool: in front of camera i-1 (z > MIN_WARP_Z) and inside its true image when rounded half up:
    # what frame i-1 could not see, nothing warped from it can be compared with
    seen: jax.Array
    z: jax.Array  # the point's depth in camera i-1
    landing: jax.Array  # int32 flat pixel of frame i-1 it lands on (rounded half up), 0 where not seen


def previous_view(depth_curr, valid_curr, K_prev, K_curr, R, t, image_hw=None) -> PreviousView:
    """Frame i's valid pixels at depth_curr moved into camera i-1 by the inverse of (R, t) and
    projected with K_prev; ``image_hw`` (2,): the frames' true size when (H, W) is padded (the
    padding is no part of frame i-1's image)."""
    R, t = R.astype(jnp.float32), t.astype(jnp.float32)
    _, z, _, _, iu, iv, _, seen = _moved_pixels(depth_curr, valid_curr, K_curr, K_prev, R.T, -(R.T @ t), image_hw)
    W = depth_curr.shape[1]
    landing = jnp.where(seen, iv.astype(jnp.int32) * W + iu.astype(jnp.int32), 0)
    return PreviousView(seen, z, landing)


def depth_at_landing(depth_prev, valid_prev, view: PreviousView):
    """(H, W) frame i-1's depth at the pixel each of frame i's pixels lands on (``view``), 0 where
    it is not seen or lands on a pixel frame i-1 does not warp (invalid depth or not ``valid_prev``,
    its static mask under spec). One gather serves its three uses: where it is 0, frame i-1 never
    saw the surface frame i shows (a sensor's dropout, a masked object), and what the warp put on
    the pixel is background seen past it (``spec_depth_error``, docs/semantics.md §3.6 step 4);
    where it is nearer than the pixel's point, frame i-1 saw that point behind it
    (``occluded_in_previous``); where the warp put a surface LOOK_BACK_RATIO times farther, it is
    read (step 5)."""
    source = jnp.where(source_pixels(depth_prev, valid_prev), depth_prev.astype(jnp.float32), 0.0).reshape(-1)
    return jnp.where(view.seen, gather_apart(source, view.landing.reshape(-1)).reshape(view.seen.shape), 0.0)


def occluded_in_previous(warped, depth_curr, view: PreviousView, at_landing):
    """(H, W) bool: pixels of frame i whose point frame i-1 saw behind a nearer surface (its depth
    ``at_landing`` below the point's z in camera i-1 by more than HOLE_DEPTH_MARGIN) and on which
    the warp put a surface farther than frame i sees by more than the margin: background seen where
    a nearer surface of frame i-1 moved away, a surface frame i-1 never saw (docs/semantics.md §3.6
    step 4)."""
    margin = 1.0 + HOLE_DEPTH_MARGIN
    return (at_landing > 0) & (margin * at_landing < view.z) & (warped > margin * depth_curr)


def looked_back_depth(warped, compared, depth_curr, at_landing):
    """(H, W) ``depth_at_landing`` read only for a compared pixel (``compared`` (H, W) bool) that
    sees a surface more than LOOK_BACK_RATIO times nearer than the warp put; 0 elsewhere."""
    return jnp.where(compared & (warped > LOOK_BACK_RATIO * depth_curr), at_landing, 0.0)


def spec_depth_error(warped, hit, depth_curr, valid_curr, static_curr, source, K_prev, K_curr, R, t, image_hw=None, *,
                     relative: bool = False):
    """The spec depth check's error (docs/semantics.md §3.6 steps 4-5) of ``warp_depth``'s output:
    ``depth_error`` where frame i's point lands on a pixel frame i-1 warped (``depth_at_landing``;
    ``source``: frame i-1's depth and the mask of what it warps, (H, W) each) and frame i-1 did not
    see it behind a nearer surface (``occluded_in_previous``), frame i-1 looked up where frame i
    sees a surface more than LOOK_BACK_RATIO times nearer than the warp put. Relative errors are
    read up to the pair's depth map (step 7)."""
    view = previous_view(depth_curr, valid_curr, K_prev, K_curr, R, t, image_hw)
    at_landing = depth_at_landing(*source, view)
    seen = (at_landing > 0) & ~occluded_in_previous(warped, depth_curr, view, at_landing)
    compared = hit & seen & _valid_depth(depth_curr, valid_curr) & static_curr
    read = looked_back_depth(warped, compared, depth_curr, at_landing)
    return depth_error(warped, hit & seen, depth_curr, valid_curr, static_curr, relative=relative,
                       looked_back=(view.z, read), pair_scale=relative)


def depth_error(warped, hit, depth_curr, valid_curr, static_curr, *, relative: bool = False, looked_back=None,
                pair_scale: bool = False):
    """Mean |warped - depth_curr| over hit & valid (depth > 0, finite) & static (H, W) -> (float32,
    int32 count): in depth units, or relative to depth_curr (AbsRel, a fraction); NaN with no overlap.
    ``looked_back``: (z, depth) (H, W), each pixel's point's depth in camera i-1 and frame i-1's depth
    where it lands (``looked_back_depth``, 0 where unread): where read, the lesser of the error and
    |depth - z| (relative to z) (docs/semantics.md §3.6 step 5). ``pair_scale``: frame i-1's depths
    (warped and looked back) read through ``pair_depth_map`` first, α depth + β (step 7)."""
    both = hit & _valid_depth(depth_curr, valid_curr) & static_curr
    n = jnp.sum(both).astype(jnp.int32)
    scale, offset = pair_depth_map(warped, depth_curr, both) if pair_scale else (1.0, 0.0)
    error = jnp.abs(scale * warped + offset - depth_curr)
    if relative:
        error = error / jnp.where(both, depth_curr, 1.0)
    if looked_back is not None:
        z, depth = looked_back
        read = depth > 0
        back = jnp.abs(scale * depth + offset - z)
        if relative:
            back = back / jnp.where(read, z, 1.0)
        error = jnp.where(read, jnp.minimum(error, back), error)
    total = jnp.sum(jnp.where(both, error, 0.0).astype(jnp.float32))
    mean = jnp.where(n > 0, total / jnp.maximum(n, 1).astype(jnp.float32), jnp.nan)
    return mean.astype(jnp.float32), n
