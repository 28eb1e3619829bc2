"""The stored arrays' dtypes and value sets: integer depth, float frames, float or labelled masks
(docs/semantics.md §1.2)."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..clip import no_reading
from .problems import Problem


def check_dtypes(arrays: Any) -> list[Problem]:
    """Stored dtypes and value sets that load fine but usually mean a unit or format mix-up."""
    problems = []
    depth = np.asarray(arrays["depth"]) if "depth" in arrays else None
    if depth is not None and not np.issubdtype(depth.dtype, np.floating):
        holes = np.count_nonzero(no_reading(depth))
        read = (f"; its {holes} pixels at {np.iinfo(depth.dtype).max}, the no-reading code of such PNGs (7-Scenes, "
                "Kinect), are read as invalid") if holes else ""
        problems.append(Problem("warning", "depth_dtype", "depth", "float depth",
                                f"dtype {depth.dtype}",
                                "integer depth is often a 16-bit PNG in millimetres: convert to float (e.g. / 1000)"
                                + read))
    frames = arrays.get("frames") if hasattr(arrays, "get") else None
    if frames is not None and np.asarray(frames).dtype != np.uint8:
        problems.append(Problem("warning", "frames_dtype", "frames", "uint8 RGB in 0..255",
                                f"dtype {np.asarray(frames).dtype}",
                                "frames are for plots only: store (frames * 255).astype(np.uint8)"))
    for name in ("static_mask", "dynamic_mask"):
        if name in arrays:
            mask = np.asarray(arrays[name])
            if mask.dtype.kind == "f":  # a network's probabilities or logits, read at even odds (§1.2)
                values = mask[:, ::4, ::4] if mask.ndim == 3 else mask
                between = np.count_nonzero((values > 0) & (values < 1))
                if between or np.any(values < 0):
                    problems.append(Problem(
                        "info", "mask_float", name, "a boolean mask",
                        f"floats in [{np.nanmin(values):.3g}, {np.nanmax(values):.3g}], {100 * between / values.size:.0f}% "
                        "strictly between 0 and 1", f"read as {'static' if name == 'static_mask' else 'moving'} where "
                        "above 0.5 (probabilities at even odds; logits at a probability of 0.62): store a boolean "
                        "mask of your own threshold to read it otherwise"))
            elif mask.dtype != bool:
                values = np.unique(mask[:, ::4, ::4]) if mask.ndim == 3 else np.unique(mask)
                if values.size > 2:
                    shown = ", ".join(str(v) for v in values[:6]) + (", ..." if values.size > 6 else "")
                    problems.append(Problem(
                        "warning", "mask_labels", name, "a boolean mask", f"{values.size} distinct values ({shown})",
                        f"every non-zero value counts as {'static' if name == 'static_mask' else 'moving'}; "
                        "object ids (0 = background) belong in dynamic_mask"))
    return problems
