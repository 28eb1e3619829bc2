"""Figures for notebooks and the CLI; every function returns a matplotlib Figure and needs
matplotlib (the ``viz`` extra).

Sensitivity studies (paper Figures 6 and 8): :func:`plot_sensitivity`, :func:`plot_component_response`.
Corpora (Figures 7 and 8a): :func:`plot_group_violins`, :func:`plot_component_correlation`,
:func:`plot_calibration_weights`. One clip: :func:`plot_pair_components`, :func:`plot_region_map`.
One pair (Figure 4 and the depth check, via :mod:`sgc_jax.research.diagnostics`): :func:`plot_pose_arrows`,
:func:`plot_depth_warp_error`, :func:`plot_region_reprojection`. The Scorer's reward: :func:`plot_rewards`.
Gradients (docs/semantics.md §10): :func:`plot_descent`, :func:`plot_track_gradients`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Mapping, Sequence

import numpy as np

from ..calibration import COMPONENTS
from ..codes import REGION_STATUS_NAMES, SCORER_STATUSES
from ..io.extras import MissingExtraError
from ..io.tables import COLUMN_UNITS

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.figure import Figure

    from ..calibration import Calibration, KFoldStability
    from ..config import SGCConfig
    from ..io.clip import Clip
    from ..scoring.result import BatchResult, ClipResult
    from .study import StudyResult



def _units(compats) -> dict[str, str]:
    """Axis units of the columns under the semantics of ``compats`` (the clips' ``compat``
    values; the default's when they are none or mixed)."""
    found = {c for c in compats if c in COLUMN_UNITS}
    return COLUMN_UNITS[found.pop() if len(found) == 1 else "spec"]


def import_pyplot():
    """``matplotlib.pyplot``; without matplotlib, an ImportError naming the ``viz`` extra (the CLI calls
    it to refuse ``--plot`` before any work)."""
    try:
        import matplotlib.pyplot as plt
    except ImportError as exc:
        raise MissingExtraError("plotting needs matplotlib: pip install 'sgc-jax[viz]' "
                                "(or pip install matplotlib)") from exc
    return plt


def plot_sensitivity(study: "StudyResult", *, references: Mapping[str, float] | None = None) -> "Figure":
    """SGC vs severity per kind (mean over base clips, band = ±1 std), and each component's mean
    response; ``references`` adds labelled dashed horizontal SGC lines (e.g. a model's score)."""
    plt = import_pyplot()
    fig, axes = plt.subplots(2, 3, figsize=(13, 7), constrained_layout=True)
    panels = ("sgc", *COMPONENTS)
    severities = np.asarray(study.severities)
    summary = study.summary()
    rho = {(c["kind"], column): c[f"rho_{column}"] for c in study.correlations() for column in panels}
    units = _units(r.get("compat") for r in study.rows)
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
            ax.set_ylabel(f"{column} [{units[column]}]")
        ax.set_xlabel("severity")
        ax.grid(alpha=0.3)
        ax.legend(fontsize="small")
    fig.suptitle(f"Sensitivity of SGC to perturbations ({len(study.bases)} base clip(s), mean per severity)")
    return fig


# ----------------------------------------------------------------------------- clips and pairs

_PAIR_AXIS = "pair i (frames i-1 → i)"
_LOCAL_COLOUR, _GLOBAL_COLOUR = "tab:blue", "tab:red"


def _clip_results(results: "ClipResult | BatchResult | Sequence[ClipResult]") -> list["ClipResult"]:
    from ..scoring.result import BatchResult, ClipResult  # noqa: PLC0415 - matplotlib-only module, flat imports

    if isinstance(results, ClipResult):
        return [results]
    clips = list(results.clips if isinstance(results, BatchResult) else results)
    return [c for c in clips if c.pairs is not None]


def _symlog(ax, linthresh: float) -> None:
    ax.set_yscale("symlog", linthresh=linthresh)
    ax.set_ylim(bottom=0)


def plot_pair_components(results: "ClipResult | BatchResult | Sequence[ClipResult]", *,
                         log: bool = True) -> "Figure":
    """Each component and the mean reprojection error per frame pair, one line per clip.

    ``log``: symmetric-log y axes (linear below 1e-2), so near-zero rigid clips and
    100 deg² spikes share a panel. Pairs without a value (reason other than ``ok``) leave gaps.
    """
    plt = import_pyplot()
    clips = _clip_results(results)
    if not clips:
        raise ValueError("no clip with per-pair arrays to plot (did every clip fail?)")
    fig, axes = plt.subplots(2, 3, figsize=(13, 7), constrained_layout=True, sharex=True)
    panels = (*COMPONENTS, "reproj_error")
    units = _units(c.compat for c in clips)
    for ax, column in zip(axes.ravel(), panels):
        for i, clip in enumerate(clips):
            values = getattr(clip.pairs, column)
            ax.plot(np.arange(1, len(values) + 1), values, marker="o", color=f"C{i % 10}", label=clip.clip_id)
        if log:
            _symlog(ax, 1e-2 if column != "depth_error" else 1e-3)
        ax.set_title(column)
        ax.set_ylabel(f"{column} [{units[column]}]")
        ax.set_xlabel(_PAIR_AXIS)
        ax.xaxis.set_major_locator(plt.MaxNLocator(integer=True))
        ax.grid(alpha=0.3)
    axes.ravel()[0].legend(fontsize="small", title="clip")
    fig.suptitle("SGC components per frame pair" + (" (symlog y axes)" if log else ""))
    return fig


def _background(clip: "Clip", frame: int) -> tuple[np.ndarray, dict]:
    """RGB frame, or the depth map in grey when the clip stores no frames."""
    if clip.frames is not None:
        return clip.frames[frame], {}
    depth = np.where(np.isfinite(clip.depth[frame]) & (clip.depth[frame] > 0), clip.depth[frame], np.nan)
    return depth, {"cmap": "gray"}


def _region_colours(n: int) -> np.ndarray:
    from matplotlib import colormaps  # noqa: PLC0415

    cmap = colormaps["tab10" if n <= 10 else "tab20"]
    return np.array([cmap(j % cmap.N) for j in range(max(n, 1))])


def _image_axes(ax, title: str) -> None:
    ax.set_title(title)
    ax.set_xlabel("x [px]")
    ax.set_ylabel("y [px]")


def plot_region_map(clip: "Clip", pair: int, *, config: "SGCConfig | None" = None,
                    scored: "ClipResult | None" = None, show_tracks: bool = False) -> "Figure":
    """The depth layers that give pair ``pair`` its regions (docs/semantics.md §3.2: frame pair-1's
    under the default ``region_frame="previous"``, frame pair's otherwise) over that frame, next to
    its depth map.

    Each region is labelled with its depth range and, with ``scored`` (the clip's result), its
    point count and pose status; ``show_tracks`` dots the usable tracks by region.
    """
    from matplotlib.patches import Patch  # noqa: PLC0415

    from . import diagnostics  # noqa: PLC0415

    plt = import_pyplot()
    tracks = diagnostics.region_tracks(clip, pair, config)
    labels, frame = tracks.labels, tracks.frame
    n = int(labels.max())
    colours = _region_colours(n)
    fig, (ax, ax_depth) = plt.subplots(1, 2, figsize=(12, 4.6), constrained_layout=True)
    image, kwargs = _background(clip, frame)
    ax.imshow(image, **kwargs)
    overlay = np.zeros((*labels.shape, 4))
    overlay[labels == 0] = (0, 0, 0, 0.55)
    for j in range(1, n + 1):
        overlay[labels == j] = (*colours[j - 1][:3], 0.6)
    ax.imshow(overlay)
    depth = np.where(np.isfinite(clip.depth[frame]) & (clip.depth[frame] > 0), clip.depth[frame], np.nan)
    pairs = scored.pairs if scored is not None else None
    handles = []
    for j in range(1, n + 1):
        d = depth[labels == j]
        text = f"{j}: depth {np.nanmin(d):.3g}–{np.nanmax(d):.3g}"
        if pairs is not None:
            status = REGION_STATUS_NAMES[int(pairs.region_status[pair - 1, j - 1])]
            text += f", {int(pairs.region_points[pair - 1, j - 1])} pts, {status}"
        handles.append(Patch(color=colours[j - 1], alpha=0.8, label=text))
    handles.append(Patch(color="black", alpha=0.55, label="no region (dynamic, invalid or small)"))
    if show_tracks and len(tracks.uv):
        inside = tracks.region > 0
        ax.scatter(tracks.uv_member[inside, 0], tracks.uv_member[inside, 1], s=3, c=colours[tracks.region[inside] - 1],
                   edgecolors="none")
    ax.set_xlim(-0.5, labels.shape[1] - 0.5)
    ax.set_ylim(labels.shape[0] - 0.5, -0.5)
    ax.legend(handles=handles, fontsize="x-small", loc="upper left", bbox_to_anchor=(1.01, 1.0),
              title="region (depth units)", title_fontsize="small")
    _image_axes(ax, f"{clip.clip_id}: {n} depth layers of frame {frame} (pair {pair})")
    shown = ax_depth.imshow(depth, cmap="viridis")
    fig.colorbar(shown, ax=ax_depth, label="depth [depth units]", shrink=0.85)
    _image_axes(ax_depth, f"depth of frame {frame}")
    return fig


def plot_pose_arrows(clip: "Clip", scored: "ClipResult", pair: int, *, config: "SGCConfig | None" = None,
                     normalize: bool = False) -> "Figure":
    """Local poses of each region vs the global pose, as image motion (paper Figure 4).

    At each region's anchor (the centroid of its points, drawn on frame pair-1) a blue arrow shows
    the motion the region's local pose predicts and a red arrow the motion the global camera pose
    predicts; a rigid scene gives equal arrows. Arrows share one magnification (in the title), so
    lengths compare; ``normalize=True`` draws unit directions as in the paper.
    """
    from matplotlib.lines import Line2D  # noqa: PLC0415

    from . import diagnostics  # noqa: PLC0415

    plt = import_pyplot()
    flow = diagnostics.pose_flow(clip, scored, pair, config)
    H, W = flow.labels.shape
    fig, ax = plt.subplots(figsize=(8, 8 * H / W + 0.8), constrained_layout=True)
    image, _ = _background(clip, pair - 1)
    grey = image.mean(axis=-1) if image.ndim == 3 else image
    ax.imshow(grey, cmap="gray", alpha=0.6)
    outline = np.where(flow.labels > 0, flow.labels, np.nan)
    ax.contour(outline, levels=np.arange(0.5, max(int(flow.labels.max()), 1) + 1), colors="black",
               linewidths=0.5, alpha=0.5)
    target = 0.12 * np.hypot(H, W)
    lengths = np.concatenate([np.linalg.norm(flow.local_px, axis=1), np.linalg.norm(flow.global_px, axis=1)])
    longest = np.nanmax(lengths) if np.isfinite(lengths).any() else 0.0
    if normalize:
        unit = lambda v: v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-12) * target  # noqa: E731
        local, global_ = unit(flow.local_px), unit(flow.global_px)
        how = "unit directions"
    else:
        gain = target / longest if longest > 0 else 1.0
        local, global_ = flow.local_px * gain, flow.global_px * gain
        how = f"arrows ×{gain:.3g}"
    start = flow.start_px
    has = np.isfinite(start).all(axis=1)
    arrow = dict(angles="xy", scale_units="xy", scale=1.0)
    ax.quiver(start[has, 0], start[has, 1], global_[has, 0], global_[has, 1], color=_GLOBAL_COLOUR,
              width=0.009, **arrow)
    ok = has & flow.accepted  # drawn on top and thinner, so equal arrows show both colours
    ax.quiver(start[ok, 0], start[ok, 1], local[ok, 0], local[ok, 1], color=_LOCAL_COLOUR, width=0.004, **arrow)
    for j in np.flatnonzero(has):
        ax.annotate(str(j + 1), start[j], xytext=(-9, -9), textcoords="offset points", color="black",
                    fontsize=8, fontweight="bold")
    rejected = has & ~flow.accepted
    ax.scatter(start[rejected, 0], start[rejected, 1], marker="x", color="orange", s=40)
    handles = [Line2D([], [], color=_LOCAL_COLOUR, lw=2.5, label="local pose of a region"),
               Line2D([], [], color=_GLOBAL_COLOUR, lw=2.5, label="global (camera) pose"),
               Line2D([], [], color="black", lw=0.8, label="region outline")]
    if rejected.any():
        handles.append(Line2D([], [], color="orange", marker="x", ls="", label="region without a pose"))
    ax.legend(handles=handles, fontsize="small", loc="lower right", framealpha=0.8)
    ax.set_xlim(-0.5, W - 0.5)
    ax.set_ylim(H - 0.5, -0.5)
    worst = np.nanmax(flow.disagreement_px) if np.isfinite(flow.disagreement_px).any() else float("nan")
    _image_axes(ax, f"{clip.clip_id}, pair {pair}: image motion each pose predicts per region\n"
                    f"({how}; largest local-global gap {worst:.2g} px)")
    return fig


def plot_depth_warp_error(clip: "Clip", pair: int, *, config: "SGCConfig | None" = None, scale: float = 1.0,
                          vmax: float | None = None, log: bool = True) -> "Figure":
    """Frame pair-1's depth warped into frame ``pair`` with the global pose, frame ``pair``'s depth,
    and their absolute difference where compared (docs/semantics.md §3.6); grey = not compared.
    ``scale``: the scored clip's ``scale`` (1, the default, is right where depth and cameras share units).

    The error colour scale runs to ``vmax`` (default: the largest error); ``log``: a log scale over
    three decades below it, so small errors over whole surfaces show next to occlusion edges.
    """
    from matplotlib.colors import LogNorm, Normalize  # noqa: PLC0415
    from matplotlib.patches import Patch  # noqa: PLC0415

    from . import diagnostics  # noqa: PLC0415

    plt = import_pyplot()
    result = diagnostics.depth_warp_error(clip, pair, config, scale=scale)
    depth = np.where(np.isfinite(clip.depth[pair]) & (clip.depth[pair] > 0), clip.depth[pair], np.nan)
    warped = np.where(result.warped > 0, result.warped, np.nan)
    fig, axes = plt.subplots(1, 3, figsize=(16, 4.4), constrained_layout=True)
    lo, hi = np.nanmin(depth), np.nanmax(depth)
    for ax, image, title in ((axes[0], warped, f"depth of frame {pair - 1} warped into frame {pair}"),
                             (axes[1], depth, f"depth of frame {pair}")):
        ax.set_facecolor("0.5")
        shown = ax.imshow(image, cmap="viridis", vmin=lo, vmax=hi)
        _image_axes(ax, title)
    fig.colorbar(shown, ax=axes[:2].tolist(), label="depth [depth units]", shrink=0.85)
    error = result.error
    if vmax is None:
        vmax = float(np.nanmax(error)) if result.compared.any() else 1.0
    vmax = max(vmax, 1e-12)
    norm = LogNorm(vmin=vmax * 1e-3, vmax=vmax, clip=True) if log else Normalize(vmin=0.0, vmax=vmax)
    ax = axes[2]
    ax.set_facecolor("0.5")
    shown = ax.imshow(error, cmap="magma", norm=norm)
    fig.colorbar(shown, ax=ax, label=f"|warped − depth| [{result.error_unit}]" + (", log scale" if log else ""),
                 shrink=0.85)
    ax.legend(handles=[Patch(color="0.5", label="not compared (dynamic, invalid or no warp)")],
              fontsize="x-small", loc="lower right")
    _image_axes(ax, f"depth-warp error, mean {result.mean:.3g} {result.error_unit}")
    fig.suptitle(f"{clip.clip_id}, pair {pair}: depth warped with the global pose")
    return fig


def plot_region_reprojection(clip: "Clip", scored: "ClipResult", pair: int, *,
                             config: "SGCConfig | None" = None) -> "Figure":
    """Reprojection error of each region's points under its own local pose and under the global
    pose (log y axis), with the RANSAC inlier threshold; x ticks give point counts and status."""
    from matplotlib.lines import Line2D  # noqa: PLC0415
    from matplotlib.patches import Patch  # noqa: PLC0415

    from . import diagnostics  # noqa: PLC0415

    plt = import_pyplot()
    reproj = diagnostics.region_reprojection(clip, scored, pair, config)
    regions = [j for j, g in enumerate(reproj.global_px) if len(g)]
    if not regions:
        raise ValueError(f"pair {pair} of {clip.clip_id!r} has no region with points")
    fig, ax = plt.subplots(figsize=(max(6.0, 0.9 * len(regions) + 2), 4.6), constrained_layout=True)
    floor = 1e-6  # px: float precision of a perfect fit; keeps the log axis finite
    positions = np.arange(len(regions), dtype=np.float64)
    box = dict(widths=0.35, showfliers=False, patch_artist=True, medianprops={"color": "black"})
    local = [np.maximum(reproj.local_px[j], floor) if len(reproj.local_px[j]) else [np.nan] for j in regions]
    global_ = [np.maximum(reproj.global_px[j], floor) for j in regions]
    for values, offset, colour in ((local, -0.2, _LOCAL_COLOUR), (global_, 0.2, _GLOBAL_COLOUR)):
        drawn = ax.boxplot(values, positions=positions + offset, **box)
        for patch in drawn["boxes"]:
            patch.set(facecolor=colour, alpha=0.45, edgecolor=colour)
    ax.set_yscale("log")
    ax.axhline(reproj.inlier_px, color="black", ls="--", lw=1)
    ax.set_xticks(positions)
    ax.set_xticklabels([f"{j + 1}\n{len(reproj.global_px[j])} pts\n{REGION_STATUS_NAMES[int(reproj.status[j])]}"
                        for j in regions], fontsize="small")
    ax.set_xlabel("region (depth layer, nearest first)")
    ax.set_ylabel("reprojection error [px]")
    ax.grid(alpha=0.3, axis="y")
    ax.legend(handles=[Patch(color=_LOCAL_COLOUR, alpha=0.45, label="under the region's local pose"),
                       Patch(color=_GLOBAL_COLOUR, alpha=0.45, label="under the global pose"),
                       Line2D([], [], color="black", ls="--", label=f"inlier threshold ({reproj.inlier_px:g} px)")],
              fontsize="small")
    ax.set_title(f"{clip.clip_id}, pair {pair}: reprojection error per region\n"
                 f"(boxes: quartiles, whiskers: 1.5 IQR, values floored at {floor:g} px)")
    return fig


# ----------------------------------------------------------------------------- studies and corpora


def plot_component_response(study: "StudyResult", targets: Mapping[str, str] | None = None) -> "Figure":
    """Each perturbation kind's targeted component vs severity (paper Figure 8b): mean over base
    clips, band = ±1 std, the clean mean as a dashed line. ``targets`` maps kind -> component
    (default :data:`sgc_jax.research.perturb.TARGET_COMPONENT`, else ``sgc``)."""
    from .perturb import TARGET_COMPONENT  # noqa: PLC0415

    plt = import_pyplot()
    targets = dict(targets or {})
    kinds = list(study.kinds)
    fig, axes = plt.subplots(1, len(kinds), figsize=(4.4 * len(kinds), 3.8), constrained_layout=True, squeeze=False)
    severities = np.asarray(study.severities, np.float64)
    for i, (ax, kind) in enumerate(zip(axes[0], kinds)):
        column = targets.get(kind, TARGET_COMPONENT.get(kind, "sgc"))
        rows = [r for r in study.rows if r["kind"] == kind and r["status"] != "error"]
        values = [np.array([float(r[column]) for r in rows if r["severity"] == s], np.float64) for s in severities]
        mean = np.array([np.nanmean(v) if np.isfinite(v).any() else np.nan for v in values])
        std = np.array([np.nanstd(v) if np.isfinite(v).any() else np.nan for v in values])
        rho = study.rho(kind, column)
        colour = f"C{i % 10}"
        ax.plot(severities, mean, marker="o", color=colour,
                label=f"{kind} (ρ={rho:.2f})" if np.isfinite(rho) else f"{kind} (flat)")
        ax.fill_between(severities, mean - std, mean + std, color=colour, alpha=0.15)
        if 0.0 in study.severities:
            ax.axhline(mean[list(study.severities).index(0.0)], color="grey", ls="--", lw=1, label="clean")
        unit = _units(r.get("compat") for r in study.rows).get(column)
        ax.set_ylabel(f"{column} [{unit}]" if unit and column != "sgc" else column)
        ax.set_xlabel("severity")
        ax.set_title(f"{kind} → {column}")
        ax.grid(alpha=0.3)
        ax.legend(fontsize="small")
    fig.suptitle(f"Component responses ({len(study.bases)} base clip(s), mean ± std per severity)")
    return fig


def _rows(rows: Any) -> list[dict[str, Any]]:
    """Per-clip dicts from a BatchResult, a DataFrame or a sequence of dicts."""
    from ..scoring.result import BatchResult  # noqa: PLC0415

    if isinstance(rows, BatchResult):
        return rows.to_records()
    if hasattr(rows, "to_dict") and hasattr(rows, "columns"):
        return rows.to_dict("records")
    return [dict(r) for r in rows]


def plot_group_violins(rows: Any, column: str = "sgc", *, seed: int = 0) -> "Figure":
    """Distribution of ``column`` per group (paper Figure 7): violins with jittered clips coloured by
    ECD (camera dynamics normalised over ``rows``), groups ordered by mean (best first).

    ``rows``: a BatchResult, per-clip records or a DataFrame with ``group``, ``column``,
    ``ecd_trans`` and ``ecd_rot``; failed clips and NaN values are left out.
    """
    from ..scoring.result import add_ecd  # noqa: PLC0415

    plt = import_pyplot()
    records = [r for r in add_ecd(_rows(rows)) if r.get("status", "ok") != "error" and np.isfinite(float(r[column]))]
    if not records:
        raise ValueError(f"no clip with a finite {column!r} to plot")
    groups: dict[str, list[dict[str, Any]]] = {}
    for r in records:
        groups.setdefault(str(r.get("group", "")) or "(no group)", []).append(r)
    order = sorted(groups, key=lambda g: np.mean([float(r[column]) for r in groups[g]]))
    fig, ax = plt.subplots(figsize=(max(6.0, 1.3 * len(order) + 2.5), 4.8), constrained_layout=True)
    rng = np.random.default_rng(seed)
    points = None
    for i, g in enumerate(order):
        values = np.array([float(r[column]) for r in groups[g]])
        if np.unique(values).size > 1:  # a KDE needs spread
            parts = ax.violinplot(values, positions=[i], widths=0.8, showextrema=False)
            for body in parts["bodies"]:
                body.set(facecolor="0.75", edgecolor="0.4", alpha=0.6)
        ecd = np.array([float(r["ecd"]) for r in groups[g]])
        points = ax.scatter(i + rng.uniform(-0.15, 0.15, values.size), values, c=ecd, cmap="plasma", vmin=0.0,
                            vmax=1.0, s=22, edgecolors="black", linewidths=0.3, zorder=3)
        ax.scatter([i], [values.mean()], marker="_", s=500, color="black", zorder=4,
                   label="group mean" if i == 0 else None)
    fig.colorbar(points, ax=ax, label="ECD (camera dynamics, min-max normalised, 0–1)")
    ax.set_xticks(np.arange(len(order)))
    ax.set_xticklabels([f"{g}\n(n={len(groups[g])})" for g in order])
    ax.set_xlabel("group")
    unit = _units(r.get("compat") for r in records).get(column)
    ax.set_ylabel("SGC (lower is better)" if column == "sgc" else f"{column} [{unit}]" if unit else column)
    ax.grid(alpha=0.3, axis="y")
    ax.legend(fontsize="small", loc="upper left")
    ax.set_title(f"{'SGC' if column == 'sgc' else column} per group, clips coloured by ECD")
    return fig


def plot_calibration_weights(calibrations: Mapping[str, "Calibration | str"],
                             stability: "KFoldStability | None" = None) -> "Figure":
    """PC1 weights of several calibrations side by side (e.g. the paper's and a fitted one);
    ``stability`` adds the k-fold mean weight with ±1 std error bars (paper appendix C.1)."""
    from ..calibration import Calibration  # noqa: PLC0415

    plt = import_pyplot()
    series = {name: Calibration.load(c).weight for name, c in calibrations.items()}
    if stability is not None:
        series[f"{stability.k}-fold mean ± std"] = stability.weight_mean
    fig, ax = plt.subplots(figsize=(9, 4.2), constrained_layout=True)
    x = np.arange(len(COMPONENTS))
    width = 0.8 / max(len(series), 1)
    for i, (name, weight) in enumerate(series.items()):
        offset = (i - (len(series) - 1) / 2) * width
        yerr = None
        if stability is not None and i == len(series) - 1:
            yerr = [stability.weight_std[c] for c in COMPONENTS]
        ax.bar(x + offset, [weight[c] for c in COMPONENTS], width, yerr=yerr, capsize=3, label=name, color=f"C{i}")
    ax.set_xticks(x)
    ax.set_xticklabels(COMPONENTS, rotation=15)
    ax.set_xlabel("component")
    ax.set_ylabel("PC1 weight (weights sum to 1)")
    ax.grid(alpha=0.3, axis="y")
    ax.legend(fontsize="small")
    ax.set_title("Calibration weights")
    return fig


def plot_component_correlation(rows: Any, *, log1p: bool = True) -> "Figure":
    """Pearson correlation matrix of the five components over the scored clips (paper Figure 8a);
    ``log1p``: of the values the score uses (log1p of the variances, docs/semantics.md §5.1), so one outlier
    clip does not decide every entry."""
    from ..calibration import LOG1P_COMPONENTS  # noqa: PLC0415
    from ..stats import pearson  # noqa: PLC0415

    plt = import_pyplot()
    records = [r for r in _rows(rows) if r.get("status", "ok") != "error"]
    columns = {c: np.array([float(r[c]) for r in records]) for c in COMPONENTS}
    if log1p:
        columns = {c: np.log1p(np.maximum(v, 0.0)) if c in LOG1P_COMPONENTS else v for c, v in columns.items()}
    matrix = np.array([[pearson(columns[a], columns[b]) for b in COMPONENTS] for a in COMPONENTS])
    fig, ax = plt.subplots(figsize=(6.4, 5.4), constrained_layout=True)
    shown = ax.imshow(matrix, cmap="RdBu_r", vmin=-1.0, vmax=1.0)
    for (i, j), value in np.ndenumerate(matrix):
        ax.text(j, i, "nan" if np.isnan(value) else f"{value:.2f}", ha="center", va="center", fontsize=9,
                color="white" if abs(value) > 0.6 else "black")
    fig.colorbar(shown, ax=ax, label="Pearson r")
    ax.set_xticks(range(len(COMPONENTS)))
    ax.set_xticklabels(COMPONENTS, rotation=30, ha="right")
    ax.set_yticks(range(len(COMPONENTS)))
    ax.set_yticklabels(COMPONENTS)
    ax.set_xlabel("component")
    ax.set_ylabel("component")
    ax.set_title(f"Component correlations over {len(records)} clips" + (" (log1p of variances)" if log1p else ""))
    return fig


def plot_rewards(labels: Sequence[str], outputs: Mapping[str, Any]) -> "Figure":
    """Candidate clips as a Scorer scored them (docs/semantics.md §9.4), best reward on top: the
    reward, the unclipped score behind it and the evidence it is scaled by, each clip's status named
    where it is not ``ok``. ``outputs``: the Scorer's dict (arrays (N,), one per label)."""
    plt = import_pyplot()
    reward, unclipped = np.asarray(outputs["reward"], float), np.asarray(outputs["sgc_unclipped"], float)
    evidence, status = np.asarray(outputs["evidence"], float), np.asarray(outputs["status"])
    order = np.argsort(-reward, kind="stable")[::-1]  # best at the top of the bars
    y = np.arange(len(order))
    fig, axes = plt.subplots(1, 3, figsize=(11, 0.45 * len(order) + 1.6), sharey=True, constrained_layout=True)
    colours = np.where(status[order] == SCORER_STATUSES.index("ok"), "tab:green", "tab:red")
    axes[0].barh(y, reward[order], color=colours)
    for yi, i in zip(y, order):
        if SCORER_STATUSES[status[i]] != "ok":
            axes[0].text(0.01, yi, SCORER_STATUSES[status[i]], va="center", fontsize="small")
    axes[0].set(xlim=(0, 1), xlabel="reward (higher is better)", yticks=y, yticklabels=[labels[i] for i in order])
    axes[1].scatter(unclipped[order], y, color="black", zorder=3)
    axes[1].axvline(0.0, color="0.5", linestyle="--", linewidth=1)
    axes[1].set(xlabel="sgc_unclipped (lower is better;\nsgc = 0 left of the dashed line)")
    axes[2].barh(y, evidence[order], color="tab:blue")
    axes[2].set(xlim=(0, 1.05), xlabel="evidence (§3.11)\nshare of the geometry measured")
    for ax in axes:
        ax.grid(alpha=0.3, axis="x")
    fig.suptitle("candidates ranked by the Scorer's reward")
    return fig


def plot_descent(steps: Sequence[int], sgc: Sequence[float], depth_error_pct: Sequence[float], *,
                 reference_sgc: float | None = None) -> "Figure":
    """A descent on ``sgc_smooth`` (docs/semantics.md §10): SGC and the depth's error to the truth
    [%] per step; ``reference_sgc`` (e.g. the clean clip's) dashed."""
    plt = import_pyplot()
    fig, (ax_score, ax_error) = plt.subplots(1, 2, figsize=(9, 3), constrained_layout=True)
    ax_score.plot(steps, sgc)
    if reference_sgc is not None:
        ax_score.axhline(reference_sgc, color="0.5", linestyle="--", label="clean clip")
        ax_score.legend()
    ax_score.set(xlabel="step", ylabel="SGC (lower is better)", title="score")
    ax_error.plot(steps, depth_error_pct)
    ax_error.set(xlabel="step", ylabel="mean |d - d_true| / d_true [%]", title="error to the true depth")
    for ax in (ax_score, ax_error):
        ax.grid(alpha=0.3)
    return fig


def plot_track_gradients(clip: "Clip", pair: int, gradient_norm) -> "Figure":
    """Each visible track of pair i = ``pair`` (frames i-1 -> i, 1..T-1, as the pair tables) at its
    pixel in frame i, over that frame's depth, coloured by its gradient norm (``gradient_norm``
    (T-1, P), row i-1 for pair i; e.g. |d sgc_smooth / d track_curr|)."""
    plt = import_pyplot()
    from matplotlib.colors import LogNorm

    fig, ax = plt.subplots(figsize=(5, 4), constrained_layout=True)
    ax.imshow(clip.depth[pair], cmap="gray")
    shown = clip.track_vis[pair - 1]
    values = np.asarray(gradient_norm, float)[pair - 1, shown]
    positive = values[values > 0]
    floor = positive.min() if positive.size else 1e-12  # tracks without a gradient at the colour map's bottom
    x, y = clip.track_curr[pair - 1, shown].T
    dots = ax.scatter(x, y, c=np.maximum(values, floor), s=6, cmap="magma", norm=LogNorm(vmin=floor))
    fig.colorbar(dots, ax=ax, label="gradient norm per track [1/px]")
    _image_axes(ax, f"pair {pair}: gradient norm per track")
    return fig
