"""SegAnyMo moving-object masks: one palette PNG per frame -> ``static_mask`` (T, H, W).

SegAnyMo (through SAM2) writes DAVIS-style palette PNGs: the pixel values are palette indices,
0 = background (static) and k > 0 = moving object k. Indices are read with Pillow; OpenCV cannot
do it: ``cv2.imread`` expands a palette PNG to its colours even with ``IMREAD_UNCHANGED``, so an
object whose palette colour is black would read as background. Single-channel (grayscale) PNGs are
accepted with a :class:`MaskFormatWarning` (0 = static, anything else = moving); colour PNGs are
refused, since object ids cannot be recovered from colours.

Masks are matched to frames by file stem (``{frame}.png``, as the authors' pipeline does). A frame
without a mask file, or no mask folder at all, means "nothing moves" there; it is reported.
"""

from __future__ import annotations

import dataclasses
import os
import warnings
from pathlib import Path
from typing import Any, Sequence

import cv2
import numpy as np

from .common import EstimatorFormatError, natural_key, resize_nearest

_GRAYSCALE_MODES = ("L", "I", "I;16", "I;16B", "I;16L", "1")


class MaskFormatWarning(UserWarning):
    """A mask file that is readable but not in SegAnyMo's palette format."""


@dataclasses.dataclass
class Masks:
    """(T, H, W) bool static mask, or None when no mask folder exists (nothing moves anywhere)."""

    static_mask: np.ndarray | None
    notes: dict[str, Any]


def read_mask_labels(path: Any) -> np.ndarray:
    """(h, w) int32 object ids of one mask PNG: palette indices (0 = static)."""
    from PIL import Image  # Pillow reads palette indices; see the module docstring

    path = Path(os.fspath(path))
    with Image.open(path) as image:
        mode = image.mode
        if mode == "P":
            return np.asarray(image, dtype=np.int32)
        if mode in _GRAYSCALE_MODES:
            warnings.warn(MaskFormatWarning(
                f"{path}: a grayscale PNG (mode {mode}), not a SegAnyMo palette PNG: reading value 0 as static "
                "and any other value as moving; save palette masks to keep object ids"), stacklevel=3)
            return (np.asarray(image) != 0).astype(np.int32)
    raise EstimatorFormatError(path, "mask", "a palette PNG (mode P, index 0 = static, k = object k) "
                               "or a single-channel label PNG", f"a {mode} image",
                               "object ids cannot be read from colours: save SegAnyMo's masks as palette PNGs "
                               "(PIL Image.putpalette) or as single-channel 0/k label images")


def mask_files(directory: Path) -> list[Path]:
    return sorted(directory.glob("*.png"), key=lambda p: natural_key(p.name))


def read_seganymo(directory: Any, *, height: int, width: int, frame_names: Sequence[str] | None = None,
                  n_frames: int | None = None) -> Masks:
    """A folder of per-frame palette PNGs -> static mask on the clip grid (nearest neighbour resize).

    ``frame_names``: frame stems in order; masks are then ``{name}.png`` and missing ones are all
    static. Without names, the sorted PNGs are the frames and their count must be ``n_frames``.
    """
    if directory is None:
        return Masks(None, {"masks": "no mask folder given: nothing moves, the whole frame is static"})
    directory = Path(os.fspath(directory))
    if not directory.is_dir():  # a mistyped folder must not pass for a clip where nothing moves
        raise FileNotFoundError(f"--masks {directory}: no such folder (leave --masks out if nothing moves)")
    files = mask_files(directory)
    if not files:
        return Masks(None, {"masks": f"no PNG in {directory}: nothing moves, the whole frame is static"})
    missing: list[str] = []
    if frame_names is not None:
        by_stem = {p.stem: p for p in files}
        chosen = [by_stem.get(name) for name in frame_names]
        if all(c is None for c in chosen):
            if len(files) != len(frame_names):
                raise EstimatorFormatError(directory, "mask", f"{{frame}}.png for frames like {frame_names[0]!r}, "
                                           f"or {len(frame_names)} PNGs", f"{len(files)} PNGs named like {files[0].name!r}",
                                           "name the masks after the frames, or give one mask per frame")
            chosen = list(files)
        missing = [name for name, c in zip(frame_names, chosen) if c is None]
    else:
        if n_frames is not None and len(files) != n_frames:
            raise EstimatorFormatError(directory, "mask", f"{n_frames} PNGs, one per frame", f"{len(files)} PNGs",
                                       "give the frames (--frames) so masks are matched by name, or one mask per frame")
        chosen = list(files)
    static = np.ones((len(chosen), height, width), bool)
    for t, path in enumerate(chosen):
        if path is not None:
            labels = read_mask_labels(path)
            static[t] = resize_nearest(labels[None], (height, width))[0] == 0
    notes: dict[str, Any] = {"masks": f"SegAnyMo palette indices from {directory} (0 = static)"}
    if missing:
        notes["masks_missing"] = missing
        notes["masks"] += f"; no mask for {len(missing)} frame(s) ({', '.join(missing[:5])}"
        notes["masks"] += "...): nothing moves there" if len(missing) > 5 else "): nothing moves there"
    return Masks(static, notes)


def grow_moving(masks: Masks, radius_px: int) -> Masks:
    """The moving-object mask of every frame grown by ``radius_px`` (a disc; 0: as read), its static
    mask shrunk so: a segmenter that falls short of a mover's outline leaves a band of it static,
    which the score reads as inconsistency (docs/semantics.md §1.5, "Motion masks")."""
    if masks.static_mask is None or radius_px == 0:
        return masks
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius_px + 1, 2 * radius_px + 1))
    moving = np.stack([cv2.dilate((~frame).astype(np.uint8), disc) for frame in masks.static_mask]).astype(bool)
    notes = {**masks.notes, "masks": masks.notes["masks"] + f"; moving objects grown by {radius_px} px"}
    return Masks(~moving, notes)


def read_mask_hw(directory: Any) -> tuple[int, int] | None:
    """(h, w) of the first mask PNG in ``directory``, or None."""
    if directory is None or not Path(os.fspath(directory)).is_dir():
        return None
    files = mask_files(Path(os.fspath(directory)))
    if not files:
        return None
    from PIL import Image

    with Image.open(files[0]) as image:
        return image.size[1], image.size[0]
