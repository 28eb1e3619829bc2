"""Estimator error models for validating the score (docs/semantics.md §7.4): what a tracker and a
depth estimator get wrong on a consistent world, applied to a clip's exact arrays.

A :class:`NoiseModel` describes the errors; :func:`add_noise` deals one seeded draw of them.

- Track errors are in pixels, ``px`` the RMS error per coordinate at each end that errs. Pairwise
  trackers queried at frame i−1 (the authors' DELTA files, LK) err at frame i only (``ends="curr"``);
  long-range trackers (DELTA's dense output, CoTracker3) err at both ends of every pair
  (``ends="both"``), with independent draws at frame i−1 and frame i.
- Correlated errors: with ``correlation_px`` ℓ > 0 a share ``shared`` of each end's error variance
  comes from a smooth random displacement field over the image, correlation exp(−d²/2ℓ²) at a
  distance d, drawn anew for each end of each pair; the rest is independent per track. With ℓ = 16
  px and a share of 0.85, tracks 8 px apart share 75 % of their variance and 32 px apart 11 %, as
  the shared real clips' LK tracks do (79–91 % within 8 px, 16–43 % at 32–64 px).
- Outliers: a fraction ``outlier_frac`` of each pair's tracks lands at a uniform random pixel of
  frame i, still visible and fully confident.
- Depth errors, multiplicative: a smooth per-frame field of relative RMS ``depth_rel`` (ℓ =
  ``DEPTH_CORRELATION_PX``), and at depth edges (a jump of more than ``DEPTH_EDGE_JUMP`` between
  neighbouring pixels) pixels within ``depth_edge_px`` of the edge blended at random between the
  two sides, as monocular estimators smear edges ("flying pixels").
- Depth as a network leaves it (:func:`enlarged_depth`, not part of a ``NoiseModel``): predicted at
  a fraction of the frame's size and enlarged bilinearly, so depth edges become ramps of mixed depths
  (docs/semantics.md §3.6, "Smooth depth edges").
- A lens's radial distortion (:func:`radially_distorted`, not part of a ``NoiseModel``): every array
  seen through a lens that bends a point at normalised radius r to r (1 + k1 r²), the clip's K still
  a pinhole's, as real footage given without undistorting it.
- Letterbox bars (:func:`letterboxed`, not part of a ``NoiseModel``): bands at the top and bottom of
  every frame with no tracks, one depth for the whole band and every frame, and marked static, as a
  depth network and a motion segmenter leave a letterboxed video's black bars.
- An overlay that stays put in the image (:func:`overlaid`, not part of a ``NoiseModel``): a watermark
  or logo in the frame's corner, which a tracker follows where it stays, a depth network gives one
  depth and a motion segmenter leaves static.
- A per-frame depth scale error: each frame's depth times exp(``depth_scale_rel`` N(0, 1)), one
  factor a frame, as depth estimated frame by frame and aligned per clip can leave.
- A per-frame depth offset: each frame's depth plus ``depth_offset_rel`` N(0, 1) times the clip's
  median depth, one offset a frame, as a relative-depth model's output aligned frame by frame can
  leave (a scale and a shift per frame).
- Camera errors, as a pose estimator's (VGGT's) per frame, independent between frames: each
  camera turned about its centre by a rotation vector of RMS ``camera_rot_deg`` per axis, and its
  centre moved by ``camera_step_rel`` times the clip's median step between camera centres per axis.

Every draw is from ``numpy.random.default_rng((NOISE_SEED, seed, stream))``: the same clip, model
and seed give the same arrays, and the track and depth draws are independent streams.
"""

from __future__ import annotations

import dataclasses
import math

import cv2
import numpy as np

from ..io.clip import Clip
from ..io.depth_edges import valid_depth

NOISE_SEED = 58_000  # the streams of this module, apart from research.synth's and the perturbations'
DEPTH_CORRELATION_PX = 32.0  # correlation length of the smooth depth error field
DEPTH_EDGE_JUMP = 0.05  # relative depth jump between neighbouring pixels that makes an edge
_TRACK_STREAM, _DEPTH_STREAM, _CAMERA_STREAM = 1, 2, 3


@dataclasses.dataclass(frozen=True)
class NoiseModel:
    """What a tracker and a depth estimator get wrong; pixels, and depth as a relative error."""

    px: float = 0.0  # RMS track error per coordinate, at each erring end [px]
    ends: str = "both"  # "curr": frame i only (per-pair queries); "both": frames i-1 and i (long-range)
    correlation_px: float = 0.0  # ℓ of the shared displacement field; 0: independent errors
    shared: float = 0.85  # share of each end's error variance in the field (when ℓ > 0)
    outlier_frac: float = 0.0  # tracks per pair moved to a uniform random pixel of frame i
    depth_rel: float = 0.0  # relative RMS of the smooth multiplicative depth error
    depth_edge_px: int = 0  # pixels on each side of a depth edge blended across it
    depth_scale_rel: float = 0.0  # relative RMS of one depth scale factor per frame
    depth_offset_rel: float = 0.0  # RMS of one depth offset per frame, relative to the clip's median depth
    camera_rot_deg: float = 0.0  # RMS per axis of each camera's rotation error [deg]
    camera_step_rel: float = 0.0  # RMS per axis of each camera centre's error [median camera steps]

    def __post_init__(self) -> None:
        checks = {
            "px >= 0": self.px >= 0,
            "ends in ('curr', 'both')": self.ends in ("curr", "both"),
            "correlation_px >= 0": self.correlation_px >= 0,
            "0 <= shared <= 1": 0 <= self.shared <= 1,
            "0 <= outlier_frac <= 1": 0 <= self.outlier_frac <= 1,
            "0 <= depth_rel < 0.5": 0 <= self.depth_rel < 0.5,
            "depth_edge_px >= 0": self.depth_edge_px >= 0,
            "0 <= depth_scale_rel < 0.5": 0 <= self.depth_scale_rel < 0.5,
            "0 <= depth_offset_rel < 0.5": 0 <= self.depth_offset_rel < 0.5,
            "camera_rot_deg >= 0": self.camera_rot_deg >= 0,
            "camera_step_rel >= 0": self.camera_step_rel >= 0,
        }
        failed = [rule for rule, ok in checks.items() if not ok]
        if failed:
            raise ValueError(f"invalid NoiseModel ({'; '.join(failed)}): {self}")

    def replace(self, **changes) -> "NoiseModel":
        return dataclasses.replace(self, **changes)


#: The protocol's noise models (issue 58's (a)-(d)); each is scaled to a level by ``.replace(px=...)``.
NOISE_MODELS = {
    "iid-curr": NoiseModel(ends="curr"),  # (a) per-pair queries: independent, frame i only
    "iid-both": NoiseModel(ends="both"),  # (a) long-range tracks: independent, both ends
    "correlated": NoiseModel(ends="both", correlation_px=16.0),  # (b) a shared field per end and pair
    "depth": NoiseModel(ends="both", depth_rel=0.01, depth_edge_px=1),  # (c) depth errors, edges most
    "outliers": NoiseModel(ends="both", outlier_frac=0.1),  # (d) 10 % of the tracks anywhere
}


def smooth_field(rng: np.random.Generator, shape: tuple[int, ...], height: int, width: int,
                 correlation_px: float) -> np.ndarray:
    """(*shape, H, W) float64 fields of unit RMS whose correlation at distance d is exp(-d²/2ℓ²):
    white noise blurred by a Gaussian of sigma ℓ/√2, each field scaled to unit RMS."""
    white = rng.standard_normal((*shape, height, width))
    if correlation_px <= 0:
        return white
    sigma = correlation_px / math.sqrt(2.0)
    flat = white.reshape(-1, height, width)
    blurred = np.stack([cv2.GaussianBlur(f, (0, 0), sigmaX=sigma, sigmaY=sigma, borderType=cv2.BORDER_REFLECT)
                        for f in flat])
    rms = np.sqrt(np.mean(blurred ** 2, axis=(1, 2), keepdims=True))
    return (blurred / np.maximum(rms, 1e-12)).reshape(white.shape)


def _sample(field: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Values (..., P) of fields (..., H, W) at the nearest pixel of positions (..., P, 2), clamped."""
    H, W = field.shape[-2:]
    col = np.clip(np.rint(np.nan_to_num(xy[..., 0])), 0, W - 1).astype(np.int64)
    row = np.clip(np.rint(np.nan_to_num(xy[..., 1])), 0, H - 1).astype(np.int64)
    return np.take_along_axis(field.reshape(*field.shape[:-2], H * W), row * W + col, axis=-1)


def track_errors(model: NoiseModel, positions: np.ndarray, height: int, width: int,
                 rng: np.random.Generator) -> np.ndarray:
    """(n, P, 2) errors [px] for n sets of P positions (x, y): independent, or ``shared`` of the
    variance from a smooth field per set and coordinate (module docstring)."""
    n, P = positions.shape[:2]
    independent = rng.standard_normal((n, P, 2))
    if model.correlation_px <= 0:
        return model.px * independent
    fields = smooth_field(rng, (n, 2), height, width, model.correlation_px)
    shared = np.stack([_sample(fields[:, c], positions) for c in range(2)], axis=-1)
    return model.px * (math.sqrt(model.shared) * shared + math.sqrt(1.0 - model.shared) * independent)


def depth_edges(depth: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """(T, H, W) bool: valid pixels whose depth differs from a valid 4-neighbour's by more than
    ``DEPTH_EDGE_JUMP`` (relative), on both sides of the jump."""
    log_depth = np.log(np.where(valid, depth, 1.0))
    edge = np.zeros_like(valid)
    for axis in (1, 2):  # rows, then columns
        lo = [slice(None)] * 3
        hi = [slice(None)] * 3
        lo[axis], hi[axis] = slice(None, -1), slice(1, None)
        jump = ((np.abs(log_depth[tuple(hi)] - log_depth[tuple(lo)]) > math.log1p(DEPTH_EDGE_JUMP))
                & valid[tuple(hi)] & valid[tuple(lo)])
        edge[tuple(lo)] |= jump
        edge[tuple(hi)] |= jump
    return edge


def enlarged_depth(depth: np.ndarray, factor: float) -> np.ndarray:
    """(T, H, W) float32: each frame of ``depth`` shrunk ``factor`` times by area averaging (over
    factor x factor blocks at a whole factor), then enlarged bilinearly back to H x W, as a depth
    network predicting at 1/factor of the frame's size leaves it (VDA at 518 px on the short side)."""
    H, W = depth.shape[1:]
    small = (max(round(W / factor), 1), max(round(H / factor), 1))
    return np.stack([cv2.resize(cv2.resize(frame, small, interpolation=cv2.INTER_AREA), (W, H),
                                interpolation=cv2.INTER_LINEAR) for frame in depth.astype(np.float32)])


def radially_distorted(clip: Clip, k1: float) -> Clip:
    """The clip as a lens with radial distortion ``k1`` images it (module docstring), each frame
    through its own K: tracks moved to where the lens puts them, depth, static mask (nearest pixel)
    and frames (bilinear) resampled from the undistorted pixel each distorted pixel shows, 0 beyond
    the frame; cameras and K as given. The id gets a ``-k1<k1>`` suffix."""
    H, W = clip.image_size
    Ks = np.broadcast_to(clip.K, (clip.n_frames, 3, 3)).astype(np.float64)
    coefficients = np.array([k1, 0.0, 0.0, 0.0])
    pixels = np.stack(np.meshgrid(np.arange(W), np.arange(H)), -1).reshape(-1, 1, 2).astype(np.float64)

    def seen(frame: int, image: np.ndarray, interpolation: int) -> np.ndarray:
        shown = cv2.undistortPoints(pixels, Ks[frame], coefficients, P=Ks[frame]).reshape(H, W, 2).astype(np.float32)
        return cv2.remap(image, shown[..., 0], shown[..., 1], interpolation, borderMode=cv2.BORDER_CONSTANT, borderValue=0)

    def bent(points: np.ndarray, K: np.ndarray) -> np.ndarray:  # (P, 2) pixels through the lens
        normalised = (points.astype(np.float64) - K[:2, 2]) / np.diag(K)[:2]
        bend = 1.0 + k1 * np.sum(normalised**2, axis=-1, keepdims=True)
        return (normalised * bend * np.diag(K)[:2] + K[:2, 2]).astype(np.float32)

    frames = range(clip.n_frames)
    return dataclasses.replace(
        clip, clip_id=f"{clip.clip_id}-k1{k1:g}",
        depth=np.stack([seen(f, clip.depth[f].astype(np.float32), cv2.INTER_NEAREST) for f in frames]),
        static_mask=np.stack([seen(f, clip.static_mask[f].astype(np.uint8), cv2.INTER_NEAREST) for f in frames]) > 0,
        track_prev=np.stack([bent(clip.track_prev[i], Ks[i]) for i in range(clip.n_pairs)]),
        track_curr=np.stack([bent(clip.track_curr[i], Ks[i + 1]) for i in range(clip.n_pairs)]),
        frames=None if clip.frames is None else np.stack([seen(f, clip.frames[f], cv2.INTER_LINEAR) for f in frames]))


def letterboxed(clip: Clip, share: float, depth_percentile: float = 50.0) -> Clip:
    """The clip with letterbox bars (module docstring): the top and bottom ``share`` of every frame's
    rows at the ``depth_percentile`` of its valid depth, static; tracks that start or land in a bar
    made invisible. The id gets a ``-bars<share>`` suffix."""
    H = clip.image_size[0]
    rows = int(round(share * H))
    depth, static = clip.depth.copy(), clip.static_mask.copy()
    valid = valid_depth(depth)
    bars = np.zeros(H, bool)
    bars[:rows], bars[H - rows:] = True, True
    depth[:, bars] = np.percentile(depth[valid], depth_percentile) if valid.any() else 1.0
    static[:, bars] = True
    in_bar = lambda track: (track[..., 1] < rows - 0.5) | (track[..., 1] >= H - rows - 0.5)  # noqa: E731
    vis = clip.track_vis & ~in_bar(clip.track_prev) & ~in_bar(clip.track_curr)
    return dataclasses.replace(clip, clip_id=f"{clip.clip_id}-bars{share:g}", depth=depth, static_mask=static,
                               track_vis=vis)


def overlaid(clip: Clip, width_share: float, height_share: float, *, masked: bool = False) -> Clip:
    """The clip with an overlay (module docstring) of ``width_share`` x ``height_share`` of the frame,
    4 px from its bottom-right corner: tracks that start on it stay where they start (visible), its
    depth one value (the median of what lay there); static, or (``masked``) left out of the static
    mask, as a user who masks it gives it. The id gets a ``-overlay<w>x<h>`` suffix."""
    H, W = clip.image_size
    x0, y0, x1, y1 = int(W * (1 - width_share)) - 4, int(H * (1 - height_share)) - 4, W - 4, H - 4
    on = lambda track: ((track[..., 0] >= x0 - 0.5) & (track[..., 0] < x1 - 0.5)  # noqa: E731
                        & (track[..., 1] >= y0 - 0.5) & (track[..., 1] < y1 - 0.5))
    stuck = on(clip.track_prev)
    curr = np.where(stuck[..., None], clip.track_prev, clip.track_curr)
    depth, static = clip.depth.copy(), clip.static_mask.copy()
    region = depth[:, y0:y1, x0:x1]
    values = region[valid_depth(region)]
    depth[:, y0:y1, x0:x1] = np.median(values) if values.size else 1.0
    static[:, y0:y1, x0:x1] = not masked
    return dataclasses.replace(clip, clip_id=f"{clip.clip_id}-overlay{width_share:g}x{height_share:g}", depth=depth,
                               static_mask=static, track_curr=curr, track_vis=clip.track_vis | stuck)


def noisy_depth(model: NoiseModel, depth: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(T, H, W) float32 depth with the model's multiplicative field, smeared edges, per-frame scale and
    offset; invalid pixels (<= 0 or non-finite) stay as they are."""
    T, H, W = depth.shape
    out = depth.astype(np.float64)
    valid = np.isfinite(out) & (out > 0)
    if model.depth_rel > 0:
        field = smooth_field(rng, (T,), H, W, DEPTH_CORRELATION_PX)
        out = np.where(valid, out * np.exp(model.depth_rel * field), out)
    if model.depth_edge_px > 0:
        kernel = np.ones((2 * model.depth_edge_px + 1,) * 2, np.uint8)
        near_edge = np.stack([cv2.dilate(e.astype(np.uint8), kernel) > 0 for e in depth_edges(out, valid)]) & valid
        # the nearest and farthest valid depth around each pixel: the two sides of its edge
        nearest = np.stack([cv2.erode(np.where(v, d, np.inf).astype(np.float32), kernel) for d, v in zip(out, valid)])
        farthest = np.stack([cv2.dilate(np.where(v, d, 0.0).astype(np.float32), kernel) for d, v in zip(out, valid)])
        blend = rng.uniform(0.0, 1.0, size=out.shape)
        with np.errstate(invalid="ignore"):  # inf - inf where no valid depth is near: not an edge, not read
            out = np.where(near_edge, nearest + blend * (farthest.astype(np.float64) - nearest), out)
    if model.depth_scale_rel > 0:  # drawn after the others: their draws stay as they were
        out = np.where(valid, out * np.exp(model.depth_scale_rel * rng.standard_normal(T))[:, None, None], out)
    if model.depth_offset_rel > 0:  # drawn last; a pixel the offset takes to 0 or below is invalid, as any such depth
        offsets = model.depth_offset_rel * np.median(depth[valid]) * rng.standard_normal(T)
        out = np.where(valid, out + offsets[:, None, None], out)
    return out.astype(np.float32)


def noisy_cameras(model: NoiseModel, R_wc: np.ndarray, t_wc: np.ndarray,
                  rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(R_wc, t_wc) world->camera with the model's camera errors (module docstring), float64: each
    camera rotated about its centre c = −Rᵀt, then its centre moved."""
    T = R_wc.shape[0]
    centres = -np.einsum("tji,tj->ti", R_wc, t_wc)
    turns = np.stack([cv2.Rodrigues(v)[0] for v in np.deg2rad(model.camera_rot_deg) * rng.standard_normal((T, 3))])
    steps = np.linalg.norm(np.diff(centres, axis=0), axis=1)
    step = float(np.median(steps)) if steps.size else 0.0
    centres = centres + model.camera_step_rel * step * rng.standard_normal((T, 3))
    R = turns @ R_wc
    return R, -np.einsum("tij,tj->ti", R, centres)


def add_noise(clip: Clip, model: NoiseModel, seed: int = 0) -> Clip:
    """The clip with one seeded draw of the model's errors (module docstring); its id gets a
    ``-noise<seed>`` suffix. Identity for the zero model."""
    rng_tracks = np.random.default_rng((NOISE_SEED, seed, _TRACK_STREAM))
    rng_depth = np.random.default_rng((NOISE_SEED, seed, _DEPTH_STREAM))
    rng_camera = np.random.default_rng((NOISE_SEED, seed, _CAMERA_STREAM))
    H, W = clip.image_size
    prev = clip.track_prev.astype(np.float64)
    curr = clip.track_curr.astype(np.float64)
    vis = clip.track_vis.copy()
    if model.px > 0:
        curr = curr + track_errors(model, curr, H, W, rng_tracks)
        if model.ends == "both":
            prev = prev + track_errors(model, prev, H, W, rng_tracks)
    if model.outlier_frac > 0:
        n_pairs, P = curr.shape[:2]
        n_out = int(round(model.outlier_frac * P))
        for pair in range(n_pairs):  # host-side data preparation, not a kernel
            bad = rng_tracks.permutation(P)[:n_out]
            curr[pair, bad] = rng_tracks.uniform([0.0, 0.0], [W - 1, H - 1], size=(n_out, 2))
            vis[pair, bad] = True
    depth = clip.depth
    if model.depth_rel > 0 or model.depth_edge_px > 0 or model.depth_scale_rel > 0 or model.depth_offset_rel > 0:
        depth = noisy_depth(model, clip.depth, rng_depth)
    R_wc, t_wc = clip.R_wc, clip.t_wc
    if model.camera_rot_deg > 0 or model.camera_step_rel > 0:
        R_wc, t_wc = noisy_cameras(model, clip.R_wc.astype(np.float64), clip.t_wc.astype(np.float64), rng_camera)
    return dataclasses.replace(clip, track_prev=prev.astype(np.float32), track_curr=curr.astype(np.float32),
                               track_vis=vis, depth=depth, R_wc=R_wc, t_wc=t_wc, clip_id=f"{clip.clip_id}-noise{seed}")
