"""Sensitivity studies (docs/semantics.md §6.4; paper §4.3 and appendix C): score every clip
under every perturbation kind and severity, and summarise how the SGC and its components respond.

Each base clip is scored once clean; a severity-0 row of any kind reuses that score (every
perturbation is exactly the identity at severity 0). All perturbed clips go through
:func:`sgc_jax.score_batch` in as few calls as ``chunk_size`` allows, so the JAX engine compiles
once per shape bucket, not once per clip.
"""

from __future__ import annotations

import dataclasses
import math
import os
import sys
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
from tqdm.auto import tqdm

from ..calibration import COMPONENTS, Calibration
from ..codes import CLIP_STATUSES
from ..config import SGCConfig
from ..io.clip import Clip, ClipFormatError
from ..io.loading import discover_clips
from ..io.tables import CLIP_COLUMNS, format_counts, format_table, records_frame, write_csv
from ..scoring.api import resolve_calibration, resolve_config, score_batch
from ..scoring.result import BatchResult, ClipResult, failed_clip
from ..stats import nanmean, spearman
from .perturb import MASK_CORRUPTIONS, PERTURBATIONS, perturb_clip, perturbed_clip_id

#: Columns of a study row: the per-clip columns (docs/semantics.md §4), the study keys, and the
#: relative change of the SGC with respect to the same base clip scored clean,
#: (sgc - sgc_clean) / sgc_clean.
STUDY_COLUMNS = ("base", "kind", "severity", *CLIP_COLUMNS, "rel_change")
#: Columns of the summary: per kind and severity, means over the scored base clips.
SUMMARY_COLUMNS = ("kind", "severity", "n", "sgc", "sgc_std", *COMPONENTS, "rel_change")
#: Columns of the rank correlations with severity, per kind.
CORRELATION_COLUMNS = ("kind", "rho_sgc", "rho_sgc_clips", *(f"rho_{c}" for c in COMPONENTS))
DEFAULT_SEVERITIES = (0.0, 0.25, 0.5, 0.75, 1.0)


def _finite_mean(values: Sequence[float]) -> float:
    values = np.asarray(values, np.float64)
    return float(nanmean(values, np.isfinite(values)))


def _nanstd(values: Sequence[float]) -> float:
    values = np.asarray(values, np.float64)
    finite = np.isfinite(values)
    return float(values[finite].std()) if finite.any() else float("nan")


def _relative_change(value: float, clean: float) -> float:
    """(value - clean) / clean; 0 when equal (a clean score of 0 included), NaN when undefined."""
    if not (math.isfinite(value) and math.isfinite(clean)):
        return float("nan")
    if value == clean:
        return 0.0
    return (value - clean) / clean if clean != 0 else float("nan")


@dataclasses.dataclass
class StudyResult:
    """Rows (one per base clip, kind and severity), the scored clips, and their summaries.

    ``rows`` have :data:`STUDY_COLUMNS`; ``batch`` holds the unique scored clips (each base clean,
    then every perturbed clip) with their per-pair arrays.
    """

    rows: list[dict[str, Any]]
    batch: BatchResult
    kinds: tuple[str, ...]
    severities: tuple[float, ...]
    perturb_seed: int = 0

    def __len__(self) -> int:
        return len(self.rows)

    def __repr__(self) -> str:  # a summary: the rows and the scored clips would flood a notebook
        severities = f"{self.severities[0]:g}..{self.severities[-1]:g}" if self.severities else ""
        return (f"StudyResult: {len(self.bases)} base clips x {len(self.kinds)} kinds ({', '.join(self.kinds)}) x "
                f"{len(self.severities)} severities ({severities}) = {len(self.rows)} rows "
                f"({format_counts((r['status'] for r in self.rows), CLIP_STATUSES) or 'none'})"
                f"; scored {self.batch._summary()}\n"
                "  .table() prints the summary and correlations; .to_records(), .to_pandas(), .to_csv(path) "
                "give the rows")

    @property
    def bases(self) -> list[str]:
        return list(dict.fromkeys(r["base"] for r in self.rows))

    def to_records(self) -> list[dict[str, Any]]:
        return [dict(r) for r in self.rows]

    def _scored(self, kind: str, severity: float) -> list[dict[str, Any]]:
        return [r for r in self.rows if r["kind"] == kind and r["severity"] == severity and r["status"] != "error"]

    def summary(self) -> list[dict[str, Any]]:
        """Per kind and severity: number of scored clips, mean and std of the SGC, mean of each
        component and mean relative change of the SGC vs the clean clip (NaN ignored)."""
        out = []
        for kind in self.kinds:
            for severity in self.severities:
                rows = self._scored(kind, severity)
                out.append({
                    "kind": kind, "severity": severity, "n": len(rows),
                    "sgc": _finite_mean([r["sgc"] for r in rows]), "sgc_std": _nanstd([r["sgc"] for r in rows]),
                    **{c: _finite_mean([r[c] for r in rows]) for c in COMPONENTS},
                    "rel_change": _finite_mean([r["rel_change"] for r in rows]),
                })
        return out

    def correlations(self) -> list[dict[str, Any]]:
        """Per kind, Spearman rho between severity and: the mean SGC over clips (``rho_sgc``,
        1 when the mean rises strictly), every clip's SGC pooled (``rho_sgc_clips``), and the
        mean of each component (``rho_<component>``). NaN with fewer than two severities."""
        summary = self.summary()
        out = []
        for kind in self.kinds:
            means = [s for s in summary if s["kind"] == kind]
            sev = [s["severity"] for s in means]
            pooled = [r for r in self.rows if r["kind"] == kind and r["status"] != "error"]
            row = {"kind": kind, "rho_sgc": spearman(sev, [s["sgc"] for s in means]),
                   "rho_sgc_clips": spearman([r["severity"] for r in pooled], [r["sgc"] for r in pooled])}
            row.update({f"rho_{c}": spearman(sev, [s[c] for s in means]) for c in COMPONENTS})
            out.append(row)
        return out

    def rho(self, kind: str, column: str = "sgc") -> float:
        """Spearman rho between severity and the mean of ``column`` (``sgc`` or a component)."""
        for row in self.correlations():
            if row["kind"] == kind:
                return float(row[f"rho_{column}"])
        raise KeyError(f"kind {kind!r} is not in this study; kinds: {self.kinds}")

    def curve(self, kind: str, column: str = "sgc") -> np.ndarray:
        """(n_severities,) mean of ``column`` per severity for ``kind``, in :attr:`severities` order."""
        if kind not in self.kinds:
            raise KeyError(f"kind {kind!r} is not in this study; kinds: {self.kinds}")
        return np.array([s[column] for s in self.summary() if s["kind"] == kind], np.float64)

    def to_csv(self, path: str | os.PathLike, summary_path: str | os.PathLike | None = None) -> Path:
        """Write the rows (and the summary, when ``summary_path``) as CSV; returns ``path``."""
        if summary_path is not None:
            write_csv(summary_path, self.summary(), SUMMARY_COLUMNS)
        return write_csv(path, self.rows, STUDY_COLUMNS)

    def to_pandas(self, summary: bool = False):
        """A DataFrame of the rows (or of the summary); needs pandas."""
        if summary:
            return records_frame(self.summary(), SUMMARY_COLUMNS)
        return records_frame(self.rows, STUDY_COLUMNS)

    def table(self) -> str:
        """The summary and the correlations as plain text."""
        summary = format_table(self.summary(), ("kind", "severity", "n", "sgc", *COMPONENTS, "rel_change"))
        corr = format_table(self.correlations(), ("kind", "rho_sgc", "rho_sgc_clips"))
        return summary + "\n\n" + corr


def _load_bases(clips: Any, config: SGCConfig, engine: str) -> list[Clip | ClipResult]:
    """Each base clip loaded, or a failed result naming why it could not be."""
    if isinstance(clips, (Clip, Mapping, str, os.PathLike)):
        clips = [clips]
    bases: list[Clip | ClipResult] = []
    for entry in discover_clips(list(clips), config):
        try:
            bases.append(entry.load())
        except ClipFormatError as exc:
            bases.append(failed_clip(entry.clip_id, str(exc), engine=engine, origin=entry.origin))
    return bases


def check_kinds(kinds: Sequence[str] | str) -> tuple[str, ...]:
    """The studied kinds, deduplicated in order; ValueError names an unknown one."""
    kinds = tuple(k.strip() for k in kinds.split(",")) if isinstance(kinds, str) else tuple(kinds)
    known = PERTURBATIONS + MASK_CORRUPTIONS
    unknown = [k for k in kinds if k not in known]
    if unknown or not kinds:
        raise ValueError(f"unknown perturbation kind(s) {unknown}; kinds: {known}")
    return tuple(dict.fromkeys(kinds))


def check_severities(severities: Sequence[float]) -> tuple[float, ...]:
    """The severities, sorted and deduplicated; ValueError for one outside [0, 1]."""
    values = tuple(sorted(dict.fromkeys(float(s) for s in severities)))
    if not values or any(not 0.0 <= s <= 1.0 for s in values):
        raise ValueError(f"severities must be in [0, 1], got {list(severities)}")
    return values


def sensitivity_study(clips: Any, kinds: Sequence[str] | str = PERTURBATIONS,
                      severities: Sequence[float] = DEFAULT_SEVERITIES, *,
                      config: SGCConfig | dict | None = None, calibration: Calibration | str | None = None,
                      engine: str = "jax", perturb_seed: int = 0, params: Mapping[str, Mapping[str, Any]] | None = None,
                      progress: bool | None = None, chunk_size: int = 256, **overrides: Any) -> StudyResult:
    """Score every clip of ``clips`` under every kind (:data:`~sgc_jax.research.perturb.PERTURBATIONS`,
    :data:`~sgc_jax.research.perturb.MASK_CORRUPTIONS`) at every severity in [0, 1].

    ``clips``: anything :func:`sgc_jax.score_batch` accepts. ``perturb_seed`` drives the
    perturbations (the RANSAC seed is ``config.seed``, e.g. ``seed=1`` as an override); ``params``
    maps a kind to its magnitude keywords, e.g. ``{"warp": {"amplitude_frac": 0.05}}``.
    ``chunk_size`` bounds how many clips are perturbed, held in memory and scored per engine call
    (each distinct call size compiles once per bucket).
    ``overrides`` are :class:`SGCConfig` fields. A base that cannot be loaded gives error rows.
    """
    kinds, severities = check_kinds(kinds), check_severities(severities)
    params = {k: dict(v) for k, v in (params or {}).items()}
    stray = sorted(set(params) - set(kinds))
    if stray:
        raise ValueError(f"params given for kind(s) {stray} that are not studied; kinds: {kinds}")
    if chunk_size < 1:
        raise ValueError(f"chunk_size must be >= 1, got {chunk_size}")
    config = resolve_config(config, overrides)
    calibration = resolve_calibration(calibration, config)
    bases = _load_bases(clips, config, engine)

    # The jobs: each loaded base clean, then each (base, kind, severity > 0).
    jobs: list[tuple[int, str, float]] = [(b, "", 0.0) for b, c in enumerate(bases) if isinstance(c, Clip)]
    jobs += [(b, kind, s) for b, c in enumerate(bases) if isinstance(c, Clip)
             for kind in kinds for s in severities if s > 0]
    show = sys.stderr.isatty() if progress is None else progress
    scored: dict[tuple[int, str, float], ClipResult] = {}
    with tqdm(total=len(jobs), desc=f"perturb study ({engine})", unit="clip", disable=not show) as bar:
        for start in range(0, len(jobs), chunk_size):
            chunk = jobs[start:start + chunk_size]
            chunk_clips = [perturb_clip(bases[b], kind, s, perturb_seed, **params.get(kind, {})) if kind else bases[b]
                           for b, kind, s in chunk]
            result = score_batch(chunk_clips, config=config, calibration=calibration, engine=engine,
                                 progress=False, chunk_size=len(chunk_clips))
            scored.update(zip(chunk, result.clips))
            bar.update(len(chunk))

    batch = BatchResult([scored[job] for job in jobs], calibration)
    records = dict(zip(jobs, batch.to_records()))
    rows = []
    for b, base in enumerate(bases):
        base_id = base.clip_id
        clean = records.get((b, "", 0.0))
        for kind in kinds:
            for s in severities:
                if isinstance(base, ClipResult):
                    record = base.record()
                elif s == 0:
                    record = clean
                else:
                    record = records[(b, kind, s)]
                row = {**record, "clip_id": perturbed_clip_id(base_id, kind, s), "base": base_id, "kind": kind,
                       "severity": s}
                row["rel_change"] = _relative_change(row["sgc"], clean["sgc"] if clean else float("nan"))
                rows.append({c: row[c] for c in STUDY_COLUMNS})
    return StudyResult(rows=rows, batch=batch, kinds=kinds, severities=severities,
                       perturb_seed=int(perturb_seed))
