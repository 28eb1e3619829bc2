"""What an engine returns for a clip: per-pair arrays (docs/semantics.md §3.7, §4)."""

from __future__ import annotations

import dataclasses

import numpy as np

from ..calibration import COMPONENTS
from ..codes import PAIR_REASON_CODE, PAIR_REASONS, REGION_EMPTY
from ..io.tables import format_counts


@dataclasses.dataclass
class PairArrays:
    """Per-pair values of one clip; index p is pair p+1 (frames p -> p+1); k region slots.

    Units (docs/semantics.md §4): rotations in degrees (variances deg^2), reprojection errors in
    pixels; under compat="spec" translation variances in (% of D)^2, ``depth_error`` in % and
    ``t_g_norm`` in % of D, while R_local, t_local and region_trans_std are the poses in units of
    D; under compat="authors" the inputs' depth and pose units."""

    local_rot_var: np.ndarray  # (n_pairs,)
    local_trans_var: np.ndarray
    global_rot_var: np.ndarray
    global_trans_var: np.ndarray
    depth_error: np.ndarray
    reproj_error: np.ndarray  # mean over accepted regions of their mean reprojection error
    n_tracks: np.ndarray  # usable tracks (visible, confident)
    n_regions: np.ndarray
    n_poses: np.ndarray  # accepted local poses
    n_ill_conditioned: np.ndarray  # poses the region-quality rule left out (ill_conditioned, ambiguous)
    t_g_norm: np.ndarray  # ||t_g||, ECD input
    R_g_angle_deg: np.ndarray  # rotation angle of R_g, ECD input
    tracks_rot_deg: np.ndarray  # rotation [deg] of the pose that fits the tracks best (§3.11); NaN: none
    tracks_trans: np.ndarray  # its translation, in t_g_norm's unit
    static_frac: np.ndarray  # share of the frame that is static with valid depth (S_i, §3.2), evidence (§3.11)
    parallax_px: np.ndarray  # image motion of a point at depth D from the camera's translation [px] (§3.11)
    reason: np.ndarray  # (n_pairs,) str, one of codes.PAIR_REASONS
    R_local: np.ndarray  # (n_pairs, k, 3, 3), NaN where no pose (ok, ill_conditioned, ambiguous)
    t_local: np.ndarray  # (n_pairs, k, 3)
    region_status: np.ndarray  # (n_pairs, k) int, codes.REGION_STATUS
    region_points: np.ndarray  # (n_pairs, k) tracks per region
    region_reproj: np.ndarray  # (n_pairs, k) mean reprojection error [px]
    region_rot_std: np.ndarray  # (n_pairs, k) RMS rotation uncertainty of the pose [deg] (NaN: no pose)
    region_trans_std: np.ndarray  # (n_pairs, k) RMS translation uncertainty [units of D]
    region_rot_noise: np.ndarray  # (n_pairs, k) RMS rotation error the noise floors count [deg] (NaN: no pose)
    region_trans_noise: np.ndarray  # (n_pairs, k) RMS translation error the noise floors count [units of D]
    region_sigma_px: np.ndarray  # (n_pairs, k) residual sigma of the pose's inliers per image coordinate [px]
    region_rot_per_px: np.ndarray  # (n_pairs, k) RMS rotation error per px of tracking error [deg / px]: its geometry
    region_trans_per_px: np.ndarray  # (n_pairs, k) RMS translation error per px of tracking error [units of D / px]
    scale: float = 1.0  # translation scale s applied to t_g (1 when not fitted)
    depth_unit: float = 1.0  # D, the clip's median static depth [input depth units] (1 under authors)

    @property
    def n_pairs(self) -> int:
        return len(self.reason)

    def __repr__(self) -> str:  # the arrays run to thousands of lines
        k = self.region_status.shape[1] if self.region_status.ndim == 2 else 0
        return (f"PairArrays({self.n_pairs} pairs, {k} region slots; reasons: "
                f"{format_counts((str(r) for r in self.reason), PAIR_REASONS) or 'none'})")

    def components(self) -> dict[str, np.ndarray]:
        return {k: getattr(self, k) for k in COMPONENTS}

    def columns(self) -> dict[str, np.ndarray]:
        """The per-pair (n_pairs,) and per-region (n_pairs, k) arrays by name, ``reason`` as
        codes.PAIR_REASON_CODE: what the summaries read (``scoring.summary``)."""
        arrays = {f.name: np.asarray(getattr(self, f.name)) for f in dataclasses.fields(self)
                  if f.name not in ("scale", "depth_unit", "reason")}
        arrays = {name: a.astype(np.float64, copy=False) if a.dtype.kind == "f" else a for name, a in arrays.items()}
        arrays["reason"] = np.array([PAIR_REASON_CODE[str(r)] for r in self.reason], np.int32)
        return arrays


def empty_pair_arrays(n_pairs: int, k: int) -> PairArrays:
    """Arrays of n_pairs pairs and k region slots with nothing scored yet (NaN, 0, empty)."""
    nan = lambda *shape: np.full(shape, np.nan)  # noqa: E731
    zeros = lambda *shape: np.zeros(shape, np.int32)  # noqa: E731
    return PairArrays(
        local_rot_var=nan(n_pairs), local_trans_var=nan(n_pairs), global_rot_var=nan(n_pairs),
        global_trans_var=nan(n_pairs), depth_error=nan(n_pairs), reproj_error=nan(n_pairs),
        n_tracks=zeros(n_pairs), n_regions=zeros(n_pairs), n_poses=zeros(n_pairs), n_ill_conditioned=zeros(n_pairs),
        t_g_norm=nan(n_pairs), R_g_angle_deg=nan(n_pairs), tracks_rot_deg=nan(n_pairs), tracks_trans=nan(n_pairs),
        static_frac=nan(n_pairs), parallax_px=nan(n_pairs),
        reason=np.full(n_pairs, "ok", dtype=object),
        R_local=nan(n_pairs, k, 3, 3), t_local=nan(n_pairs, k, 3),
        region_status=np.full((n_pairs, k), REGION_EMPTY, np.int32),
        region_points=zeros(n_pairs, k), region_reproj=nan(n_pairs, k), region_rot_std=nan(n_pairs, k),
        region_trans_std=nan(n_pairs, k), region_rot_noise=nan(n_pairs, k), region_trans_noise=nan(n_pairs, k),
        region_sigma_px=nan(n_pairs, k), region_rot_per_px=nan(n_pairs, k), region_trans_per_px=nan(n_pairs, k))
