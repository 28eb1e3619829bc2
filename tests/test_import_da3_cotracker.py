"""Depth Anything 3 and CoTracker3 outputs into clips (docs/semantics.md §1.5): each array lands on
the clip grid by its format's own rule, a file that cannot be read is named with its array, and a
clip imported from them scores like the clip they were written from."""

import warnings

import numpy as np
import pytest
from estimator_fixtures import (
    da3_processed_hw,
    long_range_tracks_of,
    write_cotracker,
    write_da3,
    write_delta_pairs,
    write_frames,
    write_seganymo,
)
from scenes import SCENE
from test_adapters import K_ATOL_PX, SCORE_RTOL
from test_validate import network_depth

from sgc_jax import load_clip, score_batch
from sgc_jax.adapters import (
    EstimatorFormatError,
    import_clip,
    leave_out_depth_ramps,
    read_cotracker,
    read_da3,
    read_tracks,
)
from sgc_jax.calibration import COMPONENTS
from sgc_jax.cli import main
from sgc_jax.io.validate import check_clip
from sgc_jax.research.synth import CLEAN_SGC_MAX, synth_clip


@pytest.fixture(scope="module")
def scene_clip():
    """test_adapters.py's clip: non-rigid, noisy, with moving objects, every component well above 0."""
    return synth_clip(seed=2, clip_id="synthetic", moving_objects=2, layer_drift=0.1, noise_px=0.5, **SCENE)


def long_range_tracks(T=5, N=60, seed=0):
    rng = np.random.default_rng(seed)
    tracks = rng.uniform(0, 150, (T, N, 2)).astype(np.float32)
    visibility = rng.uniform(size=(T, N)) > 0.2
    return tracks, visibility


# ----------------------------------------------------------------------------- Depth Anything 3


def test_da3_processed_grid_maps_back_to_the_clip_grid(tmp_path, scene_clip):
    H, W = scene_clip.image_size
    path = write_da3(tmp_path / "results.npz", scene_clip, units=2.5)
    out = read_da3(path, height=H, width=W)
    assert out.depth.notes["depth_native_hw"] == list(da3_processed_hw(H, W)) == [378, 504]
    np.testing.assert_allclose(out.cameras.K, scene_clip.K, atol=K_ATOL_PX)
    np.testing.assert_allclose(out.depth.depth, 2.5 * scene_clip.depth, rtol=1e-6)  # nearest, both ways
    np.testing.assert_allclose(out.cameras.t_wc, 2.5 * scene_clip.t_wc, rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(out.cameras.R_wc, scene_clip.R_wc, atol=1e-7)


def test_da3_confidence_below_min_conf_is_invalid_depth(tmp_path, scene_clip):
    H, W = scene_clip.image_size
    h, w = da3_processed_hw(H, W)
    conf = np.full((scene_clip.n_frames, h, w), 3.0)
    conf[:, : h // 2] = 1.0  # the top half unsure
    path = write_da3(tmp_path / "results.npz", scene_clip, conf=conf)
    kept = read_da3(path, height=H, width=W).depth.depth
    cut = read_da3(path, height=H, width=W, min_conf=2.0).depth.depth
    assert np.all(cut[:, : H // 2] == 0) and np.array_equal(cut[:, H // 2 + 1:], kept[:, H // 2 + 1:])


def test_a_da3_file_without_cameras_is_refused_naming_the_array(tmp_path, scene_clip):
    path = write_da3(tmp_path / "metric.npz", scene_clip, with_extrinsics=False)
    with pytest.raises(EstimatorFormatError, match="metric.npz: array 'extrinsics'.*DA3METRIC"):
        read_da3(path, height=120, width=160)
    np.savez(tmp_path / "other.npz", depths=np.ones((3, 8, 8)))
    with pytest.raises(EstimatorFormatError, match="other.npz: array 'depth'.*found \\['depths'\\]"):
        read_da3(tmp_path / "other.npz", height=8, width=8)


# ----------------------------------------------------------------------------- CoTracker3


@pytest.mark.parametrize("name", ["tracks.npz", "tracks.pt"])
def test_cotracker_tracks_become_consecutive_pairs_visible_at_both_ends(tmp_path, name):
    tracks, visibility = long_range_tracks()
    out = read_tracks(write_cotracker(tmp_path / name, tracks, visibility))
    np.testing.assert_array_equal(out.track_prev, tracks[:-1])
    np.testing.assert_array_equal(out.track_curr, tracks[1:])
    np.testing.assert_array_equal(out.track_vis, visibility[:-1] & visibility[1:])
    assert np.all(out.track_conf == 1.0) and "cotracker3" in out.notes["tracks_layout"]


def test_cotracker_float_visibility_counts_above_its_threshold_and_npy_tracks_are_all_visible(tmp_path):
    tracks, _ = long_range_tracks()
    raw = np.random.default_rng(1).uniform(size=tracks.shape[:2]).astype(np.float32)
    out = read_cotracker({"pred_tracks": tracks, "pred_visibility": raw})
    np.testing.assert_array_equal(out.track_vis, (raw[:-1] > 0.6) & (raw[1:] > 0.6))
    assert "> 0.6" in out.notes["track_visibility"]
    alone = read_tracks(write_cotracker(tmp_path / "tracks.npy", tracks, raw > 0.5))
    assert alone.track_vis.all() and "every track visible" in alone.notes["track_visibility"]


def test_malformed_cotracker_output_names_the_file_and_array(tmp_path):
    tracks, visibility = long_range_tracks()
    np.savez(tmp_path / "short.npz", pred_tracks=tracks, pred_visibility=visibility[:, :10])
    with pytest.raises(EstimatorFormatError, match="short.npz: array 'pred_visibility'.*shape \\(5, 60\\)"):
        read_tracks(tmp_path / "short.npz")
    np.save(tmp_path / "flat.npy", tracks[..., 0])
    with pytest.raises(EstimatorFormatError, match="flat.npy: array 'pred_tracks'.*\\(T, N, 2\\)"):
        read_tracks(tmp_path / "flat.npy")


# ----------------------------------------------------------------------------- whole clips


def test_a_clip_imported_from_da3_scores_like_the_clip_it_was_written_from(tmp_path, scene_clip):
    H, W = scene_clip.image_size
    imported = import_clip(da3=write_da3(tmp_path / "results.npz", scene_clip, units=0.37),
                           tracks=write_delta_pairs(tmp_path / "delta", scene_clip),
                           masks=write_seganymo(tmp_path / "seganymo", scene_clip, (2 * H, 2 * W)),
                           frames=write_frames(tmp_path / "frames", scene_clip), clip_id="imported")
    assert imported.meta["import"]["depth_kind"] == "da3"
    original, back = score_batch([scene_clip, imported], engine="jax").clips
    assert original.status == back.status == "ok"
    for name in COMPONENTS:
        assert back.components[name] == pytest.approx(original.components[name], rel=SCORE_RTOL), name
    assert back.sgc == pytest.approx(original.sgc, rel=SCORE_RTOL)


def test_import_cli_takes_da3_with_cotracker_and_refuses_mixed_sources(tmp_path, scene_clip, capsys):
    T = scene_clip.n_frames
    tracks, visibility = long_range_tracks(T=T)
    da3 = write_da3(tmp_path / "results.npz", scene_clip)
    cotracker = write_cotracker(tmp_path / "cotracker.pt", tracks, visibility)
    out = tmp_path / "clip.npz"
    assert main(["import", "--da3", str(da3), "--tracks", str(cotracker), "--out", str(out)]) == 0
    assert out.is_file() and "CoTracker3's boolean visibility" in capsys.readouterr().err
    assert main(["import", "--da3", str(da3), "--cameras", str(da3), "--tracks", str(cotracker),
                 "--out", str(tmp_path / "mixed.npz")]) == 2
    assert "drop --cameras" in capsys.readouterr().err


def test_a_da3_and_cotracker3_clip_imported_by_the_cli_scores_its_world_consistent_and_a_squeeze_not(tmp_path):
    """A rigid scene through DA3's file and CoTracker3-like long-range tracks (projected through
    its own geometry), imported by `sgc-jax import`, scores as the clip itself does (about 0, its
    depth error); the same tracks compressed vertically over time score above 0.1."""
    clip = synth_clip(seed=3, clip_id="rigid", **SCENE)
    tracks, visibility = long_range_tracks_of(clip, SCENE["n_tracks"])
    squeeze = 1.0 - 0.3 * np.arange(clip.n_frames)[:, None] / (clip.n_frames - 1)
    squeezed = np.stack([tracks[..., 0], tracks[..., 1] * squeeze], -1)
    H, W = clip.image_size
    common = ["--da3", str(write_da3(tmp_path / "results.npz", clip, units=0.37)),
              "--frames", str(write_frames(tmp_path / "frames", clip)),
              "--masks", str(write_seganymo(tmp_path / "seganymo", clip, (H, W)))]
    for name, arrays in (("honest", tracks), ("squeezed", squeezed)):
        track_file = write_cotracker(tmp_path / f"{name}_tracks.npz", arrays, visibility)
        assert main(["import", *common, "--tracks", str(track_file), "--out", str(tmp_path / f"{name}.npz")]) == 0
    original, honest, broken = score_batch([clip, tmp_path / "honest.npz", tmp_path / "squeezed.npz"]).clips
    assert original.status == honest.status == broken.status == "ok"
    assert max(original.sgc, honest.sgc) < CLEAN_SGC_MAX
    assert honest.components["depth_error"] == pytest.approx(original.components["depth_error"], rel=SCORE_RTOL)
    assert broken.sgc > 0.1


def test_depth_beyond_max_depth_is_imported_invalid_with_its_share_recorded(tmp_path, scene_clip, capsys):
    (H, W), da3 = scene_clip.image_size, write_da3(tmp_path / "results.npz", scene_clip)
    tracks = write_cotracker(tmp_path / "cotracker.npz", *long_range_tracks_of(scene_clip, 200))
    every, cut = (import_clip(da3=da3, tracks=tracks, size=(H, W), max_depth=limit) for limit in (None, 8.0))
    beyond = every.depth > 8.0
    assert beyond.any() and ((every.depth > 0) & ~beyond).any()
    np.testing.assert_array_equal(cut.depth, np.where(beyond, 0.0, every.depth))
    share = round(int(beyond.sum()) / int((every.depth > 0).sum()), 4)
    assert cut.meta["import"]["max_depth"] == {"limit": 8.0, "invalid_frac": share}
    with pytest.raises(ValueError, match="max_depth must be a depth > 0"):
        import_clip(da3=da3, tracks=tracks, size=(H, W), max_depth=0.0)
    out = tmp_path / "clip.npz"
    assert main(["import", "--da3", str(da3), "--tracks", str(tracks), "--size", f"{H}x{W}", "--max-depth", "8",
                 "--out", str(out)]) == 0
    assert f"depth beyond 8 invalid: {share:.0%} of the valid depth" in capsys.readouterr().err
    np.testing.assert_array_equal(load_clip(out).depth, cut.depth)


def test_depth_on_ramps_at_edges_is_imported_invalid_with_its_share_recorded(tmp_path, scene_clip, capsys):
    H, W = scene_clip.image_size
    da3 = write_da3(tmp_path / "results.npz", network_depth(scene_clip))  # a network's depth, edges as ramps
    tracks = write_cotracker(tmp_path / "cotracker.npz", *long_range_tracks_of(scene_clip, 200))
    every = import_clip(da3=da3, tracks=tracks, size=(H, W))
    [line] = [p for p in check_clip(every) if p.code == "smooth_depth_edges"]
    assert line.severity == "info" and "left out before scoring" in line.message  # scoring's default does it
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        cut = import_clip(da3=da3, tracks=tracks, size=(H, W), depth_edge_ratio=1.2)
    assert not [w for w in caught if "Smooth depth edges" in str(w.message)]
    expected = leave_out_depth_ramps(every, 1.2)
    assert 0 < expected.meta["depth_ramps"]["invalid_frac"] < 0.5
    np.testing.assert_array_equal(cut.depth, expected.depth)
    assert cut.meta["import"]["depth_ramps"] == expected.meta["depth_ramps"]
    with pytest.raises(ValueError, match="depth_edge_ratio must be > 1"):
        import_clip(da3=da3, tracks=tracks, size=(H, W), depth_edge_ratio=1.0)
    out = tmp_path / "clip.npz"
    assert main(["import", "--da3", str(da3), "--tracks", str(tracks), "--size", f"{H}x{W}", "--depth-edge-ratio",
                 "--out", str(out)]) == 0
    assert f"depth on ramps at edges spanning more than 1.2x invalid: {expected.meta['depth_ramps']['invalid_frac']:.0%}" \
        in capsys.readouterr().err
    np.testing.assert_array_equal(load_clip(out).depth, cut.depth)


# ----------------------------------------------------------------------------- frame step


def test_a_frame_step_pairs_long_range_tracks_that_many_frames_apart_and_keeps_those_frames(tmp_path, scene_clip):
    T, (H, W) = scene_clip.n_frames, scene_clip.image_size
    tracks, visibility = long_range_tracks_of(scene_clip, 200)
    sources = dict(da3=write_da3(tmp_path / "results.npz", scene_clip),
                   tracks=write_cotracker(tmp_path / "cotracker.npz", tracks, visibility),
                   masks=write_seganymo(tmp_path / "seganymo", scene_clip, (H, W)),
                   frames=write_frames(tmp_path / "frames", scene_clip))
    every, stepped = import_clip(**sources), import_clip(**sources, frame_step=2)
    kept = np.arange(0, T, 2)
    assert stepped.n_frames == len(kept)
    for name in ("depth", "K", "R_wc", "t_wc", "static_mask", "frames"):
        np.testing.assert_array_equal(getattr(stepped, name), getattr(every, name)[kept], err_msg=name)
    np.testing.assert_array_equal(stepped.track_prev, tracks[kept[:-1]])
    np.testing.assert_array_equal(stepped.track_curr, tracks[kept[1:]])
    np.testing.assert_array_equal(stepped.track_vis, visibility[kept[:-1]] & visibility[kept[1:]])
    assert stepped.meta["import"]["frame_step"] == {"step": 2, "frames_kept": len(kept), "of": T}


def test_a_frame_step_needs_long_range_tracks_the_default_semantics_and_two_frames_left(tmp_path, scene_clip, capsys):
    T = scene_clip.n_frames
    da3 = write_da3(tmp_path / "results.npz", scene_clip)
    cotracker = write_cotracker(tmp_path / "cotracker.npz", *long_range_tracks(T=T))
    with pytest.raises(ValueError, match="needs long-range tracks"):
        import_clip(da3=da3, tracks=write_delta_pairs(tmp_path / "delta", scene_clip), frame_step=2)
    with pytest.raises(ValueError, match=f"keeps 1 of the {T} frames"):
        import_clip(da3=da3, tracks=cotracker, frame_step=T)
    with pytest.raises(ValueError, match="whole number >= 1"):
        import_clip(da3=da3, tracks=cotracker, frame_step=0)
    out = tmp_path / "clip.npz"
    assert main(["import", "--da3", str(da3), "--tracks", str(cotracker), "--frame-step", "3", "--out", str(out)]) == 0
    assert f"frame step 3: {len(range(0, T, 3))} of {T} frames kept" in capsys.readouterr().err
    assert main(["import", "--da3", str(da3), "--tracks", str(tmp_path / "delta"), "--frame-step", "2",
                 "--out", str(tmp_path / "pairs.npz")]) == 2
    assert "needs long-range tracks" in capsys.readouterr().err


def test_a_long_clip_imported_at_a_frame_step_scores_its_world_consistent_and_a_squeeze_not(tmp_path):
    """As the CLI test above, a rigid scene of 7 frames through DA3's file and long-range tracks,
    imported by `sgc-jax import --frame-step 2` (frames 0, 2, 4, 6: the suite's 4-frame bucket)."""
    clip = synth_clip(seed=3, clip_id="rigid", **{**SCENE, "n_frames": 7})
    tracks, visibility = long_range_tracks_of(clip, SCENE["n_tracks"])
    squeeze = 1.0 - 0.3 * np.arange(clip.n_frames)[:, None] / (clip.n_frames - 1)
    squeezed = np.stack([tracks[..., 0], tracks[..., 1] * squeeze], -1)
    H, W = clip.image_size
    common = ["--da3", str(write_da3(tmp_path / "results.npz", clip)), "--frame-step", "2",
              "--frames", str(write_frames(tmp_path / "frames", clip)),
              "--masks", str(write_seganymo(tmp_path / "seganymo", clip, (H, W)))]
    for name, arrays in (("honest", tracks), ("squeezed", squeezed)):
        track_file = write_cotracker(tmp_path / f"{name}_tracks.npz", arrays, visibility)
        assert main(["import", *common, "--tracks", str(track_file), "--out", str(tmp_path / f"{name}.npz")]) == 0
    honest, broken = score_batch([tmp_path / "honest.npz", tmp_path / "squeezed.npz"]).clips
    assert honest.n_pairs == broken.n_pairs == 3
    assert honest.status == broken.status == "ok"
    assert honest.sgc < CLEAN_SGC_MAX
    assert broken.sgc > 0.1
