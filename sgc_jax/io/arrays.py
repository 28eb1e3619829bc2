"""Arrays -> a :class:`~sgc_jax.io.clip.Clip` (docs/semantics.md §1): the structural checks of §1.4
(missing arrays, dtypes, shapes and sizes that agree, finite and invertible cameras), which raise
:class:`~sgc_jax.io.clip.ClipFormatError` naming the clip and the array, the content checks of
:mod:`sgc_jax.io.validate` where asked, and the tracks sub-sampled to ``max_tracks``.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
from typing import Any, Callable, Mapping

import numpy as np

from ..config import SGCConfig
from .checks.cameras import check_intrinsics, check_poses
from .checks.tracks import check_track_positions
from .clip import Clip, ClipFormatError, no_reading
from .npz import shape_text
from .validate import enforce, raise_first_error

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
# K's entries below the diagonal, and K[2, 2] - 1, each as the relative change it makes to a pixel's coordinate
# or projective divisor (K[1, 0] W / fy, K[2, 0] W, K[2, 1] H): beyond this K is not the pinhole matrix every
# engine reads (the reference back-projects through the whole K^-1 but projects with its first two rows).
# Stored exactly 0 and 1 by every estimator; float32 arithmetic leaves ~1e-7.
K_PINHOLE_TOL = 1e-5


def as_clip_array(clip_id: str, name: str, value: Any, expected: str) -> np.ndarray:
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
        array = as_clip_array(clip_id, name, arrays[name], _WHAT[kinds])
        if array.dtype.kind not in kinds:
            raise ClipFormatError(clip_id, name, _WHAT[kinds], f"dtype {array.dtype}")
        typed[name] = array
    return typed


def _require(arrays: Mapping[str, Any], name: str, clip_id: str, expected: str, hint: str = "") -> np.ndarray:
    if name not in arrays:
        raise ClipFormatError(clip_id, name, expected, "no such array",
                              f"present: {sorted(arrays)}" + (f"; {hint}" if hint else ""))
    return np.asarray(arrays[name])


def check_shape(clip_id: str, name: str, array: np.ndarray, expected: tuple) -> None:
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
    frame (a long-range tracker's (T, P, ...)), axes in another order, K's four numbers, one K of a
    leading axis, or quaternions; else ""."""
    if name.startswith("track_") and shape and shape[0] == expected[0] + 1 and fits((shape[0] - 1,) + shape[1:]):
        return ("every frame's positions, as a long-range tracker gives them? give track_prev = tracks[:-1], "
                "track_curr = tracks[1:], track_vis = visible[:-1] & visible[1:] (docs/semantics.md §1.2), or "
                "`sgc-jax import --tracks`")
    for order in itertools.permutations(range(len(shape))):
        if order != tuple(range(len(shape))) and fits(tuple(shape[axis] for axis in order)):
            return f"its axes in another order: give np.transpose({name}, {order})"
    if name == "K" and shape[-1:] == (4,):
        return "(fx, fy, cx, cy)? give K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]"
    if name == "K" and shape == (1, 3, 3):
        return "one K for the clip? give K[0]: a (3, 3) K serves every frame"
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


def _check_pinhole(clip_id: str, K: np.ndarray, H: int, W: int) -> None:
    """K (T, 3, 3), finite and invertible: each frame's K must be [[fx, s, cx], [0, fy, cy], [0, 0, 1]] within
    K_PINHOLE_TOL; a transposed K (cx, cy in its last row, as a column-major or ``K.T`` copy stores it) and one
    scaled as a whole (K[2, 2] != 1) are named."""
    with np.errstate(divide="ignore", invalid="ignore"):
        deviation = np.stack([np.abs(K[:, 1, 0] / K[:, 1, 1]) * W, np.abs(K[:, 2, 0]) * W, np.abs(K[:, 2, 1]) * H,
                              np.abs(K[:, 2, 2] - 1.0)], axis=-1).max(axis=-1)
    bad = np.flatnonzero(~(deviation <= K_PINHOLE_TOL))
    if not bad.size:
        return
    t = bad[0]
    k = K[t]
    found = f"{np.round(k, 4).tolist()} in frames {_first_frames(bad)}"
    if np.all(np.abs(k[:2, 2]) * (W, H) <= K_PINHOLE_TOL) and abs(k[2, 2] - 1.0) <= K_PINHOLE_TOL:
        detail = "K looks transposed (cx, cy in its last row, as a column-major copy or K.T stores it): give np.swapaxes(K, -1, -2)"
    elif np.all(np.abs(k[[1, 2, 2], [0, 0, 1]]) * (W / abs(k[1, 1]), W, H) <= K_PINHOLE_TOL) and k[2, 2] != 0:
        detail = "K is scaled as a whole (K[2, 2] is not 1): give K / K[..., 2:3, 2:3]"
    else:
        detail = "K must be a pinhole matrix in pixels, zero below its diagonal and 1 in its corner"
    raise ClipFormatError(clip_id, "K", "a pinhole matrix [[fx, s, cx], [0, fy, cy], [0, 0, 1]]", found, detail)


def settle_votes(votes: list[tuple[str, Any]], tie_break: Callable[[list[Any]], Any]) -> tuple[Any, list[str]]:
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
    return settle_votes(votes, lambda tied: T_depth if T_depth in tied else tied[0])


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

    return settle_votes(votes, tie_break)


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


def meta_clip_id(raw: Any) -> str | None:
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
    check_shape(clip_id, "K", K, (T, 3, 3))
    _check_finite(clip_id, "K", K)
    _check_invertible(clip_id, K)
    if "R_wc" in typed or "t_wc" in typed:
        R_wc = _require(typed, "R_wc", clip_id, f"shape ({T}, 3, 3)").astype(np.float64)
        t_wc = _require(typed, "t_wc", clip_id, f"shape ({T}, 3)").astype(np.float64)
        check_shape(clip_id, "R_wc", R_wc, (T, 3, 3))
        check_shape(clip_id, "t_wc", t_wc, (T, 3))
    elif "extrinsic" in typed:
        extrinsic = _three_rows(typed["extrinsic"].astype(np.float64), clip_id, T)
        check_shape(clip_id, "extrinsic", extrinsic, (T, 3, 4))
        R_wc, t_wc = extrinsic[:, :, :3].copy(), extrinsic[:, :, 3].copy()
    else:
        raise ClipFormatError(clip_id, "R_wc", f"shape ({T}, 3, 3) with t_wc, or extrinsic ({T}, 3, 4) or ({T}, 4, 4)",
                              "no such array", f"present: {sorted(arrays)}")
    _check_finite(clip_id, "R_wc", R_wc)
    _check_finite(clip_id, "t_wc", t_wc)
    return K, R_wc, t_wc


MASK_FLOAT_TRUE_ABOVE = 0.5  # a float mask holds a network's probabilities (or logits): true above even odds


def mask_truth(mask: np.ndarray) -> np.ndarray:
    """A stored mask (NumPy or jax.numpy) as booleans (docs/semantics.md §1.2): a float mask true where above
    MASK_FLOAT_TRUE_ABOVE, booleans and integers where non-zero (0/255 bytes, object ids)."""
    return mask > MASK_FLOAT_TRUE_ABOVE if mask.dtype.kind == "f" else mask.astype(bool)


def _checked_mask(typed: Mapping[str, np.ndarray], clip_id: str, shape: tuple[int, int, int]) -> tuple[np.ndarray, str]:
    """(static mask (T, H, W) bool, its source: "static_mask", "dynamic_mask" or "none")."""
    if "static_mask" in typed:
        check_shape(clip_id, "static_mask", typed["static_mask"], shape)
        return mask_truth(typed["static_mask"]), "static_mask"
    if "dynamic_mask" in typed:
        check_shape(clip_id, "dynamic_mask", typed["dynamic_mask"], shape)
        return ~mask_truth(typed["dynamic_mask"]), "dynamic_mask"
    return np.ones(shape, bool), "none"


def _checked_tracks(typed: Mapping[str, np.ndarray], arrays: Mapping[str, Any], clip_id: str,
                    T: int) -> tuple[np.ndarray, ...]:
    """(track_prev, track_curr (T-1, P, 2), track_vis, track_conf (T-1, P)), each as stored; ``arrays``
    (every array given) name what was given instead of ``track_prev``."""
    if "track_prev" not in typed:
        _missing_pair_tracks(arrays, clip_id, T)
    track_prev = typed["track_prev"]
    check_shape(clip_id, "track_prev", track_prev, (T - 1, None, 2))
    P = track_prev.shape[1]
    if P < 1:
        raise ClipFormatError(clip_id, "track_prev", f"shape ({T - 1}, P, 2) with P >= 1 tracks per pair",
                              f"shape {shape_text(track_prev.shape)}")
    track_curr = _require(typed, "track_curr", clip_id, f"shape ({T - 1}, {P}, 2)")
    check_shape(clip_id, "track_curr", track_curr, (T - 1, P, 2))
    track_vis = _require(typed, "track_vis", clip_id, f"shape ({T - 1}, {P})",
                         f"where every track is visible, give track_vis = np.ones(({T - 1}, {P}), bool)")
    check_shape(clip_id, "track_vis", track_vis, (T - 1, P))
    if "track_conf" in typed:
        track_conf = typed["track_conf"]
        check_shape(clip_id, "track_conf", track_conf, (T - 1, P))
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
    clip = structurally_checked(arrays, clip_id)
    if validate:
        clip = dataclasses.replace(clip, warnings=enforce(clip, config, arrays))
    return subsample_tracks(clip, config)


def structurally_checked(arrays: Mapping[str, Any], clip_id: str | None) -> Clip:
    """The :class:`Clip` of a mapping of clip arrays after the structural checks of §1.4, every track kept."""
    meta = _parse_meta(arrays.get("meta"))
    clip_id = str(clip_id or meta.get("clip_id") or text_value(arrays.get("clip_id")) or "clip")
    meta.setdefault("clip_id", clip_id)
    typed = _typed_arrays(arrays, clip_id)
    depth, T, H, W = _checked_depth(typed, clip_id)
    K, R_wc, t_wc = _checked_cameras(typed, arrays, clip_id, T)
    _check_pinhole(clip_id, K, H, W)
    static_mask, mask_source = _checked_mask(typed, clip_id, (T, H, W))
    track_prev, track_curr, track_vis, track_conf = _checked_tracks(typed, arrays, clip_id, T)
    frames = typed.get("frames")
    if frames is not None:
        check_shape(clip_id, "frames", frames, (T, H, W, 3))
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


def text_value(value: Any) -> str | None:
    """A 0-d text value as str; None for anything else."""
    if isinstance(value, np.ndarray) and value.ndim == 0:
        value = value.item()
    if isinstance(value, bytes):
        value = value.decode("utf-8", errors="replace")
    return value if isinstance(value, str) and value else None


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
    checked = structurally_checked(arrays, clip.clip_id)
    mask_source = clip.mask_source if clip.static_mask is not None else "none"
    # the codes its loader found (clip_from_arrays, load_clip) stay with it, for the tables
    checked = dataclasses.replace(checked, mask_source=mask_source, warnings=tuple(clip.warnings or ()),
                                  meta=clip.meta if isinstance(clip.meta, dict) else checked.meta)
    # the content errors that say the cameras or tracks are not of this pixel grid (K in normalised
    # units, tracks of a larger frame): cheap, so a clip built in code fails as its file does
    raise_first_error(clip.clip_id, check_poses(checked) + check_intrinsics(checked) + check_track_positions(checked))
    return checked
