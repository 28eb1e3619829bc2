"""Errors nearby tracks share (docs/semantics.md §3.10): a region's reprojection residuals taken as
an error of each track's own, variance ν per image coordinate, plus a smooth field the region's
tracks share, variance ψ and correlation ρ(d) = exp(-d² / 2ℓ²) between tracks d px apart; ν and ψ
fitted to the residuals' semivariogram, and the pose covariance they imply.

Both run on block tables: each inlier's count, residual e (2), |e|² and Jacobian rows (2 x 6),
summed over squares of side ℓ / CELLS_PER_LENGTH, so that every sum over pairs of tracks is a
separable blur of a table (O(tracks), no pairwise matrix); two tracks of one square are taken as
ρ = 1 apart. Written once for NumPy (the reference engine) and ``jax.numpy`` (the JAX engine).
"""

from __future__ import annotations

import functools
import math
from typing import Any

import numpy as np

from ..config import CORRELATION_FRAC

CELLS_PER_LENGTH = 2  # squares of side ℓ / 2
# squares a side: ℓ = CORRELATION_FRAC x the diagonal, and the image's sides are <= its diagonal
GRID = math.ceil(CELLS_PER_LENGTH / CORRELATION_FRAC)
CHANNELS = 52  # count, e_u, e_v, |e|², J_u (6), J_v (6), J_uᵀJ_u + J_vᵀJ_v (36)
# the semivariogram is fitted on at least this many (correlation-weighted) pairs of nearby tracks;
# with fewer, every error is taken as the track's own (ψ = 0)
MIN_NEAR_PAIRS = 10.0


def cell_of(uv: Any, correlation_px: Any, xp=np) -> Any:
    """(N, 2) pixels -> (N,) int flat index of their square on the GRID x GRID grid of side
    correlation_px / CELLS_PER_LENGTH (clamped at its edges)."""
    cell = xp.clip(xp.floor(uv * (CELLS_PER_LENGTH / correlation_px)), 0, GRID - 1).astype(xp.int32)
    return cell[..., 1] * GRID + cell[..., 0]


def point_channels(du: Any, dv: Any, J_u: Any, J_v: Any, xp=np) -> Any:
    """(N, CHANNELS) what each track adds to its square's table: residuals du, dv (N,) [px] and
    Jacobian rows J_u, J_v (N, 6)."""
    ones = xp.ones_like(du)
    outer = (J_u[:, :, None] * J_u[:, None, :] + J_v[:, :, None] * J_v[:, None, :]).reshape(-1, 36)
    return xp.concatenate([xp.stack([ones, du, dv, du * du + dv * dv], axis=-1), J_u, J_v, outer], axis=-1)


@functools.lru_cache(maxsize=4)
def correlation_matrix(power: int) -> np.ndarray:
    """(GRID, GRID) ρ^power between the centres of squares i and j along one axis."""
    steps = np.arange(GRID)[:, None] - np.arange(GRID)[None, :]
    return np.exp(-power * steps.astype(np.float64) ** 2 / (2.0 * CELLS_PER_LENGTH ** 2))


def blur(tables: Any, power: int, xp=np) -> Any:
    """(..., GRID, GRID, C) -> the same with each square's entry replaced by the ρ^power-weighted
    sum over all squares (separable: ρ(d)^p = ρ(dx)^p ρ(dy)^p)."""
    kernel = xp.asarray(correlation_matrix(power), dtype=tables.dtype)
    return xp.einsum("ai,...ijc,bj->...abc", kernel, tables, kernel, **_precision(xp))


def _precision(xp) -> dict:
    return {} if xp is np else {"precision": "highest"}


def _inner(a: Any, b: Any, xp) -> Any:
    """Sum over the grid and channels of a * b: (..., GRID, GRID, C) -> (...,)."""
    return xp.sum(a * b, axis=(-3, -2, -1))


def _rows_product(a: Any, b: Any, xp) -> Any:
    """sum over squares and both image coordinates of aᵀ b: Jacobian-row tables (..., GRID, GRID,
    12) -> (..., 6, 6)."""
    return sum(xp.einsum("...xyi,...xyj->...ij", a[..., c:c + 6], b[..., c:c + 6], **_precision(xp)) for c in (0, 6))


def _trace_product(a: Any, b: Any, xp) -> Any:
    return xp.einsum("...ij,...ji->...", a, b)


def shared_error_variances(tables: Any, covariance: Any, usual_var: Any, xp=np) -> tuple[Any, Any]:
    """(own ν, shared ψ) (...,) [px² per coordinate] of a region's errors, from its block tables
    (..., GRID, GRID, CHANNELS) and its fit's A = (JᵀJ)⁻¹ (..., 6, 6).

    The statistics s_p = sum over pairs a != b of tracks of ρ_ab^p |r_a - r_b|² / 4, p = 1, 2
    (nearby tracks' residual differences), are quadratic forms rᵀ Q_p r of the residuals r = P e,
    P = I - J A Jᵀ, of errors e of covariance Σ = ν I + ψ R (R_ab = ρ_ab); so E s_p = ν tr(Q_p P)
    + ψ tr(Q_p P R P), which counts what the pose's own fit absorbed of the shared field. The two
    equations solved for ν, ψ >= 0; with under MIN_NEAR_PAIRS weighted pairs or no solution:
    (usual_var, 0), the region's residual variance taken as its tracks' own."""
    count, residual, residual_sq = tables[..., :1], tables[..., 1:3], tables[..., 3:4]
    rows, outer = tables[..., 4:16], tables[..., 16:]
    n = xp.sum(count, axis=(-3, -2, -1))
    near = {p: blur(count, p, xp) for p in (1, 2, 3)}  # D_p: ρ^p-weighted tracks around each square
    near_rows = {p: blur(rows, p, xp) for p in (1, 2)}
    pairs = {p: _inner(count, near[p], xp) - n for p in (1, 2, 3)}  # sum_{a != b} ρ^p
    shared_rows = _rows_product(rows, near_rows[1], xp)  # Jᵀ R J
    equations = []
    for p in (1, 2):
        spread = 0.5 * (_inner(residual_sq, near[p], xp) - _inner(residual, blur(residual, p, xp), xp))
        weighted_outer = xp.sum(near[p] * outer, axis=(-3, -2)).reshape(outer.shape[:-3] + (6, 6))
        form = 0.5 * (weighted_outer - _rows_product(rows, near_rows[p], xp))  # Jᵀ Q_p J
        form_shared = 0.5 * (_rows_product(near_rows[1], near[p] * rows, xp)  # Jᵀ R Q_p J
                             - _rows_product(near_rows[1], count * near_rows[p], xp))
        own_weight = pairs[p] - _trace_product(covariance, form, xp)
        shared_weight = (pairs[p] - pairs[p + 1] - 2.0 * _trace_product(covariance, form_shared, xp)
                         + _trace_product(covariance @ form, covariance @ shared_rows, xp))
        equations.append((own_weight, shared_weight, spread))
    (a1, b1, s1), (a2, b2, s2) = equations
    det = a1 * b2 - a2 * b1
    solvable = (pairs[1] >= MIN_NEAR_PAIRS) & (xp.abs(det) > 1e-3 * (xp.abs(a1 * b2) + xp.abs(a2 * b1)))
    safe = lambda x: xp.where(xp.abs(x) > 0, x, 1.0)  # noqa: E731
    own, shared = (b2 * s1 - b1 * s2) / safe(det), (a1 * s2 - a2 * s1) / safe(det)
    own_only = (a1 * s1 + a2 * s2) / safe(a1 * a1 + a2 * a2)  # least squares with ψ = 0
    shared_only = (b1 * s1 + b2 * s2) / safe(b1 * b1 + b2 * b2)  # with ν = 0
    own, shared = (xp.where(shared < 0, own_only, xp.where(own < 0, 0.0, own)),
                   xp.where(shared < 0, 0.0, xp.where(own < 0, shared_only, shared)))
    return (xp.where(solvable, xp.maximum(own, 0.0), usual_var),
            xp.where(solvable, xp.maximum(shared, 0.0), 0.0))


def shared_error_information(tables: Any, own_var: Any, shared_var: Any, normal: Any, xp=np) -> Any:
    """(..., 6, 6) sum_ab Σ_ab J_aᵀ J_b over a region's inliers, Σ_ab = ψ ρ_ab + ν δ_ab per image
    coordinate, from its block tables (..., GRID, GRID, CHANNELS), ν, ψ (...,) and its normal
    matrix JᵀJ (..., 6, 6). The pose covariance is A (this) A, A = (JᵀJ)⁻¹."""
    rows = tables[..., 4:16]
    shared = _rows_product(rows, blur(rows, 1, xp), xp)
    return own_var[..., None, None] * normal + shared_var[..., None, None] * shared
