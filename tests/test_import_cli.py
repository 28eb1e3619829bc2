"""`sgc-jax import`, `pack` and `validate`, run as the real console script on real files."""

import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from estimator_fixtures import vggt_intrinsics, write_all
from scenes import IMPORT_SCENE

from sgc_jax import load_clip, load_clips
from sgc_jax.adapters import LINE_RATIO, leave_out_line_tracks
from sgc_jax.io.arrays import clip_from_arrays
from sgc_jax.io.clip import clip_to_arrays, save_clip
from sgc_jax.research.synth import synth_clip

_SCRIPT = Path(sys.executable).with_name("sgc-jax")
CLI = [str(_SCRIPT)] if _SCRIPT.exists() else [shutil.which("sgc-jax") or "sgc-jax"]
SMALL = IMPORT_SCENE


def run(*args):
    return subprocess.run([*CLI, *map(str, args)], capture_output=True, text=True, timeout=300)


@pytest.fixture(scope="module")
def clip():
    return synth_clip(seed=5, clip_id="scene", moving_objects=1, **SMALL)


@pytest.fixture()
def outputs(tmp_path, clip):
    H, W = clip.image_size
    return write_all(tmp_path / "estimators", clip, depth_size=(2 * H, 2 * W), mask_size=(2 * H, 2 * W))


def import_args(paths, out, *extra):
    return ("import", "--cameras", paths["cameras"], "--depth", paths["depth"], "--tracks", paths["tracks"],
            "--masks", paths["masks"], "--frames", paths["frames"], "--out", out, *extra)


def test_import_writes_a_clip_equal_to_the_scene(tmp_path, clip, outputs):
    out = tmp_path / "clips" / "scene.npz"
    proc = run(*import_args(outputs, out, "--depth-kind", "disparity", "--group", "synthetic"))
    assert proc.returncode == 0, proc.stderr
    assert "depth = 1 / disparity" in proc.stderr and "rescaled from VGGT's 392x518 grid to 96x128" in proc.stderr
    assert f"wrote {out}: 4 frames, 96x128, 512 tracks per pair" in proc.stderr
    back = load_clip(out)
    assert back.clip_id == "scene" and back.group == "synthetic" and back.meta["import"]["reference_compat"] is False
    np.testing.assert_allclose(back.K, clip.K, atol=1e-3)
    np.testing.assert_allclose(back.depth, clip.depth, rtol=1e-6)
    np.testing.assert_array_equal(back.static_mask, clip.static_mask)
    np.testing.assert_array_equal(back.track_curr, clip.track_curr)
    np.testing.assert_array_equal(back.frames, clip.frames)


def test_import_needs_the_depth_kind_and_names_bad_files(tmp_path, outputs):
    proc = run(*import_args(outputs, tmp_path / "x.npz"))
    assert proc.returncode == 2 and "--depth-kind disparity|metric" in proc.stderr and "Traceback" not in proc.stderr
    np.savez(tmp_path / "bad.npz", extrinsic=np.zeros((4, 3, 4)))
    outputs["cameras"] = tmp_path / "bad.npz"
    proc = run(*import_args(outputs, tmp_path / "x.npz", "--depth-kind", "disparity"))
    assert proc.returncode == 2 and f"{tmp_path / 'bad.npz'}: array 'intrinsic'" in proc.stderr
    assert not (tmp_path / "x.npz").exists()


def test_import_without_masks_or_frames_reports_that_nothing_moves(tmp_path, outputs):
    out = tmp_path / "c.npz"
    base = ("import", "--cameras", outputs["cameras"], "--depth", outputs["depth"], "--tracks", outputs["tracks"],
            "--depth-kind", "disparity", "--out", out)
    proc = run(*base)  # the grid then comes from the depth maps (2x): the tracks do not fit it
    assert proc.returncode == 0 and "warning" in proc.stderr and "tracks computed on a smaller grid" in proc.stderr
    proc = run(*base, "--size", "96x128")
    assert proc.returncode == 0 and "warning" not in proc.stderr, proc.stderr
    assert "nothing moves" in proc.stderr and load_clip(out).mask_source == "none"


def test_import_reference_compat_keeps_the_authors_choices(tmp_path, outputs):
    out = tmp_path / "compat.npz"
    proc = run(*import_args(outputs, out, "--reference-compat"))
    assert proc.returncode == 0, proc.stderr
    assert "(reference-compat)" in proc.stderr and "warning" not in proc.stderr
    back = load_clip(out)
    np.testing.assert_allclose(back.K, np.load(outputs["cameras"])["intrinsic"], rtol=1e-6)
    np.testing.assert_allclose(back.depth, np.load(outputs["depth"])["depths"][:, ::2, ::2] / 1000, rtol=1e-6)


def test_import_brings_a_smaller_depth_map_up_in_blocks_with_a_warning_or_bilinearly_on_request(tmp_path, clip):
    H, W = clip.image_size
    outputs = write_all(tmp_path / "small", clip, depth_size=(H // 2, W // 2), mask_size=(H, W))
    proc = run(*import_args(outputs, tmp_path / "blocks.npz", "--depth-kind", "disparity"))
    assert proc.returncode == 0 and "depth: expected depth that varies from pixel to pixel" in proc.stderr, proc.stderr
    proc = run(*import_args(outputs, tmp_path / "smooth.npz", "--depth-kind", "disparity", "--depth-resize", "bilinear"))
    assert proc.returncode == 0 and "depth_in_blocks" not in proc.stderr and "varies from pixel" not in proc.stderr
    assert load_clip(tmp_path / "smooth.npz").meta["import"]["depth_resize"] == "bilinear"
    proc = run(*import_args(outputs, tmp_path / "x.npz", "--reference-compat", "--depth-resize", "bilinear"))
    assert proc.returncode == 2 and "nearest neighbour: drop --depth-resize" in proc.stderr


def test_import_can_leave_out_the_tracks_on_lines_and_needs_the_frames_for_it(tmp_path, clip, outputs):
    out = tmp_path / "lines.npz"
    proc = run(*import_args(outputs, out, "--depth-kind", "disparity", "--leave-out-line-tracks"))
    assert proc.returncode == 0, proc.stderr
    back = load_clip(out)
    expected = leave_out_line_tracks(clip)
    np.testing.assert_array_equal(back.track_vis, expected.track_vis)
    record = back.meta["import"]["line_tracks"]
    assert record["max_ratio"] == LINE_RATIO and 0 < record["left_out"] < 1
    assert f"tracks on lines left out: {record['left_out']:.0%}" in proc.stderr
    proc = run("import", "--cameras", outputs["cameras"], "--depth", outputs["depth"], "--tracks", outputs["tracks"],
               "--depth-kind", "disparity", "--size", "96x128", "--out", tmp_path / "x.npz", "--leave-out-line-tracks")
    assert proc.returncode == 2 and "--frames" in proc.stderr and "Traceback" not in proc.stderr


def test_pack_stacks_clips_and_refuses_broken_ones(tmp_path, clip):
    for i in range(2):
        save_clip(tmp_path / "clips" / f"c{i}.npz", synth_clip(seed=i, clip_id=f"c{i}", **{**SMALL, "n_tracks": 128 * (i + 1)}))
    out = tmp_path / "batch.npz"
    proc = run("pack", tmp_path / "clips", "--out", out)
    assert proc.returncode == 0, proc.stderr
    packed = list(load_clips(out))
    assert [c.clip_id for c in packed] == ["c0", "c1"] and [c.n_tracks for c in packed] == [128, 256]
    assert list(np.load(out)["n_frames"]) == [4, 4]
    bad = clip_from_arrays({**clip_to_arrays(clip), "R_wc": 2 * clip.R_wc}, validate=False)
    save_clip(tmp_path / "clips" / "c2.npz", bad)
    out2 = tmp_path / "batch2.npz"
    proc = run("pack", tmp_path / "clips", "--out", out2)
    assert proc.returncode == 1 and "c2.npz" in proc.stderr and "'R_wc'" in proc.stderr and not out2.exists()
    proc = run("pack", tmp_path / "clips", "--out", out2, "--skip-errors")
    assert proc.returncode == 1 and len(list(load_clips(out2))) == 2


def test_validate_prints_one_line_per_problem_and_fails_on_errors(tmp_path, clip):
    good = save_clip(tmp_path / "good.npz", clip)
    K = vggt_intrinsics(clip.K, 96, 128, "crop")[0]
    depth = np.where(clip.depth > 0, 1 / clip.depth, 0).astype(np.float32)
    bad = save_clip(tmp_path / "bad.npz", clip_from_arrays({**clip_to_arrays(clip), "K": K, "depth": depth},
                                                          validate=False))
    proc = run("validate", good)
    assert proc.returncode == 0 and proc.stdout == "" and "1 clip(s) checked: 0 with errors" in proc.stderr
    assert run("validate", good, "-v").stdout.count("info:") == 3  # depth range, track and mask coverage
    proc = run("validate", good, bad)
    assert proc.returncode == 1, proc.stdout
    lines = proc.stdout.splitlines()
    assert [line.split(": ")[1:3] for line in lines] == [["error", "K"], ["error", "K"], ["warning", "depth"]]
    assert all(line.startswith(f"{bad}: ") for line in lines)
    disparity_only = save_clip(tmp_path / "disp.npz", clip_from_arrays({**clip_to_arrays(clip), "depth": depth},
                                                                      validate=False))
    assert run("validate", disparity_only).returncode == 0
    assert run("validate", disparity_only, "--strict").returncode == 1
