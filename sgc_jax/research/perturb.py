"""Controlled corruptions of a clip for sensitivity studies (docs/semantics.md §6.4; paper §4.3
and appendix C).

Geometric perturbations grow linearly in time: frame t (0-based, T frames) gets the amplitude
``a_t = severity * t / (T - 1)``, so frame 0 is untouched and the last frame gets the full
severity. A point seen in frame t is moved by frame t's map: ``track_prev`` of pair i (frame i-1)
by a_{i-1}, ``track_curr`` (frame i) by a_i.

- ``warp``: a smooth sinusoidal displacement field, drifting in phase over time, moves the tracks
  and the frames; depth and masks are untouched (so the depth error is too), the tracks no longer
  land on the depth they were seen at and the local poses leave the camera's (global rotation
  variance).
- ``squeeze``: vertical compression of the track positions about the principal point's row,
  y' = cy + (1 - c a_t)(y - cy); frames, depth and masks are untouched (local rotation variance).
- ``depth_warp``: one spatial remap (a sinusoidal field, of longer wavelength than ``warp``'s)
  applied alike to depth, frames, masks and tracks, so each frame stays self-consistent but its
  depth no longer agrees with its neighbours' (depth error).

Mask corruptions act on the dynamic mask (``~static_mask``) of every frame alike, at a severity
that does not grow in time: ``erode`` shrinks it (under-segmentation: moving pixels called static)
and ``dilate`` grows it (over-segmentation), by a radius of ``severity * radius_frac`` times the
image diagonal; ``false_positive`` marks static pixels dynamic and ``false_negative`` marks dynamic
pixels static, each pixel with probability ``severity * rate`` (salt-and-pepper noise).

Every function is pure (the input clip is not modified), depends only on the clip, the severity and
``seed``, and is exactly the identity at severity 0. Displacements are in pixels, x = column,
y = row, pixel centres at integer coordinates.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Callable

import cv2
import numpy as np

from ..io.clip import Clip

#: Geometric perturbations (grow linearly in time).
PERTURBATIONS = ("warp", "squeeze", "depth_warp")
#: Corruptions of the static/dynamic masks (same in every frame).
MASK_CORRUPTIONS = ("erode", "dilate", "false_positive", "false_negative")
#: The SGC component each geometric perturbation is designed to raise (paper §4.5, component responses).
TARGET_COMPONENT = {"warp": "global_rot_var", "squeeze": "local_rot_var", "depth_warp": "depth_error"}

# Default magnitudes at severity 1. Chosen so that on the synthetic scenes of the test suite each
# kind raises its targeted component and the SGC strictly at every step 0, 0.25, ..., 1 (as in the
# paper's Figure 6); see tests/test_study.py for the ladder.
WARP_AMPLITUDE_FRAC = 0.05  # peak displacement of the last frame, fraction of the image diagonal
WARP_WAVELENGTH_FRAC = 0.5  # wavelength of the sinusoid, fraction of the diagonal
WARP_PHASE_PER_FRAME = 0.5  # phase drift per frame, radians
SQUEEZE_MAX = 0.6  # vertical compression of the last frame: y' = cy + (1 - 0.6)(y - cy)
DEPTH_WARP_AMPLITUDE_FRAC = 0.02
DEPTH_WARP_WAVELENGTH_FRAC = 1.0
DEPTH_WARP_PHASE_PER_FRAME = 0.5
MORPH_RADIUS_FRAC = 0.05  # erode/dilate radius at severity 1, fraction of the image diagonal
NOISE_RATE = 0.5  # salt-and-pepper flip probability at severity 1


# ----------------------------------------------------------------------------- helpers


def _check_severity(severity: float) -> float:
    severity = float(severity)
    if not 0.0 <= severity <= 1.0 or math.isnan(severity):
        raise ValueError(f"severity must be in [0, 1], got {severity}")
    return severity


def time_ramp(n_frames: int, severity: float) -> np.ndarray:
    """(T,) per-frame amplitude ``severity * t / (T - 1)``: 0 at frame 0, ``severity`` at the last."""
    return severity * np.arange(n_frames, dtype=np.float64) / max(n_frames - 1, 1)


def _diagonal(clip: Clip) -> float:
    H, W = clip.image_size
    return math.hypot(H, W)


def _rng(seed: int, kind: str) -> np.random.Generator:
    """An independent stream per (seed, kind), so kinds never share draws; ``seed`` >= 0."""
    if int(seed) < 0:
        raise ValueError(f"seed must be >= 0, got {seed}")
    return np.random.default_rng([int(seed), (PERTURBATIONS + MASK_CORRUPTIONS).index(kind)])


@dataclasses.dataclass(frozen=True)
class SineField:
    """Displacement d(x, y, t) = a_t * amplitude_px * (sin(k.r_x + phi_x + w t), sin(k.r_y + phi_y + w t)).

    The x displacement varies along one random direction, the y displacement along another, so
    the field shears, stretches and rotates neighbourhoods differently across the image.
    """

    amplitude_px: float
    wavenumber: float  # radians per pixel
    phase_per_frame: float  # radians
    dir_x: tuple[float, float]  # unit direction along which the x displacement varies
    dir_y: tuple[float, float]
    phase_x: float
    phase_y: float

    @classmethod
    def random(cls, clip: Clip, rng: np.random.Generator, amplitude_frac: float, wavelength_frac: float,
               phase_per_frame: float) -> "SineField":
        # the displacement's Jacobian has norm up to sqrt(2) amplitude wavenumber (two components,
        # each of slope up to amplitude wavenumber): below 1 the map p -> p + d(p) cannot fold
        if not (amplitude_frac >= 0 and wavelength_frac > 0
                and np.sqrt(2.0) * 2 * np.pi * amplitude_frac / wavelength_frac < 1):
            raise ValueError(f"amplitude_frac {amplitude_frac} and wavelength_frac {wavelength_frac}: need "
                             "sqrt(2) 2 pi amplitude / wavelength < 1, or the field may fold the image onto itself")
        diag = _diagonal(clip)
        angles = rng.uniform(0.0, 2.0 * np.pi, size=2)
        phases = rng.uniform(0.0, 2.0 * np.pi, size=2)
        return cls(amplitude_px=amplitude_frac * diag, wavenumber=2.0 * np.pi / (wavelength_frac * diag),
                   phase_per_frame=phase_per_frame,
                   dir_x=(float(np.cos(angles[0])), float(np.sin(angles[0]))),
                   dir_y=(float(np.cos(angles[1])), float(np.sin(angles[1]))),
                   phase_x=float(phases[0]), phase_y=float(phases[1]))

    def __call__(self, x: np.ndarray, y: np.ndarray, t: int, amplitude: float) -> tuple[np.ndarray, np.ndarray]:
        """(dx, dy) in pixels at positions (x, y) of frame t with time-ramp ``amplitude``."""
        a = amplitude * self.amplitude_px
        drift = self.phase_per_frame * t
        dx = a * np.sin(self.wavenumber * (self.dir_x[0] * x + self.dir_x[1] * y) + self.phase_x + drift)
        dy = a * np.sin(self.wavenumber * (self.dir_y[0] * x + self.dir_y[1] * y) + self.phase_y + drift)
        return dx, dy


def _move_tracks(clip: Clip, ramp: np.ndarray, move: Callable[[np.ndarray, int, float], np.ndarray]
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Apply ``move(points (P, 2), frame t, a_t)`` to track_prev (frame i-1) and track_curr (frame i)."""
    prev, curr = clip.track_prev.copy(), clip.track_curr.copy()
    for pair in range(clip.n_pairs):
        if ramp[pair] > 0:
            prev[pair] = move(clip.track_prev[pair].astype(np.float64), pair, ramp[pair])
        if ramp[pair + 1] > 0:
            curr[pair] = move(clip.track_curr[pair].astype(np.float64), pair + 1, ramp[pair + 1])
    return prev, curr


def _field_mover(field: SineField) -> Callable[[np.ndarray, int, float], np.ndarray]:
    def move(points: np.ndarray, t: int, a: float) -> np.ndarray:
        dx, dy = field(points[:, 0], points[:, 1], t, a)
        return points + np.stack([dx, dy], -1)
    return move


def _inverse_maps(field: SineField, H: int, W: int, t: int, a: float, iterations: int = 10
                  ) -> tuple[np.ndarray, np.ndarray]:
    """cv2.remap maps for the forward displacement p -> p + d(p): for each output pixel q, the
    source p with p + d(p) = q, by fixed-point iteration. It converges while the displacement's
    Jacobian norm, at most sqrt(2) amplitude_px * wavenumber (0.89 for ``warp`` at severity 1),
    stays below 1."""
    qy, qx = np.mgrid[0:H, 0:W].astype(np.float64)
    px, py = qx.copy(), qy.copy()
    for _ in range(iterations):
        dx, dy = field(px, py, t, a)
        px, py = qx - dx, qy - dy
    return px.astype(np.float32), py.astype(np.float32)


def _remap_frames(clip: Clip, field: SineField, ramp: np.ndarray, *, depth: bool) -> dict[str, Any]:
    """Remap the frames (and depth and masks when ``depth``) of every frame with a_t > 0."""
    H, W = clip.image_size
    out_frames = None if clip.frames is None else clip.frames.copy()
    out_mask = clip.static_mask.copy()
    out_depth = clip.depth.copy()
    for t, a in enumerate(ramp):
        if a <= 0:
            continue
        map_x, map_y = _inverse_maps(field, H, W, t, a)
        if out_frames is not None:
            out_frames[t] = cv2.remap(clip.frames[t], map_x, map_y, cv2.INTER_LINEAR,
                                      borderMode=cv2.BORDER_REFLECT)
        if depth and clip.mask_source != "none":
            out_mask[t] = cv2.remap(clip.static_mask[t].astype(np.uint8), map_x, map_y, cv2.INTER_NEAREST,
                                    borderMode=cv2.BORDER_REFLECT).astype(bool)
        if depth:
            # nearest neighbour: no depth is invented between a foreground and a background surface
            out_depth[t] = cv2.remap(clip.depth[t], map_x, map_y, cv2.INTER_NEAREST,
                                     borderMode=cv2.BORDER_REFLECT)
    changes: dict[str, Any] = {"frames": out_frames}
    if depth:
        changes.update(depth=out_depth, static_mask=out_mask)
    return changes


# ----------------------------------------------------------------------------- geometric


def warp(clip: Clip, severity: float, seed: int = 0, *, amplitude_frac: float = WARP_AMPLITUDE_FRAC,
         wavelength_frac: float = WARP_WAVELENGTH_FRAC, phase_per_frame: float = WARP_PHASE_PER_FRAME) -> Clip:
    """Sinusoidal non-rigid deformation of tracks and frames; depth and masks untouched.

    Peak displacement of frame t: ``a_t * amplitude_frac * diagonal`` pixels (a_t: :func:`time_ramp`).
    """
    return _sine_remap(clip, severity, seed, "warp", amplitude_frac, wavelength_frac, phase_per_frame, depth=False)


def squeeze(clip: Clip, severity: float, seed: int = 0, *, max_compression: float = SQUEEZE_MAX) -> Clip:
    """Vertical compression of the tracks only: y' = cy + (1 - max_compression * a_t)(y - cy).

    cy is the principal point's row of frame t; x, frames, depth and masks are untouched. The
    compression is deterministic; ``seed`` is accepted for a uniform signature.
    """
    severity = _check_severity(severity)
    del seed
    if severity == 0:
        return _copy(clip)

    def move(points: np.ndarray, t: int, a: float) -> np.ndarray:
        cy = clip.K[t, 1, 2]
        out = points.copy()
        out[:, 1] = cy + (1.0 - max_compression * a) * (points[:, 1] - cy)
        return out

    prev, curr = _move_tracks(clip, time_ramp(clip.n_frames, severity), move)
    return dataclasses.replace(_copy(clip), track_prev=prev.astype(np.float32), track_curr=curr.astype(np.float32))


def depth_warp(clip: Clip, severity: float, seed: int = 0, *, amplitude_frac: float = DEPTH_WARP_AMPLITUDE_FRAC,
               wavelength_frac: float = DEPTH_WARP_WAVELENGTH_FRAC,
               phase_per_frame: float = DEPTH_WARP_PHASE_PER_FRAME) -> Clip:
    """One spatial remap per frame applied to depth and masks (nearest neighbour), frames and tracks.

    Peak displacement of frame t: ``a_t * amplitude_frac * diagonal`` pixels.
    """
    return _sine_remap(clip, severity, seed, "depth_warp", amplitude_frac, wavelength_frac, phase_per_frame,
                       depth=True)


def _sine_remap(clip: Clip, severity: float, seed: int, stream: str, amplitude_frac: float,
                wavelength_frac: float, phase_per_frame: float, *, depth: bool) -> Clip:
    """Tracks and frames moved by a random sine field ramped over time; depth and masks too when
    ``depth`` (the shared body of ``warp`` and ``depth_warp``; ``stream`` names the seed stream)."""
    severity = _check_severity(severity)
    if severity == 0:
        return _copy(clip)
    field = SineField.random(clip, _rng(seed, stream), amplitude_frac, wavelength_frac, phase_per_frame)
    ramp = time_ramp(clip.n_frames, severity)
    prev, curr = _move_tracks(clip, ramp, _field_mover(field))
    return dataclasses.replace(_copy(clip), track_prev=prev.astype(np.float32), track_curr=curr.astype(np.float32),
                               **_remap_frames(clip, field, ramp, depth=depth))


# ----------------------------------------------------------------------------- masks


def _with_dynamic(clip: Clip, dynamic: np.ndarray) -> Clip:
    """The clip with static_mask = ~dynamic; a clip without masks gets one only when it changed."""
    static = ~dynamic
    if clip.mask_source == "none" and static.all():
        return _copy(clip)
    source = "static_mask" if clip.mask_source == "none" else clip.mask_source
    return dataclasses.replace(_copy(clip), static_mask=static, mask_source=source)


def morph_radius_px(clip: Clip, severity: float, radius_frac: float = MORPH_RADIUS_FRAC) -> int:
    """Erode/dilate radius in pixels: round(severity * radius_frac * image diagonal)."""
    return int(round(_check_severity(severity) * radius_frac * _diagonal(clip)))


def _morph(clip: Clip, severity: float, radius_frac: float, op: Callable) -> Clip:
    radius = morph_radius_px(clip, severity, radius_frac)
    if radius == 0:
        return _copy(clip)
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
    dynamic = ~clip.static_mask
    # pixels beyond the border count as "not dynamic", so erosion does not stop at the image edge
    out = np.stack([op(m.astype(np.uint8), kernel, borderType=cv2.BORDER_CONSTANT, borderValue=0).astype(bool)
                    for m in dynamic])
    return _with_dynamic(clip, out)


def erode(clip: Clip, severity: float, seed: int = 0, *, radius_frac: float = MORPH_RADIUS_FRAC) -> Clip:
    """Shrink the dynamic mask by :func:`morph_radius_px` (under-segmentation); ``seed`` unused."""
    del seed
    return _morph(clip, severity, radius_frac, cv2.erode)


def dilate(clip: Clip, severity: float, seed: int = 0, *, radius_frac: float = MORPH_RADIUS_FRAC) -> Clip:
    """Grow the dynamic mask by :func:`morph_radius_px` (over-segmentation); ``seed`` unused."""
    del seed
    return _morph(clip, severity, radius_frac, cv2.dilate)


def _flip(clip: Clip, severity: float, seed: int, rate: float, kind: str, from_dynamic: bool) -> Clip:
    severity = _check_severity(severity)
    if severity == 0:
        return _copy(clip)
    # one uniform draw per pixel, thresholded: a higher severity flips a superset of the pixels
    u = _rng(seed, kind).random(clip.static_mask.shape)
    dynamic = ~clip.static_mask
    flip = (u < severity * rate) & (dynamic if from_dynamic else ~dynamic)
    return _with_dynamic(clip, dynamic ^ flip)


def false_positive(clip: Clip, severity: float, seed: int = 0, *, rate: float = NOISE_RATE) -> Clip:
    """Mark each static pixel dynamic with probability ``severity * rate`` (salt noise)."""
    return _flip(clip, severity, seed, rate, "false_positive", from_dynamic=False)


def false_negative(clip: Clip, severity: float, seed: int = 0, *, rate: float = NOISE_RATE) -> Clip:
    """Mark each dynamic pixel static with probability ``severity * rate`` (pepper noise)."""
    return _flip(clip, severity, seed, rate, "false_negative", from_dynamic=True)


# ----------------------------------------------------------------------------- entry point


def _copy(clip: Clip) -> Clip:
    """A clip sharing no mutable array with ``clip``."""
    copy = lambda a: None if a is None else np.array(a, copy=True)  # noqa: E731
    return dataclasses.replace(
        clip, depth=copy(clip.depth), K=copy(clip.K), R_wc=copy(clip.R_wc), t_wc=copy(clip.t_wc),
        static_mask=copy(clip.static_mask), track_prev=copy(clip.track_prev), track_curr=copy(clip.track_curr),
        track_vis=copy(clip.track_vis), track_conf=copy(clip.track_conf), frames=copy(clip.frames),
        meta=dict(clip.meta))


_KINDS: dict[str, Callable[..., Clip]] = {
    "warp": warp, "squeeze": squeeze, "depth_warp": depth_warp,
    "erode": erode, "dilate": dilate, "false_positive": false_positive, "false_negative": false_negative,
}


def perturbed_clip_id(clip_id: str, kind: str, severity: float) -> str:
    """The id of a perturbed clip, e.g. ``scene~warp@0.25``."""
    return f"{clip_id}~{kind}@{severity:g}"


def perturb_clip(clip: Clip, kind: str, severity: float, seed: int = 0, **params: Any) -> Clip:
    """``clip`` corrupted by ``kind`` (one of :data:`PERTURBATIONS` or :data:`MASK_CORRUPTIONS`).

    The result has a new ``clip_id`` (:func:`perturbed_clip_id`) and ``meta`` records the base id,
    kind, severity and seed; ``params`` are the kind's magnitude keywords (e.g. ``amplitude_frac``).
    Unknown kinds or keywords raise.
    """
    if kind not in _KINDS:
        raise ValueError(f"unknown perturbation {kind!r}; kinds: {PERTURBATIONS + MASK_CORRUPTIONS}")
    severity = _check_severity(severity)
    out = _KINDS[kind](clip, severity, seed, **params)
    clip_id = perturbed_clip_id(clip.clip_id, kind, severity)
    meta = {**clip.meta, "clip_id": clip_id,
            "perturbation": {"base": clip.clip_id, "kind": kind, "severity": severity, "seed": int(seed),
                             **params}}
    return dataclasses.replace(out, clip_id=clip_id, meta=meta)
