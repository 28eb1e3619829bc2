"""Figures for sensitivity studies (paper Figure 6); needs matplotlib (the ``viz`` extra)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Mapping

import numpy as np

from .calibration import COMPONENTS

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.figure import Figure

    from .study import StudyResult

_UNITS = {"local_rot_var": "deg²", "global_rot_var": "deg²", "local_trans_var": "depth units²",
          "global_trans_var": "pose units²", "depth_error": "depth units"}


def _pyplot():
    try:
        import matplotlib.pyplot as plt
    except ImportError as exc:
        raise ImportError("plotting needs matplotlib: pip install 'sgc-jax[viz]' (or pip install matplotlib)") from exc
    return plt


def plot_sensitivity(study: "StudyResult", *, references: Mapping[str, float] | None = None) -> "Figure":
    """SGC vs severity per kind (mean over base clips, band = ±1 std), and each component's mean
    response; ``references`` adds labelled dashed horizontal SGC lines (e.g. a model's score)."""
    plt = _pyplot()
    fig, axes = plt.subplots(2, 3, figsize=(13, 7), constrained_layout=True)
    panels = ("sgc", *COMPONENTS)
    severities = np.asarray(study.severities)
    summary = study.summary()
    rho = {(c["kind"], column): c[f"rho_{column}"] for c in study.correlations() for column in panels}
    for ax, column in zip(axes.ravel(), panels):
        for kind in study.kinds:
            rows = [s for s in summary if s["kind"] == kind]
            mean = np.array([s[column] for s in rows], np.float64)
            r = rho[kind, column]
            label = f"{kind} (ρ={r:.2f})" if np.isfinite(r) else f"{kind} (flat)"
            (line,) = ax.plot(severities, mean, marker="o", label=label)
            if column == "sgc":
                std = np.array([s["sgc_std"] for s in rows], np.float64)
                ax.fill_between(severities, mean - std, mean + std, color=line.get_color(), alpha=0.15)
        if column == "sgc":
            for i, (name, value) in enumerate((references or {}).items()):
                ax.axhline(value, linestyle="--", color=f"C{len(study.kinds) + i}", label=f"{name} ({value:.3g})")
            ax.set_title("SGC (lower is better)")
            ax.set_ylabel("SGC")
        else:
            ax.set_title(column)
            ax.set_ylabel(f"{column} [{_UNITS[column]}]")
        ax.set_xlabel("severity")
        ax.grid(alpha=0.3)
        ax.legend(fontsize="small")
    fig.suptitle(f"Sensitivity of SGC to perturbations ({len(study.bases)} base clip(s), mean per severity)")
    return fig
