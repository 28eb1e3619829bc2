"""The depth check (docs/semantics.md §3.6): frame i-1's depth warped into frame i, its holes, the pair's depth map and error."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ...config import (
    DEPTH_EDGE_RATIO,
    DEPTH_MAP_DAMPING,
    DEPTH_MAP_GATE,
    DEPTH_MAP_STEPS,
    DEPTH_MAP_WEIGHT_FLOOR,
    DEPTH_SCALE_MIN_PIXELS,
    DEPTH_SCALE_STRIDE,
    HOLE_DEPTH_MARGIN,
    LOOK_BACK_RATIO,
    MAX_HOLE_REACH_PX,
    SGCConfig,
)
from ...io.clip import Clip
from ..units import PERCENT
from .regions import valid_depth


def at_pixel_centre(u: np.ndarray, v: np.ndarray, z: np.ndarray, depth_curr: np.ndarray,
                    comparable: np.ndarray) -> np.ndarray:
    """Each point's depth z (n,) at (u, v) (n,) in frame i carried to its rounded pixel's centre along
    frame i's surface: z d_i(pixel) / d_i(u, v), 1 / d_i(u, v) frame i's inverse depth interpolated
    bilinearly over the four pixels around (u, v), where those four are ``comparable`` (H, W) and
    lie on one surface (largest / smallest <= DEPTH_EDGE_RATIO); z elsewhere (§3.6 step 2)."""
    H, W = depth_curr.shape
    d = np.where(comparable, depth_curr, 0.0).astype(np.float64)
    u0, v0 = np.floor(u), np.floor(v)
    inside = (u0 >= 0) & (u0 < W - 1) & (v0 >= 0) & (v0 < H - 1)
    fu, fv = np.where(inside, u - u0, 0.0), np.where(inside, v - v0, 0.0)
    r, c = np.where(inside, v0, 0).astype(np.int64), np.where(inside, u0, 0).astype(np.int64)
    corners = np.stack([d[r, c], d[r, c + 1], d[r + 1, c], d[r + 1, c + 1]])
    lowest, highest = corners.min(axis=0), corners.max(axis=0)
    one_surface = inside & (lowest > 0) & (highest <= DEPTH_EDGE_RATIO * lowest)
    d00, d10, d01, d11 = np.where(one_surface, corners, 1.0)
    inverse = (1.0 - fv) * ((1.0 - fu) / d00 + fu / d10) + fv * ((1.0 - fu) / d01 + fu / d11)
    right, below = fu >= 0.5, fv >= 0.5
    at_pixel = np.where(below, np.where(right, d11, d01), np.where(right, d10, d00))
    return np.where(one_surface, z * at_pixel * inverse, z)


def warp_depth(depth_prev: np.ndarray, K_prev: np.ndarray, K_curr: np.ndarray, R: np.ndarray,
               t: np.ndarray, nearest: bool = True, mask_holes: bool = False,
               at_point: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Forward-warp the valid pixels of depth_prev (H, W) into frame i; 0 where nothing lands.

    Rounds to the nearest pixel (half up), keeps z > 1e-5 inside the image; collisions keep the
    nearest depth (z-buffer), or the farthest with ``nearest=False`` (the authors' code).
    ``mask_holes``: 0 also where a point nearer by more than ``HOLE_DEPTH_MARGIN``, magnified m
    times, lies within max(m, 1) px (``hole_squares``): the splat is seen through a hole in that
    surface or past its last splat. ``at_point`` (spec, with ``nearest``): frame i's depth and
    compared pixels (H, W), each point's z read at its pixel's centre (``at_pixel_centre``).
    """
    H, W = depth_prev.shape
    rows, cols = np.nonzero(valid_depth(depth_prev))
    d = depth_prev[rows, cols].astype(np.float64)
    pix = np.stack([cols, rows, np.ones_like(cols)], axis=0).astype(np.float64)
    X = (np.linalg.inv(K_prev) @ pix) * d
    cam = R @ X + t[:, None]
    z = cam[2]
    front = z > 1e-5
    proj = K_curr @ (cam[:, front] / z[front])
    z_front = z[front]
    focal_ratio = np.sqrt(K_curr[0, 0] * K_curr[1, 1] / (K_prev[0, 0] * K_prev[1, 1]))
    magnification = d[front] * focal_ratio / z_front
    iu, iv, z = np.floor(proj[0] + 0.5).astype(np.int64), np.floor(proj[1] + 0.5).astype(np.int64), z_front
    inside = (iu >= 0) & (iu < W) & (iv >= 0) & (iv < H)
    if nearest and at_point is not None:
        z = at_pixel_centre(proj[0], proj[1], z, *at_point)
    iu, iv, z = iu[inside], iv[inside], z[inside]
    if nearest:
        buffer = np.full((H, W), np.inf)
        np.minimum.at(buffer, (iv, iu), z)
        if mask_holes:
            cover = _hole_cover(proj, z_front, magnification, H, W)
            buffer[buffer > (1.0 + HOLE_DEPTH_MARGIN) * cover] = np.inf
        return np.where(np.isfinite(buffer), buffer, 0.0)
    buffer = np.zeros((H, W))
    np.maximum.at(buffer, (iv, iu), z)
    return buffer


def hole_squares(centre: np.ndarray, magnification: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per axis, the pixels first .. last - 1 a point at ``centre`` (n,) covers in the hole rule:
    k with centre - r < k <= centre + r, its reach r its magnification m, at least 1 and at most
    MAX_HOLE_REACH_PX -> (first, last) int64 (n,)."""
    reach = np.clip(magnification, 1.0, MAX_HOLE_REACH_PX)
    return (np.floor(centre - reach) + 1).astype(np.int64), (np.floor(centre + reach) + 1).astype(np.int64)


def _hole_cover(proj: np.ndarray, z: np.ndarray, magnification: np.ndarray, H: int, W: int) -> np.ndarray:
    """(H, W) nearest z among the points (projections (2+, n), depths (n,)) whose squares
    (``hole_squares``) include the pixel; inf where none: squares of up to 4 pixels a side (every
    point magnified less than 2x) by their offsets, larger ones point by point."""
    u0, u1 = hole_squares(proj[0], magnification)
    v0, v1 = hole_squares(proj[1], magnification)
    cover = np.full((H, W), np.inf)
    small = (u1 - u0 <= 4) & (v1 - v0 <= 4)
    for du in range(4):
        for dv in range(4):
            iu, iv = u0 + du, v0 + dv
            on = small & (iu < u1) & (iv < v1) & (iu >= 0) & (iu < W) & (iv >= 0) & (iv < H)
            np.minimum.at(cover, (iv[on], iu[on]), z[on])
    for k in np.nonzero(~small)[0]:
        window = cover[max(v0[k], 0):max(v1[k], 0), max(u0[k], 0):max(u1[k], 0)]
        np.minimum(window, z[k], out=window)
    return cover


def affine_depth_map(z: np.ndarray, d: np.ndarray, start: np.ndarray, steps: int = DEPTH_MAP_STEPS + 1) -> np.ndarray:
    """(α, β) float64 of least Σ |α z + β − d| / d over (n,) warped depths z and frame i's d: iteratively
    reweighted least squares from ``start`` (2,), ``steps`` steps, each the weighted regression of d
    on z, centred, weights 1 / max(|e|, DEPTH_MAP_WEIGHT_FLOOR), β shrunk by DEPTH_MAP_DAMPING
    (``kernels.depth_map``)."""
    kappa = DEPTH_MAP_DAMPING / (1.0 + DEPTH_MAP_DAMPING)
    coef = np.asarray(start, np.float64)
    for _ in range(steps):
        u = 1.0 / np.maximum(np.abs((coef[0] * z + coef[1] - d) / d), DEPTH_MAP_WEIGHT_FLOOR) / (d * d)
        total = np.sum(u)
        z_mean, d_mean = np.sum(u * z) / total, np.sum(u * d) / total
        var, cov = np.sum(u * (z - z_mean) ** 2) / total, np.sum(u * (z - z_mean) * (d - d_mean)) / total
        alpha = (cov + kappa * z_mean * d_mean) / (var + kappa * z_mean * z_mean)
        coef = np.array([alpha, (d_mean - alpha * z_mean) / (1.0 + DEPTH_MAP_DAMPING)])
    return coef


def pair_depth_map(warped: np.ndarray, depth_curr: np.ndarray, both: np.ndarray) -> tuple[float, float]:
    """The pair's depth map (α, β) (§3.6 step 7) on the ``both`` (H, W) pixels of every
    DEPTH_SCALE_STRIDE-th row and column, (1, 0) with fewer than DEPTH_SCALE_MIN_PIXELS: the affine map
    (``affine_depth_map``, from the scale) where its median relative error there is below
    DEPTH_MAP_GATE times the scale's, else the scale (the median of d / ẑ in float32, as the JAX
    engine's, and 0)."""
    s = DEPTH_SCALE_STRIDE
    sub = both[::s, ::s]
    if sub.sum() < DEPTH_SCALE_MIN_PIXELS:
        return 1.0, 0.0
    z, d = warped[::s, ::s][sub].astype(np.float64), depth_curr[::s, ::s][sub].astype(np.float64)
    scale = np.array([np.median((depth_curr[::s, ::s][sub] / warped[::s, ::s][sub]).astype(np.float32)), 0.0])
    affine = affine_depth_map(z, d, scale)
    median_error = [np.median(np.abs((c[0] * z + c[1] - d) / d)) for c in (affine, scale)]
    chosen = affine if median_error[0] < DEPTH_MAP_GATE * median_error[1] else scale
    return float(chosen[0]), float(chosen[1])


def depth_error_map(warped: np.ndarray, depth_curr: np.ndarray, static_curr: np.ndarray, relative: bool = False,
                    looked_back: tuple[np.ndarray, np.ndarray] | None = None, pair_scale: bool = False
                    ) -> tuple[np.ndarray, np.ndarray, float, float]:
    """(error (n,) of the compared pixels in row-major order, compared (H, W) bool, the pair's
    depth map α, β): |warped - depth_curr| where both are valid and the pixel is static, divided by
    depth_curr pixel by pixel when ``relative`` (AbsRel). ``looked_back``: (z, depth) (H, W), each
    pixel's point's depth in camera i-1 and frame i-1's depth where it lands (0 where unread):
    where read, the lesser of the error and |depth - z| (relative to z) (§3.6 step 5).
    ``pair_scale``: frame i-1's depths (warped and looked back) read through ``pair_depth_map``
    first, α depth + β (step 7; else (1, 0))."""
    both = (warped > 0) & valid_depth(depth_curr) & static_curr
    scale, offset = pair_depth_map(warped, depth_curr, both) if pair_scale and both.any() else (1.0, 0.0)
    error = np.abs(scale * warped[both] + offset - depth_curr[both])
    if relative:
        error = error / depth_curr[both]
    if looked_back is not None:
        z, depth = (a[both] for a in looked_back)
        read = depth > 0
        back = np.abs(scale * depth + offset - z)
        back = back / np.where(read, z, 1.0) if relative else back
        error = np.where(read, np.minimum(error, back), error)
    return error, both, scale, offset


def depth_error(warped: np.ndarray, depth_curr: np.ndarray, static_curr: np.ndarray, relative: bool = False,
                looked_back: tuple[np.ndarray, np.ndarray] | None = None, pair_scale: bool = False) -> float:
    """The mean of ``depth_error_map``'s errors (the same arguments); NaN if no pixel is compared."""
    error, *_ = depth_error_map(warped, depth_curr, static_curr, relative, looked_back, pair_scale)
    return float(np.mean(error)) if error.size else float("nan")


def previous_view(depth_curr: np.ndarray, K_prev: np.ndarray, K_curr: np.ndarray, R: np.ndarray,
                  t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Frame i's valid pixels (H, W) at depth_curr moved into camera i-1 ((R, t) moves camera i-1's
    points into camera i) and projected with K_prev -> (seen (H, W) bool: in front (z > 1e-5) and
    inside its image when rounded half up; z (H, W) their depth there; iu, iv (H, W) int64 the pixel,
    0 where not seen)."""
    H, W = depth_curr.shape
    rows, cols = np.mgrid[:H, :W]
    valid = valid_depth(depth_curr)
    d = np.where(valid, depth_curr, 1.0).astype(np.float64)
    pix = np.stack([cols.ravel(), rows.ravel(), np.ones(H * W)]).astype(np.float64)
    cam = R.T @ ((np.linalg.inv(K_curr) @ pix) * d.ravel() - t[:, None])
    z = cam[2]
    front = valid.ravel() & (z > 1e-5)
    proj = K_prev @ (cam / np.where(front, z, 1.0))
    iu, iv = np.floor(proj[0] + 0.5), np.floor(proj[1] + 0.5)
    seen = front & (iu >= 0) & (iu < W) & (iv >= 0) & (iv < H)
    iu, iv = (np.where(seen, a, 0).astype(np.int64).reshape(H, W) for a in (iu, iv))
    return seen.reshape(H, W), z.reshape(H, W), iu, iv


def seen_from_previous(depth_curr: np.ndarray, K_prev: np.ndarray, K_curr: np.ndarray, R: np.ndarray,
                       t: np.ndarray) -> np.ndarray:
    """(H, W) bool: valid pixels of frame i whose point at depth_curr lies in front of camera i-1
    (z > 1e-5) and inside its image when rounded half up; (R, t) moves camera i-1's points into
    camera i. Only there can a warp from frame i-1 be compared (§3.6)."""
    return previous_view(depth_curr, K_prev, K_curr, R, t)[0]


def warp_source(clip: Clip, pair: int, config: SGCConfig) -> np.ndarray:
    """Depth of frame pair-1 that the depth check warps: its static, valid pixels under spec (a
    masked moving object must not cover static pixels of frame pair), every valid one (authors)."""
    depth = clip.depth[pair - 1]
    if config.compat == "authors" or not config.use_mos:
        return depth
    return np.where(clip.static_mask[pair - 1], depth, 0.0)


class PairDepthError(NamedTuple):
    """A pair's depth check (``pair_depth_check``): frame i-1's depth warped into frame i (H, W) (0
    where nothing is compared), each compared pixel's error (H, W) (NaN elsewhere; percent of depth
    under spec), their mean and the pair's depth map α ẑ + β (§3.6 step 7; 1 and 0 where not applied;
    β in the clip's depth units as scored, units of D under spec)."""

    warped: np.ndarray
    error: np.ndarray
    mean: float
    depth_scale: float
    depth_offset: float = 0.0


def pair_depth_check(clip: Clip, pair: int, R: np.ndarray, t: np.ndarray, config: SGCConfig) -> PairDepthError:
    """Frame pair-1 warped into frame pair with (R, t), compared on the static, valid pixels of
    frame pair -> PairDepthError."""
    spec = config.compat != "authors"
    source = warp_source(clip, pair, config)
    static = clip.static_mask[pair] if config.use_mos else np.ones(clip.image_size, bool)
    at_point = (clip.depth[pair], valid_depth(clip.depth[pair]) & static) if config.depth_at_point else None
    warped = warp_depth(source, clip.K[pair - 1], clip.K[pair], R, t, nearest=spec, mask_holes=spec, at_point=at_point)
    looked_back = None
    if spec:
        seen, z, iu, iv = previous_view(clip.depth[pair], clip.K[pair - 1], clip.K[pair], R, t)
        source = np.where(valid_depth(source), source, 0.0)
        at_landing = source[iv, iu]
        # compared only where frame i's point lands on a pixel frame i-1 warped, and frame i-1 did
        # not see it behind a nearer surface where the warp put a farther one (§3.6 step 4)
        margin = 1.0 + HOLE_DEPTH_MARGIN
        occluded = (margin * at_landing < z) & (warped > margin * clip.depth[pair])
        warped = np.where(seen & (at_landing > 0) & ~occluded, warped, 0.0)
        # frame i-1 read where the warp put a surface LOOK_BACK_RATIO times farther than frame i sees (§3.6 step 5)
        needed = (warped > LOOK_BACK_RATIO * clip.depth[pair]) & valid_depth(clip.depth[pair]) & static
        looked_back = z, np.where(needed, at_landing, 0.0)
    error, compared, scale, offset = depth_error_map(warped, clip.depth[pair], static, relative=config.scale_free,
                                                     looked_back=looked_back, pair_scale=spec and config.scale_free)
    unit = PERCENT if config.scale_free else 1.0
    error_map = np.full(compared.shape, np.nan)
    error_map[compared] = error * unit
    mean = float(np.mean(error)) * unit if error.size else float("nan")
    return PairDepthError(warped, error_map, mean, scale, offset)


def pair_depth_error(clip: Clip, pair: int, R: np.ndarray, t: np.ndarray, config: SGCConfig) -> tuple[np.ndarray, float]:
    """(warped depth (H, W), the pair's depth error) of ``pair_depth_check``."""
    check = pair_depth_check(clip, pair, R, t, config)
    return check.warped, check.mean
