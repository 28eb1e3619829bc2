"""Reading clips (docs/semantics.md §1): arrays -> a validated :class:`~sgc_jax.io.clip.Clip`,
single-clip and batch files, clip sources (paths, directories, globs, mappings), and the reports of
``sgc-jax validate``.

Structural problems (missing arrays, shapes, dtypes, non-finite cameras) are checked here and raise
:class:`~sgc_jax.io.clip.ClipFormatError`; the content checks are :mod:`sgc_jax.io.validate`'s.
"""

from __future__ import annotations

import dataclasses
import functools
import glob
import itertools
import json
import os
import threading
from pathlib import Path
from typing import Any, Callable, Container, Iterable, Iterator, Mapping

import numpy as np

from ..config import SGCConfig
from .checks.cameras import check_intrinsics, check_poses
from .checks.problems import Problem
from .checks.tracks import check_track_positions
from .clip import Clip, ClipFormatError, no_reading
from .npz import NpzError, npz_headers, read_npz, shape_text
from .remote import is_url, list_files
from .validate import check_clip, enforce, raise_first_error

# ----------------------------------------------------------------------------- validation

# dtype kinds a clip array may have: real numbers, plus booleans where the format says bool.
# Complex values, text and Python objects are refused rather than cast (a cast drops the
# imaginary part or fails with a message that names no array).
_REAL, _BOOL_OR_REAL = "iuf", "biuf"
_WHAT = {_REAL: "real numbers (int or float)", _BOOL_OR_REAL: "booleans or real numbers"}
_KINDS = {"depth": _REAL, "K": _REAL, "R_wc": _REAL, "t_wc": _REAL, "extrinsic": _REAL,
          "static_mask": _BOOL_OR_REAL, "dynamic_mask": _BOOL_OR_REAL, "frames": _BOOL_OR_REAL,
          "track_prev": _REAL, "track_curr": _REAL, "track_vis": _BOOL_OR_REAL, "track_conf": _REAL}
# K with a larger condition number cannot be inverted to back-project pixels (float64 keeps ~16 digits).
K_CONDITION_MAX = 1e12


def _as_array(clip_id: str, name: str, value: Any, expected: str) -> np.ndarray:
    """``value`` as an ndarray; a value NumPy cannot make one of (ragged lists, ...) raises ClipFormatError."""
    try:
        return np.asarray(value)
    except (ValueError, TypeError, OverflowError, RecursionError) as exc:
        raise ClipFormatError(clip_id, name, expected, f"{type(exc).__name__}: {exc}") from None


def _typed_arrays(arrays: Mapping[str, Any], clip_id: str) -> dict[str, np.ndarray]:
    """The clip arrays present in ``arrays``, each checked for its dtype kind (see ``_KINDS``)."""
    typed = {}
    for name, kinds in _KINDS.items():
        if name not in arrays or arrays[name] is None:
            continue
        array = _as_array(clip_id, name, arrays[name], _WHAT[kinds])
        if array.dtype.kind not in kinds:
            raise ClipFormatError(clip_id, name, _WHAT[kinds], f"dtype {array.dtype}")
        typed[name] = array
    return typed


def _require(arrays: Mapping[str, Any], name: str, clip_id: str, expected: str, hint: str = "") -> np.ndarray:
    if name not in arrays:
        raise ClipFormatError(clip_id, name, expected, "no such array",
                              f"present: {sorted(arrays)}" + (f"; {hint}" if hint else ""))
    return np.asarray(arrays[name])


def _check_shape(clip_id: str, name: str, array: np.ndarray, expected: tuple) -> None:
    """``expected`` holds ints or None (any size); raise naming both shapes on mismatch."""
    fits = lambda shape: len(shape) == len(expected) and all(e is None or e == s for e, s in zip(expected, shape))  # noqa: E731
    if not fits(array.shape):
        want = shape_text("*" if e is None else e for e in expected)
        raise ClipFormatError(clip_id, name, f"shape {want}", f"shape {shape_text(array.shape)}",
                              _squeeze_hint(name, array.shape, fits) or _shape_hint(name, array.shape, expected, fits))


def _squeeze_hint(name: str, shape: tuple[int, ...], fits: Callable[[tuple[int, ...]], bool]) -> str:
    """How to drop a singleton axis (a network's channel axis, (T, 1, H, W)) where that gives a
    shape that ``fits``; else ""."""
    for axis, size in enumerate(shape):
        if size == 1 and fits(shape[:axis] + shape[axis + 1:]):
            return f"a singleton axis: give {name}.squeeze({axis})"
    return ""


def _shape_hint(name: str, shape: tuple[int, ...], expected: tuple, fits: Callable[[tuple[int, ...]], bool]) -> str:
    """What a shape that does not fit most likely holds, and how to give it: a track array of every
    frame (a long-range tracker's (T, P, ...)), axes in another order, K's four numbers or
    quaternions; else ""."""
    if name.startswith("track_") and shape and shape[0] == expected[0] + 1 and fits((shape[0] - 1,) + shape[1:]):
        return ("every frame's positions, as a long-range tracker gives them? give track_prev = tracks[:-1], "
                "track_curr = tracks[1:], track_vis = visible[:-1] & visible[1:] (docs/semantics.md §1.2), or "
                "`sgc-jax import --tracks`")
    for order in itertools.permutations(range(len(shape))):
        if order != tuple(range(len(shape))) and fits(tuple(shape[axis] for axis in order)):
            return f"its axes in another order: give np.transpose({name}, {order})"
    if name == "K" and shape[-1:] == (4,):
        return "(fx, fy, cx, cy)? give K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]"
    if name == "R_wc" and shape[-1:] == (4,):
        return ("quaternions? give rotation matrices, e.g. scipy.spatial.transform.Rotation.from_quat(q).as_matrix() "
                "(scalar last; mind the convention: a conjugated quaternion transposes R)")
    return ""


def _first_frames(frames: np.ndarray) -> str:
    """The first five of ``frames`` (indices), then "..." where there are more."""
    return ", ".join(str(int(t)) for t in frames[:5]) + (", ..." if frames.size > 5 else "")


def _check_finite(clip_id: str, name: str, array: np.ndarray) -> None:
    """A camera array (T, ...) without NaN or inf; the error names the frames that hold one."""
    finite = np.isfinite(array).reshape(array.shape[0], -1).all(axis=1)
    if not finite.all():
        frames = _first_frames(np.flatnonzero(~finite))
        raise ClipFormatError(clip_id, name, "finite values",
                              f"{int((~np.isfinite(array)).sum())} non-finite value(s) in frames {frames} of {array.shape[0]}",
                              "frames an estimator failed on? score the pieces of the clip on either side of them")


def _check_invertible(clip_id: str, K: np.ndarray) -> None:
    """K (T, 3, 3), finite: each frame's K must be invertible (pixels are back-projected through K^-1)."""
    with np.errstate(divide="ignore", invalid="ignore"):  # a singular K has an infinite condition number
        condition = np.linalg.cond(K)
    bad = np.flatnonzero(~(condition < K_CONDITION_MAX))
    if bad.size:
        raise ClipFormatError(clip_id, "K", "an invertible pinhole matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]",
                              f"a singular matrix (condition number {condition[bad[0]]:.3g}) in frames {_first_frames(bad)}")


def _settle(votes: list[tuple[str, Any]], tie_break: Callable[[list[Any]], Any]) -> tuple[Any, list[str]]:
    """The value most arrays agree on, and the arrays that agree; ``tie_break`` picks among equals."""
    counts: dict[Any, list[str]] = {}
    for name, value in votes:
        counts.setdefault(value, []).append(name)
    most = max(len(names) for names in counts.values())
    value = tie_break([v for v, names in counts.items() if len(names) == most])
    return value, counts[value]


def _frame_count(typed: Mapping[str, np.ndarray], T_depth: int) -> tuple[int, list[str]]:
    """T as most arrays give it: depth, cameras and masks (T, ...), tracks (T-1, ...); ties keep depth's."""
    votes = [("depth", T_depth)]
    for name in ("K", "R_wc", "t_wc", "extrinsic", "static_mask", "dynamic_mask", "frames"):
        if name in typed and typed[name].ndim >= (3 if name == "K" else 1):
            votes.append((name, typed[name].shape[0]))
    for name in ("track_prev", "track_curr", "track_vis", "track_conf"):
        if name in typed and typed[name].ndim >= 1:
            votes.append((name, typed[name].shape[0] + 1))
    return _settle(votes, lambda tied: T_depth if T_depth in tied else tied[0])


def _image_size(typed: Mapping[str, np.ndarray], HW_depth: tuple[int, int]) -> tuple[tuple[int, int], list[str]]:
    """(H, W) as most of depth, masks and frames give it; between equals, the one K's principal point
    is the centre of (a mask or depth on another grid is the usual cause), else depth's."""
    votes = [("depth", HW_depth)]
    for name in ("static_mask", "dynamic_mask", "frames"):
        if name in typed and typed[name].ndim >= 3:
            votes.append((name, tuple(typed[name].shape[1:3])))

    def tie_break(tied: list[tuple[int, int]]) -> tuple[int, int]:
        K = typed.get("K")
        if K is None or K.shape[-2:] != (3, 3) or not np.isfinite(K).all():
            return HW_depth if HW_depth in tied else tied[0]
        centre = np.array([np.median(K[..., 1, 2]), np.median(K[..., 0, 2])])
        return min(tied, key=lambda hw: (float(np.abs((np.array(hw) - 1) / 2 - centre).sum()), hw != HW_depth))

    return _settle(votes, tie_break)


def _parse_meta(raw: Any) -> dict:
    """A clip's ``meta`` as a dict: JSON text, bytes or a dict; anything else is kept as ``{"note": text}``."""
    if raw is None:
        return {}
    value = raw
    if isinstance(raw, np.ndarray) and raw.ndim == 0:
        value = raw.item()
    if isinstance(value, bytes):
        value = value.decode("utf-8", errors="replace")
    if isinstance(value, dict):
        return dict(value)
    text = str(value)
    try:
        meta = json.loads(text)
    except (ValueError, RecursionError):  # not JSON, or nested too deeply to parse
        return {"note": text}
    return meta if isinstance(meta, dict) else {"note": meta}


def _meta_id(raw: Any) -> str | None:
    """The ``clip_id`` a clip's ``meta`` names, as text; None when it names none."""
    value = _parse_meta(raw).get("clip_id")
    return None if value is None or str(value) == "" else str(value)


def _checked_depth(typed: Mapping[str, np.ndarray], clip_id: str) -> tuple[np.ndarray, int, int, int]:
    """(depth float32 (T, H, W), T, H, W): the sizes most arrays agree on, depth's shape checked against them."""
    depth = _require(typed, "depth", clip_id, "shape (T, H, W)")
    if depth.ndim != 3:
        raise ClipFormatError(clip_id, "depth", "shape (T, H, W)", f"shape {shape_text(depth.shape)}",
                              _squeeze_hint("depth", depth.shape, lambda shape: len(shape) == 3 and shape[0] >= 2))
    if depth.shape[0] < 2:
        raise ClipFormatError(clip_id, "depth", "T >= 2 frames", f"T = {depth.shape[0]}")
    if min(depth.shape[1:]) < 1:
        raise ClipFormatError(clip_id, "depth", "an image of H >= 1 by W >= 1 pixels",
                              f"shape {shape_text(depth.shape)}")
    # The sizes most arrays agree on: an array of another size is the one blamed, depth included.
    T, agree_T = _frame_count(typed, depth.shape[0])
    (H, W), agree_HW = _image_size(typed, depth.shape[1:])
    if T < 2:
        raise ClipFormatError(clip_id, "depth", "T >= 2 frames", f"T = {T} in {', '.join(agree_T)}")
    if depth.shape != (T, H, W):
        raise ClipFormatError(clip_id, "depth", f"shape ({T}, {H}, {W}), the T of {', '.join(agree_T)} and the "
                              f"H x W of {', '.join(agree_HW)}", f"shape {shape_text(depth.shape)}")
    if depth.dtype.kind == "u":  # a 16-bit PNG's no-reading code is invalid depth
        depth = np.where(no_reading(depth), 0, depth)
    with np.errstate(over="ignore"):  # float64 beyond float32's range becomes inf: invalid depth
        return depth.astype(np.float32), T, H, W


def _three_rows(extrinsic: np.ndarray, clip_id: str, T: int) -> np.ndarray:
    """A (T, 4, 4) homogeneous extrinsic's top three rows, [R_wc | t_wc]; other shapes as given."""
    if extrinsic.shape != (T, 4, 4):
        return extrinsic
    bottom = extrinsic[:, 3]
    if not np.allclose(bottom, [0.0, 0.0, 0.0, 1.0], atol=1e-6):
        worst = int(np.argmax(np.abs(bottom - [0.0, 0.0, 0.0, 1.0]).max(axis=1)))
        raise ClipFormatError(clip_id, "extrinsic", f"shape ({T}, 3, 4), or ({T}, 4, 4) with a last row (0, 0, 0, 1)",
                              f"last row {np.round(bottom[worst], 4).tolist()} in frame {worst}",
                              "give the world->camera matrices [R_wc | t_wc]")
    return extrinsic[:, :3]


def _checked_cameras(typed: Mapping[str, np.ndarray], arrays: Mapping[str, Any], clip_id: str,
                     T: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(K (T, 3, 3), R_wc (T, 3, 3), t_wc (T, 3)) float64, from K and R_wc / t_wc or extrinsic."""
    K = _require(typed, "K", clip_id, f"shape ({T}, 3, 3) or (3, 3)").astype(np.float64)
    if K.shape == (3, 3):
        K = np.broadcast_to(K, (T, 3, 3)).copy()
    _check_shape(clip_id, "K", K, (T, 3, 3))
    _check_finite(clip_id, "K", K)
    _check_invertible(clip_id, K)
    if "R_wc" in typed or "t_wc" in typed:
        R_wc = _require(typed, "R_wc", clip_id, f"shape ({T}, 3, 3)").astype(np.float64)
        t_wc = _require(typed, "t_wc", clip_id, f"shape ({T}, 3)").astype(np.float64)
        _check_shape(clip_id, "R_wc", R_wc, (T, 3, 3))
        _check_shape(clip_id, "t_wc", t_wc, (T, 3))
    elif "extrinsic" in typed:
        extrinsic = _three_rows(typed["extrinsic"].astype(np.float64), clip_id, T)
        _check_shape(clip_id, "extrinsic", extrinsic, (T, 3, 4))
        R_wc, t_wc = extrinsic[:, :, :3].copy(), extrinsic[:, :, 3].copy()
    else:
        raise ClipFormatError(clip_id, "R_wc", f"shape ({T}, 3, 3) with t_wc, or extrinsic ({T}, 3, 4) or ({T}, 4, 4)",
                              "no such array", f"present: {sorted(arrays)}")
    _check_finite(clip_id, "R_wc", R_wc)
    _check_finite(clip_id, "t_wc", t_wc)
    return K, R_wc, t_wc


MASK_FLOAT_TRUE_ABOVE = 0.5  # a float mask holds a network's probabilities (or logits): true above even odds


def mask_truth(mask: np.ndarray) -> np.ndarray:
    """A stored mask as booleans (docs/semantics.md §1.2): a float mask true where above
    MASK_FLOAT_TRUE_ABOVE, booleans and integers where non-zero (0/255 bytes, object ids)."""
    return mask > MASK_FLOAT_TRUE_ABOVE if mask.dtype.kind == "f" else mask.astype(bool)


def _checked_mask(typed: Mapping[str, np.ndarray], clip_id: str, shape: tuple[int, int, int]) -> tuple[np.ndarray, str]:
    """(static mask (T, H, W) bool, its source: "static_mask", "dynamic_mask" or "none")."""
    if "static_mask" in typed:
        _check_shape(clip_id, "static_mask", typed["static_mask"], shape)
        return mask_truth(typed["static_mask"]), "static_mask"
    if "dynamic_mask" in typed:
        _check_shape(clip_id, "dynamic_mask", typed["dynamic_mask"], shape)
        return ~mask_truth(typed["dynamic_mask"]), "dynamic_mask"
    return np.ones(shape, bool), "none"


def _checked_tracks(typed: Mapping[str, np.ndarray], arrays: Mapping[str, Any], clip_id: str,
                    T: int) -> tuple[np.ndarray, ...]:
    """(track_prev, track_curr (T-1, P, 2), track_vis, track_conf (T-1, P)), each as stored; ``arrays``
    (every array given) name what was given instead of ``track_prev``."""
    if "track_prev" not in typed:
        _missing_pair_tracks(arrays, clip_id, T)
    track_prev = typed["track_prev"]
    _check_shape(clip_id, "track_prev", track_prev, (T - 1, None, 2))
    P = track_prev.shape[1]
    if P < 1:
        raise ClipFormatError(clip_id, "track_prev", f"shape ({T - 1}, P, 2) with P >= 1 tracks per pair",
                              f"shape {shape_text(track_prev.shape)}")
    track_curr = _require(typed, "track_curr", clip_id, f"shape ({T - 1}, {P}, 2)")
    _check_shape(clip_id, "track_curr", track_curr, (T - 1, P, 2))
    track_vis = _require(typed, "track_vis", clip_id, f"shape ({T - 1}, {P})",
                         f"where every track is visible, give track_vis = np.ones(({T - 1}, {P}), bool)")
    _check_shape(clip_id, "track_vis", track_vis, (T - 1, P))
    if "track_conf" in typed:
        track_conf = typed["track_conf"]
        _check_shape(clip_id, "track_conf", track_conf, (T - 1, P))
    else:
        track_conf = np.ones((T - 1, P), np.float32)
    return track_prev, track_curr, track_vis, track_conf


def _missing_pair_tracks(arrays: Mapping[str, Any], clip_id: str, T: int) -> None:
    """Raise ClipFormatError for a clip without ``track_prev``, naming every array given and, where
    one is shaped (T, N, 2) (tracks over the whole video, as CoTracker3's ``pred_tracks``), how to
    give it as pairs."""
    def shape(name):
        try:
            return np.shape(arrays[name])
        except (ValueError, TypeError, KeyError):  # a ragged list, say: no tracks
            return ()

    names = sorted(str(name) for name in arrays)
    whole = [name for name in names if name not in _KINDS and len(shape(name)) == 3 and shape(name)[::2] == (T, 2)]
    fix = (f"; {whole[0]!r} of shape (T, N, 2) looks like tracks over the whole video: give track_prev = "
           f"{whole[0]}[:-1], track_curr = {whole[0]}[1:], track_vis = visible[:-1] & visible[1:] (docs/semantics.md "
           "§1.2), or `sgc-jax import --tracks`") if whole else ""
    raise ClipFormatError(clip_id, "track_prev", f"shape ({T - 1}, P, 2)", "no such array", f"present: {names}{fix}")


def clip_from_arrays(arrays: Mapping[str, Any], *, clip_id: str | None = None,
                     config: SGCConfig | None = None, validate: bool = True) -> Clip:
    """Validate a mapping of clip arrays (docs/semantics.md §1) and return a :class:`Clip`.

    Raises :class:`ClipFormatError` for structural problems (docs/semantics.md §1.4). ``validate``:
    also run the content checks of :mod:`sgc_jax.io.validate` (errors raise ClipValidationError,
    warnings are ClipWarning). Tracks beyond ``config.max_tracks`` are sub-sampled
    deterministically (:func:`subsample_tracks`).
    """
    config = config or SGCConfig()
    clip = _structurally_checked(arrays, clip_id)
    if validate:
        clip = dataclasses.replace(clip, warnings=enforce(clip, config, arrays))
    return subsample_tracks(clip, config)


def _structurally_checked(arrays: Mapping[str, Any], clip_id: str | None) -> Clip:
    """The :class:`Clip` of a mapping of clip arrays after the structural checks of §1.4, every track kept."""
    meta = _parse_meta(arrays.get("meta"))
    clip_id = str(clip_id or meta.get("clip_id") or _text(arrays.get("clip_id")) or "clip")
    meta.setdefault("clip_id", clip_id)
    typed = _typed_arrays(arrays, clip_id)
    depth, T, H, W = _checked_depth(typed, clip_id)
    K, R_wc, t_wc = _checked_cameras(typed, arrays, clip_id, T)
    static_mask, mask_source = _checked_mask(typed, clip_id, (T, H, W))
    track_prev, track_curr, track_vis, track_conf = _checked_tracks(typed, arrays, clip_id, T)
    frames = typed.get("frames")
    if frames is not None:
        _check_shape(clip_id, "frames", frames, (T, H, W, 3))
    with np.errstate(over="ignore", invalid="ignore"):  # float64 beyond float32's range becomes inf: invalid
        return Clip(clip_id=clip_id, depth=depth, K=K, R_wc=R_wc, t_wc=t_wc, static_mask=static_mask,
                    track_prev=np.asarray(track_prev, np.float32), track_curr=np.asarray(track_curr, np.float32),
                    track_vis=(track_vis > 0) if track_vis.dtype != bool else track_vis.copy(),
                    track_conf=np.nan_to_num(np.asarray(track_conf, np.float32), nan=0.0),
                    mask_source=mask_source, frames=frames, meta=meta)


def evenly_spaced_ranks(n: Any, limit: int, xp=np) -> Any:
    """The ranks floor(k (n - 1) / (limit - 1)), k < limit, of ``limit`` of ``n > limit`` items, in
    integers: int64 on the host, int32 on the device (``xp=jax.numpy``), where n - 1 = q (limit -
    1) + r keeps every product below limit^2."""
    k = xp.arange(limit, dtype=xp.int64 if xp is np else xp.int32)
    span = max(limit - 1, 1)
    q, r = (n - 1) // span, (n - 1) % span
    return k * q + (k * r) // span


def subsample_tracks(clip: Clip, config: SGCConfig) -> Clip:
    """Keep at most ``config.max_tracks`` tracks per pair, deterministically.

    Per pair, usable tracks (docs/semantics.md §1.2) come first in their original order; when there are more
    than ``max_tracks`` of them, the evenly spaced ranks of ``evenly_spaced_ranks`` are kept. Clips
    within the limit are unchanged.
    """
    P, limit = clip.n_tracks, config.max_tracks
    if P <= limit:
        return clip
    usable = clip.usable_tracks(config.min_track_conf, repeats=config.counts_repeated_tracks)
    index = np.empty((clip.n_pairs, limit), np.int64)
    for pair, usable_row in enumerate(usable):
        kept = np.flatnonzero(usable_row)
        if kept.size > limit:
            kept = kept[evenly_spaced_ranks(kept.size, limit)]
        rest = np.flatnonzero(~usable_row)[: limit - kept.size]
        index[pair] = np.concatenate([kept, rest])
    take2 = lambda a: np.take_along_axis(a, index[..., None], axis=1)  # noqa: E731
    take1 = lambda a: np.take_along_axis(a, index, axis=1)  # noqa: E731
    return dataclasses.replace(
        clip,
        track_prev=take2(clip.track_prev),
        track_curr=take2(clip.track_curr),
        track_vis=take1(clip.track_vis),
        track_conf=take1(clip.track_conf),
    )


def is_batch(arrays: Mapping[str, Any]) -> bool:
    return "n_frames" in arrays


# ----------------------------------------------------------------------------- batch layout

_PER_FRAME = ("depth", "K", "R_wc", "t_wc", "extrinsic", "static_mask", "dynamic_mask", "frames")
_PER_PAIR = ("track_prev", "track_curr", "track_vis", "track_conf")
_IMAGES = ("depth", "static_mask", "dynamic_mask", "frames")  # (B, T, H, W, ...)
BOOKKEEPING = ("n_frames", "n_tracks", "heights", "widths", "clip_id", "mask_source", "meta")
# Arrays only plots use (docs/semantics.md §1.2): scoring a file checks their headers, not their data.
PLOTS_ONLY = ("frames",)


@dataclasses.dataclass(frozen=True)
class BatchLayout:
    """What a batch file's bookkeeping says about its B members (docs/semantics.md §1.3)."""

    ids: list[str]  # clip ids, in member order
    sizes: list[tuple[int, int, int | None, int | None]]  # each member's true (T, P, H, W); None: not cut
    problems: dict[int, ClipFormatError]  # members whose sizes do not fit the stored arrays

    def __len__(self) -> int:
        return len(self.ids)


def _bookkeeping(book: Mapping[str, np.ndarray], name: str, label: str, count: int, source: str,
                 kinds: str = "iu") -> np.ndarray | None:
    """Bookkeeping array ``name``: (count,) integers (or text); None when absent."""
    if name not in book:
        return None
    what = "integers" if kinds == "iu" else "text"
    array = _as_array(label, name, book[name], f"a ({count},) array of {what}")
    if array.ndim != 1 or array.dtype.kind not in kinds or len(array) != count:
        raise ClipFormatError(label, name, f"a ({count},) array of {what}, one per member ({source})",
                              f"shape {shape_text(array.shape)}, dtype {array.dtype}")
    return array


def batch_layout(shapes: Mapping[str, tuple[int, ...]], book: Mapping[str, Any], label: str) -> BatchLayout:
    """Check a batch's bookkeeping arrays (``book``) against the stored arrays' ``shapes``.

    Raises :class:`ClipFormatError` (clip ``label``, usually the file name) when the file as a whole is
    inconsistent: stored arrays that disagree on B, bookkeeping arrays of another length than B or
    of the wrong dtype. A member whose own T, P, H or W do not fit the stored arrays gets its error in
    :attr:`BatchLayout.problems`; the other members stay loadable.
    """
    if "n_frames" not in book:
        raise ClipFormatError(label, "n_frames", "a (B,) array of integers", "no such array")
    # B is what most stored arrays hold; absent any, n_frames says it
    stacked = [name for name in _PER_FRAME + _PER_PAIR if name in shapes]
    for name in stacked:
        if len(shapes[name]) == 0:
            raise ClipFormatError(label, name, "a leading axis of B members", "a 0-d array")
    leading = [(name, shapes[name][0]) for name in stacked]
    if leading:
        count, agree = _settle(leading, lambda tied: tied[0])
        source = f"as {', '.join(agree)} hold"
        for name, size in leading:
            if size != count:
                raise ClipFormatError(label, name, f"a leading axis of B = {count} members, {source}",
                                      f"shape {shape_text(shapes[name])}")
    else:
        count, source = int(np.size(book["n_frames"])), "as n_frames lists"
    n_frames = _bookkeeping(book, "n_frames", label, count, source)
    if count < 1:
        raise ClipFormatError(label, "n_frames", "at least one member", "B = 0")
    if "n_tracks" not in book:
        raise ClipFormatError(label, "n_tracks", f"a ({count},) array of integers", "no such array")
    n_tracks = _bookkeeping(book, "n_tracks", label, count, source)
    heights = _bookkeeping(book, "heights", label, count, source)
    widths = _bookkeeping(book, "widths", label, count, source)
    texts = {name: _bookkeeping(book, name, label, count, source, kinds="US")
             for name in ("clip_id", "mask_source", "meta")}

    def stored(names: Iterable[str], axis: int, min_ndim: int, plus: int = 0) -> list[tuple[int, str]]:
        return [(shapes[n][axis] + plus, n) for n in names if n in shapes and len(shapes[n]) >= min_ndim]

    frame_room = stored([n for n in _PER_FRAME if n != "K"], 1, 2) + stored(["K"], 1, 4) + stored(_PER_PAIR, 1, 2, 1)
    track_room = stored(_PER_PAIR, 2, 3)
    height_room, width_room = stored(_IMAGES, 2, 4), stored(_IMAGES, 3, 4)
    ids, sizes, problems = [], [], {}
    for b in range(count):
        text_id = str(texts["clip_id"][b]) if texts["clip_id"] is not None else ""
        meta_id = _meta_id(texts["meta"][b]) if texts["meta"] is not None else None
        ids.append(text_id or meta_id or f"clip{b}")
        T, P = int(n_frames[b]), int(n_tracks[b])
        # absent heights / widths: nothing cut, so arrays padded differently are found by the loader
        H = int(heights[b]) if heights is not None else None
        W = int(widths[b]) if widths is not None else None
        sizes.append((T, P, H, W))
        checks = (("n_frames", T, 2, frame_room, "frames"), ("n_tracks", P, 1, track_room, "tracks"),
                  ("heights", H, 1, height_room, "rows"), ("widths", W, 1, width_room, "columns"))
        for name, value, least, room, unit in checks:
            if value is None:
                continue
            if value < least:
                problems[b] = ClipFormatError(ids[b], name, f"{name}[{b}] >= {least}", f"{name}[{b}] = {value}")
                break
            over = [(s, n) for s, n in room if value > s]
            if over:
                s, n = over[0]
                problems[b] = ClipFormatError(ids[b], name, f"{name}[{b}] at most the {s} {unit} stored in {n}",
                                              f"{name}[{b}] = {value}")
                break
    return BatchLayout(ids, sizes, problems)


def _batch_member(arrays: Mapping[str, Any], b: int, layout: BatchLayout) -> dict[str, Any]:
    """Slice clip ``b`` out of a batch mapping, cutting the padding away; raises its layout problem."""
    if b in layout.problems:
        raise layout.problems[b]
    T, P, H, W = layout.sizes[b]
    images, cameras, pairs = (T, H, W), (T,), (T - 1, P)
    cuts = {name: images for name in _IMAGES} | {"R_wc": cameras, "t_wc": cameras, "extrinsic": cameras}
    cuts |= {"K": cameras if np.ndim(arrays.get("K")) == 4 else ()} | {name: pairs for name in _PER_PAIR}
    member: dict[str, Any] = {}
    for name, cut in cuts.items():
        if name in arrays:
            a = np.asarray(np.asarray(arrays[name])[b])  # 0-d for a (B,) array: the validator names it
            member[name] = a[tuple(slice(0, c) for c in cut[:a.ndim])]
    if "meta" in arrays:
        member["meta"] = np.asarray(arrays["meta"])[b]
    source = np.asarray(arrays["mask_source"])[b] if "mask_source" in arrays else "static_mask"
    if str(source) == "none":
        member.pop("static_mask", None)
    return member


# ----------------------------------------------------------------------------- sources


@dataclasses.dataclass
class ClipEntry:
    """A clip to be loaded lazily: its id, where it comes from, and how to read it.

    ``read`` returns the clip's arrays (docs/semantics.md §1.2), or the :class:`Clip` given in
    memory, and raises :class:`ClipFormatError` for a file that cannot give them. A file's entry
    pickles (without ``id_owners``), so a reader process can read it.
    """

    clip_id: str
    origin: str
    read: Callable[[], Mapping[str, Any] | Clip]
    config: SGCConfig = dataclasses.field(default_factory=SGCConfig)
    path: str | None = None  # the file it comes from; None for clips given in memory
    id_owners: dict[str, "ClipEntry"] | None = None  # clip id -> the entry that claimed it, shared by a run's files
    # ``read``, but PLOTS_ONLY arrays from their headers alone (a file's entry; None: ``read``)
    read_for_scoring: Callable[[], Mapping[str, Any]] | None = None

    def load(self) -> Clip:
        """The validated clip with its id claimed for the run (``read_clip``, then ``claim_id``);
        raises :class:`ClipFormatError` (only) for a bad input."""
        clip = self.read_clip()
        self.claim_id()
        return clip

    def read_clip(self, for_scoring: bool = False) -> Clip:
        """The validated clip, its id not yet claimed: safe to call from several threads, as long
        as ``claim_id`` is then called in input order (the first file with an id keeps it).
        ``for_scoring``: without PLOTS_ONLY arrays, whose shapes and dtypes are checked as usual
        but whose data a file's entry does not read."""
        read = self.read_for_scoring if for_scoring and self.read_for_scoring is not None else self.read
        source = read()
        if isinstance(source, Clip):
            clip = subsample_tracks(source, self.config)
        else:
            clip = clip_from_arrays(source, clip_id=self.clip_id, config=self.config)
        return dataclasses.replace(clip, **dict.fromkeys(PLOTS_ONLY)) if for_scoring else clip

    def claim_id(self) -> None:
        """Claim this clip's id for the run; raises :class:`ClipFormatError` when another clip file has it."""
        if self.id_owners is None:
            return
        owner = self.id_owners.setdefault(self.clip_id, self)
        if owner is not self:
            raise duplicate_error(self.clip_id, owner.origin)


def duplicate_error(clip_id: str, first_origin: str) -> ClipFormatError:
    return ClipFormatError(clip_id, "clip_id", "an id no other clip file of the run has",
                           f"a duplicate: first seen in {first_origin}",
                           "this clip is not scored; give it its own clip_id")


def _raise(exc: ClipFormatError) -> Any:
    raise exc


def _failing(exc: ClipFormatError) -> Callable[[], Any]:
    return functools.partial(_raise, exc)


def _read(path: Path, clip_id: str, names: Iterable[str] | None = None, headers: bool = False,
          shape_only: Container[str] = ()) -> dict[str, Any]:
    """:func:`sgc_jax.io.npz.read_npz` (or its headers) with its errors as :class:`ClipFormatError` of ``clip_id``."""
    try:
        return npz_headers(path) if headers else read_npz(path, names, shape_only)
    except NpzError as exc:
        raise ClipFormatError(clip_id, exc.array, exc.expected, exc.found, exc.path) from None


def entries_from_file(path: Path | str, config: SGCConfig) -> list[ClipEntry]:
    """The clips of one clip or batch ``.npz`` (a path or a URL); a file that cannot be listed is
    one failing entry."""
    origin, stem = os.fspath(path), Path(os.fspath(path)).stem
    try:
        headers = _read(path, stem, headers=True)
        if not is_batch(headers):
            clip_id = _meta_id(_read(path, stem, ["meta"]).get("meta")) or stem
            return [ClipEntry(clip_id, origin, functools.partial(_read, path, clip_id), config, origin,
                              read_for_scoring=functools.partial(_read, path, clip_id, shape_only=PLOTS_ONLY))]
        layout = batch_layout({k: shape for k, (shape, _) in headers.items()}, _read(path, stem, BOOKKEEPING), stem)
    except ClipFormatError as exc:
        return [ClipEntry(stem, origin, _failing(exc), config, origin)]
    listing = next(_LISTINGS)
    return [ClipEntry(layout.ids[b], f"{origin}[{b}]",
                      functools.partial(_read_batch_member, path, listing, b, layout.ids[b], stem), config, origin,
                      read_for_scoring=functools.partial(_read_batch_member, path, listing, b, layout.ids[b], stem,
                                                         PLOTS_ONLY))
            for b in range(len(layout))]


# A batch file's members are read one by one, each from the arrays of the whole file: the arrays of
# the batch read last are kept (one per process), so B members decompress the file once, not B
# times. Keyed by the listing that made the entries, so a file rewritten and listed again is read again.
_LISTINGS = itertools.count()
_LAST_BATCH: dict[tuple, dict[str, Any]] = {}
_LAST_BATCH_LOCK = threading.Lock()


def _read_batch_member(path: Path | str, listing: int, b: int, clip_id: str, stem: str,
                       shape_only: Container[str] = ()) -> dict[str, Any]:
    key = (os.fspath(path), listing, tuple(sorted(shape_only)))
    with _LAST_BATCH_LOCK:
        arrays = _LAST_BATCH.get(key)
    if arrays is None:
        arrays = _read(path, clip_id, shape_only=shape_only)
        with _LAST_BATCH_LOCK:
            _LAST_BATCH.clear()
            _LAST_BATCH[key] = arrays
    member = _batch_member(arrays, b, batch_layout({k: a.shape for k, a in arrays.items()}, arrays, stem))
    # copies, as the kept arrays serve the other members; shape-only placeholders stay views (no memory)
    return {name: a if name in shape_only else np.array(a) for name, a in member.items()}


def _entries_from_mapping(source: Mapping[str, Any], config: SGCConfig) -> list[ClipEntry]:
    if not is_batch(source):
        clip_id = _meta_id(source.get("meta")) or _text(source.get("clip_id")) or "clip"
        return [ClipEntry(clip_id, "<memory>", lambda: source, config)]
    try:
        arrays = {k: _as_array("batch", k, v, "an array") for k, v in source.items()}
        layout = batch_layout({k: a.shape for k, a in arrays.items()}, arrays, "batch")
    except ClipFormatError as exc:
        return [ClipEntry("batch", "<memory>", _failing(exc), config)]
    return [ClipEntry(layout.ids[b], f"<memory>[{b}]", lambda b=b: _batch_member(arrays, b, layout), config)
            for b in range(len(layout))]


def _text(value: Any) -> str | None:
    """A 0-d text value as str; None for anything else."""
    if isinstance(value, np.ndarray) and value.ndim == 0:
        value = value.item()
    if isinstance(value, bytes):
        value = value.decode("utf-8", errors="replace")
    return value if isinstance(value, str) and value else None


def _npz_in(directory: Path) -> list[Path]:
    try:
        return sorted(directory.glob("*.npz"))
    except OSError:  # an unreadable directory: reading it reports why
        return [directory]


def list_clip_files(source: str | os.PathLike, *, allow_empty: bool = False) -> list[Path | str]:
    """The ``.npz`` files a path names: a directory's ``*.npz`` (sorted), a file (or a link, even
    one that leads nowhere: reading it reports that), or a glob's ``.npz`` matches, directories
    among them expanded. Raises FileNotFoundError when it names nothing (or an empty directory, unless ``allow_empty``).
    A URL (``s3://bucket/clips/``, ``file:///...``; :mod:`sgc_jax.io.remote`) gives URLs: its
    directory's ``.npz`` files, the file, or a wildcard's matches in its last part.
    """
    text = os.fspath(source)
    files: list[Path | str]
    if is_url(text):
        files = list_files(text)
    elif os.path.isdir(text):
        files = _npz_in(Path(text))
    elif os.path.lexists(text):
        files = [Path(text)]
    else:
        # glob only where there are wildcards: a literal name is matched by os.path.lexists above
        matches = sorted(glob.glob(text)) if glob.has_magic(text) else []
        files = [f for m in matches for f in (_npz_in(Path(m)) if os.path.isdir(m) else [Path(m)])
                 if f.suffix.lower() == ".npz"]  # as in a directory: a glob's other files are not clips
        if not matches:
            raise FileNotFoundError(f"no clip file, directory or glob match for {text!r}")
    if not files and not allow_empty:
        raise FileNotFoundError(f"no .npz clips in {text}")
    return files


def guard_duplicate_ids(entries: list[ClipEntry]) -> None:
    """Give the clips from files one id registry (docs/semantics.md §1.4): of the clips with one id,
    the first that loads keeps it and later ones raise :class:`ClipFormatError` when loaded.

    Clips given in memory are left alone: variants of one clip (perturbed, rescaled) share its id on purpose.
    """
    owners: dict[str, ClipEntry] = {}
    for entry in entries:
        if entry.path is not None:
            entry.id_owners = owners


# A Clip's array fields, read back through the file schema's checks when the clip is given in memory.
CLIP_ARRAY_FIELDS = ("depth", "K", "R_wc", "t_wc", "static_mask", "track_prev", "track_curr", "track_vis",
                     "track_conf", "frames")


def checked_in_memory(clip: Clip) -> Clip:
    """A :class:`Clip` given in memory (built or changed in code, not loaded) read through the
    structural checks of a file's arrays (docs/semantics.md §1.4: types, shapes, sizes that agree,
    finite and invertible cameras; a field left ``None`` counts as absent, as a missing array does)
    and the content errors of its cameras and track positions (§1.6: not a rotation, intrinsics not
    of the grid, tracks of another grid). Returns the clip with the schema's dtypes, every track, its
    meta, mask source and warning codes kept; raises :class:`ClipFormatError` (``ClipValidationError`` for a
    content error)."""
    if not isinstance(clip, Clip):
        raise TypeError(f"expected a sgc_jax.Clip, got {type(clip).__name__}")
    arrays = {name: getattr(clip, name) for name in CLIP_ARRAY_FIELDS if getattr(clip, name) is not None}
    checked = _structurally_checked(arrays, clip.clip_id)
    mask_source = clip.mask_source if clip.static_mask is not None else "none"
    # the codes its loader found (clip_from_arrays, load_clip) stay with it, for the tables
    checked = dataclasses.replace(checked, mask_source=mask_source, warnings=tuple(clip.warnings or ()),
                                  meta=clip.meta if isinstance(clip.meta, dict) else checked.meta)
    # the content errors that say the cameras or tracks are not of this pixel grid (K in normalised
    # units, tracks of a larger frame): cheap, so a clip built in code fails as its file does
    raise_first_error(clip.clip_id, check_poses(checked) + check_intrinsics(checked) + check_track_positions(checked))
    return checked


def _discover(source: Any, config: SGCConfig) -> list[ClipEntry]:
    if isinstance(source, Clip):
        return [ClipEntry(source.clip_id, "<memory>", lambda: checked_in_memory(source), config)]
    if isinstance(source, Mapping):
        return _entries_from_mapping(source, config)
    if isinstance(source, (list, tuple)):
        return [e for item in source for e in _discover(item, config)]
    return [e for path in list_clip_files(source) for e in entries_from_file(path, config)]


def discover_clips(source: Any, config: SGCConfig | None = None) -> list[ClipEntry]:
    """Expand a source into lazily loaded clips.

    ``source``: a clip or batch ``.npz`` path, a directory (its ``*.npz``, sorted), a glob, a
    :class:`Clip`, a mapping of arrays (single clip or batch), or a list of any of these. A broken
    file or batch member never raises here: its entry raises :class:`ClipFormatError` when loaded.
    Raises FileNotFoundError for a path, directory or glob that names no file.
    """
    entries = _discover(source, config or SGCConfig())
    guard_duplicate_ids(entries)
    return entries


def load_clips(source: Any, config: SGCConfig | None = None) -> Iterator[Clip]:
    """Load every clip of a source (raises :class:`ClipFormatError` on the first broken one; see :func:`discover_clips`)."""
    for entry in discover_clips(source, config):
        yield entry.load()


def load_clip(source: Any, config: SGCConfig | None = None) -> Clip:
    """Load exactly one clip from a path, mapping or :class:`Clip`."""
    entries = discover_clips(source, config)
    if len(entries) != 1:
        raise ValueError(f"expected one clip, {source!r} holds {len(entries)}")
    return entries[0].load()


# ----------------------------------------------------------------------------- sgc-jax validate


@dataclasses.dataclass
class Report:
    """The findings for one clip of a source."""

    origin: str
    clip_id: str
    problems: list[Problem]

    @property
    def ok(self) -> bool:
        return not any(p.severity == "error" for p in self.problems)

    def lines(self, *, show_info: bool = False) -> list[str]:
        return [f"{self.origin}: {p.line()}" for p in self.problems if show_info or p.severity != "info"]


def validate_paths(sources: list[Any], config: SGCConfig | None = None) -> list[Report]:
    """Check every clip of clip / batch ``.npz`` files, directories or globs.

    A broken file or member is a report, never an exception; raises FileNotFoundError only for a
    path or glob that names nothing. Of clips with one id, the first without errors keeps it; later ones get a
    ``duplicate_clip_id`` error (docs/semantics.md §1.4).
    """
    config = config or SGCConfig()
    entries = [e for source in sources for path in list_clip_files(source, allow_empty=True)
               for e in entries_from_file(path, config)]
    guard_duplicate_ids(entries)
    reports = []
    for entry in entries:
        try:
            arrays = entry.read()
            clip = clip_from_arrays(arrays, clip_id=entry.clip_id, config=config, validate=False)
        except ClipFormatError as exc:
            code = "unreadable" if exc.array == "<file>" else "structure"
            reports.append(Report(entry.origin, entry.clip_id,
                                  [Problem("error", code, exc.array, exc.expected, exc.found, exc.detail)]))
            continue
        problems = check_clip(clip, config, arrays)
        if not any(p.severity == "error" for p in problems):  # as when scoring: the first clip that loads owns its id
            try:
                entry.claim_id()
            except ClipFormatError as exc:
                problems.insert(0, Problem("error", "duplicate_clip_id", exc.array, exc.expected, exc.found,
                                           exc.detail))
        reports.append(Report(entry.origin, clip.clip_id, problems))
    return reports
