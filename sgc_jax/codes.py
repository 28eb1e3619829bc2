"""Every status and reason code (docs/semantics.md §3.7), defined once for the kernels, both engines
and the result tables.

Region statuses are int32 codes (per region slot, ``PairArrays.region_status``); pair reasons and
clip statuses are text in the tables, and the JAX engine carries a pair's reason as its index in
:data:`PAIR_REASONS` (:data:`PAIR_REASON_CODE`).
"""

from __future__ import annotations

#: Why a pair lacks a value (``ok``: every component exists); codes in order of introduction, the
#: order a pair's first problem is found in is docs/semantics.md §3.7's table.
PAIR_REASONS = ("ok", "too_few_tracks", "no_static", "no_region", "no_pose", "no_depth_overlap", "ill_conditioned",
                "one_pose")
#: Pair reason -> its int code inside the JAX engine (the index in :data:`PAIR_REASONS`).
PAIR_REASON_CODE = {name: i for i, name in enumerate(PAIR_REASONS)}

# Per-region status codes shared by both engines.
REGION_OK = 0  # accepted pose, kept by the region-quality rule
REGION_TOO_FEW_POINTS = 1  # members < min_points
REGION_REJECTED = 2  # too few inliers, non-finite, or not a proper rotation
REGION_EMPTY = 3  # no such region (slot beyond N_s), or the pair has fewer than 4 usable tracks
# ill_conditioned / ambiguous: a pose was found but the region-quality rule (SGCConfig.quality_rule,
# docs/semantics.md §3.3) leaves it out of the variances.
REGION_ILL_CONDITIONED = 4
REGION_AMBIGUOUS = 5
# Regions the quality rule leaves out: posed, but not counted (docs/semantics.md §3.3)
EXCLUDED_STATUSES = (REGION_ILL_CONDITIONED, REGION_AMBIGUOUS)
#: Region status name -> code.
REGION_STATUS = {"ok": REGION_OK, "too_few_points": REGION_TOO_FEW_POINTS, "rejected": REGION_REJECTED,
                 "empty": REGION_EMPTY, "ill_conditioned": REGION_ILL_CONDITIONED, "ambiguous": REGION_AMBIGUOUS}
#: Region status names by code (inverse of :data:`REGION_STATUS`).
REGION_STATUS_NAMES = {code: name for name, code in REGION_STATUS.items()}

#: Clip status codes; ``low_evidence``: scored, but on less than the evidence the score needs to see
#: an inconsistency (docs/semantics.md §3.11).
CLIP_STATUSES = ("ok", "partial", "error", "low_evidence")
#: The Scorer's clip status (docs/semantics.md §9.3), an int code per clip: ``ok`` and ``partial``
#: as in the tables; a clip with no pair scored says why when every pair shares the reason
#: (``no_tracks``: no pair has 4 usable tracks; ``no_static``: no pair has static valid depth, e.g.
#: an all-dynamic mask), else ``error``; ``static_camera``: scored, but the camera moves less than
#: the reward's full-motion level (§9.4); ``low_evidence`` as in the tables (§3.11).
SCORER_STATUSES = ("ok", "partial", "error", "no_tracks", "no_static", "static_camera", "low_evidence")
SCORER_STATUS_CODE = {name: i for i, name in enumerate(SCORER_STATUSES)}
