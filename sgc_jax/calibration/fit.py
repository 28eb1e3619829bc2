"""Fitting a calibration on a corpus (docs/semantics.md §5.5), and how stable its weights are
under k-fold resampling (paper appendix C.1)."""

from __future__ import annotations

import dataclasses
import warnings
from typing import Any, Mapping, Sequence

import numpy as np

from ..stats import spearman
from .formula import FLOOR_COLUMNS, excess_over_floors, sgc_score
from .model import COMPONENTS, LOG1P_COMPONENTS, Calibration, CalibrationMismatchError


def _as_records(rows: Any) -> Any:
    """Per-clip rows as records (a list of dicts), or the (n, 5) array they were given as."""
    if hasattr(rows, "clips") and hasattr(rows, "to_records"):  # BatchResult
        return rows.to_records()
    if hasattr(rows, "columns") and hasattr(rows, "to_dict"):  # DataFrame
        return rows.to_dict("records")
    return rows if isinstance(rows, np.ndarray) else list(rows)


def component_rows(rows: Any) -> tuple[np.ndarray, list[str]]:
    """(n, 5) component matrix and the n group labels of per-clip rows.

    ``rows``: records (dicts with the component keys and optionally ``group``), a ``BatchResult``,
    a pandas DataFrame, or an (n, 5) array (groups all empty).
    """
    rows = _as_records(rows)
    if isinstance(rows, np.ndarray):
        matrix = np.asarray(rows, np.float64).reshape(-1, len(COMPONENTS))
        return matrix, [""] * matrix.shape[0]
    records = list(rows)
    matrix = np.array([[float(r[k]) for k in COMPONENTS] for r in records], np.float64).reshape(-1, len(COMPONENTS))
    return matrix, [str(r.get("group", "") or "") for r in records]


def excess_rows(rows: Any, matrix: np.ndarray, floor_band: float) -> np.ndarray:
    """``matrix`` (n, 5) with each pose component replaced by its excess over ``floor_band`` times
    its floor (docs/semantics.md §5.1), the floors read from the rows' <component>_floor columns."""
    if not floor_band > 0:
        raise ValueError(f"floor_band must be > 0 (0: fit the components as they are), got {floor_band!r}")
    rows = _as_records(rows)
    if isinstance(rows, np.ndarray):
        raise ValueError("floor_band needs rows with the noise-floor columns (<component>_floor), not a bare array")
    records = list(rows)
    missing = [k for k in FLOOR_COLUMNS if any(k not in r for r in records)]
    if missing:
        raise ValueError(f"floor_band needs the noise-floor columns {missing} in every row (sgc-jax score writes them)")
    floors = {k: np.array([float(r[k]) if r[k] not in ("", None) else np.nan for r in records], np.float64)
              for k in FLOOR_COLUMNS}
    excess = excess_over_floors({k: matrix[:, j] for j, k in enumerate(COMPONENTS)}, floors, floor_band)
    return np.column_stack([excess[k] for k in COMPONENTS])


def _fit_matrix(matrix: np.ndarray, groups: Sequence[str], by: str) -> np.ndarray:
    """The rows a calibration is fitted on: clips, or NaN-ignoring group means (sorted by group);
    rows with every component NaN (failed clips) are left out."""
    if by not in ("clip", "group"):
        raise ValueError(f"by must be 'clip' or 'group', got {by!r}")
    if by == "group":
        labels = sorted(set(groups))
        member = np.array(groups)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # a component NaN in a whole group
            matrix = np.array([np.nanmean(matrix[member == g], axis=0) for g in labels]).reshape(-1, len(COMPONENTS))
    return matrix[~np.isnan(matrix).all(axis=1)]


def _fit(matrix: np.ndarray, flags: Mapping[str, bool]) -> tuple[dict[str, np.ndarray], float]:
    """mu, sigma (ddof 0), z bounds and PC1 weights of a (n, 5) matrix; and PC1's explained variance."""
    if matrix.shape[0] < 2:
        raise ValueError(f"calibration needs at least 2 rows, got {matrix.shape[0]}")
    empty = [k for j, k in enumerate(COMPONENTS) if np.isnan(matrix[:, j]).all()]
    if empty:
        raise ValueError(f"calibration needs a value of every component; none in any row for {empty}")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a component NaN in every row stays NaN
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
    return {"mu": mu, "sigma": sigma, "z_min": z_min, "z_max": z_max, "weight": weights}, explained


def _as_dict(values: np.ndarray) -> dict[str, float]:
    return {k: float(values[j]) for j, k in enumerate(COMPONENTS)}


def rows_compat(rows: Any) -> str:
    """The one ``compat`` of per-clip rows ("" when no row says); mixed semantics raise."""
    rows = _as_records(rows)
    if isinstance(rows, np.ndarray):
        return ""
    found = sorted({str(r.get("compat") or "") for r in rows} - {"", "nan"})
    if len(found) > 1:
        raise CalibrationMismatchError(f"the rows mix semantics compat={found}; score them with one compat")
    return found[0] if found else ""


def calibrate(rows: Any, *, by: str = "clip", name: str = "custom",
              log1p: Sequence[str] = LOG1P_COMPONENTS, compat: str | None = None,
              floor_band: float = 0.0) -> Calibration:
    """Fit (mu, sigma, z_min, z_max, w) on a corpus (docs/semantics.md §5).

    ``rows``: per-clip records (dicts with the component keys and ``group``), a ``BatchResult``,
    a DataFrame, or an (n, 5) array. ``by="group"`` first averages the clips of each group (the
    paper's way). mu, sigma with ddof 0; weights = |PC1 loadings| of the M'' matrix (NaN -> column
    mean), sum 1. Failed clips (every component NaN) are left out. ``extra`` records PC1's
    explained-variance ratio and the number of rows fitted. ``compat``: the semantics of the rows,
    recorded in the calibration (default: the rows' ``compat`` column). ``floor_band`` > 0 fits an
    excess calibration: the pose components' excess over that many times their noise floors (the
    rows' <component>_floor columns), as ``sgc-spec-2026`` scores them.
    """
    rows = _as_records(rows)
    compat = rows_compat(rows) if compat is None else compat
    matrix, groups = component_rows(rows)
    if floor_band != 0:
        matrix = excess_rows(rows, matrix, floor_band)
    if by == "group" and isinstance(rows, np.ndarray):
        raise ValueError("by='group' needs rows with a 'group' field, not a bare array")
    matrix = _fit_matrix(matrix, groups, by)
    flags = {k: k in log1p for k in COMPONENTS}
    fitted, explained = _fit(matrix, flags)
    return Calibration(
        name=name, log1p=flags, **{f: _as_dict(v) for f, v in fitted.items()},
        rows="dataset-group means" if by == "group" else "clips", compat=compat, floor_band=float(floor_band),
        description=f"fitted by sgc_jax.calibrate on {matrix.shape[0]} rows (by={by}"
                    + (f", excess over {floor_band:g} floors)" if floor_band else ")"),
        extra={"pc1_explained_variance_ratio": explained, "n_rows": int(matrix.shape[0])},
    )


# ----------------------------------------------------------------------------- k-fold stability


@dataclasses.dataclass(frozen=True)
class KFoldStability:
    """Weights fitted on k training splits (paper appendix C.1) and how the scores move.

    ``fold_weights`` (k, 5) in :data:`COMPONENTS` order; ``spearman`` (k,): Spearman rho between
    the scores of every row under the fold's calibration and under the full one. Means and
    standard deviations are over folds (ddof 0).
    """

    k: int
    by: str
    seed: int
    n_rows: int
    full_weights: dict[str, float]
    fold_weights: np.ndarray
    spearman: np.ndarray

    def __repr__(self) -> str:  # the (k, 5) weights of a leave-one-out run would fill a screen
        return (f"KFoldStability(k={self.k}, by={self.by!r}, seed={self.seed}, n_rows={self.n_rows}; Spearman "
                f"{self.spearman_mean:.4f} +- {self.spearman_std:.4f}; .table() for the weights)")

    @property
    def weight_mean(self) -> dict[str, float]:
        return _as_dict(self.fold_weights.mean(axis=0))

    @property
    def weight_std(self) -> dict[str, float]:
        return _as_dict(self.fold_weights.std(axis=0))

    @property
    def spearman_mean(self) -> float:
        return float(np.nanmean(self.spearman)) if not np.isnan(self.spearman).all() else float("nan")

    @property
    def spearman_std(self) -> float:
        return float(np.nanstd(self.spearman)) if not np.isnan(self.spearman).all() else float("nan")

    def to_dict(self) -> dict[str, Any]:
        return {"k": self.k, "by": self.by, "seed": self.seed, "n_rows": self.n_rows,
                "weight_mean": self.weight_mean, "weight_std": self.weight_std,
                "full_weight": dict(self.full_weights), "spearman_mean": self.spearman_mean,
                "spearman_std": self.spearman_std, "spearman": [float(v) for v in self.spearman]}

    def table(self) -> str:
        """The paper's Table (stability of PCA weights) as plain text."""
        lines = [f"{'component':<18}{'fold mean':>11}{'fold std':>11}{'full':>9}"]
        for k in sorted(COMPONENTS, key=lambda c: -self.full_weights[c]):
            lines.append(f"{k:<18}{self.weight_mean[k]:>11.4f}{self.weight_std[k]:>11.4f}{self.full_weights[k]:>9.4f}")
        lines.append(f"Spearman(fold scores, full scores) = {self.spearman_mean:.4f} +- {self.spearman_std:.4f}"
                     f" over {self.k} folds ({self.n_rows} rows, by={self.by}, seed={self.seed})")
        return "\n".join(lines)


def kfold_stability(rows: Any, k: int = 5, *, by: str = "clip", seed: int = 0,
                    log1p: Sequence[str] = LOG1P_COMPONENTS, floor_band: float = 0.0) -> KFoldStability:
    """k-fold stability of a calibration (paper appendix C.1, Table "Stability of PCA weights").

    The rows (clips; for ``by="group"`` clips with a ``group``) are shuffled with ``seed`` and cut
    into k folds; each fold's calibration is fitted like :func:`calibrate` on the other k-1 folds
    (grouped first when ``by="group"``) and scores every row; its Spearman rho against the scores
    under the full-data calibration measures how much the ranking depends on the sample.
    A k above the number of scored rows n becomes n (leave-one-out) with a warning; the result's
    ``k`` is the number of folds used. ``floor_band``: as :func:`calibrate`'s.
    """
    rows = _as_records(rows)
    matrix, groups = component_rows(rows)
    if floor_band != 0:  # the excess enters each fold's fit and score alike
        matrix = excess_rows(rows, matrix, floor_band)
    keep = ~np.isnan(matrix).all(axis=1)
    matrix, groups = matrix[keep], [g for g, kept in zip(groups, keep) if kept]
    n = matrix.shape[0]
    if k < 2:
        raise ValueError(f"k must be at least 2, got {k}")
    if n < 2:
        raise ValueError(f"k-fold stability needs at least 2 scored rows, got {n}")
    if k > n:  # folds are cut from the clips, so n is their natural limit: leave-one-out
        warnings.warn(f"k={k} folds but only {n} scored rows to cut them from: using leave-one-out (k={n})",
                      UserWarning, stacklevel=2)
        k = n
    flags = {c: c in log1p for c in COMPONENTS}
    to_calibration = lambda fitted: Calibration(  # noqa: E731
        name="fold", log1p=flags, **{f: _as_dict(v) for f, v in fitted.items()})
    full = to_calibration(_fit(_fit_matrix(matrix, groups, by), flags)[0])
    columns = {c: matrix[:, j] for j, c in enumerate(COMPONENTS)}
    full_scores = sgc_score(columns, full)
    folds = np.array_split(np.random.default_rng(seed).permutation(n), k)
    weights, rhos = [], []
    for held_out in folds:
        train = np.setdiff1d(np.arange(n), held_out)
        train_matrix = _fit_matrix(matrix[train], [groups[i] for i in train], by)
        if train_matrix.shape[0] < 2:
            raise ValueError(f"a training split of {k}-fold has fewer than 2 rows (by={by}); use a smaller k")
        fold = to_calibration(_fit(train_matrix, flags)[0])
        weights.append([fold.weight[c] for c in COMPONENTS])
        rhos.append(spearman(sgc_score(columns, fold), full_scores))
    return KFoldStability(k=k, by=by, seed=seed, n_rows=n, full_weights=dict(full.weight),
                          fold_weights=np.array(weights), spearman=np.array(rhos))
