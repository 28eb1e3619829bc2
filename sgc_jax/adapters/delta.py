"""DELTA tracks -> ``track_prev``, ``track_curr`` (T-1, P, 2), ``track_vis``, ``track_conf`` (T-1, P).

Two layouts are read:
- per-pair files, as the SGC authors' pipeline writes them (DELTA queried on a grid at frame a and
  tracked to the next frame b): ``{a}_{a}.npy`` and ``{a}_{b}.npy``, float32 (N, 4) with columns
  x, y, vis, conf, where a, b are frame-file stems. Pair (a -> b): track_prev = x, y of
  ``{a}_{a}``; track_curr, vis and conf from ``{a}_{b}``.
- dense arrays, as DELTA's ``demo_2d.py`` pickles them (``dense_2d_track.pkl``, or an ``.npz`` with
  the same keys): ``coords`` (T, N, 2), ``vis`` (T, N), ``conf`` (T, N), all queried at frame 0.
  Pair i: track_prev = coords[i-1], track_curr = coords[i]; visible when visible in both frames.
Visibility: DELTA's visibility is a probability; a track is visible when it exceeds
``vis_threshold`` (0.8, the threshold of DELTA's own ``DensePredictor2D``). The reference-compat
mode keeps the raw value instead, so any vis > 0 counts, as in the authors' pipeline (which had
commented the threshold out). Coordinates are pixels on the frames DELTA saw (x = column).
"""

from __future__ import annotations

import dataclasses
import os
import pickle
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..io.npz import shape_text
from .common import EstimatorFormatError, load_arrays, load_npy, natural_key, squeeze_batch

DELTA_VIS_THRESHOLD = 0.8  # DensePredictor2D: dense_vis_e = dense_vis_e > 0.8


@dataclasses.dataclass(frozen=True)
class LongRangeTracks:
    """The same N points located in every frame (a long-range tracker's output), pixels."""

    coords: np.ndarray  # (T, N, 2) float32
    visible: np.ndarray  # (T, N) bool
    conf: np.ndarray  # (T, N) float32


@dataclasses.dataclass
class Tracks:
    """Per-pair tracks in the clip layout; ``frame_names`` when the files name the frames;
    ``long_range`` when every pair's tracks come from one set of points tracked through the clip
    (then pairs of frames further apart can be formed: :func:`every_nth_frame`)."""

    track_prev: np.ndarray  # (T-1, P, 2) float32
    track_curr: np.ndarray  # (T-1, P, 2) float32
    track_vis: np.ndarray  # (T-1, P) bool, or float raw visibility in reference-compat mode
    track_conf: np.ndarray  # (T-1, P) float32
    frame_names: list[str] | None
    notes: dict[str, Any]
    long_range: LongRangeTracks | None = None

    @property
    def n_frames(self) -> int:
        return self.track_prev.shape[0] + 1


def every_nth_frame(tracks: Tracks, step: int) -> Tracks:
    """The pairs of frames (0, step), (step, 2 step), ... of long-range tracks: a point is visible
    in a pair when it is visible at both of its frames; its confidence is the later frame's."""
    if tracks.long_range is None:
        raise ValueError(f"a frame step of {step} pairs frames {step} apart, which needs long-range tracks "
                         "(DELTA's dense output or CoTracker3, read without reference-compat); these are "
                         f"{tracks.notes.get('tracks_layout', 'tracks of consecutive frames only')}")
    kept = np.arange(0, tracks.n_frames, step)
    lr = tracks.long_range
    names = None if tracks.frame_names is None else [tracks.frame_names[k] for k in kept]
    return Tracks(lr.coords[kept[:-1]].copy(), lr.coords[kept[1:]].copy(), lr.visible[kept[:-1]] & lr.visible[kept[1:]],
                  lr.conf[kept[1:]].copy(), names, tracks.notes, lr)


def _visibility(vis: np.ndarray, threshold: float, reference_compat: bool) -> np.ndarray:
    vis = np.nan_to_num(np.asarray(vis, np.float32), nan=0.0)
    return vis if reference_compat else vis > threshold


def frame_stems(directory: Path) -> list[str]:
    """Frame stems named by the files in ``directory``, in natural order: every s with a query file
    ``{s}_{s}.npy`` (frames 0..T-2), then the target b of the last query's ``{a}_{b}.npy`` (frame T-1,
    which starts no pair and so has no query file)."""
    stems = []
    for path in directory.glob("*.npy"):
        name = path.stem
        half = (len(name) - 1) // 2
        if len(name) % 2 == 1 and name[half] == "_" and name[:half] == name[half + 1:]:
            stems.append(name[:half])
    stems.sort(key=natural_key)
    if stems:
        last = stems[-1]
        later = [p.stem[len(last) + 1:] for p in directory.glob(f"{last}_*.npy")]
        later = [b for b in later if b not in stems and natural_key(b) > natural_key(last)]
        if later:
            stems.append(min(later, key=natural_key))
    return stems


def _load_pair_file(path: Path) -> np.ndarray:
    data = load_npy(path)
    if data.ndim != 2 or data.shape[1] < 4:
        raise EstimatorFormatError(path, "x, y, vis, conf", "shape (N, 4) float32 (DELTA per-pair layout)",
                                   f"shape {shape_text(data.shape)}")
    return np.asarray(data, np.float32)


def read_delta_pairs(directory: Any, *, frame_names: Sequence[str] | None = None,
                     vis_threshold: float = DELTA_VIS_THRESHOLD, reference_compat: bool = False) -> Tracks:
    """The authors' per-pair ``{a}_{a}.npy`` / ``{a}_{b}.npy`` files -> clip tracks.

    ``frame_names``: frame-file stems in order (from the frames folder); default: the stems of the
    ``{s}_{s}.npy`` files. Pairs with fewer points are padded with invisible tracks.
    """
    directory = Path(os.fspath(directory))
    if not directory.is_dir():
        raise FileNotFoundError(f"{directory}: no such tracks folder")
    names = list(frame_names) if frame_names is not None else frame_stems(directory)
    own = frame_stems(directory)
    renamed = frame_names is not None and not any((directory / f"{a}_{a}.npy").is_file() for a in names)
    if renamed and len(own) == len(names):  # the files use other frame names: pair them up in order
        names = own
    if len(names) < 2:
        raise EstimatorFormatError(directory, "{a}_{a}.npy", "query files of at least 2 frames",
                                   f"{len(names)} ({sorted(p.name for p in directory.glob('*.npy'))[:4]}...)",
                                   "point --tracks at DELTA's output folder of per-pair .npy files")
    prev, curr, vis, conf = [], [], [], []
    for a, b in zip(names[:-1], names[1:]):
        query_path, target_path = directory / f"{a}_{a}.npy", directory / f"{a}_{b}.npy"
        for path in (query_path, target_path):
            if not path.is_file():
                raise EstimatorFormatError(path, "x, y, vis, conf", f"the DELTA file of pair {a} -> {b}",
                                           "no such file", "rerun DELTA for this pair, or check that the "
                                           "frame names match the track files")
        query, target = _load_pair_file(query_path), _load_pair_file(target_path)
        if len(query) != len(target):
            raise EstimatorFormatError(target_path, "x, y, vis, conf", f"{len(query)} rows like {query_path.name}",
                                       f"{len(target)} rows", "both files of a pair must hold the same tracks")
        prev.append(query[:, :2])
        curr.append(target[:, :2])
        vis.append(_visibility(target[:, 2], vis_threshold, reference_compat))
        conf.append(target[:, 3])
    P = max(len(p) for p in prev)

    def stack(rows: list[np.ndarray], fill: Any) -> np.ndarray:
        out = np.full((len(rows), P) + rows[0].shape[1:], fill, dtype=rows[0].dtype)
        for i, row in enumerate(rows):
            out[i, :len(row)] = row
        return out

    notes = {"tracks_layout": "delta per-pair {a}_{a}.npy / {a}_{b}.npy"
             + (" (file names differ from the frame names: matched in order)" if renamed else ""),
             "track_visibility": "raw DELTA vis, vis > 0 (reference-compat)" if reference_compat
             else f"DELTA vis > {vis_threshold:g}"}
    return Tracks(stack(prev, 0.0), stack(curr, 0.0), stack(vis, False if not reference_compat else 0.0),
                  np.nan_to_num(stack(conf, 0.0), nan=0.0), names, notes)


def read_delta_dense(source: Any, *, vis_threshold: float = DELTA_VIS_THRESHOLD,
                     reference_compat: bool = False) -> Tracks:
    """DELTA dense ``coords`` (T, N, 2), ``vis`` (T, N), ``conf`` (T, N) (``.pkl``, ``.npz`` or mapping).

    A ``.pkl`` is unpickled: only open pickles you made yourself.
    """
    if isinstance(source, (str, os.PathLike)) and Path(source).suffix == ".pkl":
        label = str(source)
        try:
            with open(source, "rb") as handle:
                raw = pickle.load(handle)  # noqa: S301 - the user's own DELTA output, documented above
        except (pickle.UnpicklingError, EOFError, AttributeError, ImportError) as exc:  # truncated, or not a pickle
            raise EstimatorFormatError(label, "<pickle>", "a pickled dict with coords, vis, conf",
                                       f"{type(exc).__name__}: {exc}") from None
        if not isinstance(raw, dict):
            raise EstimatorFormatError(label, "<pickle>", "a dict with coords, vis, conf", type(raw).__name__)
        arrays = {k: np.asarray(v) for k, v in raw.items()}
    else:
        label, arrays = load_arrays(source, "<delta arrays>")
    if "coords" not in arrays:
        raise EstimatorFormatError(label, "coords", "(T, N, 2) pixel positions", f"no such array (found {sorted(arrays)})",
                                   "DELTA's demo_2d.py saves 'coords', 'vis' and 'conf' in dense_2d_track.pkl")
    coords = squeeze_batch(np.asarray(arrays["coords"], np.float32), 3)
    if coords.ndim != 3 or coords.shape[2] != 2 or coords.shape[0] < 2:
        raise EstimatorFormatError(label, "coords", "shape (T, N, 2) with T >= 2", f"shape {shape_text(coords.shape)}")
    T, N = coords.shape[:2]
    vis = squeeze_batch(np.asarray(arrays["vis"]), 2) if "vis" in arrays else np.ones((T, N), np.float32)
    conf = squeeze_batch(np.asarray(arrays["conf"], np.float32), 2) if "conf" in arrays else np.ones((T, N), np.float32)
    for name, array in (("vis", vis), ("conf", conf)):
        if array.shape != (T, N):
            raise EstimatorFormatError(label, name, f"shape ({T}, {N}) like coords", f"shape {shape_text(array.shape)}")
    visible = _visibility(vis, vis_threshold, False)
    track_vis = _visibility(vis[1:], vis_threshold, True) if reference_compat else visible[:-1] & visible[1:]
    notes = {"tracks_layout": "delta dense coords/vis/conf (queried at frame 0)",
             "track_visibility": "raw DELTA vis of frame i, vis > 0 (reference-compat)" if reference_compat
             else f"DELTA vis > {vis_threshold:g} in both frames"}
    conf = np.nan_to_num(conf, nan=0.0)
    long_range = None if reference_compat else LongRangeTracks(coords, visible, conf)
    return Tracks(coords[:-1].copy(), coords[1:].copy(), track_vis, conf[1:].copy(), None, notes, long_range)


def read_delta(source: Any, *, frame_names: Sequence[str] | None = None,
               vis_threshold: float = DELTA_VIS_THRESHOLD, reference_compat: bool = False) -> Tracks:
    """A folder of per-pair files, or a dense ``.pkl`` / ``.npz`` file (or mapping) -> clip tracks."""
    if isinstance(source, (str, os.PathLike)) and Path(source).is_dir():
        return read_delta_pairs(source, frame_names=frame_names, vis_threshold=vis_threshold,
                                reference_compat=reference_compat)
    return read_delta_dense(source, vis_threshold=vis_threshold, reference_compat=reference_compat)
