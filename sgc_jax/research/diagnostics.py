"""Per-pair diagnostics for plots and notebooks: what one frame pair's score is made of.

``pair`` is the index i (docs/semantics.md §3) of frames i-1 -> i (1..T-1), the ``pair`` column of
``to_pandas(pairs=True)``; region label j (1..N_s) is slot j-1 of the per-region arrays of
:class:`~sgc_jax.engines.pairs.PairArrays`. Every quantity is recomputed with the reference
implementation (NumPy + OpenCV) from the clip and the config that scored it; the poses come from
the scored :class:`~sgc_jax.engines.pairs.PairArrays`, so the diagnostics show what either engine
found. Pixels: x = column, y = row; depth and local translations in units of D under
``compat="spec"``, in depth units under "authors" (a warped depth map is given back in depth units).
"""

from __future__ import annotations

import dataclasses
import warnings
from typing import Any

import numpy as np

from ..codes import REGION_STATUS
from ..config import SGCConfig
from ..engines import reference
from ..engines.pairs import PairArrays
from ..engines.units import in_depth_units
from ..io.clip import Clip
from ..io.loading import load_clip
from ..scoring.result import ClipResult


def _prepare(clip: Clip | Any, pair: int, config: SGCConfig | None) -> tuple[Clip, SGCConfig]:
    """The clip as the engines score it: the same track sub-sampling, depth in units of D."""
    clip, config, _ = _prepare_with_unit(clip, pair, config)
    return clip, config


def _prepare_with_unit(clip: Clip | Any, pair: int, config: SGCConfig | None) -> tuple[Clip, SGCConfig, float]:
    config = config or SGCConfig()
    clip = load_clip(clip, config)
    if not 1 <= pair <= clip.n_pairs:
        raise ValueError(f"pair must be in 1..{clip.n_pairs} (frames pair-1 -> pair) for clip "
                         f"{clip.clip_id!r}, got {pair}")
    clip, unit = in_depth_units(clip, config)
    return clip, config, unit


def _pair_arrays(scored: ClipResult | PairArrays) -> PairArrays:
    pairs = scored.pairs if isinstance(scored, ClipResult) else scored
    if pairs is None:
        raise ValueError(f"clip {getattr(scored, 'clip_id', '?')!r} has no per-pair arrays (it failed to score)")
    return pairs


def _check_regions(labels: np.ndarray, pairs: PairArrays, pair: int, clip_id: str) -> None:
    """Warn when the label map recomputed here does not have the scored number of regions (the
    JAX engine clusters in float32: a cluster at the pixel threshold can fall either side)."""
    scored = int(pairs.n_regions[pair - 1])
    if int(labels.max()) != scored:
        warnings.warn(f"{clip_id!r} pair {pair}: the recomputed label map has {int(labels.max())} regions, the "
                      f"scored result {scored}; region slots may not line up", RuntimeWarning, stacklevel=3)


def region_labels(clip: Clip | Any, pair: int, config: SGCConfig | None = None) -> np.ndarray:
    """(H, W) int32 region label map of pair ``pair``'s regions (frame pair, or pair - 1 under
    ``region_frame="previous"``) for ``config.partition``: 0 = no region, 1..N_s = regions (with the
    default ``"depth"``: depth layers, nearest first; docs/semantics.md §3.2)."""
    clip, config = _prepare(clip, pair, config)
    return reference.pair_points(clip, pair, config).labels


@dataclasses.dataclass(frozen=True)
class RegionTracks:
    """The usable tracks of a pair with depth: X (n, 3) in camera pair-1, uv (n, 2) px in frame
    pair, region (n,) label at uv (at uv_prev under ``region_frame="previous"``; 0 = none), uv_prev
    (n, 2) px in frame pair-1."""

    X: np.ndarray
    uv: np.ndarray
    uv_prev: np.ndarray
    region: np.ndarray
    labels: np.ndarray  # (H, W) region label map of the pair's regions (region_labels)
    pair: int
    frame: int  # the frame those regions partition: pair, or pair - 1 under region_frame="previous"

    @property
    def uv_member(self) -> np.ndarray:
        """(n, 2) px: where each track's region is read, in ``frame``."""
        return self.uv_prev if self.frame != self.pair else self.uv


def region_tracks(clip: Clip | Any, pair: int, config: SGCConfig | None = None) -> RegionTracks:
    """The points PnP sees per region (docs/semantics.md §3.2 steps 3-5)."""
    return _region_tracks(*_prepare(clip, pair, config), pair)


def _region_tracks(clip: Clip, config: SGCConfig, pair: int) -> RegionTracks:
    """``region_tracks`` of a clip already in the engines' units (``_prepare``)."""
    points = reference.pair_points(clip, pair, config)
    return RegionTracks(X=points.X, uv=points.uv, uv_prev=points.uv_prev, region=points.region, labels=points.labels,
                        pair=pair, frame=reference.region_frame(pair, config))


def global_pose(clip: Clip | Any, pair: int, config: SGCConfig | None = None, *,
                scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """(R_g (3, 3), scale * t_g / D (3,)): the camera's relative pose from frame pair-1 to pair
    (docs/semantics.md §3.4), its translation in the units the engines use (D = 1 under authors);
    ``scale``: the scored clip's ``scale`` (depth units per pose unit; 1 is right only where depth
    and cameras share units). The cameras' pose also under ``global_pose=False``, where the score
    uses the mean local pose instead (§6.3)."""
    clip, config, unit = _prepare_with_unit(clip, pair, config)
    R_g, t_g = reference.global_relative_pose(clip, pair, config)
    return R_g, scale * t_g / unit


@dataclasses.dataclass(frozen=True)
class PoseFlow:
    """Image motion each relative pose predicts for each region (paper Figure 4).

    Per region slot (k): ``anchor`` (k, 3) the centroid of the region's points in camera pair-1
    (units of D under spec, depth units under authors); ``start_px`` (k, 2) its projection in frame
    pair-1; ``local_px`` / ``global_px`` (k, 2) the displacement in pixels of that point under the
    region's local pose / the global pose; ``status`` (k,) :data:`~sgc_jax.codes.REGION_STATUS`
    codes; ``n_points`` (k,). Rows of regions without an accepted pose (or without points) are NaN.
    """

    pair: int
    anchor: np.ndarray
    start_px: np.ndarray
    local_px: np.ndarray
    global_px: np.ndarray
    status: np.ndarray
    n_points: np.ndarray
    labels: np.ndarray

    @property
    def accepted(self) -> np.ndarray:
        return self.status == REGION_STATUS["ok"]

    @property
    def disagreement_px(self) -> np.ndarray:
        """(k,) pixel distance between the local and the global displacement."""
        return np.linalg.norm(self.local_px - self.global_px, axis=1)


def _project(K: np.ndarray, X: np.ndarray) -> np.ndarray:
    return X[..., :2] / X[..., 2:] * K[[0, 1], [0, 1]] + K[:2, 2]


def pose_flow(clip: Clip | Any, scored: ClipResult | PairArrays, pair: int,
              config: SGCConfig | None = None) -> PoseFlow:
    """Where each region's centroid moves under its local pose and under the global pose.

    ``scored``: the clip's :class:`~sgc_jax.scoring.result.ClipResult` (or its ``pairs``), scored with
    ``config``. Each arrow is the optical flow the pose predicts at the region's anchor:
    project(K[pair], R X + t) - project(K[pair-1], X); a rigid scene gives equal arrows.
    """
    pairs = _pair_arrays(scored)
    R_g, t_g = global_pose(clip, pair, config, scale=pairs.scale)
    clip, config = _prepare(clip, pair, config)
    tracks = _region_tracks(clip, config, pair)
    _check_regions(tracks.labels, pairs, pair, clip.clip_id)
    p = pair - 1
    k = pairs.region_status.shape[1]
    anchor = np.full((k, 3), np.nan)
    for j in range(k):
        member = tracks.region == j + 1
        if member.any():
            anchor[j] = tracks.X[member].mean(axis=0)
    start = _project(clip.K[pair - 1], anchor)
    moved_local = np.einsum("kij,kj->ki", pairs.R_local[p], anchor) + pairs.t_local[p]
    moved_global = anchor @ R_g.T + t_g
    local_px = _project(clip.K[pair], moved_local) - start
    global_px = _project(clip.K[pair], moved_global) - start
    accepted = pairs.region_status[p] == REGION_STATUS["ok"]
    local_px[~accepted] = np.nan
    return PoseFlow(pair=pair, anchor=anchor, start_px=start, local_px=local_px, global_px=global_px,
                    status=pairs.region_status[p].copy(), n_points=pairs.region_points[p].copy(),
                    labels=tracks.labels)


@dataclasses.dataclass(frozen=True)
class RegionReprojection:
    """Per region slot j (label j+1): reprojection errors in pixels of the region's points under
    its own local pose (``local_px[j]``, empty without an accepted pose) and under the global pose
    (``global_px[j]``); ``status`` (k,) and ``mean_local_px`` (k,) as scored."""

    pair: int
    local_px: list[np.ndarray]
    global_px: list[np.ndarray]
    status: np.ndarray
    mean_local_px: np.ndarray
    inlier_px: float


def region_reprojection(clip: Clip | Any, scored: ClipResult | PairArrays, pair: int,
                        config: SGCConfig | None = None) -> RegionReprojection:
    """Reprojection error of every point of every region, under the local and the global pose."""
    pairs = _pair_arrays(scored)
    R_g, t_g = global_pose(clip, pair, config, scale=pairs.scale)
    clip, config = _prepare(clip, pair, config)
    tracks = _region_tracks(clip, config, pair)
    _check_regions(tracks.labels, pairs, pair, clip.clip_id)
    p, K = pair - 1, clip.K[pair]
    local, global_ = [], []
    for j in range(pairs.region_status.shape[1]):
        member = tracks.region == j + 1
        X, uv = tracks.X[member], tracks.uv[member]
        global_.append(reference.reprojection_errors(X, uv, K, R_g, t_g))
        if pairs.region_status[p, j] == REGION_STATUS["ok"]:
            local.append(reference.reprojection_errors(X, uv, K, pairs.R_local[p, j], pairs.t_local[p, j]))
        else:
            local.append(np.zeros(0))
    return RegionReprojection(pair=pair, local_px=local, global_px=global_, status=pairs.region_status[p].copy(),
                              mean_local_px=pairs.region_reproj[p].copy(), inlier_px=config.inlier_px)


@dataclasses.dataclass(frozen=True)
class DepthWarpError:
    """The depth check of one pair (docs/semantics.md §3.6): ``warped`` (H, W) depth of frame pair-1
    forward-warped into frame pair with the global pose, in the clip's depth units (0 where nothing
    lands); ``error`` (H, W) |warped - depth[pair]| where compared (NaN elsewhere), in
    ``error_unit`` (% of depth under compat="spec", depth units under "authors"), under spec the
    lesser of that and what frame pair-1 shows where the warp put a far surface (§3.6 step 5);
    ``mean`` its mean (the pair's ``depth_error`` with the global pose); ``depth_scale`` and
    ``depth_offset`` the pair's depth map α, β the error reads ``warped`` through, α warped + β (§3.6
    step 7; 1 and 0 under "authors")."""

    pair: int
    warped: np.ndarray
    error: np.ndarray
    mean: float
    error_unit: str = "% of depth"
    depth_scale: float = 1.0
    depth_offset: float = 0.0

    @property
    def compared(self) -> np.ndarray:
        """(H, W) bool: pixels that enter the mean (both depths valid, static in frame pair)."""
        return ~np.isnan(self.error)


def depth_warp_error(clip: Clip | Any, pair: int, config: SGCConfig | None = None, *,
                     scale: float = 1.0) -> DepthWarpError:
    """Per-pixel depth-warp error of a pair with the global pose; ``scale``: the scored clip's
    ``scale`` (depth units per pose unit; the default 1 is right only where depth and cameras share
    units, as in synthetic clips). Under compat="spec" depths are in units of D and the error in
    percent of depth; under "authors" both in depth units."""
    original = clip
    clip, config, unit = _prepare_with_unit(clip, pair, config)
    R_g, t_g = global_pose(original, pair, config, scale=scale)
    check = reference.pair_depth_check(clip, pair, R_g, t_g, config)
    return DepthWarpError(pair=pair, warped=check.warped * unit, error=check.error, mean=check.mean,
                          error_unit="% of depth" if config.scale_free else "depth units",
                          depth_scale=check.depth_scale, depth_offset=check.depth_offset * unit)
