"""Video frames for the clip's optional ``frames`` (T, H, W, 3) uint8 RGB, from a folder or a video.

The frames also name the frames (file stems, used to match DELTA and SegAnyMo files) and give the
clip grid when none is asked for.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from .common import EstimatorFormatError, natural_key

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")


@dataclasses.dataclass
class Frames:
    frames: np.ndarray  # (T, H, W, 3) uint8 RGB
    names: list[str]  # frame stems, in order


def frame_files(directory: Path) -> list[Path]:
    files = [p for p in directory.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES]
    return sorted(files, key=lambda p: natural_key(p.name))


def read_frames(source: Any) -> Frames:
    """A folder of images (natural order) or a video file -> RGB frames and their names."""
    path = Path(os.fspath(source))
    if path.is_dir():
        files = frame_files(path)
        if not files:
            raise FileNotFoundError(f"{path}: no image files ({', '.join(IMAGE_SUFFIXES)})")
        frames = []
        for file in files:
            image = cv2.imread(str(file), cv2.IMREAD_COLOR)
            if image is None:
                raise EstimatorFormatError(file, "frame", "a readable image", "unreadable file")
            if frames and image.shape != frames[0].shape:
                raise EstimatorFormatError(file, "frame", f"size {frames[0].shape[0]}x{frames[0].shape[1]} like "
                                           f"{files[0].name}", f"{image.shape[0]}x{image.shape[1]}",
                                           "all frames of a clip share one size")
            frames.append(cv2.cvtColor(image, cv2.COLOR_BGR2RGB))
        return Frames(np.stack(frames), [f.stem for f in files])
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such frames folder or video file")
    capture = cv2.VideoCapture(str(path))
    frames = []
    try:
        while True:
            ok, image = capture.read()
            if not ok:
                break
            frames.append(cv2.cvtColor(image, cv2.COLOR_BGR2RGB))
    finally:
        capture.release()
    if not frames:
        raise EstimatorFormatError(path, "frames", "a video OpenCV can decode", "no frame decoded")
    return Frames(np.stack(frames), [f"{i:05d}" for i in range(len(frames))])
