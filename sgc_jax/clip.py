"""The clip schema (docs/semantics.md §1): load, validate, sub-sample, save; single-clip and batch files.

Pixel grid: x = column, y = row, pixel centres at integer coordinates. Poses are world->camera
(OpenCV): x_cam = R_wc @ X_world + t_wc. Pair i (i = 1..T-1) goes from frame i-1 to frame i and
its tracks live at index i-1 of the (T-1, P) track arrays.
"""

from __future__ import annotations

import dataclasses
import glob
import json
import os
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator, Mapping

import numpy as np

from .config import SGCConfig


class ClipFormatError(ValueError):
    """A structural problem with a clip: missing array, wrong rank or shape, non-finite camera."""

    def __init__(self, clip_id: str, array: str, expected: str, found: str, detail: str = ""):
        self.clip_id, self.array, self.expected, self.found, self.detail = clip_id, array, expected, found, detail
        message = f"clip {clip_id!r}: array {array!r}: expected {expected}, found {found}"
        super().__init__(message + (f" ({detail})" if detail else ""))


@dataclasses.dataclass
class Clip:
    """One validated clip; arrays are NumPy, shapes use T frames, H x W pixels, P tracks."""

    clip_id: str
    depth: np.ndarray  # (T, H, W) float32; <= 0 or non-finite = invalid
    K: np.ndarray  # (T, 3, 3) float64 pinhole intrinsics
    R_wc: np.ndarray  # (T, 3, 3) float64 world -> camera rotation
    t_wc: np.ndarray  # (T, 3) float64 world -> camera translation
    static_mask: np.ndarray  # (T, H, W) bool, true on static background
    track_prev: np.ndarray  # (T-1, P, 2) float32 positions in frame i-1
    track_curr: np.ndarray  # (T-1, P, 2) float32 positions in frame i
    track_vis: np.ndarray  # (T-1, P) bool, visible in frame i
    track_conf: np.ndarray  # (T-1, P) float32 tracker confidence in frame i
    mask_source: str = "static_mask"  # "static_mask" | "dynamic_mask" | "none" (whole frame static)
    frames: np.ndarray | None = None  # (T, H, W, 3) uint8, plots only
    meta: dict = dataclasses.field(default_factory=dict)

    @property
    def n_frames(self) -> int:
        return int(self.depth.shape[0])

    @property
    def n_pairs(self) -> int:
        return self.n_frames - 1

    @property
    def n_tracks(self) -> int:
        return int(self.track_prev.shape[1])

    @property
    def image_size(self) -> tuple[int, int]:
        """(H, W) in pixels."""
        return int(self.depth.shape[1]), int(self.depth.shape[2])

    @property
    def group(self) -> str:
        return str(self.meta.get("group", ""))

    def usable_tracks(self, min_track_conf: float) -> np.ndarray:
        """(T-1, P) bool: visible, confident and finite (docs/semantics.md §1.2)."""
        finite = np.isfinite(self.track_prev).all(-1) & np.isfinite(self.track_curr).all(-1)
        return self.track_vis & (self.track_conf >= min_track_conf) & finite

    def median_depth(self) -> float:
        d = self.depth[np.isfinite(self.depth) & (self.depth > 0)]
        return float(np.median(d)) if d.size else float("nan")


# ----------------------------------------------------------------------------- validation


def _shape_str(shape: Iterable[Any]) -> str:
    return "(" + ", ".join(str(s) for s in shape) + ")"


def _require(arrays: Mapping[str, Any], name: str, clip_id: str, expected: str) -> np.ndarray:
    if name not in arrays:
        raise ClipFormatError(clip_id, name, expected, "no such array",
                              f"present: {sorted(arrays)}")
    return np.asarray(arrays[name])


def _check_shape(clip_id: str, name: str, array: np.ndarray, expected: tuple) -> None:
    """``expected`` holds ints or None (any size); raise naming both shapes on mismatch."""
    ok = array.ndim == len(expected) and all(e is None or e == s for e, s in zip(expected, array.shape))
    if not ok:
        want = _shape_str("*" if e is None else e for e in expected)
        raise ClipFormatError(clip_id, name, f"shape {want}", f"shape {_shape_str(array.shape)}")


def _check_finite(clip_id: str, name: str, array: np.ndarray) -> None:
    if not np.isfinite(array).all():
        bad = int((~np.isfinite(array)).sum())
        raise ClipFormatError(clip_id, name, "finite values", f"{bad} non-finite value(s)")


def _parse_meta(raw: Any) -> dict:
    if raw is None:
        return {}
    value = np.asarray(raw).item() if np.ndim(raw) == 0 else raw
    if isinstance(value, bytes):
        value = value.decode()
    if isinstance(value, dict):
        return dict(value)
    try:
        meta = json.loads(str(value))
    except json.JSONDecodeError:
        return {"note": str(value)}
    return meta if isinstance(meta, dict) else {"note": meta}


def clip_from_arrays(arrays: Mapping[str, Any], *, clip_id: str | None = None,
                     config: SGCConfig | None = None, validate: bool = True) -> Clip:
    """Validate a mapping of clip arrays (docs/semantics.md §1) and return a :class:`Clip`.

    Raises :class:`ClipFormatError` for structural problems. ``validate``: also run the content
    checks of :mod:`sgc_jax.validate` (K against the grid, rotations, tracks on the grid, depth vs
    disparity): errors raise ``ClipValidationError``, warnings are issued as ``ClipWarning``.
    Tracks beyond ``config.max_tracks`` are sub-sampled deterministically (see :func:`subsample_tracks`).
    """
    config = config or SGCConfig()
    meta = _parse_meta(arrays.get("meta"))
    clip_id = str(clip_id or meta.get("clip_id") or arrays.get("clip_id", "") or "clip")
    meta.setdefault("clip_id", clip_id)

    depth = _require(arrays, "depth", clip_id, "shape (T, H, W)")
    if depth.ndim != 3:
        raise ClipFormatError(clip_id, "depth", "shape (T, H, W)", f"shape {_shape_str(depth.shape)}")
    T, H, W = depth.shape
    if T < 2:
        raise ClipFormatError(clip_id, "depth", "T >= 2 frames", f"T = {T}")
    depth = depth.astype(np.float32)

    K = _require(arrays, "K", clip_id, f"shape ({T}, 3, 3) or (3, 3)").astype(np.float64)
    if K.shape == (3, 3):
        K = np.broadcast_to(K, (T, 3, 3)).copy()
    _check_shape(clip_id, "K", K, (T, 3, 3))
    _check_finite(clip_id, "K", K)

    if "R_wc" in arrays or "t_wc" in arrays:
        R_wc = _require(arrays, "R_wc", clip_id, f"shape ({T}, 3, 3)").astype(np.float64)
        t_wc = _require(arrays, "t_wc", clip_id, f"shape ({T}, 3)").astype(np.float64)
        _check_shape(clip_id, "R_wc", R_wc, (T, 3, 3))
        _check_shape(clip_id, "t_wc", t_wc, (T, 3))
    elif "extrinsic" in arrays:
        extrinsic = np.asarray(arrays["extrinsic"]).astype(np.float64)
        _check_shape(clip_id, "extrinsic", extrinsic, (T, 3, 4))
        R_wc, t_wc = extrinsic[:, :, :3].copy(), extrinsic[:, :, 3].copy()
    else:
        raise ClipFormatError(clip_id, "R_wc", f"shape ({T}, 3, 3) with t_wc, or extrinsic ({T}, 3, 4)",
                              "no such array", f"present: {sorted(arrays)}")
    _check_finite(clip_id, "R_wc", R_wc)
    _check_finite(clip_id, "t_wc", t_wc)

    if "static_mask" in arrays:
        static_mask = np.asarray(arrays["static_mask"])
        _check_shape(clip_id, "static_mask", static_mask, (T, H, W))
        static_mask, mask_source = static_mask.astype(bool), "static_mask"
    elif "dynamic_mask" in arrays:
        dynamic_mask = np.asarray(arrays["dynamic_mask"])
        _check_shape(clip_id, "dynamic_mask", dynamic_mask, (T, H, W))
        static_mask, mask_source = ~dynamic_mask.astype(bool), "dynamic_mask"
    else:
        static_mask, mask_source = np.ones((T, H, W), bool), "none"

    track_prev = _require(arrays, "track_prev", clip_id, f"shape ({T - 1}, P, 2)")
    _check_shape(clip_id, "track_prev", track_prev, (T - 1, None, 2))
    P = track_prev.shape[1]
    track_curr = _require(arrays, "track_curr", clip_id, f"shape ({T - 1}, {P}, 2)")
    _check_shape(clip_id, "track_curr", track_curr, (T - 1, P, 2))
    track_vis = _require(arrays, "track_vis", clip_id, f"shape ({T - 1}, {P})")
    _check_shape(clip_id, "track_vis", track_vis, (T - 1, P))
    if "track_conf" in arrays and arrays["track_conf"] is not None:
        track_conf = np.asarray(arrays["track_conf"])
        _check_shape(clip_id, "track_conf", track_conf, (T - 1, P))
    else:
        track_conf = np.ones((T - 1, P), np.float32)

    frames = arrays.get("frames")
    if frames is not None:
        frames = np.asarray(frames)
        _check_shape(clip_id, "frames", frames, (T, H, W, 3))

    vis = np.asarray(track_vis)
    clip = Clip(
        clip_id=clip_id,
        depth=depth,
        K=K,
        R_wc=R_wc,
        t_wc=t_wc,
        static_mask=static_mask,
        track_prev=np.asarray(track_prev, np.float32),
        track_curr=np.asarray(track_curr, np.float32),
        track_vis=(vis > 0) if vis.dtype != bool else vis.copy(),
        track_conf=np.nan_to_num(np.asarray(track_conf, np.float32), nan=0.0),
        mask_source=mask_source,
        frames=frames,
        meta=meta,
    )
    if validate:
        from .validate import enforce  # the checks use Clip; imported here to keep the modules acyclic

        enforce(clip, config, arrays)
    return subsample_tracks(clip, config)


def subsample_tracks(clip: Clip, config: SGCConfig) -> Clip:
    """Keep at most ``config.max_tracks`` tracks per pair, deterministically.

    Per pair, usable tracks (docs/semantics.md §1.2) come first in their original order; when there are more
    than ``max_tracks`` of them, evenly spaced ones are kept. Clips within the limit are unchanged.
    """
    P, limit = clip.n_tracks, config.max_tracks
    if P <= limit:
        return clip
    usable = clip.usable_tracks(config.min_track_conf)
    index = np.empty((clip.n_pairs, limit), np.int64)
    for pair, usable_row in enumerate(usable):
        kept = np.flatnonzero(usable_row)
        if kept.size > limit:
            kept = kept[np.linspace(0, kept.size - 1, limit).astype(np.int64)]
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


# ----------------------------------------------------------------------------- files


def clip_to_arrays(clip: Clip) -> dict[str, np.ndarray]:
    """The clip arrays (docs/semantics.md §1.2) of a clip (inverse of :func:`clip_from_arrays`)."""
    arrays = dict(
        depth=clip.depth, K=clip.K, R_wc=clip.R_wc, t_wc=clip.t_wc,
        track_prev=clip.track_prev, track_curr=clip.track_curr,
        track_vis=clip.track_vis, track_conf=clip.track_conf,
        meta=np.asarray(json.dumps({**clip.meta, "clip_id": clip.clip_id})),
    )
    if clip.mask_source != "none":
        arrays["static_mask"] = clip.static_mask
    if clip.frames is not None:
        arrays["frames"] = clip.frames
    return arrays


def save_clip(path: str | os.PathLike, clip: Clip) -> Path:
    """Write one clip as a compressed ``.npz``; returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, **clip_to_arrays(clip))
    return path


def _pad_to(array: np.ndarray, shape: tuple[int, ...], fill: Any = 0) -> np.ndarray:
    out = np.full(shape, fill, dtype=array.dtype)
    out[tuple(slice(0, s) for s in array.shape)] = array
    return out


def save_batch(path: str | os.PathLike, clips: list[Clip]) -> Path:
    """Stack clips into one batch file padded to common (T, H, W, P) (docs/semantics.md §1.3)."""
    if not clips:
        raise ValueError("save_batch needs at least one clip")
    T = max(c.n_frames for c in clips)
    H = max(c.image_size[0] for c in clips)
    W = max(c.image_size[1] for c in clips)
    P = max(c.n_tracks for c in clips)
    eye = np.broadcast_to(np.eye(3), (T, 3, 3))

    def pad_frames(a: np.ndarray, tail: np.ndarray) -> np.ndarray:
        return np.concatenate([a, np.broadcast_to(tail, (T - len(a),) + a.shape[1:])])

    stacked: dict[str, list] = {k: [] for k in (
        "depth", "K", "R_wc", "t_wc", "static_mask", "track_prev", "track_curr", "track_vis", "track_conf")}
    for c in clips:
        stacked["depth"].append(_pad_to(c.depth, (T, H, W)))
        stacked["K"].append(pad_frames(c.K, c.K[-1]))
        stacked["R_wc"].append(pad_frames(c.R_wc, eye[0]))
        stacked["t_wc"].append(pad_frames(c.t_wc, np.zeros(3)))
        stacked["static_mask"].append(_pad_to(c.static_mask, (T, H, W), False))
        stacked["track_prev"].append(_pad_to(c.track_prev, (T - 1, P, 2)))
        stacked["track_curr"].append(_pad_to(c.track_curr, (T - 1, P, 2)))
        stacked["track_vis"].append(_pad_to(c.track_vis, (T - 1, P), False))
        stacked["track_conf"].append(_pad_to(c.track_conf, (T - 1, P)))
    arrays = {k: np.stack(v) for k, v in stacked.items()}
    arrays.update(
        n_frames=np.array([c.n_frames for c in clips]),
        n_tracks=np.array([c.n_tracks for c in clips]),
        heights=np.array([c.image_size[0] for c in clips]),
        widths=np.array([c.image_size[1] for c in clips]),
        clip_id=np.array([c.clip_id for c in clips]),
        mask_source=np.array([c.mask_source for c in clips]),
        meta=np.array([json.dumps({**c.meta, "clip_id": c.clip_id}) for c in clips]),
    )
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, **arrays)
    return path


def is_batch(arrays: Mapping[str, Any]) -> bool:
    return "n_frames" in arrays


def _batch_member(arrays: Mapping[str, Any], b: int) -> tuple[str, dict[str, Any]]:
    """Slice clip ``b`` out of a batch mapping, cutting the padding away."""
    T = int(np.asarray(arrays["n_frames"])[b])
    P = int(np.asarray(arrays["n_tracks"])[b])
    depth = np.asarray(arrays["depth"])
    H = int(np.asarray(arrays["heights"])[b]) if "heights" in arrays else depth.shape[2]
    W = int(np.asarray(arrays["widths"])[b]) if "widths" in arrays else depth.shape[3]
    clip_id = str(np.asarray(arrays["clip_id"])[b]) if "clip_id" in arrays else f"clip{b}"
    member: dict[str, Any] = {}
    per_frame = {"depth": (T, H, W), "static_mask": (T, H, W), "dynamic_mask": (T, H, W),
                 "K": (T,), "R_wc": (T,), "t_wc": (T,), "extrinsic": (T,), "frames": (T, H, W)}
    per_pair = {"track_prev": (T - 1, P), "track_curr": (T - 1, P), "track_vis": (T - 1, P),
                "track_conf": (T - 1, P)}
    for name, cut in {**per_frame, **per_pair}.items():
        if name in arrays:
            a = np.asarray(arrays[name])[b]
            member[name] = a[tuple(slice(0, c) for c in cut)]
    if "meta" in arrays:
        member["meta"] = np.asarray(arrays["meta"])[b]
    source = np.asarray(arrays["mask_source"])[b] if "mask_source" in arrays else "static_mask"
    if str(source) == "none":
        member.pop("static_mask", None)
    return clip_id, member


# ----------------------------------------------------------------------------- sources


@dataclasses.dataclass
class ClipEntry:
    """A clip to be loaded lazily: its id, where it comes from, and how to load it."""

    clip_id: str
    origin: str
    load: Callable[[], Clip]


def _entries_from_npz(path: Path, config: SGCConfig) -> list[ClipEntry]:
    origin = str(path)
    try:
        with np.load(path, allow_pickle=False) as data:
            batch = is_batch(data)
            ids = [str(i) for i in data["clip_id"]] if batch and "clip_id" in data else None
            count = len(np.asarray(data["n_frames"])) if batch else 1
    except Exception as exc:  # unreadable file: one failing entry, reported not raised
        def fail(exc=exc) -> Clip:
            raise ClipFormatError(path.stem, "<file>", "a readable .npz", f"{type(exc).__name__}: {exc}")
        return [ClipEntry(path.stem, origin, fail)]
    if not batch:
        def load_single() -> Clip:
            with np.load(path, allow_pickle=False) as data:
                return clip_from_arrays(dict(data), clip_id=_meta_id(data) or path.stem, config=config)
        return [ClipEntry(path.stem, origin, load_single)]

    def load_member(b: int) -> Clip:
        with np.load(path, allow_pickle=False) as data:
            clip_id, member = _batch_member(data, b)
            return clip_from_arrays(member, clip_id=clip_id, config=config)
    return [ClipEntry(ids[b] if ids else f"{path.stem}[{b}]", f"{origin}[{b}]",
                      lambda b=b: load_member(b)) for b in range(count)]


def _meta_id(data: Mapping[str, Any]) -> str | None:
    if "meta" not in data:
        return None
    return _parse_meta(data["meta"]).get("clip_id")


def discover_clips(source: Any, config: SGCConfig | None = None) -> list[ClipEntry]:
    """Expand a source into lazily loaded clips.

    ``source``: a clip or batch ``.npz`` path, a directory (its ``*.npz``, sorted), a glob, a
    :class:`Clip`, a mapping of arrays (single clip or batch), or a list of any of these.
    """
    config = config or SGCConfig()
    if isinstance(source, Clip):
        return [ClipEntry(source.clip_id, "<memory>", lambda: subsample_tracks(source, config))]
    if isinstance(source, Mapping):
        if is_batch(source):
            count = len(np.asarray(source["n_frames"]))
            entries = []
            for b in range(count):
                clip_id, member = _batch_member(source, b)
                entries.append(ClipEntry(clip_id, f"<memory>[{b}]",
                                         lambda m=member, c=clip_id: clip_from_arrays(m, clip_id=c, config=config)))
            return entries
        clip_id = _parse_meta(source.get("meta")).get("clip_id") or str(source.get("clip_id", "clip"))
        return [ClipEntry(clip_id, "<memory>", lambda: clip_from_arrays(source, config=config))]
    if isinstance(source, (list, tuple)):
        return [e for item in source for e in discover_clips(item, config)]
    text = os.fspath(source)
    path = Path(text)
    if path.is_dir():
        files = sorted(path.glob("*.npz"))
        if not files:
            raise FileNotFoundError(f"no .npz clips in directory {text}")
        return [e for f in files for e in _entries_from_npz(f, config)]
    if path.is_file():
        return _entries_from_npz(path, config)
    matches = sorted(glob.glob(text))
    if matches:
        return [e for m in matches for e in discover_clips(m, config)]
    raise FileNotFoundError(f"no clip file, directory or glob match for {text!r}")


def load_clips(source: Any, config: SGCConfig | None = None) -> Iterator[Clip]:
    """Load every clip of a source (raises on the first broken one; see :func:`discover_clips`)."""
    for entry in discover_clips(source, config):
        yield entry.load()


def load_clip(source: Any, config: SGCConfig | None = None) -> Clip:
    """Load exactly one clip from a path, mapping or :class:`Clip`."""
    entries = discover_clips(source, config)
    if len(entries) != 1:
        raise ValueError(f"expected one clip, {source!r} holds {len(entries)}")
    return entries[0].load()
