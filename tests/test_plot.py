"""sgc_jax.research.plot: every helper returns a Figure that saves as PNG, with labelled axes (units),
legends or colour bars, and draws the numbers it is given."""

import subprocess
import sys

import matplotlib  # the viz extra (the dev extra installs it)
import numpy as np
import pytest

matplotlib.use("Agg")
import matplotlib.figure  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.collections import PathCollection  # noqa: E402
from matplotlib.quiver import Quiver  # noqa: E402
from scenes import SCENE  # noqa: E402

import sgc_jax  # noqa: E402
from sgc_jax import COMPONENTS  # noqa: E402
from sgc_jax.research import diagnostics, plot  # noqa: E402
from sgc_jax.research.perturb import TARGET_COMPONENT  # noqa: E402
from sgc_jax.research.synth import synth_clip  # noqa: E402

PAIR = 2


@pytest.fixture(scope="module")
def clips(rigid_clip, drift_clip, moving_clip):
    return {c.clip_id: c for c in (rigid_clip, drift_clip, moving_clip)}


@pytest.fixture(scope="module")
def scored(clips):
    return sgc_jax.score_batch(list(clips.values()))


@pytest.fixture(scope="module")
def study(rigid_clip):
    return sgc_jax.sensitivity_study([rigid_clip], severities=(0, 0.5, 1))


@pytest.fixture(scope="module")
def corpus():
    """Three groups of three clips, flaws growing by group."""
    drift = {"clean": 0.0, "mild": 0.05, "strong": 0.3}
    clips = [synth_clip(seed=10 * g + i, clip_id=f"{name}-{i}", group=name, layer_drift=d,
                        rot_deg_per_frame=0.5 + i, **{**SCENE, "n_frames": 3})
             for g, (name, d) in enumerate(drift.items()) for i in range(3)]
    return sgc_jax.score_batch(clips)


@pytest.fixture(autouse=True)
def close_figures():
    yield
    plt.close("all")


def _data_axes(fig):
    return [ax for ax in fig.axes if ax.get_label() != "<colorbar>"]


def _colorbar_labels(fig):
    return [ax.get_ylabel() or ax.get_xlabel() for ax in fig.axes if ax.get_label() == "<colorbar>"]


def check_figure(fig, path, *, units=True):
    """Saved PNG; every data axes has x and y labels (with a [unit] when ``units``); a legend or a
    labelled colour bar explains the colours."""
    assert isinstance(fig, matplotlib.figure.Figure)
    fig.savefig(path, dpi=60)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    for ax in _data_axes(fig):
        assert ax.get_xlabel(), f"axes {ax.get_title()!r} has no x label"
        assert ax.get_ylabel(), f"axes {ax.get_title()!r} has no y label"
        if units:
            assert "[" in ax.get_ylabel() or ax.get_ylabel().startswith("SGC"), ax.get_ylabel()
    legends = [ax.get_legend() for ax in fig.axes if ax.get_legend() is not None]
    assert legends or all(_colorbar_labels(fig)) and _colorbar_labels(fig), "no legend and no labelled colour bar"
    for legend in legends:
        assert all(t.get_text() for t in legend.get_texts())


def test_pair_components_draw_each_clip_per_pair(scored, tmp_path):
    fig = plot.plot_pair_components(scored)
    check_figure(fig, tmp_path / "components.png")
    axes = _data_axes(fig)
    assert [ax.get_title() for ax in axes] == [*COMPONENTS, "reproj_error"]
    assert "[deg²]" in axes[0].get_ylabel() and "[px]" in axes[5].get_ylabel()
    assert [t.get_text() for t in axes[0].get_legend().get_texts()] == scored.clip_ids
    for ax, column in zip(axes, [*COMPONENTS, "reproj_error"]):
        assert len(ax.get_lines()) == len(scored)
        for line, clip in zip(ax.get_lines(), scored):
            np.testing.assert_array_equal(line.get_xdata(), np.arange(1, clip.n_pairs + 1))
            np.testing.assert_array_equal(line.get_ydata(), getattr(clip.pairs, column))


def test_pair_components_accept_one_clip_and_refuse_none(scored, tmp_path):
    check_figure(plot.plot_pair_components(scored[0], log=False), tmp_path / "one.png")
    with pytest.raises(ValueError, match="no clip with per-pair arrays"):
        plot.plot_pair_components([])


def test_region_map_lists_every_region_with_its_status(clips, scored, tmp_path):
    clip = clips["moving"]
    fig = plot.plot_region_map(clip, PAIR, scored=scored.clip("moving"), show_tracks=True)
    check_figure(fig, tmp_path / "regions.png")
    n_regions = int(scored.clip("moving").pairs.n_regions[PAIR - 1])
    texts = [t.get_text() for t in _data_axes(fig)[0].get_legend().get_texts()]
    assert len(texts) == n_regions + 1
    assert texts[0].startswith("1: depth") and texts[-1].startswith("no region")
    assert all(" pts, " in t for t in texts[:-1])
    assert _colorbar_labels(fig) == ["depth [depth units]"]
    overlay = _data_axes(fig)[0].get_images()[1].get_array()
    dynamic = ~clip.static_mask[diagnostics.region_tracks(clip, PAIR).frame]  # the partitioned frame's
    assert np.allclose(overlay[dynamic][:, :3], 0.0)  # moving objects are "no region"


def test_pose_arrows_draw_local_and_global_motion(clips, scored, tmp_path):
    clip, result = clips["drift"], scored.clip("drift")
    fig = plot.plot_pose_arrows(clip, result, PAIR)
    check_figure(fig, tmp_path / "arrows.png", units=False)
    ax = _data_axes(fig)[0]
    assert ax.get_xlabel() == "x [px]" and ax.get_ylabel() == "y [px]"
    flow = diagnostics.pose_flow(clip, result, PAIR)
    global_arrows, local_arrows = [c for c in ax.collections if isinstance(c, Quiver)]
    ok = flow.accepted & np.isfinite(flow.start_px).all(axis=1)
    assert local_arrows.N == ok.sum()
    # one magnification for both colours: arrow vectors stay proportional to the predicted motion
    gain = local_arrows.U[0] / flow.local_px[ok][0, 0]
    np.testing.assert_allclose(local_arrows.U, gain * flow.local_px[ok][:, 0], rtol=1e-6)
    np.testing.assert_allclose(global_arrows.V, gain * flow.global_px[np.isfinite(flow.start_px).all(axis=1)][:, 1],
                               rtol=1e-6)
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert labels[:2] == ["local pose of a region", "global (camera) pose"]


def test_pose_arrows_normalised_have_equal_length(clips, scored, tmp_path):
    fig = plot.plot_pose_arrows(clips["drift"], scored.clip("drift"), PAIR, normalize=True)
    check_figure(fig, tmp_path / "arrows-unit.png", units=False)
    for arrows in (c for c in _data_axes(fig)[0].collections if isinstance(c, Quiver)):
        lengths = np.hypot(arrows.U, arrows.V)
        np.testing.assert_allclose(lengths, lengths[0], rtol=1e-6)


def test_depth_warp_error_map_shows_the_pairs_depth_error(clips, scored, tmp_path):
    clip = clips["drift"]
    fig = plot.plot_depth_warp_error(clip, PAIR)
    check_figure(fig, tmp_path / "warp.png", units=False)
    axes = _data_axes(fig)
    expected = scored.clip("drift").pairs.depth_error[PAIR - 1]
    assert f"mean {expected:.3g} % of depth" in axes[2].get_title()  # compat="spec": the error in % (docs §3.6)
    shown = np.ma.filled(axes[2].get_images()[0].get_array(), np.nan)
    np.testing.assert_allclose(shown, diagnostics.depth_warp_error(clip, PAIR).error, equal_nan=True)
    assert _colorbar_labels(fig) == ["depth [depth units]", "|warped − depth| [% of depth], log scale"]
    linear = plot.plot_depth_warp_error(clip, PAIR, log=False, vmax=1.0)
    assert _colorbar_labels(linear)[-1] == "|warped − depth| [% of depth]"


def test_region_reprojection_shows_local_and_global_errors(clips, scored, tmp_path):
    clip, result = clips["drift"], scored.clip("drift")
    fig = plot.plot_region_reprojection(clip, result, PAIR)
    check_figure(fig, tmp_path / "reproj.png")
    ax = _data_axes(fig)[0]
    assert ax.get_yscale() == "log"
    with_points = int(np.sum(result.pairs.region_points[PAIR - 1] > 0))
    assert len(ax.get_xticks()) == with_points
    threshold = [line for line in ax.get_lines() if line.get_linestyle() == "--"]
    assert threshold and threshold[0].get_ydata()[0] == sgc_jax.SGCConfig().inlier_px
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert labels == ["under the region's local pose", "under the global pose", "inlier threshold (8 px)"]


def test_component_response_follows_the_targeted_component(study, tmp_path):
    fig = plot.plot_component_response(study)
    check_figure(fig, tmp_path / "response.png")
    for ax, kind in zip(_data_axes(fig), study.kinds):
        column = TARGET_COMPONENT[kind]
        assert ax.get_title() == f"{kind} → {column}"
        assert ax.get_ylabel().startswith(column + " [")
        np.testing.assert_allclose(ax.get_lines()[0].get_ydata(), study.curve(kind, column))
    other = plot.plot_component_response(study, targets={"warp": "sgc"})
    assert _data_axes(other)[0].get_ylabel() == "sgc"  # a custom target without units is named as is


def test_sensitivity_figure_saves(study, tmp_path):
    check_figure(plot.plot_sensitivity(study, references={"a model": 0.3}), tmp_path / "sensitivity.png")


def test_group_violins_order_groups_and_colour_clips_by_ecd(corpus, tmp_path):
    fig = plot.plot_group_violins(corpus)
    check_figure(fig, tmp_path / "violins.png")
    ax = _data_axes(fig)[0]
    records = corpus.to_records()
    means = {g: np.mean([r["sgc"] for r in records if r["group"] == g]) for g in {r["group"] for r in records}}
    ticks = [t.get_text().split("\n")[0] for t in ax.get_xticklabels()]
    assert ticks == sorted(means, key=means.get)
    points = [c for c in ax.collections if isinstance(c, PathCollection) and len(c.get_offsets()) > 1]
    assert sum(len(p.get_offsets()) for p in points) == len(records)
    np.testing.assert_allclose(np.concatenate([p.get_array() for p in points]),
                               [r["ecd"] for g in ticks for r in records if r["group"] == g])
    assert _colorbar_labels(fig)[0].startswith("ECD")
    assert ax.get_ylabel() == "SGC (lower is better)"


def test_group_violins_from_a_dataframe_and_for_a_component(corpus, tmp_path):
    fig = plot.plot_group_violins(corpus.to_pandas(), "depth_error")
    check_figure(fig, tmp_path / "violins-depth.png")
    assert _data_axes(fig)[0].get_ylabel() == "depth_error [% of depth]"
    with pytest.raises(ValueError, match="no clip with a finite"):
        plot.plot_group_violins([{**r, "sgc": float("nan")} for r in corpus.to_records()])


def test_calibration_weights_draw_each_calibration_and_fold_spread(corpus, tmp_path):
    fitted = sgc_jax.calibrate(corpus, by="clip")
    stability = sgc_jax.kfold_stability(corpus, k=3)
    fig = plot.plot_calibration_weights({"paper": "sgc-paper-2026", "fitted": fitted}, stability=stability)
    check_figure(fig, tmp_path / "weights.png", units=False)
    ax = _data_axes(fig)[0]
    assert [t.get_text() for t in ax.get_legend().get_texts()] == ["paper", "fitted", "3-fold mean ± std"]
    heights = np.array([patch.get_height() for patch in ax.patches]).reshape(3, len(COMPONENTS))
    paper = sgc_jax.Calibration.load("sgc-paper-2026")
    np.testing.assert_allclose(heights[0], [paper.weight[c] for c in COMPONENTS])
    np.testing.assert_allclose(heights[1], [fitted.weight[c] for c in COMPONENTS])
    np.testing.assert_allclose(heights[2], [stability.weight_mean[c] for c in COMPONENTS])


def test_component_correlation_is_a_symmetric_matrix_with_unit_diagonal(corpus, tmp_path):
    fig = plot.plot_component_correlation(corpus)
    check_figure(fig, tmp_path / "correlation.png", units=False)
    matrix = np.asarray(_data_axes(fig)[0].get_images()[0].get_array())
    np.testing.assert_allclose(np.diag(matrix), 1.0)
    np.testing.assert_allclose(matrix, matrix.T)
    assert _colorbar_labels(fig) == ["Pearson r"]


def test_compare_cli_writes_the_violin_plot(corpus, tmp_path):
    scores = corpus.to_csv(tmp_path / "scores.csv")
    out = tmp_path / "violins.png"
    proc = subprocess.run([sys.executable, "-m", "sgc_jax.cli", "compare", str(scores), "--plot", str(out)],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert f"wrote {out}" in proc.stderr


def test_descent_draws_the_score_and_the_depth_error_per_step(tmp_path):
    steps = np.arange(5)
    fig = plot.plot_descent(steps, [1.1, 0.6, 0.4, 0.2, 0.16], [4.0, 2.2, 1.6, 1.1, 1.2], reference_sgc=0.09)
    check_figure(fig, tmp_path / "descent.png")
    score, error = _data_axes(fig)
    assert len(score.get_lines()) == 2 and len(error.get_lines()) == 1  # the clean clip's line dashed


def test_track_gradients_colour_each_visible_track(rigid_clip, tmp_path):
    norm = np.abs(np.random.default_rng(0).normal(size=rigid_clip.track_vis.shape))
    norm[0, :10] = 0.0  # tracks without a gradient are drawn too
    fig = plot.plot_track_gradients(rigid_clip, 1, norm)  # pair 1: row 0
    check_figure(fig, tmp_path / "tracks.png")
    dots = [c for c in _data_axes(fig)[0].collections if isinstance(c, PathCollection)]
    assert len(dots) == 1 and len(dots[0].get_offsets()) == rigid_clip.track_vis[0].sum()
