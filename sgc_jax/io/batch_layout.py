"""A batch file's layout (docs/semantics.md §1.3): its bookkeeping arrays, each member's sizes, and
one member's arrays cut from the padded batch."""

from __future__ import annotations

import dataclasses
from typing import Any, Iterable, Mapping

import numpy as np

from .arrays import as_clip_array, meta_clip_id, settle_votes
from .clip import ClipFormatError
from .npz import shape_text


def is_batch(arrays: Mapping[str, Any]) -> bool:
    return "n_frames" in arrays


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
    array = as_clip_array(label, name, book[name], f"a ({count},) array of {what}")
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
        count, agree = settle_votes(leading, lambda tied: tied[0])
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
        meta_id = meta_clip_id(texts["meta"][b]) if texts["meta"] is not None else None
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


def batch_member(arrays: Mapping[str, Any], b: int, layout: BatchLayout) -> dict[str, Any]:
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
