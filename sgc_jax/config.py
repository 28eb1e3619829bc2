"""Frozen hyperparameters of the SGC computation (docs/semantics.md §2).

``STATIC_FIELDS`` shape the JAX engine's compiled program; the other fields can change without
a new compile.
"""

from __future__ import annotations

import dataclasses
import warnings
from typing import Any, Mapping

PARTITIONS = ("depth", "grid", "depth+spatial")
COMPATS = ("spec", "authors")
REGION_FRAMES = ("current", "previous")
TRACK_PIXELS = ("floor", "nearest")
DEPTH_CHECK_AT = ("pixel", "point")
SMOOTH_DEPTH_EDGES = ("leave_out", "keep")
# Depth layers per track on the background (docs/semantics.md §3.2 step 2): 2 layers from 140 tracks,
# 7 at 1,000, k_seg from 1,400 (bench/history/issue-58.md, "Larger depth layers on two noise draws").
TRACKS_PER_LAYER = 140

# Constants of the semantics, shared by both engines (the kernels read them; they are no options).
# The spec depth check (docs/semantics.md §3.6): a warped depth is seen through a hole in a
# nearer surface when a point nearer by more than this fraction covers it (a depth edge, not the
# slope of one surface), step 3; and frame i's point was hidden in frame i-1 when frame i-1's depth
# where it lands is nearer by more than this fraction while the warp put a surface farther by more
# than it, step 4 (``kernels.warp.occluded_in_previous``). Not fitted: a margin of the hole rule,
# reused.
HOLE_DEPTH_MARGIN = 0.05
# A pixel whose 3 x 3 neighbourhood's valid depths span more than this (largest / smallest) is at a
# depth edge (io.depth_edges); four pixels that span no more lie on one surface (§3.6 step 2).
# Chosen on FIT's random pool by rule E1 (bench/history/issue-58.md, "Smooth depth edges"): the
# largest of 1.02-1.2 whose consistent clips, with depth from half the frame's size and every edge
# pixel left out, kept at most 1 of 48 above 0.10 (all four kept none); leaving out only the ramps
# (rule E2) keeps that and depth_warp's detection on depth whose edges are steps.
DEPTH_EDGE_RATIO = 1.2
# A point magnified m times (its surface's splats lie about m px apart) covers the pixels within
# max(m, 1) px of it (its reach, at most MAX_HOLE_REACH_PX): the gaps between its surface's splats
# and, at an edge, the up to m px its surface extends past its last splat. Reaches fall into levels
# 2^l <= r < 2^(l+1), l = 0 .. HOLE_LEVELS (docs/semantics.md §3.6 step 3).
HOLE_LEVELS = 6
MAX_HOLE_REACH_PX = 2.0 ** (HOLE_LEVELS + 1) - 1.0
# Where frame i sees a surface more than this many times nearer than the warp put (a relative error
# beyond 900 %, which near the camera has no bound), the depth check also looks the pixel up in frame
# i-1 and keeps the lesser error (docs/semantics.md §3.6 step 5; 3 % of FIT's pairs hold such a pixel).
LOOK_BACK_RATIO = 10.0
# The spec depth check reads each pair's error up to the pair's depth map (docs/semantics.md §3.6
# step 7), started from its depth scale: the median of frame i's depth over the warped one on every
# DEPTH_SCALE_STRIDE-th row and column of the compared pixels (a standard pair's ~9,000 of
# ~150,000); the identity with fewer than DEPTH_SCALE_MIN_PIXELS of them.
DEPTH_SCALE_STRIDE = 4
DEPTH_SCALE_MIN_PIXELS = 16
# ... or up to an affine map, alpha z + beta, where it fits far better (a relative-depth model aligned
# frame by frame leaves a shift beside its scale): the least absolute relative error on those pixels,
# by iteratively reweighted least squares, DEPTH_MAP_STEPS steps from the median ratio and beta = 0
# (it settles in about ten; a weight at most 1 / DEPTH_MAP_WEIGHT_FLOOR), beta shrunk by
# DEPTH_MAP_DAMPING so that a pair whose compared depths barely vary keeps the scale alone: numerics,
# not fitted. It replaces the scale where its median relative error on those pixels is below
# DEPTH_MAP_GATE times the scale's, chosen on FIT's pool (bench/history/issue-58.md, "A per-frame depth
# offset read up to an affine map"): a shift of the whole frame lowers nearly every pixel's error, a
# part of the world moved in depth only its own.
DEPTH_MAP_STEPS = 20
DEPTH_MAP_WEIGHT_FLOOR = 1e-5
DEPTH_MAP_DAMPING = 1e-4
DEPTH_MAP_GATE = 0.5
# Where the camera's pose reprojects a pair's region points (median error, cut at inlier_px) worse
# than this many times its refit to those points does, the refit also warps the depth check and the
# lesser error counts (docs/semantics.md §3.6 step 6). With exact cameras the ratio sits at 1.00 (median
# of FIT's pool); a camera turned 0.3 deg per frame reads 1.76, one moved a tenth of a step 1.36.
CAMERA_REFIT_RATIO = 1.25
# The refit and its gate use at most this many of a pair's region points, every n-th in track order:
# on all 4,096 of a standard clip's, a local optimum as the refit cost a warm clip 15 %
# (bench/history/issue-58.md, "The camera refitted to the tracks").
REFIT_POINTS = 512
# Gauss-Newton updates of that refit from the camera's pose (undamped, as a minimal sample's): it
# starts within a few pixels of its optimum; a local optimum's loop cost a warm clip 6 %.
REFIT_UPDATES = 3
# A pair's camera translation counts as 0 where |t_g| is at most this share of |t_wc[i]| + |t_wc[i-1]|
# (docs/semantics.md §3.4): float32's resolution of the cameras, so that a held centre's rounding is no
# motion (bench/history/issue-59.md, "Cameras that claim no translation"). A held centre's t_g in
# float32 reaches 1.7e-7 of that sum (FIT's held cameras, the real clips'); the bound is the power of
# two at least 8x that (rule B4, "A world whose origin lies far from its cameras"), not fitted to a
# score: 2^-16 took a 5 mm step 1,000 units from the origin for none.
CAMERA_TRANSLATION_RESOLUTION = 2.0**-19
# A region's noise-level cut (docs/semantics.md §3.2 step 6): NOISE_CUT x its pixel noise sigma,
# never tighter than MIN_CUT_PX nor looser than inlier_px. 3.5 sigma keeps 99.8% of Gaussian inliers.
NOISE_CUT = 3.5
MIN_CUT_PX = 1.0
# The noise floors' squares (docs/semantics.md §3.10): this fraction of the image diagonal a side,
# so at most BLOCKS_PER_AXIS along either side of the image (W, H <= diagonal).
NOISE_BLOCK_FRAC = 0.05
BLOCKS_PER_AXIS = 21
# The largest factor by which the floors count the inlier cut (docs/semantics.md §3.10,
# ``stats.cut_variance_factor``), chosen on FIT: 1.5 and 4 calmed as many clips and cost more warp
# detection (bench/history/issue-58.md, "The floors' noise corrected for the inlier cut").
MAX_CUT_FACTOR = 1.25
# Field names of earlier releases that config files and ``SGCConfig.from_dict`` still accept, with
# a DeprecationWarning: old name -> field.
DEPRECATED_FIELDS = {"gn_steps": "lm_steps"}


# How the JAX engine uses each field (docs/semantics.md §2). STATIC fields shape its compiled
# program (array sizes, loop counts, branches): a new value compiles a new program. VALUE fields
# enter the program as traced scalars and HOST fields act before it (loading, padding), so
# changing either reuses the program.
STATIC_FIELDS = ("k_seg", "ransac_hypotheses", "kmeans_bins", "lm_steps", "partition", "region_frame", "compat",
                 "global_pose", "align_scale", "borrow_region_poses", "depth_check_at")
HOST_FIELDS = ("max_tracks", "min_track_conf", "use_mos", "smooth_depth_edges")
VALUE_FIELDS = ("min_region_pixels", "tracks_per_layer", "min_points", "inlier_px", "confidence", "min_inlier_frac",
                "seed", "track_pixel", "quality_rule", "min_region_points", "max_rot_std_deg", "max_rot_std_px",
                "quality_noise_px", "min_region_extent", "ambiguous_rot_deg", "ambiguous_inlier_frac")


def _field(default: Any, help: str, *, flag: str | None = None, choices: tuple[str, ...] | None = None) -> Any:
    """A dataclass field with its command-line form: ``help`` for ``sgc-jax score --help``, ``flag``
    when the option is not ``--field-name``, ``choices`` for a string field."""
    return dataclasses.field(default=default, metadata={"help": help, "flag": flag, "choices": choices})


@dataclasses.dataclass(frozen=True)
class SGCConfig:
    """Hyperparameters (docs/semantics.md §2, which says which defaults are the paper's and which
    this package's semantics chose). Each field's
    help text doubles as its ``sgc-jax score`` / ``perturb`` option (:func:`cli_flag`)."""

    k_seg: int = _field(10, "region slots per frame: depth clusters, grid cells or components")
    min_region_pixels: int = _field(200, "clusters, cells or components with fewer pixels are dropped")
    tracks_per_layer: int = _field(TRACKS_PER_LAYER, "depth layers follow the tracks: a pair's background gets one "
                                                     "layer per this many of its tracks on it, two from this many "
                                                     "on (at most k_seg); 0: always k_seg; depth partition only, "
                                                     "not under compat='authors' (docs/semantics.md §3.2)")
    min_points: int = _field(4, "tracks a region needs for a local pose (>= 4)")
    inlier_px: float = _field(8.0, "RANSAC inlier threshold on the reprojection error, pixels")
    ransac_hypotheses: int = _field(100, "most minimal samples drawn per region")
    confidence: float = _field(0.99, "RANSAC confidence of the adaptive stop, in (0, 1): the JAX engine draws 3x "
                                     "the samples it asks for, cv2.solvePnPRansac (--compat authors) uses it as is "
                                     "(docs/semantics.md §2)")
    min_inlier_frac: float = _field(0.3, "a pose is accepted when its inliers >= max(4, floor(frac * n)), "
                                         "n = the region's tracks")
    min_track_conf: float = _field(0.5, "tracks below this confidence are unusable")
    max_tracks: int = _field(4096, "tracks kept per pair at load time (deterministic sub-sampling)")
    seed: int = _field(0, "every random draw derives from it: same seed, same result")
    partition: str = _field("depth", "how the static background is split into regions: depth layers, a k_seg "
                                     "grid over its bounding box, or depth layers split into connected parts "
                                     "(docs/semantics.md §3.2, §6.1)", choices=PARTITIONS)
    region_frame: str = _field("previous", "the frame whose background is partitioned and where each track's "
                                           "region is read: previous (frame i-1, the track's query point, where its "
                                           "depth is read) or current (frame i, the paper's); compat='authors' always "
                                           "reads frame i (docs/semantics.md §3.2)", choices=REGION_FRAMES)
    track_pixel: str = _field("floor", "the pixel where a track's depth and region are read: floor ((floor x, "
                                       "floor y), the paper's code) or nearest (the pixel whose centre, at integer "
                                       "coordinates, is nearest); compat='authors' always reads floor "
                                       "(docs/semantics.md §1.1)", choices=TRACK_PIXELS)
    depth_check_at: str = _field("pixel", "where the depth check compares a warped point with frame i's depth: pixel "
                                          "(the depth of the pixel it rounds to) or point (its own position: frame "
                                          "i's inverse depth interpolated where the four pixels around it lie on one "
                                          "surface); compat='authors' always reads pixel (docs/semantics.md §3.6 "
                                          "step 2)", choices=DEPTH_CHECK_AT)
    smooth_depth_edges: str = _field("leave_out", "depth whose edges are ramps of mixed depths, as a depth network's "
                                                 "enlarged output: leave_out its ramps before scoring (they lie on no "
                                                 "surface), or keep them; compat='authors' always keeps them "
                                                 "(docs/semantics.md §3.6, \"Smooth depth edges\")",
                                     choices=SMOOTH_DEPTH_EDGES)
    use_mos: bool = _field(True, "use the static masks; --no-mos ignores them (the paper's no-MOS ablation, "
                                 "docs/semantics.md §6.2)", flag="--mos")
    # None: on under compat="spec" (docs/semantics.md §3.4), off under compat="authors".
    align_scale: bool | None = _field(None, "fit one scale per clip between local (depth-unit) and global "
                                            "(pose-unit) translations (default: on, off with --compat authors)")
    global_pose: bool = _field(True, "use the global camera pose; --no-global-pose is the paper's 'w/o VGGT' "
                                     "variant: each pair's mean local pose stands in for it and the global "
                                     "variances drop out (docs/semantics.md §6.3)")
    compat: str = _field("spec", "authors: reproduce the paper code's choices (docs/semantics.md §3.9)",
                         choices=COMPATS)
    kmeans_bins: int = _field(1024, "histogram resolution of the exact 1-D k-means")
    lm_steps: int = _field(10, "most Levenberg-Marquardt steps per least-squares fit of a local optimum "
                                "(JAX engine, docs/semantics.md §7.1)")
    quality_rule: bool = _field(True, "leave the accepted local poses that the data do not pin down out of the "
                                      "variances (status ill_conditioned / ambiguous, docs/semantics.md §3.3); "
                                      "never applied with --compat authors, which keeps every accepted pose")
    min_region_points: int = _field(10, "quality rule: inliers an accepted pose needs")
    max_rot_std_deg: float = _field(1.0, "quality rule: largest RMS rotation uncertainty (Gauss-Newton "
                                         "covariance), degrees")
    max_rot_std_px: float = _field(4.0, "quality rule: that bound is the angle this many pixels subtend at the "
                                        "focal length, when larger")
    quality_noise_px: float = _field(1.0, "quality rule: the residual sigma behind that uncertainty is capped "
                                          "here, pixels (misfit beyond is inconsistency)")
    min_region_extent: float = _field(0.02, "quality rule: smallest RMS radius of the inlier pixels, as a "
                                            "fraction of the image diagonal, in [0, 1)")
    ambiguous_rot_deg: float = _field(3.0, "quality rule: a rival fit at least this far away in "
                                           "rotation, degrees, that loses at most --ambiguous-inlier-frac of the "
                                           "inliers makes the pose ambiguous")
    ambiguous_inlier_frac: float = _field(0.05, "quality rule: see --ambiguous-rot-deg; in [0, 1)")
    borrow_region_poses: bool = _field(True, "JAX engine: each region's search also starts from the pair's other "
                                             "region pose that fits its points best (docs/semantics.md §7.1)")

    def __post_init__(self) -> None:
        if self.partition not in PARTITIONS:
            raise ValueError(f"partition must be one of {PARTITIONS}, got {self.partition!r}")
        if self.region_frame not in REGION_FRAMES:
            raise ValueError(f"region_frame must be one of {REGION_FRAMES}, got {self.region_frame!r}")
        if self.track_pixel not in TRACK_PIXELS:
            raise ValueError(f"track_pixel must be one of {TRACK_PIXELS}, got {self.track_pixel!r}")
        if self.depth_check_at not in DEPTH_CHECK_AT:
            raise ValueError(f"depth_check_at must be one of {DEPTH_CHECK_AT}, got {self.depth_check_at!r}")
        if self.smooth_depth_edges not in SMOOTH_DEPTH_EDGES:
            raise ValueError(f"smooth_depth_edges must be one of {SMOOTH_DEPTH_EDGES}, got {self.smooth_depth_edges!r}")
        if self.compat not in COMPATS:
            raise ValueError(f"compat must be one of {COMPATS}, got {self.compat!r}")
        for name in ("k_seg", "min_points", "ransac_hypotheses", "max_tracks", "kmeans_bins", "lm_steps"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)!r}")
        if int(self.tracks_per_layer) < 0:
            raise ValueError(f"tracks_per_layer must be >= 0 (0: always k_seg layers), got {self.tracks_per_layer!r}")
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
    def track_pixel_offset(self) -> float:
        """Added to a track's (x, y) before flooring it to the pixel its depth and region are read
        at: 0.5 reads the nearest pixel (``track_pixel`` "nearest", not under ``compat="authors"``),
        0 the floor pixel."""
        return 0.5 if self.track_pixel == "nearest" and self.compat != "authors" else 0.0

    @property
    def depth_at_point(self) -> bool:
        """The depth check compares each warped point at its own position (``depth_check_at`` "point",
        not under ``compat="authors"``), not at the pixel it rounds to."""
        return self.depth_check_at == "point" and self.compat != "authors"

    @property
    def reads_previous_frame(self) -> bool:
        """A pair's regions are frame i-1's, read at each track's frame i-1 position (``region_frame``
        "previous" and not ``compat="authors"``, which reads frame i)."""
        return self.region_frame == "previous" and self.compat != "authors"

    @property
    def layers_follow_tracks(self) -> bool:
        """The depth layers' count follows the tracks (``tracks_per_layer`` > 0, ``partition="depth"``
        and not ``compat="authors"``, which always has k_seg)."""
        return self.tracks_per_layer > 0 and self.partition == "depth" and self.compat != "authors"

    @property
    def counts_repeated_tracks(self) -> bool:
        """A track at the same positions at both ends as an earlier one counts again (``compat="authors"``
        only; docs/semantics.md §1.2)."""
        return self.compat == "authors"

    @property
    def leaves_out_depth_ramps(self) -> bool:
        """A clip whose depth edges are ramps has them left out before scoring (``smooth_depth_edges``
        "leave_out" and not ``compat="authors"``; docs/semantics.md §3.6)."""
        return self.smooth_depth_edges == "leave_out" and self.compat != "authors"

    @property
    def applies_quality_rule(self) -> bool:
        """The region-quality rule is on: ``quality_rule`` and not ``compat="authors"``."""
        return bool(self.quality_rule) and self.compat != "authors"

    @classmethod
    def from_dict(cls, values: Mapping[str, Any]) -> "SGCConfig":
        """Build a config from a mapping (a config file's); unknown keys raise instead of being
        ignored, deprecated names (DEPRECATED_FIELDS) are renamed with a warning."""
        return cls().replace(**renamed_fields(values))

    def replace(self, **changes: Any) -> "SGCConfig":
        """A copy with some fields changed; a misspelled field name raises ``TypeError``."""
        known = {f.name for f in dataclasses.fields(self)}
        unknown = sorted(set(changes) - known)
        if unknown:
            raise TypeError(f"unknown SGCConfig field(s) {unknown}; known fields: {sorted(known)}")
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


def renamed_fields(values: Mapping[str, Any]) -> dict[str, Any]:
    """``values`` with deprecated field names (DEPRECATED_FIELDS) renamed, each with a DeprecationWarning."""
    out = dict(values)
    for old, new in DEPRECATED_FIELDS.items():
        if old in out:
            warnings.warn(f"SGCConfig field {old!r} is now {new!r}; the old name goes in a later release",
                          DeprecationWarning, stacklevel=3)
            if new in out:
                raise TypeError(f"both {old!r} (deprecated) and {new!r} given; keep {new!r}")
            out[new] = out.pop(old)
    return out


def cli_flag(field: dataclasses.Field) -> str:
    """The ``sgc-jax score`` / ``perturb`` option that sets ``field``: ``--field-name`` unless the
    field names another; a bool field also takes the ``--no-`` form of it."""
    return field.metadata.get("flag") or "--" + field.name.replace("_", "-")
