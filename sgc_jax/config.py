"""Frozen hyperparameters of the SGC computation (docs/semantics.md §2).

``STATIC_FIELDS`` shape the JAX engine's compiled program; the other fields can change without
a new compile.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Mapping

PARTITIONS = ("depth", "grid", "depth+spatial")
COMPATS = ("spec", "authors")
# The spec depth check (docs/semantics.md §3.6): a warped depth is seen through a hole in a
# nearer surface when a point nearer by more than this fraction lands within one pixel of it (a
# depth edge, not the slope of one surface).
HOLE_DEPTH_MARGIN = 0.05


# How the JAX engine uses each field (docs/semantics.md §2). STATIC fields shape its compiled
# program (array sizes, loop counts, branches): a new value compiles a new program. VALUE fields
# enter the program as traced scalars and HOST fields act before it (loading, padding), so
# changing either reuses the program.
STATIC_FIELDS = ("k_seg", "ransac_hypotheses", "kmeans_bins", "gn_steps", "partition", "compat", "global_pose",
                 "align_scale", "quality_rule", "borrow_region_poses")
HOST_FIELDS = ("max_tracks", "min_track_conf", "use_mos")
VALUE_FIELDS = ("min_region_pixels", "min_points", "inlier_px", "confidence", "min_inlier_frac", "seed",
                "min_region_points", "max_rot_std_deg", "max_rot_std_px", "quality_noise_px", "min_region_extent",
                "ambiguous_rot_deg", "ambiguous_inlier_frac")


@dataclasses.dataclass(frozen=True)
class SGCConfig:
    """Hyperparameters; defaults are the paper's (appendix, Table of hyperparameters)."""

    k_seg: int = 10  # depth clusters per frame
    min_region_pixels: int = 200  # clusters smaller than this are dropped
    min_points: int = 4  # tracks a region needs for a local pose
    inlier_px: float = 8.0  # RANSAC inlier threshold on reprojection error, pixels
    ransac_hypotheses: int = 100  # minimal samples per region
    confidence: float = 0.99  # RANSAC confidence: adaptive stop in both engines (OpenCV and JAX)
    min_inlier_frac: float = 0.3  # pose accepted when inliers >= max(4, floor(frac * n))
    min_track_conf: float = 0.5  # tracks below this confidence are unusable
    max_tracks: int = 4096  # tracks kept per pair at load time (deterministic sub-sampling)
    seed: int = 0  # every random draw derives from this
    partition: str = "depth"  # "depth" | "grid" | "depth+spatial"
    use_mos: bool = True  # False: ignore the static mask (the paper's no-MOS ablation)
    # One scale s per clip between local (depth-unit) and global (pose-unit) translations:
    # None = on under compat="spec" (docs/semantics.md §4), off under compat="authors".
    align_scale: bool | None = None
    global_pose: bool = True  # False: the "w/o VGGT" variant, the mean local pose stands in for the global one
    compat: str = "spec"  # "spec" | "authors" (docs/semantics.md §3.9)
    kmeans_bins: int = 1024  # histogram resolution of the exact 1-D k-means
    gn_steps: int = 10  # Gauss-Newton steps per PnP solve (JAX engine)
    # Region-quality rule (issue 7, sgc_jax.kernels.uncertainty): accepted local poses that the data do not
    # pin down are left out of the variances with status ill_conditioned / ambiguous. Never applied
    # under compat="authors" (the authors keep every accepted pose).
    quality_rule: bool = True
    min_region_points: int = 10  # inliers an accepted pose needs
    max_rot_std_deg: float = 1.0  # largest RMS rotation uncertainty (Gauss-Newton covariance), deg,
    max_rot_std_px: float = 4.0  # ... or the angle this many pixels subtend at the focal length, if larger
    quality_noise_px: float = 1.0  # ... at the residual sigma, capped here: misfit beyond is inconsistency
    min_region_extent: float = 0.02  # smallest RMS radius of the inlier pixels, x image diagonal
    ambiguous_rot_deg: float = 3.0  # a rival fit this far away in rotation ...
    ambiguous_inlier_frac: float = 0.05  # ... losing at most this fraction of inliers: ambiguous (JAX)
    # JAX engine: each region also tries the other regions' poses of its pair as RANSAC hypotheses
    # (sgc_jax.kernels.ransac.borrow_region_poses), kept only where they fit its own points better.
    borrow_region_poses: bool = True

    def __post_init__(self) -> None:
        if self.partition not in PARTITIONS:
            raise ValueError(f"partition must be one of {PARTITIONS}, got {self.partition!r}")
        if self.compat not in COMPATS:
            raise ValueError(f"compat must be one of {COMPATS}, got {self.compat!r}")
        for name in ("k_seg", "min_points", "ransac_hypotheses", "max_tracks", "kmeans_bins", "gn_steps"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)!r}")
        if self.min_points < 4:
            raise ValueError(f"min_points must be >= 4 (PnP needs 4 points), got {self.min_points}")
        if not 0.0 < self.confidence < 1.0:
            raise ValueError(f"confidence must be in (0, 1), got {self.confidence}")
        if self.inlier_px <= 0:
            raise ValueError(f"inlier_px must be > 0, got {self.inlier_px}")
        for name in ("max_rot_std_deg", "max_rot_std_px", "quality_noise_px", "ambiguous_rot_deg"):
            if not float(getattr(self, name)) > 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)!r}")
        for name in ("min_region_extent", "ambiguous_inlier_frac"):
            if not 0.0 <= float(getattr(self, name)) < 1.0:
                raise ValueError(f"{name} must be in [0, 1), got {getattr(self, name)!r}")

    @property
    def fits_translation_scale(self) -> bool:
        """The per-clip translation scale is fitted: ``align_scale``, or by default in spec mode."""
        return self.compat == "spec" if self.align_scale is None else bool(self.align_scale)

    @property
    def scale_free(self) -> bool:
        """Depth in units of the clip's median static depth, translations and depth error in
        percent of it (``compat="spec"``); raw units under ``compat="authors"``."""
        return self.compat == "spec"

    @property
    def applies_quality_rule(self) -> bool:
        """The region-quality rule is on: ``quality_rule`` and not ``compat="authors"``."""
        return bool(self.quality_rule) and self.compat != "authors"

    @classmethod
    def from_dict(cls, values: Mapping[str, Any]) -> "SGCConfig":
        """Build a config from a mapping; unknown keys raise instead of being ignored."""
        return cls().replace(**values)

    def replace(self, **changes: Any) -> "SGCConfig":
        """A copy with some fields changed; a misspelled field name raises ``TypeError``."""
        known = {f.name for f in dataclasses.fields(self)}
        unknown = sorted(set(changes) - known)
        if unknown:
            raise TypeError(f"unknown SGCConfig field(s) {unknown}; known fields: {sorted(known)}")
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)
