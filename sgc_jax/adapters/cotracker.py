"""CoTracker3 tracks -> ``track_prev``, ``track_curr`` (T-1, P, 2), ``track_vis``, ``track_conf`` (T-1, P).

CoTracker3's predictors return ``pred_tracks`` (B, T, N, 2) and ``pred_visibility`` (B, T, N); a
script saves them as it likes. Read here: an ``.npz`` (or a mapping) with ``pred_tracks`` and
``pred_visibility`` (or ``tracks`` and ``visibility``); a ``.pt`` from ``torch.save`` of such a
dict or of the tuple ``(pred_tracks, pred_visibility)``; an ``.npy`` of ``pred_tracks`` alone
(every track then counts as visible, and the notes say so). A batch axis of 1 is dropped.

- Coordinates: x (column), y (row) in pixels of the video given to the predictor, pixel centres
  at integers (CoTracker scales its internal grid back by (W - 1) / (w - 1), the align-corners
  rule), so they are on the clip grid when the video was; otherwise ``track_size`` rescales them.
- Visibility: the predictors already return bools (visibility x confidence > 0.6 in CoTracker3);
  a float visibility (a model's raw output) counts above ``vis_threshold`` (default 0.6, the
  predictors' own). A pair's track is visible when it is visible in both frames. CoTracker3 folds
  its confidence into the visibility, so ``track_conf`` is 1.
- Queries: tracks queried at frame 0 (``grid_query_frame=0``, the default) run through the clip;
  a track queried later is invisible before its query frame, as CoTracker reports it.
Pair i: track_prev = pred_tracks[i-1], track_curr = pred_tracks[i]: long-range tracks, whose
errors sit at both ends of a pair (docs/semantics.md §7.4).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from ..io.npz import shape_text
from .common import EstimatorFormatError, load_arrays, load_npy, squeeze_batch
from .delta import LongRangeTracks, Tracks

COTRACKER_VIS_THRESHOLD = 0.6  # CoTracker3's predictors: visibility * confidence > 0.6
TRACK_KEYS = ("pred_tracks", "tracks")
VISIBILITY_KEYS = ("pred_visibility", "visibility")


def _as_numpy(value: Any) -> np.ndarray:
    """A torch tensor (any device, with or without grad) or array-like -> NumPy."""
    if hasattr(value, "detach"):
        value = value.detach().cpu().numpy()
    return np.asarray(value)


def _load_pt(path: Path) -> dict[str, np.ndarray]:
    try:
        import torch
    except ImportError:
        raise EstimatorFormatError(path, "<file>", "a torch.save file (reading it needs torch)", "no torch installed",
                                   'pip install "sgc-jax[torch]", or save the tracks with np.savez') from None
    try:
        raw = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many kinds for a file it cannot read
        raise EstimatorFormatError(path, "<file>", "a torch.save of tensors", f"{type(exc).__name__}: {exc}") from None
    if isinstance(raw, (tuple, list)) and len(raw) >= 2:
        return {"pred_tracks": _as_numpy(raw[0]), "pred_visibility": _as_numpy(raw[1])}
    if isinstance(raw, Mapping):
        return {str(k): _as_numpy(v) for k, v in raw.items()}
    if hasattr(raw, "detach"):
        return {"pred_tracks": _as_numpy(raw)}
    raise EstimatorFormatError(path, "<file>", "a dict with pred_tracks and pred_visibility, or the tuple "
                               "(pred_tracks, pred_visibility)", type(raw).__name__)


def cotracker_arrays(source: Any) -> tuple[str, dict[str, np.ndarray]]:
    """(label, arrays) of a CoTracker3 output: ``.npz``, ``.pt``, ``.npy`` or a mapping."""
    if isinstance(source, Mapping):
        return "<cotracker arrays>", {k: _as_numpy(v) for k, v in source.items()}
    path = Path(os.fspath(source))
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    if path.suffix in (".pt", ".pth"):
        return str(path), _load_pt(path)
    if path.suffix == ".npy":
        return str(path), {"pred_tracks": load_npy(path)}
    return load_arrays(path)


def holds_cotracker(source: Any) -> bool:
    """Whether ``source`` is a CoTracker3 output (by suffix, or by its arrays' names)."""
    if isinstance(source, Mapping):
        return any(k in source for k in TRACK_KEYS)
    path = Path(os.fspath(source))
    if path.suffix in (".pt", ".pth", ".npy"):
        return True
    if path.suffix == ".npz" and path.is_file():
        try:
            with np.load(path) as archive:  # the names only: nothing is decompressed
                return any(k in archive.files for k in TRACK_KEYS)
        except (ValueError, OSError):  # not an archive: the DELTA reader names the problem
            return False
    return False


def read_cotracker(source: Any, *, vis_threshold: float | None = None) -> Tracks:
    """CoTracker3 ``pred_tracks`` (T, N, 2) and ``pred_visibility`` (T, N) -> clip tracks, one pair
    per consecutive frames."""
    label, arrays = cotracker_arrays(source)
    key = next((k for k in TRACK_KEYS if k in arrays), None)
    if key is None:
        raise EstimatorFormatError(label, "pred_tracks", "(T, N, 2) pixel positions",
                                   f"no such array (found {sorted(arrays)})",
                                   "save CoTracker3's outputs as np.savez(path, pred_tracks=..., pred_visibility=...)")
    tracks = squeeze_batch(np.asarray(arrays[key], np.float32), 3)
    if tracks.ndim != 3 or tracks.shape[2] != 2 or tracks.shape[0] < 2:
        raise EstimatorFormatError(label, key, "shape (T, N, 2) with T >= 2 (or (1, T, N, 2))",
                                   f"shape {shape_text(np.shape(arrays[key]))}")
    T, N = tracks.shape[:2]
    threshold = COTRACKER_VIS_THRESHOLD if vis_threshold is None else float(vis_threshold)
    vis_key = next((k for k in VISIBILITY_KEYS if k in arrays), None)
    if vis_key is None:
        visible = np.ones((T, N), bool)
        rule = "no visibility saved: every track visible"
    else:
        raw = np.asarray(arrays[vis_key])
        raw = raw[..., 0] if raw.ndim >= 3 and raw.shape[-1] == 1 else raw
        raw = squeeze_batch(raw, 2)
        if raw.shape != (T, N):
            raise EstimatorFormatError(label, vis_key, f"shape ({T}, {N}) like {key}", f"shape {shape_text(raw.shape)}")
        if raw.dtype == bool:
            visible, rule = raw, "CoTracker3's boolean visibility"
        else:
            visible = np.nan_to_num(raw.astype(np.float32), nan=0.0) > threshold
            rule = f"CoTracker3 visibility > {threshold:g}"
    finite = np.isfinite(tracks).all(axis=-1)
    visible = visible & finite
    tracks = np.where(finite[..., None], tracks, 0.0).astype(np.float32)
    notes = {"tracks_layout": "cotracker3 pred_tracks/pred_visibility (long-range, consecutive frames)",
             "track_visibility": rule + ", in both frames of a pair"}
    conf = np.ones((T, N), np.float32)
    return Tracks(tracks[:-1].copy(), tracks[1:].copy(), visible[:-1] & visible[1:], conf[1:], None, notes,
                  LongRangeTracks(tracks, visible, conf))
