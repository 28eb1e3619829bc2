"""Tracks against a clip's own geometry: where each track's frame-(i−1) point lands in frame i under
the clip's depth and cameras, and how far the tracker put it from there (px).

On a clip whose depth and cameras are ground truth (``../shared/realdata``, synthetic scenes) this
is the tracker's error as the score sees it; on an estimated clip it mixes the estimators'
disagreements. Conventions of docs/semantics.md §1.1 and §3.2 step 4 (depth at the floor pixel).
"""

from __future__ import annotations

import numpy as np

from ..config import SGCConfig
from ..engines.reference import back_project_tracks, global_relative_pose, pair_points, project, rotation_angle_deg
from ..io.clip import Clip


def points_prev(clip: Clip, pair: int) -> tuple[np.ndarray, np.ndarray]:
    """Pair ``pair``'s tracks back-projected from frame i−1's depth at their floor pixels (X (P, 3),
    camera i−1), and where that depth is valid (P,)."""
    return back_project_tracks(clip, pair, clip.track_prev[pair - 1].astype(np.float64))


def exact_positions(clip: Clip, pair: int) -> tuple[np.ndarray, np.ndarray]:
    """Frame-i positions (P, 2) of pair ``pair``'s tracks under the clip's depth and relative camera
    pose, and where they exist (P,): valid depth, in front of camera i."""
    X, valid = points_prev(clip, pair)
    R, t = global_relative_pose(clip, pair, SGCConfig())
    Y = X @ R.T + t
    return project(clip.K[pair], Y), valid & (Y[:, 2] > 1e-6)


def motion_errors(clip: Clip, min_track_conf: float = SGCConfig().min_track_conf) -> np.ndarray:
    """Distances [px] between the usable tracks' frame-i positions and their exact positions, over
    all pairs (the tracks with an exact position only)."""
    usable = clip.usable_tracks(min_track_conf)
    errors = []
    for pair in range(1, clip.n_frames):
        exact, exists = exact_positions(clip, pair)
        keep = usable[pair - 1] & exists
        errors.append(np.linalg.norm(clip.track_curr[pair - 1][keep].astype(np.float64) - exact[keep], axis=1))
    return np.concatenate(errors)


def region_motion_errors(clip: Clip, pairs, config: SGCConfig | None = None, off_px: float = 3.0) -> list[dict]:
    """Every accepted local pose of a scored clip (``pairs``: its PairArrays, status ``ok``)
    against the clip's own geometry, one record per pose: pair (0-based), region slot, members,
    ``deg_off`` (its rotation's angle from the clip's relative camera rotation), the median
    distance [px] of its members' tracks from their exact positions and the share beyond
    ``off_px``. Members as the reference engine assigns them (``pair_points``) under ``config``."""
    config = config or SGCConfig()
    records = []
    for p in range(clip.n_pairs):
        points = pair_points(clip, p + 1, config)
        R, t = global_relative_pose(clip, p + 1, config)
        exact = project(clip.K[p + 1], points.X @ R.T + t)
        distance = np.linalg.norm(points.uv - exact, axis=1)
        for j in np.flatnonzero(np.asarray(pairs.region_status[p]) == 0):
            member = points.region == j + 1
            records.append(dict(pair=p, region=int(j), members=int(member.sum()),
                                deg_off=rotation_angle_deg(np.asarray(pairs.R_local[p, j], np.float64), R),
                                median_px=float(np.median(distance[member])) if member.any() else float("nan"),
                                share_off=float(np.mean(distance[member] > off_px)) if member.any() else float("nan")))
    return records
