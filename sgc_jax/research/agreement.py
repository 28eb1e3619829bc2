"""How closely two scorings of the same clips agree (docs/semantics.md §7): the agreement corpus
(30 synthetic clips: six families and eight perturbations), the tolerances of a component, and
the figures of one comparison: components within tolerance, Spearman rho of SGC, same region
status, and where two local poses differ, which one is the worse optimum (higher truncated cost
at the cut).

Any two scorings compare: the two engines, or one engine under two seeds or search efforts (its
own reproducibility: the ceiling of any cross-engine figure).
"""

from __future__ import annotations

from typing import NamedTuple, Sequence

import numpy as np

from ..calibration import COMPONENTS
from ..codes import REGION_EMPTY
from ..config import SGCConfig
from ..engines import reference
from ..engines.reference import pose_search
from ..engines.units import in_depth_units
from ..scoring.result import BatchResult
from ..stats import spearman
from .perturb import perturb_clip
from .synth import synth_clip

_BASE = dict(n_layers=1, static_spheres=5, n_frames=4)
_SIZES = (dict(height=120, width=160, n_tracks=2048), dict(height=96, width=128, n_tracks=1024))
_LADDER = (("warp", 0.25), ("warp", 0.75), ("squeeze", 0.25), ("squeeze", 0.75),
           ("depth_warp", 0.25), ("depth_warp", 0.75), ("warp", 0.5), ("squeeze", 0.5))

# The agreement bar in the scale-free units of docs/semantics.md §4: rotation variances 0.05
# deg^2 (the rigid-scene bar); translation variances (1% of the median depth)^2 = 1 (% of D)^2 and the
# depth error 0.1% (1e-4 md^2 and 1e-3 md in depth units); or 5% of the value.
ATOL = {"local_rot_var": 0.05, "global_rot_var": 0.05, "local_trans_var": 1.0, "global_trans_var": 1.0,
        "depth_error": 0.1}
RTOL = 0.05
#: Two local poses further apart than this [deg] are different optima.
DIFFER_DEG = 1.0


def agreement_corpus() -> list:
    """30 clips, 4 frames each, at 120x160 / 96x128 px with 2048 / 1024 tracks: rigid; two masked
    moving objects; track noise 0.5-1.25 px; 1 px noise with 30% outlier tracks; two unmasked
    moving objects; 30% low-confidence tracks; and eight perturbations (warp, squeeze, depth warp
    at severities 0.25-0.75) of the rigid clips."""
    specs = []
    for family, seed0, extra in (
        ("rigid", 10, {}),
        ("moving", 20, dict(moving_objects=2)),
        ("noisy", 30, None),
        ("outliers", 40, dict(noise_px=1.0, outlier_frac=0.3)),
        ("unmasked", 60, dict(moving_objects=2, with_mask=False)),
    ):
        for i in range(4):
            kw = extra if extra is not None else dict(noise_px=0.5 + 0.25 * i)
            specs.append((f"{family}{i}", family, dict(seed=seed0 + i, **kw, **_SIZES[i % 2])))
    for i in range(2):
        specs.append((f"lowconf{i}", "lowconf", dict(seed=70 + i, low_conf_frac=0.3, noise_px=0.5, **_SIZES[i])))
    clips = [synth_clip(clip_id=name, group=family, **_BASE, **kw) for name, family, kw in specs]
    for i, (kind, severity) in enumerate(_LADDER):
        clips.append(perturb_clip(clips[i % 4], kind, severity, seed=i))
    return clips


def family(clip) -> str:
    """The corpus family of a clip: its group, or ``perturbed``."""
    return "perturbed" if "~" in clip.clip_id else clip.group


def within_tolerance(a: float, b: float, component: str) -> bool:
    """|a - b| <= max(ATOL[component], RTOL |a|), a the base (the reference engine's value); two
    NaNs agree."""
    if np.isnan(a) and np.isnan(b):
        return True
    return bool(abs(b - a) <= max(ATOL[component], RTOL * abs(a)))


def region_costs(clips: Sequence, a: BatchResult, b: BatchResult, config: SGCConfig | None = None) -> np.ndarray:
    """(n, 3): rotation difference [deg], cost under a, cost under b of every region both scorings
    posed; the cost is the truncated cost on the region's points at the noise-level cut of
    whichever pose has the lower cost at inlier_px (docs/semantics.md §3.2 step 6)."""
    config = config or SGCConfig()
    out = []
    for clip, ca, cb in zip(clips, a.clips, b.clips):
        unit_clip, _ = in_depth_units(clip, config)
        for p in range(clip.n_pairs):
            points = reference.pair_points(unit_clip, p + 1, config)
            K = unit_clip.K[p + 1].astype(np.float64)
            posed = np.isfinite(ca.pairs.R_local[p]).all((1, 2)) & np.isfinite(cb.pairs.R_local[p]).all((1, 2))
            for slot in np.flatnonzero(posed):
                member = points.region == slot + 1
                X, uv = points.X[member], points.uv[member]
                err = [pose_search.pose_errors_sq(pose_search.Pose(
                    pairs.R_local[p, slot].astype(np.float64), pairs.t_local[p, slot].astype(np.float64)), X, uv, K)
                    for pairs in (ca.pairs, cb.pairs)]
                coarse = [pose_search.truncated_costs(e, config.inlier_px) for e in err]
                cut = pose_search.noise_cut(err[int(np.argmin(coarse))], config.inlier_px)
                out.append((reference.rotation_angle_deg(ca.pairs.R_local[p, slot], cb.pairs.R_local[p, slot]),
                            *(pose_search.truncated_costs(e, cut) for e in err)))
    return np.array(out).reshape(-1, 3)


class Agreement(NamedTuple):
    """The figures of one comparison of scorings a and b of the same clips."""

    components_within: int  # (clip, component) cases within tolerance
    components: int
    spearman: float  # of the clips' SGC
    same_status: int  # regions of the same status (regions empty in a left out)
    regions: int
    posed: int  # regions both posed
    differ: int  # of those, poses more than DIFFER_DEG apart
    a_worse: int  # of those, a's pose of higher cost
    b_worse: int

    @property
    def component_share(self) -> float:
        return self.components_within / self.components

    @property
    def status_share(self) -> float:
        return self.same_status / self.regions


def within_by_family(clips: Sequence, a: BatchResult, b: BatchResult) -> dict[str, list[bool]]:
    """Family -> whether each of its (clip, component) cases is within tolerance."""
    within: dict[str, list[bool]] = {}
    for clip, ca, cb in zip(clips, a.clips, b.clips):
        for k in COMPONENTS:
            within.setdefault(family(clip), []).append(within_tolerance(ca.components[k], cb.components[k], k))
    return within


def compare(clips: Sequence, a: BatchResult, b: BatchResult, config: SGCConfig | None = None) -> Agreement:
    """The agreement of scorings a (the base of the relative tolerances) and b of ``clips`` (same
    order)."""
    within = np.concatenate(list(within_by_family(clips, a, b).values()))
    existing = np.concatenate([ca.pairs.region_status.ravel() != REGION_EMPTY for ca in a.clips])
    same = np.concatenate([ca.pairs.region_status.ravel() == cb.pairs.region_status.ravel()
                           for ca, cb in zip(a.clips, b.clips)])
    angle, cost_a, cost_b = region_costs(clips, a, b, config).T
    differ = angle > DIFFER_DEG
    return Agreement(int(within.sum()), len(within), float(spearman([c.sgc for c in a.clips], [c.sgc for c in b.clips])),
                     int(same[existing].sum()), int(existing.sum()), len(angle), int(differ.sum()),
                     int(np.sum(differ & (cost_a > cost_b))), int(np.sum(differ & (cost_b > cost_a))))
