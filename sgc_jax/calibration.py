"""From components to the SGC score (SPEC §4): normalisation, PCA weights, calibration JSON.

This file holds the only copy of the score formula; both engines call :func:`sgc_score`.
"""

from __future__ import annotations

import dataclasses
import json
import os
from importlib import resources
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

COMPONENTS = ("local_rot_var", "local_trans_var", "global_rot_var", "global_trans_var", "depth_error")
LOG1P_COMPONENTS = COMPONENTS[:4]  # variances are log1p-transformed, depth error is used raw
BUILTIN = ("sgc-paper-2026",)


@dataclasses.dataclass(frozen=True)
class Calibration:
    """Per component: log1p flag, mean ``mu``, std ``sigma``, z bounds and weight (SPEC §4)."""

    name: str
    mu: dict[str, float]
    sigma: dict[str, float]
    z_min: dict[str, float]
    z_max: dict[str, float]
    weight: dict[str, float]
    log1p: dict[str, bool]
    description: str = ""
    rows: str = ""
    extra: dict[str, Any] = dataclasses.field(default_factory=dict)

    # --------------------------------------------------------------- JSON
    def to_dict(self) -> dict[str, Any]:
        components = {
            k: {"log1p": self.log1p[k], "mu": self.mu[k], "sigma": self.sigma[k],
                "z_min": self.z_min[k], "z_max": self.z_max[k], "weight": self.weight[k]}
            for k in COMPONENTS
        }
        out = {"name": self.name, "description": self.description, "rows": self.rows,
               "components": components}
        out.update(self.extra)
        return out

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> "Calibration":
        comps = data.get("components")
        if not isinstance(comps, Mapping) or set(comps) != set(COMPONENTS):
            found = sorted(comps) if isinstance(comps, Mapping) else type(comps).__name__
            raise ValueError(f"calibration needs components {list(COMPONENTS)}, found {found}")
        fields = ("log1p", "mu", "sigma", "z_min", "z_max", "weight")
        for k in COMPONENTS:
            missing = [f for f in fields if f not in comps[k]]
            if missing:
                raise ValueError(f"calibration component {k!r} lacks {missing}")
        known = {"name", "description", "rows", "components"}
        return cls(
            name=str(data.get("name", "custom")),
            description=str(data.get("description", "")),
            rows=str(data.get("rows", "")),
            extra={k: v for k, v in data.items() if k not in known},
            **{f: {k: (bool(comps[k][f]) if f == "log1p" else float(comps[k][f])) for k in COMPONENTS}
               for f in fields},
        )

    def save(self, path: str | os.PathLike) -> Path:
        path = Path(path)
        path.write_text(json.dumps(self.to_dict(), indent=2) + "\n")
        return path

    @classmethod
    def load(cls, name_or_path: "str | os.PathLike | Calibration") -> "Calibration":
        """A shipped calibration by name (``"sgc-paper-2026"``) or a JSON file."""
        if isinstance(name_or_path, Calibration):
            return name_or_path
        text = os.fspath(name_or_path)
        if text in BUILTIN:
            raw = resources.files("sgc_jax").joinpath("calibration", f"{text}.json").read_text()
        else:
            path = Path(text)
            if not path.is_file():
                raise FileNotFoundError(f"calibration {text!r} is neither a shipped name {BUILTIN} nor a file")
            raw = path.read_text()
        return cls.from_dict(json.loads(raw))


# ----------------------------------------------------------------------------- score formula


def transform(components: Mapping[str, Any], calibration: Calibration) -> dict[str, np.ndarray]:
    """p_k: log1p(max(0, m_k)) for flagged components, m_k otherwise; arrays broadcast."""
    out = {}
    for k in COMPONENTS:
        m = np.asarray(components[k], np.float64)
        out[k] = np.log1p(np.maximum(m, 0.0)) if calibration.log1p[k] else m
    return out


def normalise(components: Mapping[str, Any], calibration: Calibration) -> dict[str, np.ndarray]:
    """M''_k = max(0, (z_k - zmin_k) / (zmax_k - zmin_k)), z_k = (p_k - mu_k) / sigma_k.

    sigma_k = 0 gives z_k = 0, a zero z span gives M''_k = 0; NaN stays NaN; no upper clip.
    """
    p = transform(components, calibration)
    out = {}
    for k in COMPONENTS:
        sigma, span = calibration.sigma[k], calibration.z_max[k] - calibration.z_min[k]
        z = (p[k] - calibration.mu[k]) / sigma if sigma != 0 else np.where(np.isnan(p[k]), np.nan, 0.0)
        scaled = (z - calibration.z_min[k]) / span if span != 0 else np.where(np.isnan(z), np.nan, 0.0)
        out[k] = np.where(np.isnan(scaled), np.nan, np.maximum(scaled, 0.0))
    return out


def sgc_score(components: Mapping[str, Any], calibration: Calibration) -> np.ndarray:
    """SGC = sum_k w_k M''_k / sum_k w_k over the non-NaN M''_k (NaN when all are NaN). Lower is better."""
    normalised = normalise(components, calibration)
    stacked = np.stack([normalised[k] for k in COMPONENTS], axis=-1)
    weights = np.array([calibration.weight[k] for k in COMPONENTS])
    present = ~np.isnan(stacked)
    total_weight = (weights * present).sum(-1)
    weighted = np.where(present, stacked, 0.0) @ weights
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(total_weight > 0, weighted / np.where(total_weight > 0, total_weight, 1.0), np.nan)


# ----------------------------------------------------------------------------- fitting


def _rows_matrix(rows: Any, by: str) -> np.ndarray:
    """(n_rows, 5) component matrix from records, a DataFrame-like, a BatchResult or an array."""
    if hasattr(rows, "to_records") and not isinstance(rows, np.ndarray):
        rows = rows.to_records()
    if isinstance(rows, np.ndarray):
        return np.asarray(rows, np.float64).reshape(-1, len(COMPONENTS))
    records = list(rows)
    if by == "group":
        groups: dict[str, list] = {}
        for r in records:
            groups.setdefault(str(r.get("group", "")), []).append(r)
        return np.array([[np.nanmean([float(r[k]) for r in members]) for k in COMPONENTS]
                         for _, members in sorted(groups.items())])
    return np.array([[float(r[k]) for k in COMPONENTS] for r in records])


def calibrate(rows: Any, *, by: str = "clip", name: str = "custom",
              log1p: Sequence[str] = LOG1P_COMPONENTS) -> Calibration:
    """Fit (mu, sigma, z_min, z_max, w) on a corpus (SPEC §4).

    ``rows``: per-clip records (dicts with the component keys and ``group``), a ``BatchResult``,
    or an (n, 5) array. ``by="group"`` first averages the clips of each group (the paper's way).
    mu, sigma with ddof 0; weights = |PC1 loadings| of the M'' matrix (NaN -> column mean), sum 1.
    """
    if by not in ("clip", "group"):
        raise ValueError(f"by must be 'clip' or 'group', got {by!r}")
    matrix = _rows_matrix(rows, by)
    if matrix.shape[0] < 2:
        raise ValueError(f"calibration needs at least 2 rows, got {matrix.shape[0]}")
    flags = {k: k in log1p for k in COMPONENTS}
    p = np.column_stack([np.log1p(np.maximum(matrix[:, j], 0.0)) if flags[k] else matrix[:, j]
                         for j, k in enumerate(COMPONENTS)])
    mu = np.nanmean(p, axis=0)
    sigma = np.nanstd(p, axis=0, ddof=0)
    z = np.where(sigma > 0, (p - mu) / np.where(sigma > 0, sigma, 1.0), 0.0)
    z_min, z_max = np.nanmin(z, axis=0), np.nanmax(z, axis=0)
    span = z_max - z_min
    normalised = np.where(span > 0, (z - z_min) / np.where(span > 0, span, 1.0), 0.0)
    normalised = np.where(np.isnan(p), np.nan, normalised)
    filled = np.where(np.isnan(normalised), np.nanmean(normalised, axis=0), normalised)
    centred = filled - filled.mean(axis=0)
    _, singular, vt = np.linalg.svd(centred, full_matrices=False)
    loadings = np.abs(vt[0])
    weights = loadings / loadings.sum()
    explained = float(singular[0] ** 2 / np.sum(singular**2)) if np.sum(singular**2) > 0 else float("nan")
    as_dict = lambda a: {k: float(a[j]) for j, k in enumerate(COMPONENTS)}  # noqa: E731
    return Calibration(
        name=name, mu=as_dict(mu), sigma=as_dict(sigma), z_min=as_dict(z_min), z_max=as_dict(z_max),
        weight=as_dict(weights), log1p=flags, rows="dataset-group means" if by == "group" else "clips",
        description=f"fitted by sgc_jax.calibrate on {matrix.shape[0]} rows (by={by})",
        extra={"pc1_explained_variance_ratio": explained, "n_rows": int(matrix.shape[0])},
    )
