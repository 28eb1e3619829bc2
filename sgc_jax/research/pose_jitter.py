"""Pose jitter: how much each depth layer's local pose changes from one frame pair to the next,
against what its fits' own noise gives that change (docs/semantics.md §3.10).

A tracker's errors are drawn anew for every pair; a generator's inconsistency, or a tracker's
failure that follows a layer, persists. For every two depth layers (slots j, l, §3.2) that hold
accepted poses in pairs t and t+1, layer j's pose relative to layer l's (deg, % of D) is compared
between the two pairs: the squared change, over the variance the floors' pose noise gives it
(``region_rot_noise``, ``region_trans_noise``; §3.10), each two weighted by their geometry as the
components weigh poses (§3.5). Relative to each other, not to the pair's mean pose, whose weights
change from pair to pair. The ratio is about 1 when the poses carry the noise the floors count
and the world persists, above 1 when their errors change between pairs by more (errors nearby
tracks share, depth that flickers, an inconsistency that changes from frame to frame); a
persistent disagreement raises the pose components over their floors and leaves it near 1.
Research only: the score does not use it (bench/history/issue-58.md, "Shared errors scatter the
poses"). NaN under compat="authors", which has no floors.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..codes import REGION_OK
from ..engines.pairs import PairArrays
from ..engines.units import PERCENT


class PoseJitter(NamedTuple):
    """Squared change of every two layers' relative pose between consecutive pairs over its
    expected value from the fits' noise, for the rotations and the translations; NaN with no two
    layers to compare."""

    rot: float
    trans: float
    compared: int  # (pair, two layers) changes compared


class _Poses(NamedTuple):
    slots: np.ndarray  # (n,) layer slots of the pair's accepted poses
    weight: np.ndarray  # (n,) their weights in the components (§3.5)
    pose: np.ndarray  # (n, 3, 3) rotations or (n, 3) translations [% of D]
    noise_sq: np.ndarray  # (n,) squared RMS noise the floors count [deg² or (% of D)²]


def rotation_log_deg(R: np.ndarray) -> np.ndarray:
    """Rotation vectors [deg] (..., 3) of rotations (..., 3, 3), accurate from 1e-6 deg to ~179 deg
    (atan2 of the sine and cosine parts; OpenCV's Rodrigues returns 0 below ~6e-4 deg, where the
    poses of exact tracks differ)."""
    vee = 0.5 * np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
    sine = np.linalg.norm(vee, axis=-1, keepdims=True)
    angle = np.arctan2(sine, 0.5 * (np.trace(R, axis1=-2, axis2=-1)[..., None] - 1.0))
    return np.degrees(vee * np.where(sine > 0.0, angle / np.where(sine > 0.0, sine, 1.0), 1.0))


def _accepted(pairs: PairArrays, t: int, part: str) -> _Poses:
    per_px = pairs.region_rot_per_px if part == "rot" else pairs.region_trans_per_px
    accepted = (pairs.region_status[t] == REGION_OK) & np.isfinite(per_px[t]) & (per_px[t] > 0)
    if part == "rot":
        pose, noise = pairs.R_local[t][accepted], pairs.region_rot_noise[t][accepted]
    else:
        pose, noise = PERCENT * pairs.t_local[t][accepted], PERCENT * pairs.region_trans_noise[t][accepted]
    return _Poses(np.flatnonzero(accepted), 1.0 / per_px[t][accepted] ** 2, pose, noise**2)


def _between_layers(poses: _Poses, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(m, 3): pose a[i] relative to pose b[i] [deg or % of D]."""
    if poses.pose.ndim == 3:
        return rotation_log_deg(np.swapaxes(poses.pose[b], -1, -2) @ poses.pose[a])
    return poses.pose[a] - poses.pose[b]


def _ratio(per_pair: list[_Poses]) -> tuple[float, int]:
    change = expected = 0.0
    compared = 0
    for now, then in zip(per_pair[:-1], per_pair[1:]):
        common, i_now, i_then = np.intersect1d(now.slots, then.slots, return_indices=True)
        if len(common) < 2:
            continue
        a, b = np.triu_indices(len(common), 1)  # every two layers both pairs hold
        difference = (_between_layers(now, i_now[a], i_now[b]) - _between_layers(then, i_then[a], i_then[b]))
        variance = now.noise_sq[i_now[a]] + now.noise_sq[i_now[b]] + then.noise_sq[i_then[a]] + then.noise_sq[i_then[b]]
        weight = 1.0 / (1.0 / now.weight[i_now[a]] + 1.0 / now.weight[i_now[b]] + 1.0 / then.weight[i_then[a]]
                        + 1.0 / then.weight[i_then[b]])
        change += (weight * (difference**2).sum(-1)).sum()
        expected += (weight * variance).sum()
        compared += len(a)
    return (change / expected if expected > 0 else float("nan")), compared


def pose_jitter(pairs: PairArrays) -> PoseJitter:
    """A scored clip's pose jitter (module docstring) from its per-pair arrays
    (``ClipResult.pairs``, compat="spec"; the floors' noise is NaN under "authors")."""
    rot, compared = _ratio([_accepted(pairs, t, "rot") for t in range(pairs.n_pairs)])
    trans, _ = _ratio([_accepted(pairs, t, "trans") for t in range(pairs.n_pairs)])
    return PoseJitter(float(rot), float(trans), compared)
