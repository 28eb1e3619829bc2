"""Estimator outputs -> clips (docs/semantics.md §1.5). Fixtures are written in each estimator's own
format and resolution by tests/estimator_fixtures.py (an independent restatement of the formats)."""

import dataclasses
import pickle
import warnings

import cv2
import numpy as np
import pytest
from estimator_fixtures import (
    DAVIS_PALETTE,
    delta_vis,
    frame_names,
    vggt_intrinsics,
    vggt_preprocess,
    write_all,
    write_delta_dense,
    write_delta_pairs,
    write_frames,
    write_palette_png,
    write_seganymo,
    write_vda,
    write_vggt,
)
from scenes import SCENE

from sgc_jax import ClipWarning, score_batch
from sgc_jax.adapters import (
    EstimatorFormatError,
    IntrinsicsWarning,
    MaskFormatWarning,
    Masks,
    every_nth_frame,
    grow_moving,
    import_clip,
    read_delta,
    read_frames,
    read_mask_labels,
    read_seganymo,
    read_vggt,
    read_video_depth,
    resize_depth,
    vggt_grid,
)
from sgc_jax.calibration import COMPONENTS
from sgc_jax.research.synth import synth_clip

# tests/conftest.py's SCENE (T, H, W, P), so the scoring test reuses the engine compiled for the
# other tests. Portrait grids (VGGT's crop mode really crops) are checked array by array below.
# Float32 storage in the estimators' files moves K and depth by ~1e-7 relative; scores move by
# ~1e-5 relative (measured 4e-6). 1% is the required agreement.
SCORE_RTOL = 0.01
K_ATOL_PX = 1e-3  # float32 K on a 518-px grid: ~3e-5 px


@pytest.fixture(scope="module")
def scene_clip():
    """Non-rigid, noisy, with moving objects: every component is well away from zero."""
    return synth_clip(seed=2, clip_id="synthetic", moving_objects=2, layer_drift=0.1, noise_px=0.5, **SCENE)


def K_of(height, width, fov_deg=60.0):
    f = (width / 2) / np.tan(np.radians(fov_deg) / 2)
    return np.tile(np.array([[f, 0, (width - 1) / 2], [0, f * 1.02, (height - 1) / 2], [0, 0, 1]]), (3, 1, 1))


# ----------------------------------------------------------------------------- VGGT


@pytest.mark.parametrize("size, mode, grid, offset", [
    ((120, 160), "crop", (392, 518), (0, 0)),  # 120 * 518 / 160 = 388.5 -> 28 * 14
    ((128, 120), "crop", (518, 518), (0, -14)),  # 546 rows, centre crop from row 14
    ((480, 854), "crop", (294, 518), (0, 0)),  # 291.1 -> 21 * 14
    ((120, 160), "pad", (518, 518), (0, 63)),  # 392 rows padded by (518 - 392) // 2 on top
    ((160, 120), "pad", (518, 518), (63, 0)),
])
def test_vggt_grid_follows_load_and_preprocess_images(size, mode, grid, offset):
    g = vggt_grid(*size, mode)
    assert (g.height, g.width) == grid and (g.offset_x, g.offset_y) == offset
    assert (g.height, g.width) == vggt_preprocess(*size, mode)[:2]


@pytest.mark.parametrize("size, mode", [((120, 160), "crop"), ((128, 120), "crop"), ((480, 854), "crop"),
                                        ((120, 160), "pad"), ((160, 120), "pad")])
def test_vggt_intrinsics_map_back_to_the_clip_grid(tmp_path, size, mode):
    H, W = size
    K = K_of(H, W)
    intrinsic, (h, w) = vggt_intrinsics(K, H, W, mode)
    extrinsic = np.concatenate([np.tile(np.eye(3), (3, 1, 1)), np.arange(9.0).reshape(3, 3, 1)], axis=2)
    path = tmp_path / "predictions.npz"
    np.savez(path, extrinsic=extrinsic.astype(np.float32), intrinsic=intrinsic.astype(np.float32),
             images=np.zeros((3, 3, h, w), np.float32))
    cams = read_vggt(path, height=H, width=W, mode=mode)
    np.testing.assert_allclose(cams.K, K, atol=K_ATOL_PX)
    np.testing.assert_allclose(cams.t_wc, np.arange(9.0).reshape(3, 3))


def test_vggt_frames_of_another_size_are_rescaled_to_the_grid(tmp_path):
    K = K_of(120, 160)
    A = np.diag([2.0, 2.0, 1.0])
    A[:2, 2] = 0.5  # the same camera on frames twice as large (pixel centres)
    intrinsic, _ = vggt_intrinsics(A @ K, 240, 320, "crop")
    path = tmp_path / "p.npz"
    np.savez(path, extrinsic=np.zeros((3, 3, 4), np.float32) + np.eye(3, 4, dtype=np.float32), intrinsic=intrinsic)
    cams = read_vggt(path, height=120, width=160, source_size=(240, 320))
    np.testing.assert_allclose(cams.K, K, atol=K_ATOL_PX)


def test_vggt_reference_compat_keeps_the_518px_intrinsics(tmp_path, scene_clip):
    path = write_vggt(tmp_path / "p.npz", scene_clip)
    cams = read_vggt(path, height=120, width=160, reference_compat=True)
    np.testing.assert_array_equal(cams.K, np.load(path)["intrinsic"].astype(np.float64))
    assert "not rescaled" in cams.notes["intrinsics"]


@pytest.mark.parametrize("change, array, words", [
    (lambda a: a.pop("intrinsic"), "intrinsic", ["no such array", "extrinsic"]),
    (lambda a: a.update(pose_enc=np.zeros((4, 9))) or a.pop("extrinsic"), "extrinsic", ["pose_encoding_to_extri_intri"]),
    (lambda a: a.update(intrinsic=a["intrinsic"][:, :2]), "intrinsic", ["shape (4, 3, 3)", "(4, 2, 3)"]),
    (lambda a: a.update(extrinsic=a["extrinsic"][:, 0]), "extrinsic", ["shape (S, 3, 4)"]),
    (lambda a: a.update(intrinsic=a["intrinsic"][:3]), "intrinsic", ["one per extrinsic"]),
    (lambda a: a.update(images=np.zeros((4, 3, 518, 518), np.float32)), "images", ["392x518", "--vggt-mode pad"]),
    (lambda a: a.update(images=np.zeros((4, 3, 294, 518), np.float32)), "images", ["--vggt-source-size"]),
])
def test_malformed_vggt_output_names_file_and_array(tmp_path, scene_clip, change, array, words):
    path = write_vggt(tmp_path / "p.npz", scene_clip, mode="crop")
    arrays = dict(np.load(path))
    change(arrays)
    bad = tmp_path / "bad.npz"
    np.savez(bad, **arrays)
    with pytest.raises(EstimatorFormatError) as info:
        read_vggt(bad, height=120, width=160)
    assert info.value.array == array and str(bad) in str(info.value)
    for word in words:
        assert word in str(info.value)


def test_vggt_mode_mismatch_says_which_mode_fits(tmp_path, scene_clip):
    path = write_vggt(tmp_path / "p.npz", scene_clip, mode="pad", with_images=False)
    with pytest.raises(EstimatorFormatError, match="--vggt-mode pad"):  # found from the principal point
        read_vggt(path, height=120, width=160, mode="crop")
    np.testing.assert_allclose(read_vggt(path, height=120, width=160, mode="pad").K, scene_clip.K, atol=K_ATOL_PX)


def test_vggt_intrinsics_at_the_wrong_resolution_are_refused(tmp_path, scene_clip):
    """K already on the clip grid (not VGGT's) would be rescaled twice: the principal point gives it away."""
    H, W = scene_clip.image_size
    path = tmp_path / "p.npz"
    np.savez(path, extrinsic=np.concatenate([scene_clip.R_wc, scene_clip.t_wc[..., None]], 2), intrinsic=scene_clip.K)
    with pytest.raises(EstimatorFormatError) as info:
        read_vggt(path, height=H, width=W)
    message = str(info.value)
    assert info.value.array == "intrinsic" and str(path) in message
    assert "principal point (259.0, 196.0)" in message and "store it as the clip's K" in message


@pytest.mark.parametrize("batch", [False, True])
def test_vggt_depth_and_confidence_are_read_on_the_preprocessed_grid(tmp_path, scene_clip, batch):
    """demo_gradio's predictions.npz drops the batch axis; a raw model output keeps B = 1."""
    path = write_vggt(tmp_path / "p.npz", scene_clip)
    depth = np.random.default_rng(0).uniform(1, 5, (4, 392, 518, 1)).astype(np.float32)
    conf = 1 + depth[..., 0]
    arrays = {**np.load(path), "depth": depth[None] if batch else depth, "depth_conf": conf[None] if batch else conf}
    cams = read_vggt(arrays, height=120, width=160, with_depth=True)
    np.testing.assert_array_equal(cams.depth.depth, depth[..., 0])
    np.testing.assert_array_equal(cams.depth.conf, conf)
    assert cams.depth.grid == vggt_grid(120, 160) and cams.depth.frame_hw == (120, 160)
    assert read_vggt(arrays, height=120, width=160).depth is None  # only read when asked for


# ----------------------------------------------------------------------------- Video Depth Anything


@pytest.mark.parametrize("kind, scale", [("disparity", 3.0), ("metric", 1.0), ("metric", 0.5)])
def test_vda_depth_at_its_own_resolution_round_trips(tmp_path, scene_clip, kind, scale):
    H, W = scene_clip.image_size
    path = write_vda(tmp_path / "v_depths.npz", scene_clip, (int(1.5 * H), int(1.5 * W)), kind=kind, scale=scale)
    depth = read_video_depth(path, height=H, width=W, kind=kind, depth_scale=scale)
    np.testing.assert_allclose(depth.depth, scene_clip.depth, rtol=1e-6)
    assert depth.notes["depth_native_hw"] == [int(1.5 * H), int(1.5 * W)]


def test_depth_smaller_than_the_grid_comes_up_in_blocks_by_default_and_bilinear_within_valid_depth_on_request():
    slope = np.add.outer(np.arange(6.0), np.arange(8.0))[None] + 10.0  # a sloping surface on a 6x8 grid
    slope[0, 0, 0] = 0.0  # a hole
    kwargs = dict(height=12, width=16, kind="metric")
    blocks = read_video_depth({"depths": slope}, **kwargs).depth[0]
    assert np.all(blocks[2:, 2:][::2, ::2] == blocks[2:, 2:][1::2, 1::2])  # 2x2 blocks
    smooth = read_video_depth({"depths": slope}, resize="bilinear", **kwargs)
    depth = smooth.depth[0]
    rows, cols = np.mgrid[0:12, 0:16]
    plane = (rows + 0.5) / 2 - 0.5 + (cols + 0.5) / 2 - 0.5 + 10.0  # the surface, at each target pixel centre
    inside = (rows >= 3) & (rows <= 10) & (cols >= 3) & (cols <= 14)  # between source centres, away from the hole
    np.testing.assert_allclose(depth[inside], plane[inside], rtol=1e-6)
    assert np.all(depth[:2, :2] == 0)  # beside the hole: invalid, not blended with 0
    assert smooth.notes["depth_resize"] == "bilinear"
    np.testing.assert_array_equal(resize_depth(np.full((1, 12, 16), 3.0), (6, 8)), 3.0)  # smaller grids: nearest
    with pytest.raises(ValueError, match="one of"):
        resize_depth(slope, (12, 16), "bicubic")


def test_vda_disparity_rule_marks_zero_disparity_invalid():
    disparity = np.array([[[2.0, 0.0], [0.5, -1.0]]] * 2)
    depth = read_video_depth({"depths": disparity}, height=2, width=2, kind="disparity", depth_scale=4.0).depth
    np.testing.assert_array_equal(depth[0], [[2.0, 0.0], [8.0, 0.0]])


def test_vda_reference_compat_divides_by_1000_without_inverting():
    raw = np.full((2, 3, 4), 2500.0)
    depth = read_video_depth({"depths": raw}, height=3, width=4, reference_compat=True)
    np.testing.assert_allclose(depth.depth, 2.5)
    with pytest.raises(ValueError, match="cannot be combined"):
        read_video_depth({"depths": raw}, height=3, width=4, kind="metric", reference_compat=True)


def test_vda_kind_must_be_stated():
    with pytest.raises(ValueError, match="kind='disparity'.*kind='metric'"):
        read_video_depth({"depths": np.ones((2, 3, 4))}, height=3, width=4)


@pytest.mark.parametrize("arrays, words", [
    ({"depth": np.ones((2, 3, 4))}, ["'depths'", "found ['depth']", "--depth-key"]),
    ({"depths": np.ones((3, 4))}, ["shape (T, H, W)", "(3, 4)"]),
])
def test_malformed_vda_output_names_file_and_array(tmp_path, arrays, words):
    path = tmp_path / "x_depths.npz"
    np.savez(path, **arrays)
    with pytest.raises(EstimatorFormatError) as info:
        read_video_depth(path, height=3, width=4, kind="disparity")
    assert str(path) in str(info.value)
    for word in words:
        assert word in str(info.value)


# ----------------------------------------------------------------------------- DELTA


def test_delta_pair_files_round_trip(tmp_path, scene_clip):
    directory = write_delta_pairs(tmp_path / "delta", scene_clip)
    tracks = read_delta(directory)
    assert tracks.frame_names == frame_names(scene_clip)
    np.testing.assert_array_equal(tracks.track_prev, scene_clip.track_prev)
    np.testing.assert_array_equal(tracks.track_curr, scene_clip.track_curr)
    np.testing.assert_array_equal(tracks.track_vis, scene_clip.track_vis)
    np.testing.assert_array_equal(tracks.track_conf, scene_clip.track_conf)


def test_delta_visibility_is_thresholded_except_in_reference_compat(tmp_path, scene_clip):
    directory = write_delta_pairs(tmp_path / "delta", scene_clip)
    raw = read_delta(directory, reference_compat=True).track_vis
    np.testing.assert_allclose(raw, delta_vis(scene_clip.track_vis))  # raw probabilities, all > 0
    assert read_delta(directory, vis_threshold=0.01).track_vis.all()


def test_delta_pairs_follow_frame_names_with_underscores(tmp_path, scene_clip):
    names = [f"frame_{t:03d}" for t in range(scene_clip.n_frames)]
    directory = write_delta_pairs(tmp_path / "delta", scene_clip, names)
    assert read_delta(directory).frame_names == names
    renamed = read_delta(directory, frame_names=[f"{t:05d}" for t in range(4)])  # frames named otherwise
    assert renamed.frame_names == names and "matched in order" in renamed.notes["tracks_layout"]
    np.testing.assert_array_equal(renamed.track_curr, scene_clip.track_curr)


def test_tracks_from_another_resolution_are_rescaled_with_track_size(tmp_path, scene_clip):
    H, W = scene_clip.image_size
    paths = write_all(tmp_path, scene_clip)
    # the same tracks on a grid twice as large (pixel centres: u' = 2 u + 0.5)
    doubled = dataclasses.replace(scene_clip, track_prev=2 * scene_clip.track_prev + 0.5,
                                  track_curr=2 * scene_clip.track_curr + 0.5)
    paths["tracks"] = write_delta_pairs(tmp_path / "delta2x", doubled)
    clip = import_clip(**paths, depth_kind="disparity", track_size=f"{2 * H}x{2 * W}")
    np.testing.assert_allclose(clip.track_prev, scene_clip.track_prev, atol=1e-4)
    np.testing.assert_allclose(clip.track_curr, scene_clip.track_curr, atol=1e-4)
    assert clip.meta["import"]["track_size"] == [2 * H, 2 * W]


def test_an_estimators_per_frame_focal_lengths_become_one_k_unless_kept_and_a_zoom_warns(tmp_path, scene_clip):
    T = scene_clip.n_frames
    K = np.repeat(scene_clip.K[:1].astype(np.float64), T, axis=0)
    K[:, :2, :2] *= np.array([1.0, 1.012, 0.99, 1.006])[:T, None, None]  # 0.8 % RMS over 4 frames
    paths = write_all(tmp_path, dataclasses.replace(scene_clip, K=K.astype(np.float32)))
    shared = import_clip(**paths, depth_kind="disparity")
    with pytest.warns(ClipWarning, match="focal lengths in every frame"):  # kept: the loader's check says so
        kept = import_clip(**paths, depth_kind="disparity", per_frame_intrinsics=True)
    np.testing.assert_allclose(shared.K, np.repeat(np.median(kept.K, axis=0, keepdims=True), T, axis=0), rtol=1e-6)
    assert np.ptp(kept.K[:, 0, 0]) > 0 and "one K for the clip" in shared.meta["import"]["intrinsics"]
    zoom = K.copy()
    zoom[:, :2, :2] *= np.linspace(1.0, 1.2, T)[:, None, None]
    paths = write_all(tmp_path / "zoom", dataclasses.replace(scene_clip, K=zoom.astype(np.float32)))
    with pytest.warns(IntrinsicsWarning, match="--per-frame-intrinsics"):
        import_clip(**paths, depth_kind="disparity")


@pytest.mark.parametrize("damage, words", [
    (lambda d: (d / "00001_00002.npy").unlink(), ["00001_00002.npy", "no such file", "pair 00001 -> 00002"]),
    (lambda d: np.save(d / "00000_00001.npy", np.zeros((2048, 3), np.float32)), ["(N, 4)", "(2048, 3)"]),
    (lambda d: np.save(d / "00000_00001.npy", np.zeros((10, 4), np.float32)), ["2048 rows", "found 10 rows"]),
])
def test_malformed_delta_output_names_the_file(tmp_path, scene_clip, damage, words):
    directory = write_delta_pairs(tmp_path / "delta", scene_clip)
    damage(directory)
    with pytest.raises(EstimatorFormatError) as info:
        read_delta(directory)
    for word in words:
        assert word in str(info.value)


def test_delta_dense_arrays_become_consecutive_pairs(tmp_path):
    rng = np.random.default_rng(0)
    T, N = 4, 50
    coords = rng.uniform(0, 60, (T, N, 2)).astype(np.float32)
    vis = rng.uniform(0, 1, (T, N)).astype(np.float32)
    conf = rng.uniform(0, 1, (T, N)).astype(np.float32)
    for path in (write_delta_dense(tmp_path / "dense_2d_track.pkl", coords, vis, conf), tmp_path / "dense.npz"):
        if path.suffix == ".npz":
            np.savez(path, coords=coords, vis=vis, conf=conf)
        tracks = read_delta(path)
        np.testing.assert_array_equal(tracks.track_prev, coords[:-1])
        np.testing.assert_array_equal(tracks.track_curr, coords[1:])
        np.testing.assert_array_equal(tracks.track_vis, (vis[:-1] > 0.8) & (vis[1:] > 0.8))
        np.testing.assert_array_equal(tracks.track_conf, conf[1:])
        np.testing.assert_array_equal(read_delta(path, reference_compat=True).track_vis, vis[1:])  # raw
    with open(tmp_path / "bad.pkl", "wb") as handle:
        pickle.dump({"coords": coords, "vis": vis[:, :10]}, handle)
    with pytest.raises(EstimatorFormatError, match=r"'vis'.*shape \(4, 50\)"):
        read_delta(tmp_path / "bad.pkl")
    np.savez(tmp_path / "renamed.npz", trajs_uv=coords, vis=vis)
    with pytest.raises(EstimatorFormatError, match=r"renamed\.npz: array 'coords'.*found \['trajs_uv', 'vis'\]"):
        read_delta(tmp_path / "renamed.npz")
    for name, content in (("empty.npz", b""), ("cut.npz", (tmp_path / "renamed.npz").read_bytes()[:100]),
                          ("cut.pkl", (tmp_path / "bad.pkl").read_bytes()[:20])):
        (tmp_path / name).write_bytes(content)
        with pytest.raises(EstimatorFormatError, match=name):  # a broken file is named, never a traceback
            read_delta(tmp_path / name)


def test_delta_dense_tracks_pair_frames_a_step_apart_and_per_pair_files_cannot(tmp_path, scene_clip):
    rng = np.random.default_rng(1)
    T, N = 5, 40
    coords = rng.uniform(0, 60, (T, N, 2)).astype(np.float32)
    vis = rng.uniform(0, 1, (T, N)).astype(np.float32)
    conf = rng.uniform(0, 1, (T, N)).astype(np.float32)
    stepped = every_nth_frame(read_delta({"coords": coords, "vis": vis, "conf": conf}), 2)  # frames 0, 2, 4
    np.testing.assert_array_equal(stepped.track_prev, coords[[0, 2]])
    np.testing.assert_array_equal(stepped.track_curr, coords[[2, 4]])
    np.testing.assert_array_equal(stepped.track_vis, (vis[[0, 2]] > 0.8) & (vis[[2, 4]] > 0.8))
    np.testing.assert_array_equal(stepped.track_conf, conf[[2, 4]])
    with pytest.raises(ValueError, match="needs long-range tracks"):
        every_nth_frame(read_delta(write_delta_pairs(tmp_path / "delta", scene_clip)), 2)


# ----------------------------------------------------------------------------- SegAnyMo


def test_palette_indices_are_read_not_colours(tmp_path):
    """Object 3's palette colour is black, like the background: only its index tells them apart."""
    labels = np.zeros((6, 8), np.uint8)
    labels[1:3, 2:5], labels[4:, 6:], labels[0, 0] = 1, 2, 3
    palette = DAVIS_PALETTE[:9] + [0, 0, 0]
    path = write_palette_png(tmp_path / "00000.png", labels, palette)
    np.testing.assert_array_equal(read_mask_labels(path), labels)
    as_cv2 = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)  # why Pillow: OpenCV returns colours
    assert as_cv2.shape == (6, 8, 3) and as_cv2[0, 0].tolist() == [0, 0, 0]


def test_seganymo_masks_at_their_own_resolution_round_trip(tmp_path, scene_clip):
    H, W = scene_clip.image_size
    directory = write_seganymo(tmp_path / "masks", scene_clip, (2 * H, 2 * W))
    masks = read_seganymo(directory, height=H, width=W, frame_names=frame_names(scene_clip))
    np.testing.assert_array_equal(masks.static_mask, scene_clip.static_mask)
    assert (~scene_clip.static_mask).any()  # the scene has moving objects


def test_moving_masks_grow_by_a_disc_of_the_radius_asked_and_the_import_records_it(tmp_path, scene_clip):
    static = np.ones((1, 21, 21), bool)
    static[0, 10, 10] = False  # one moving pixel
    grown = grow_moving(Masks(static, {"masks": "one pixel"}), 3)
    rows, cols = np.nonzero(~grown.static_mask[0])
    assert ((rows - 10) ** 2 + (cols - 10) ** 2).max() <= 3.5 ** 2  # OpenCV's disc of radius 3 on the pixel grid
    assert not grown.static_mask[0, 10, 13] and not grown.static_mask[0, 7, 10] and grown.static_mask[0, 10, 14]
    assert grow_moving(Masks(None, {"masks": "none"}), 3).static_mask is None
    paths = write_all(tmp_path, scene_clip)
    plain = import_clip(**paths, depth_kind="disparity")
    wider = import_clip(**paths, depth_kind="disparity", mask_grow_px=2)
    assert (~wider.static_mask).sum() > (~plain.static_mask).sum() and not (wider.static_mask & ~plain.static_mask).any()
    assert "grown by 2 px" in wider.meta["import"]["masks"]
    with pytest.raises(ValueError, match="mask_grow_px must be a whole number"):
        import_clip(**paths, depth_kind="disparity", mask_grow_px=-1)
    with pytest.raises(ValueError, match=r"needs masks \(--masks\)"):
        import_clip(**{**paths, "masks": None}, depth_kind="disparity", mask_grow_px=2)


def test_grayscale_masks_warn_and_colour_masks_are_refused(tmp_path):
    labels = np.zeros((6, 8), np.uint8)
    labels[2:4, 2:4] = 255
    cv2.imwrite(str(tmp_path / "gray.png"), labels)
    with pytest.warns(MaskFormatWarning, match=r"gray\.png: a grayscale PNG.*value 0 as static"):
        np.testing.assert_array_equal(read_mask_labels(tmp_path / "gray.png"), labels > 0)
    cv2.imwrite(str(tmp_path / "rgb.png"), np.dstack([labels, labels * 0, labels]))
    with pytest.raises(EstimatorFormatError, match=r"rgb\.png.*'mask'.*palette PNG.*RGB image"):
        read_mask_labels(tmp_path / "rgb.png")


def test_missing_masks_mean_nothing_moves_and_are_reported(tmp_path, scene_clip):
    H, W = scene_clip.image_size
    names = frame_names(scene_clip)
    directory = write_seganymo(tmp_path / "masks", scene_clip, (H, W))
    (directory / f"{names[2]}.png").unlink()
    masks = read_seganymo(directory, height=H, width=W, frame_names=names)
    assert masks.static_mask[2].all() and masks.notes["masks_missing"] == [names[2]]
    assert "nothing moves there" in masks.notes["masks"]
    absent = read_seganymo(None, height=H, width=W, frame_names=names)
    assert absent.static_mask is None and "nothing moves" in absent.notes["masks"]
    with pytest.raises(FileNotFoundError, match="nowhere: no such folder"):  # mistyped: not "nothing moves"
        read_seganymo(tmp_path / "nowhere", height=H, width=W, frame_names=names)
    with pytest.raises(EstimatorFormatError, match=r"expected 4 PNGs, one per frame, found 3 PNGs"):
        read_seganymo(directory, height=H, width=W, n_frames=4)


# ----------------------------------------------------------------------------- frames, assembly


def test_frames_from_a_folder_and_from_a_video(tmp_path, scene_clip):
    frames = read_frames(write_frames(tmp_path / "frames", scene_clip))
    np.testing.assert_array_equal(frames.frames, scene_clip.frames)
    assert frames.names == frame_names(scene_clip)
    path = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 8, (160, 120))
    for frame in scene_clip.frames:
        writer.write(cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
    writer.release()
    video = read_frames(path)
    assert video.frames.shape == scene_clip.frames.shape and video.names == ["00000", "00001", "00002", "00003"]
    assert np.abs(video.frames.astype(int) - scene_clip.frames).mean() < 10  # MJPG is lossy


def test_estimators_that_disagree_on_the_frame_count_are_refused(tmp_path, scene_clip):
    paths = write_all(tmp_path, scene_clip)
    short = synth_clip(seed=2, **{**SCENE, "n_frames": 3})
    paths["depth"] = write_vda(tmp_path / "short_depths.npz", short, short.image_size)
    paths.pop("frames")
    with pytest.raises(ValueError, match=r"disagree on the number of frames.*cameras .*: 4, depth .*short_depths.npz\): 3"):
        import_clip(**paths, depth_kind="disparity")


def test_reference_compat_import_reproduces_the_authors_choices(tmp_path, scene_clip):
    paths = write_all(tmp_path, scene_clip)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the deliberate choices are not warned about
        clip = import_clip(**paths, reference_compat=True)
    np.testing.assert_array_equal(clip.K, np.load(paths["cameras"])["intrinsic"].astype(np.float64))
    raw = np.load(paths["depth"])["depths"]
    np.testing.assert_allclose(clip.depth, raw / 1000.0)
    assert clip.track_vis.all()  # raw DELTA visibility > 0: invisible tracks (0.03) kept
    assert clip.meta["import"]["reference_compat"] is True


def test_round_trip_through_native_formats_scores_like_the_synthetic_clip(tmp_path, scene_clip):
    """VGGT (518 x 392 grid, crop mode), VDA (1.5x), DELTA (per-pair files),
    SegAnyMo (2x palette PNGs) and frames, imported back, score like the clip itself (JAX engine)."""
    H, W = scene_clip.image_size
    paths = write_all(tmp_path, scene_clip, depth_size=(int(1.5 * H), int(1.5 * W)), mask_size=(2 * H, 2 * W),
                      depth_scale=3.0)
    imported = import_clip(**paths, depth_kind="disparity", depth_scale=3.0, clip_id="imported")
    assert imported.meta["import"]["vggt_grid"] == [392, 518]
    result = score_batch([scene_clip, imported], engine="jax")
    original, back = result.clips
    assert original.status == back.status == "ok"
    for name in COMPONENTS:
        assert original.components[name] > 1e-3, name  # far from zero, so 1% means something
        assert back.components[name] == pytest.approx(original.components[name], rel=SCORE_RTOL), name
    assert back.sgc == pytest.approx(original.sgc, rel=SCORE_RTOL)
