"""Fit Video Depth Anything's relative disparity to VGGT's depth: one scale and one shift per clip.

The relative VDA models predict affine-invariant inverse depth, disp = a' / depth + b' with unknown
a' > 0 and b' per clip. VGGT's ``depth`` map shares the units of its camera translations. Fitting
1 / depth_vggt = a * disp + b in inverse depth (where the affine model holds) over static, confident
pixels of all frames gives depth = 1 / (a * disp + b) in the cameras' units; 0 (invalid) where
a * disp + b <= 0 or disp <= 0.

The fit starts from medians and median absolute deviations (exact for an affine map, unmoved by a
minority of bad pixels), then runs iteratively reweighted least squares with Tukey's biweight on the
relative residual r = depth_vggt * (a * disp + b) - 1, whose scale is re-estimated each step from the
residuals' median absolute value. Pixels where VGGT is wrong (moving objects outside the masks, gross
errors) get weight 0 once |r| passes TUKEY_C * sigma. NumPy only.
"""

from __future__ import annotations

import dataclasses
import warnings
from typing import Any

import numpy as np

from .common import resize_factors
from .vggt import VGGTDepth, VGGTGrid
from .video_depth_anything import Depth

METHOD = "IRLS with Tukey's biweight on relative inverse-depth residuals, from a median/MAD start"
# VGGT's confidence is 1 + exp(.): unbounded, with a scale that changes from clip to clip, so only a
# quantile transfers between clips (VGGT's own point-cloud export thresholds at a percentile too).
# The median keeps the upper half: it drops sky, depth edges and the other pixels VGGT is least sure
# of, and still leaves tens of thousands of pixels per clip for two parameters.
CONF_QUANTILE = 0.5
MIN_FIT_PIXELS = 500  # below this the pixels cover a sliver of the scene; a shift fitted there is a guess
MAX_FIT_PIXELS = 200_000  # drawn with a fixed seed beyond this: bounds memory and time on long clips
TUKEY_C = 4.685  # Tukey's constant for 95% efficiency under Gaussian noise
MAD_TO_SIGMA = 1.4826  # a Gaussian's standard deviation per median absolute deviation
MIN_SIGMA = 1e-3  # relative; noise-free inputs would otherwise weigh only pixels fitted to float precision
# Beyond this the two estimators do not see the same depth up to an affine map, whatever a and b are
# (published relative-depth errors of either model are ~5-15%).
MAX_MEDIAN_REL_RESIDUAL = 0.25
_MAX_ITERATIONS = 100
_TOL = 1e-10  # relative change of (a, b) at which IRLS stops


class DepthAlignmentWarning(UserWarning):
    """The disparity could not be fitted to VGGT's depth; the import fell back to shift 0."""


@dataclasses.dataclass(frozen=True)
class DisparityFit:
    """1 / depth_ref ~ ``scale`` * disparity + ``shift``; ``status`` "ok" or why the fit is unusable
    ("too_few_pixels", "nonfinite", "nonpositive_scale", "poor_fit"). Residuals are relative."""

    status: str
    scale: float
    shift: float
    n_pixels: int
    inlier_frac: float
    median_rel_residual: float
    n_iterations: int = 0

    @property
    def ok(self) -> bool:
        return self.status == "ok"


def fit_inverse_depth_affine(disparity: np.ndarray, depth_ref: np.ndarray) -> DisparityFit:
    """Robust (scale, shift) with 1 / depth_ref ~ scale * disparity + shift over 1-D samples
    (disparity > 0, depth_ref > 0, any units); minimises sum rho(depth_ref * (scale * disp + shift) - 1)."""
    x = np.asarray(disparity, np.float64).ravel()
    z = np.asarray(depth_ref, np.float64).ravel()
    n = x.size
    nan = float("nan")
    if n < MIN_FIT_PIXELS:
        return DisparityFit("too_few_pixels", nan, nan, n, nan, nan)
    y = 1.0 / z
    med_x, med_y = np.median(x), np.median(y)
    with np.errstate(divide="ignore", invalid="ignore"):  # no spread in disparity: reported as nonfinite
        a = np.median(np.abs(y - med_y)) / np.median(np.abs(x - med_x))
    b = med_y - a * med_x
    zx = z * x
    iterations = 0
    for iterations in range(1, _MAX_ITERATIONS + 1):
        if not (np.isfinite(a) and np.isfinite(b)):
            break
        r = z * (a * x + b) - 1.0
        sigma = max(MAD_TO_SIGMA * float(np.median(np.abs(r))), MIN_SIGMA)
        u = r / (TUKEY_C * sigma)
        w = np.where(np.abs(u) < 1.0, (1.0 - u * u) ** 2, 0.0)
        # weighted least squares of rows (z x, z) against 1: the 2x2 normal equations
        s_xx, s_xz, s_zz = np.sum(w * zx * zx), np.sum(w * zx * z), np.sum(w * z * z)
        t_x, t_z = np.sum(w * zx), np.sum(w * z)
        det = s_xx * s_zz - s_xz * s_xz
        if not det > 0:
            a = b = nan
            break
        a_new, b_new = (s_zz * t_x - s_xz * t_z) / det, (s_xx * t_z - s_xz * t_x) / det
        step = max(abs(a_new - a) * med_x, abs(b_new - b))  # change of the prediction at the median disparity
        a, b = a_new, b_new
        if step <= _TOL * abs(a * med_x + b):
            break
    if not (np.isfinite(a) and np.isfinite(b)):
        return DisparityFit("nonfinite", float(a), float(b), n, nan, nan, iterations)
    r = np.abs(z * (a * x + b) - 1.0)
    sigma = max(MAD_TO_SIGMA * float(np.median(r)), MIN_SIGMA)
    inlier_frac, median_rel = float(np.mean(r < TUKEY_C * sigma)), float(np.median(r))
    status = "ok"
    if not a > 0:
        status = "nonpositive_scale"
    elif median_rel > MAX_MEDIAN_REL_RESIDUAL:
        status = "poor_fit"
    return DisparityFit(status, float(a), float(b), n, inlier_frac, median_rel, iterations)


def vggt_pixels_of_clip(grid: VGGTGrid, frame_hw: tuple[int, int],
                        clip_hw: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Row (H,) and column (W,) of the preprocessed pixel nearest each clip pixel centre, -1 where
    that pixel is VGGT's padding or outside its crop. ``frame_hw``: the frames VGGT saw."""
    a_x, b_x, a_y, b_y = grid.to_frame()  # frame = a * pre + b
    c_x, d_x, c_y, d_y = resize_factors(clip_hw, frame_hw)  # frame = c * clip + d

    def axis(n_clip: int, n_frame: int, n_pre: int, a: float, b: float, c: float, d: float) -> np.ndarray:
        pre = np.floor((c * np.arange(n_clip) + d - b) / a + 0.5).astype(np.int64)
        in_frame = np.abs(a * pre + b - (n_frame - 1) / 2.0) <= n_frame / 2.0  # not padding
        return np.where((pre >= 0) & (pre < n_pre) & in_frame, pre, -1)

    H, W = clip_hw
    return (axis(H, frame_hw[0], grid.height, a_y, b_y, c_y, d_y),
            axis(W, frame_hw[1], grid.width, a_x, b_x, c_x, d_x))


def vggt_depth_on_clip_grid(vggt: VGGTDepth, clip_hw: tuple[int, int]) -> tuple[np.ndarray, np.ndarray | None]:
    """VGGT's depth and confidence (T, H, W) sampled at the clip's pixel centres (nearest), depth 0
    where VGGT saw padding or cropped the pixel away; confidence None when the file has none."""
    rows, cols = vggt_pixels_of_clip(vggt.grid, vggt.frame_hw, clip_hw)
    inside = (rows >= 0)[:, None] & (cols >= 0)[None, :]
    index = (slice(None), np.maximum(rows, 0)[:, None], np.maximum(cols, 0)[None, :])
    depth = np.where(inside, vggt.depth[index], 0.0).astype(np.float32)
    conf = None if vggt.conf is None else vggt.conf[index]
    return depth, conf


def _finite_or_none(value: float) -> float | None:
    return float(value) if np.isfinite(value) else None


def align_depth_to_vggt(depth: Depth, vggt: VGGTDepth | None, *, static_mask: np.ndarray | None = None,
                        enabled: bool = True, conf_quantile: float = CONF_QUANTILE) -> Depth:
    """VDA ``depth`` (its raw disparity on the clip grid) -> depth = 1 / (a disp + b) in VGGT's camera
    units, fitted over ``static_mask`` (T, H, W) pixels (all when None) whose VGGT confidence is at
    least its ``conf_quantile``. What was done or assumed goes to ``notes["depth_alignment"]``; a
    failed fit warns (:class:`DepthAlignmentWarning`) and keeps the shift-0 depth."""
    kind = depth.notes.get("depth_kind")
    rule = depth.notes.get("depth_rule", "")
    units = ("units of depth and camera translations may differ (the default compat='spec' scorer fits one "
             "translation scale per clip; under compat='authors' pass align_scale=True, CLI --align-scale)")
    reason = None
    if kind == "authors":
        reason = "none: reference-compat (the authors' depth = VDA output / 1000, used as is)"
    elif kind != "disparity" or depth.disparity is None:
        reason = f"none: kind={kind!r}: the metric depth is used as is (metres); {units}"
    elif not enabled:
        reason = f"off (align_depth=False, CLI --no-align-depth): {rule}; {units}"
    elif vggt is None:
        reason = f"none: no VGGT depth in the cameras file; {rule}; {units}"
    if reason is not None:
        return dataclasses.replace(depth, notes={**depth.notes, "depth_alignment": reason})

    disparity = depth.disparity
    T, H, W = disparity.shape
    ref, conf = vggt_depth_on_clip_grid(vggt, (H, W))
    usable = np.isfinite(disparity) & (disparity > 0) & np.isfinite(ref) & (ref > 0)
    if static_mask is not None:
        usable &= static_mask
    record: dict[str, Any] = {"method": METHOD,
                              "static": "SegAnyMo static mask" if static_mask is not None else "all pixels (no masks)"}
    if conf is not None:
        finite_conf = usable & np.isfinite(conf)
        threshold = float(np.quantile(conf[finite_conf], conf_quantile)) if finite_conf.any() else np.inf
        usable = finite_conf & (conf >= threshold)
        record.update(conf_quantile=float(conf_quantile), conf_threshold=_finite_or_none(threshold))
    else:
        record["conf_threshold"] = "none: no depth_conf in the cameras file, every valid pixel used"
    x, z = disparity[usable], ref[usable]
    if x.size > MAX_FIT_PIXELS:
        pick = np.random.default_rng(0).choice(x.size, MAX_FIT_PIXELS, replace=False)
        x, z = x[pick], z[pick]
        record["n_sampled"] = MAX_FIT_PIXELS
    fit = fit_inverse_depth_affine(x, z)
    record.update(status=fit.status, scale=_finite_or_none(fit.scale), shift=_finite_or_none(fit.shift),
                  n_pixels=int(usable.sum()), inlier_frac=_finite_or_none(fit.inlier_frac),
                  median_rel_residual=_finite_or_none(fit.median_rel_residual), iterations=fit.n_iterations)
    if not fit.ok:
        why = {"too_few_pixels": f"{int(usable.sum())} confident static pixels, fewer than {MIN_FIT_PIXELS}",
               "nonfinite": "the fit is not finite (no spread in disparity or depth?)",
               "nonpositive_scale": f"scale {fit.scale:.4g} <= 0: VGGT's depth grows with the disparity",
               "poor_fit": (f"median relative residual {fit.median_rel_residual:.3g} > {MAX_MEDIAN_REL_RESIDUAL}: "
                            "VGGT's and VDA's depth disagree beyond an affine map")}[fit.status]
        record["fallback"] = f"{rule}; {units}"
        warnings.warn(DepthAlignmentWarning(f"depth alignment to VGGT's depth failed ({fit.status}: {why}); "
                                            f"falling back to {rule}"), stacklevel=3)
        return dataclasses.replace(depth, notes={**depth.notes, "depth_alignment": record})

    inverse = np.float32(fit.scale) * disparity + np.float32(fit.shift)  # float32: clip-sized arrays
    valid = np.isfinite(disparity) & (disparity > 0) & (inverse > 0)
    aligned = np.where(valid, 1.0 / np.where(valid, inverse, 1.0), 0.0).astype(np.float32)
    record["rule"] = "depth = 1 / (scale * disparity + shift), in VGGT's camera units; <= 0 invalid"
    new_rule = (f"depth = 1 / ({fit.scale:.6g} * disparity + {fit.shift:.6g}), scale and shift fitted to VGGT's "
                f"depth (camera units; {record['n_pixels']} pixels, median relative residual "
                f"{fit.median_rel_residual:.3g}); disparity <= 0 or 1 / depth <= 0 -> invalid")
    notes = {**depth.notes, "depth_rule": new_rule, "depth_alignment": record}
    return dataclasses.replace(depth, depth=aligned, notes=notes)
