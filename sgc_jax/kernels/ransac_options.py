"""The frozen options of a pair's pose search (RANSAC, local optima, the rival pose) and of the
region-quality rule: the engine builds them from ``SGCConfig`` (docs/semantics.md §2, §7.1).
Static fields shape the program; the others are values, traced where the caller traces them."""

from __future__ import annotations

import equinox as eqx


class RansacOptions(eqx.Module):
    inlier_px: float  # inlier threshold on the reprojection error [px]
    min_inlier_frac: float  # a pose is accepted with >= max(4, floor(frac m)) inliers of m members
    min_points: int  # members a region needs for a pose
    confidence: float  # of RANSAC's adaptive stop, in (0, 1)
    ambiguous_rot_deg: float  # a rival this far away in rotation [deg] ...
    ambiguous_inlier_frac: float  # ... that loses at most this share of the members makes a pose ambiguous
    hypotheses: int = eqx.field(static=True)  # most minimal samples per region
    lm_steps: int = eqx.field(static=True)  # most Levenberg-Marquardt steps per least-squares fit
    borrow: bool = eqx.field(static=True, default=True)  # also start from the pair's other regions' poses
    sample_size: int = eqx.field(static=True, default=4)  # points per minimal sample
    chunk: int = eqx.field(static=True, default=10)  # samples drawn between two checks of the adaptive stop
    sample_updates: int = eqx.field(static=True, default=2)  # Gauss-Newton updates of a minimal sample's fit
    score_points: int = eqx.field(static=True, default=512)  # members candidates are scored on, at most
    lo_candidates: int = eqx.field(static=True, default=8)  # best candidates given a least-squares fit
    fit_points: int = eqx.field(static=True, default=128)  # scored members that fit uses, at most
    lo_steps: int = eqx.field(static=True, default=3)  # optimistix Gauss-Newton steps of that fit (2 updates)
    max_rounds: int = eqx.field(static=True, default=5)  # least-squares fits per local optimum, at most


class QualityRule(eqx.Module):
    """The region-quality rule's thresholds (``SGCConfig`` fields of the same names)."""

    min_region_points: int  # inliers an accepted pose needs
    max_rot_std_deg: float  # largest rotation uncertainty [deg] ...
    max_rot_std_px: float  # ... or the angle this many pixels subtend at the focal length, when larger
    min_region_extent: float  # smallest RMS radius of the inliers, fraction of the image diagonal
    quality_noise_px: float  # the residual sigma behind the uncertainty is capped here [px]
