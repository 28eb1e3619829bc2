"""A calibration: per component a transform flag, mean, spread, z bounds and weight
(docs/semantics.md §5.2), its JSON file, and the semantics (``compat``) it was fitted for."""

from __future__ import annotations

import dataclasses
import json
import os
from importlib import resources
from pathlib import Path
from typing import Any, Mapping

COMPONENTS = ("local_rot_var", "local_trans_var", "global_rot_var", "global_trans_var", "depth_error")
LOG1P_COMPONENTS = COMPONENTS[:4]  # variances are log1p-transformed, depth error is used raw
BUILTIN = ("sgc-spec-2026", "sgc-paper-2026")
#: The shipped calibration each semantics uses by default (docs/semantics.md §5.2).
DEFAULT_CALIBRATION = {"spec": "sgc-spec-2026", "authors": "sgc-paper-2026"}
#: What each component's number means under each semantics; recorded in calibration JSON.
UNITS = {
    "spec": {"local_rot_var": "deg^2", "global_rot_var": "deg^2", "local_trans_var": "(% of D)^2",
             "global_trans_var": "(% of D)^2", "depth_error": "% (mean |warped - depth| / depth)",
             "D": "the clip's median static depth"},
    "authors": {"local_rot_var": "deg^2", "global_rot_var": "deg^2", "local_trans_var": "depth units^2",
                "global_trans_var": "pose units^2", "depth_error": "depth units"},
}


class CalibrationMismatchError(ValueError):
    """A calibration applied to components of another semantics (``compat``) than it was fitted for."""


def default_calibration(compat: str) -> str:
    """The shipped calibration name for a semantics (``"spec"`` or ``"authors"``)."""
    if compat not in DEFAULT_CALIBRATION:
        raise ValueError(f"compat must be one of {tuple(DEFAULT_CALIBRATION)}, got {compat!r}")
    return DEFAULT_CALIBRATION[compat]


@dataclasses.dataclass(frozen=True)
class Calibration:
    """Per component: log1p flag, mean ``mu``, std ``sigma``, z bounds and weight (docs/semantics.md §5)."""

    name: str
    mu: dict[str, float]
    sigma: dict[str, float]
    z_min: dict[str, float]
    z_max: dict[str, float]
    weight: dict[str, float]
    log1p: dict[str, bool]
    description: str = ""
    rows: str = ""
    compat: str = ""  # semantics of the components it was fitted on: "spec" | "authors" ("" = unknown)
    # > 0: the pose components enter as their excess over this many times their noise floors (§5.1)
    floor_band: float = 0.0
    extra: dict[str, Any] = dataclasses.field(default_factory=dict)

    def __repr__(self) -> str:  # the five dicts, description and corpus record run to thousands of characters
        weights = ", ".join(f"{k} {self.weight[k]:.3f}" for k in COMPONENTS)
        return (f"Calibration({self.name!r}, compat={self.compat!r}, rows={self.rows!r}; weights {weights}"
                "; .to_dict() for every field)")

    @property
    def excess(self) -> bool:
        """The pose components enter as their excess over ``floor_band`` times their floors."""
        return self.floor_band > 0

    def check_compat(self, compat: str, what: str = "these scores") -> None:
        """Raise :class:`CalibrationMismatchError` when ``compat`` is known and differs from the
        semantics this calibration was fitted for."""
        if self.compat and compat and compat != self.compat:
            raise CalibrationMismatchError(
                f"calibration {self.name!r} was fitted on compat={self.compat!r} components "
                f"({_units_text(self.compat)}); {what} are compat={compat!r} "
                f"({_units_text(compat)}): use --calibration {default_calibration(compat)} "
                f"(or a calibration fitted on compat={compat!r} scores); see docs/semantics.md §5.2")

    # --------------------------------------------------------------- JSON
    def to_dict(self) -> dict[str, Any]:
        components = {
            k: {"log1p": self.log1p[k], "mu": self.mu[k], "sigma": self.sigma[k],
                "z_min": self.z_min[k], "z_max": self.z_max[k], "weight": self.weight[k]}
            for k in COMPONENTS
        }
        out = {"name": self.name, "description": self.description, "rows": self.rows}
        if self.compat:
            out.update(compat=self.compat, units=UNITS[self.compat])
        if self.floor_band:
            out["floor_band"] = self.floor_band
        out["components"] = components
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
        known = {"name", "description", "rows", "components", "compat", "units", "floor_band"}
        compat = str(data.get("compat", ""))
        if compat and compat not in UNITS:
            raise ValueError(f"calibration compat must be one of {tuple(UNITS)}, got {compat!r}")
        if "excess" in data:  # the key's first name: read silently as an extra, it would score without floors
            raise ValueError("calibration key 'excess' is not read: give 'floor_band', the number of noise floors "
                             "the pose components count above (sgc-spec-2026: 1.25; docs/semantics.md §5.2)")
        band = data.get("floor_band", 0.0)
        if isinstance(band, bool) or not isinstance(band, (int, float)) or not band >= 0:
            raise ValueError(f"calibration key 'floor_band' must be a number >= 0, got {band!r}")
        return cls(
            compat=compat, floor_band=float(band),
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
            raw = resources.files(__package__).joinpath(f"{text}.json").read_text()
        else:
            path = Path(text)
            if not path.is_file():
                raise FileNotFoundError(f"calibration {text!r} is neither a shipped name {BUILTIN} nor a file")
            raw = path.read_text()
        return cls.from_dict(json.loads(raw))


def _units_text(compat: str) -> str:
    units = UNITS[compat]
    return f"translation variances in {units['local_trans_var']}, depth error in {units['depth_error']}"
