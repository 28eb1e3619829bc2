"""Rotations and the clip's global relative pose (docs/semantics.md §3.4): angles in degrees."""

from __future__ import annotations

import cv2
import numpy as np

from ...config import SGCConfig
from ...io.clip import Clip
from ..units import resolved_translation
from . import pose_search


def so3_log(R: np.ndarray) -> np.ndarray:
    """Rotation vector (3,) in radians of a rotation matrix (3, 3)."""
    rotvec, _ = cv2.Rodrigues(np.asarray(R, np.float64))
    return rotvec.ravel()


def so3_exp(rotvec: np.ndarray) -> np.ndarray:
    """Rotation matrix (3, 3) of a rotation vector (3,) in radians."""
    R, _ = cv2.Rodrigues(np.asarray(rotvec, np.float64).reshape(3, 1))
    return R


def rotation_angle_deg(R_a: np.ndarray, R_b: np.ndarray) -> float:
    """Angle of R_a^T R_b in degrees via atan2 (stable for tiny angles, unlike arccos)."""
    return float(pose_search.rotation_angles_deg(np.asarray(R_a, np.float64),
                                                           np.asarray(R_b, np.float64)[None])[0])


def rotation_angle_deg_authors(R_a: np.ndarray, R_b: np.ndarray) -> float:
    """The authors' distance: arccos((trace(R_a^T R_b) - 1) / 2) in float32 (0 for tiny angles)."""
    cos = (np.float32(np.trace((R_a.T @ R_b).astype(np.float32))) - np.float32(1)) / np.float32(2)
    return float(np.degrees(np.arccos(np.clip(cos, np.float32(-1), np.float32(1)))))


def nearest_rotation(M: np.ndarray) -> np.ndarray:
    """Closest rotation (det +1) to a 3x3 matrix, by SVD."""
    U, _, Vt = np.linalg.svd(M)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def global_relative_pose(clip: Clip, pair: int, config: SGCConfig) -> tuple[np.ndarray, np.ndarray]:
    """(R_g, t_g) from camera pair-1 to camera pair (docs/semantics.md §3.4)."""
    product = clip.R_wc[pair] @ clip.R_wc[pair - 1].T
    R_g = nearest_rotation(product)
    if config.compat == "authors":
        return R_g, clip.t_wc[pair] - product @ clip.t_wc[pair - 1]
    t_g = clip.t_wc[pair] - R_g @ clip.t_wc[pair - 1]
    return R_g, resolved_translation(t_g, clip.t_wc[pair - 1], clip.t_wc[pair])
