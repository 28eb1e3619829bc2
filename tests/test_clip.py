"""SPEC §2: the clip file, its accepted alternatives, validation errors, batch files."""

import dataclasses
import json
import warnings
import zipfile

import numpy as np
import pytest

from sgc_jax import ClipFormatError, SGCConfig, clip_from_arrays, load_clip, load_clips, save_batch, save_clip
from sgc_jax.io.clip import clip_to_arrays, repeated_tracks
from sgc_jax.io.loading import discover_clips
from sgc_jax.io.validate import ClipWarning
from sgc_jax.research.synth import synth_clip


def tiny_arrays(T=3, H=8, W=10, P=12, seed=0):
    rng = np.random.default_rng(seed)
    return {
        "depth": rng.uniform(1, 5, (T, H, W)).astype(np.float32),
        "K": np.array([[10.0, 0, 4.5], [0, 10.0, 3.5], [0, 0, 1]]),
        "R_wc": np.broadcast_to(np.eye(3), (T, 3, 3)).copy(),
        "t_wc": rng.normal(size=(T, 3)),
        "static_mask": np.ones((T, H, W), bool),
        "track_prev": rng.uniform(0, 7, (T - 1, P, 2)).astype(np.float32),
        "track_curr": rng.uniform(0, 7, (T - 1, P, 2)).astype(np.float32),
        "track_vis": np.ones((T - 1, P), bool),
        "track_conf": rng.uniform(0, 1, (T - 1, P)).astype(np.float32),
        "meta": np.asarray(json.dumps({"clip_id": "tiny", "group": "g1"})),
    }


def test_valid_clip_loads_with_its_metadata():
    clip = clip_from_arrays(tiny_arrays())
    assert clip.clip_id == "tiny" and clip.group == "g1"
    assert clip.K.shape == (3, 3, 3) and clip.mask_source == "static_mask"


def test_arrays_in_fortran_order_load_and_find_repeats_as_in_c_order():
    arrays = tiny_arrays()
    for name in ("track_prev", "track_curr"):
        arrays[name][0, 5] = arrays[name][0, 2]  # one track given twice
    fortran = {name: np.asfortranarray(a) if a.ndim > 1 else a for name, a in arrays.items()}  # a transposed source's
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ClipWarning)
        clip, again = clip_from_arrays(arrays), clip_from_arrays(fortran)
    np.testing.assert_array_equal(again.track_curr, clip.track_curr)
    assert again.warnings == clip.warnings
    found = repeated_tracks(fortran["track_prev"], fortran["track_curr"], fortran["track_vis"])
    assert found.sum() == 1 and found[0, 5]


@pytest.mark.parametrize("name, change, expected", [
    ("depth", lambda a: a.pop("depth"), "no such array"),
    ("depth", lambda a: a.update(depth=a["depth"][0]), "shape (8, 10)"),
    ("depth", lambda a: a.update(depth=a["depth"][:1]), "T = 1"),
    ("K", lambda a: a.update(K=np.eye(4)), "shape (4, 4)"),
    ("K", lambda a: a.update(K=np.full((3, 3), np.nan)), "non-finite"),
    ("R_wc", lambda a: a.update(R_wc=a["R_wc"][:2]), "shape (2, 3, 3)"),
    ("t_wc", lambda a: a["t_wc"].__setitem__((1, 0), np.inf), "1 non-finite value(s) in frames 1 of 3"),
    ("static_mask", lambda a: a.update(static_mask=a["static_mask"][:, :4]), "shape (3, 4, 10)"),
    ("track_prev", lambda a: a.update(track_prev=a["track_prev"][:1]), "shape (1, 12, 2)"),
    ("track_curr", lambda a: a.update(track_curr=a["track_curr"][:, :5]), "shape (2, 5, 2)"),
    ("track_vis", lambda a: a.pop("track_vis"), "no such array"),
    ("track_conf", lambda a: a.update(track_conf=a["track_conf"][:, :3]), "shape (2, 3)"),
])
def test_structural_errors_name_clip_array_and_shapes(name, change, expected):
    arrays = tiny_arrays()
    change(arrays)
    with pytest.raises(ClipFormatError) as info:
        clip_from_arrays(arrays)
    message = str(info.value)
    assert "'tiny'" in message and f"'{name}'" in message and expected in message
    assert info.value.array == name and info.value.clip_id == "tiny"

def every_frames_tracks(a):
    """A long-range tracker's positions of every frame, (T, P, 2), given as both track arrays."""
    tracks = np.concatenate([a["track_prev"][:1], a["track_curr"]])
    a.update(track_prev=tracks, track_curr=tracks)


@pytest.mark.parametrize("name, change, hint", [
    ("track_prev", every_frames_tracks, "track_prev = tracks[:-1], track_curr = tracks[1:]"),
    ("track_prev", lambda a: a.update(track_prev=a["track_prev"].transpose(1, 0, 2)),
     "give np.transpose(track_prev, (1, 0, 2))"),
    ("K", lambda a: a.update(K=np.array([5.0, 5.0, 4.5, 3.5])), "K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]"),
    ("R_wc", lambda a: a.update(R_wc=np.tile([0.0, 0.0, 0.0, 1.0], (3, 1))), "Rotation.from_quat(q).as_matrix()"),
    ("track_vis", lambda a: a.pop("track_vis"), "track_vis = np.ones((2, 12), bool)"),
])
def test_a_shape_that_does_not_fit_is_read_for_what_it_most_likely_holds(name, change, hint):
    arrays = tiny_arrays()
    change(arrays)
    with pytest.raises(ClipFormatError) as info:
        clip_from_arrays(arrays)
    assert info.value.array == name and hint in str(info.value), str(info.value)


def test_extrinsic_dynamic_mask_and_float_visibility_are_accepted_alternatives():
    arrays = tiny_arrays()
    R, t = arrays.pop("R_wc"), arrays.pop("t_wc")
    arrays["extrinsic"] = np.concatenate([R, t[:, :, None]], axis=2)
    dynamic = np.zeros((3, 8, 10), bool)
    dynamic[:, :2] = True
    arrays["dynamic_mask"] = dynamic
    del arrays["static_mask"], arrays["track_conf"]
    arrays["track_vis"] = np.linspace(-1, 1, 24).reshape(2, 12)  # float visibility: > 0 is visible
    clip = clip_from_arrays(arrays)
    np.testing.assert_array_equal(clip.t_wc, t)
    assert clip.mask_source == "dynamic_mask" and not clip.static_mask[:, :2].any()
    assert (clip.track_conf == 1).all() and clip.track_vis.sum() == 12


def test_a_float_mask_is_true_above_even_odds_and_other_numbers_where_non_zero():
    arrays = tiny_arrays()
    static = arrays.pop("static_mask")
    static[:, :2] = False  # a mover over the top rows
    as_bool = clip_from_arrays(dict(arrays, static_mask=static)).static_mask
    for stored in ({"static_mask": np.where(static, 0.98, 0.03)},  # a network's probabilities
                   {"dynamic_mask": np.where(static, 0.02, 0.97).astype(np.float32)},
                   {"dynamic_mask": np.where(static, -4.0, 4.0)},  # logits
                   {"static_mask": 255 * static.astype(np.uint8)}, {"dynamic_mask": 3 * (~static).astype(np.int32)}):
        np.testing.assert_array_equal(clip_from_arrays(dict(arrays, **stored)).static_mask, as_bool)


def test_missing_mask_means_whole_frame_static_and_says_so():
    arrays = tiny_arrays()
    del arrays["static_mask"]
    clip = clip_from_arrays(arrays)
    assert clip.static_mask.all() and clip.mask_source == "none"


def test_clip_id_defaults_to_file_name(tmp_path):
    arrays = tiny_arrays()
    del arrays["meta"]
    np.savez(tmp_path / "my_clip.npz", **arrays)
    assert load_clip(tmp_path / "my_clip.npz").clip_id == "my_clip"


def test_subsampling_is_deterministic_and_keeps_usable_tracks_first():
    arrays = tiny_arrays(P=50)
    config = SGCConfig(max_tracks=8)
    a, b = clip_from_arrays(arrays, config=config), clip_from_arrays(arrays, config=config)
    assert a.n_tracks == 8
    np.testing.assert_array_equal(a.track_prev, b.track_prev)
    usable = arrays["track_conf"] >= 0.5
    for pair in range(2):  # every pair has more than 8 usable tracks: all kept tracks are usable
        assert usable[pair].sum() > 8
        assert (a.track_conf[pair] >= 0.5).all()
        kept_rows = [np.flatnonzero((arrays["track_prev"][pair] == p).all(1))[0] for p in a.track_prev[pair]]
        assert kept_rows == sorted(kept_rows)


def test_clip_file_round_trip(tmp_path):
    clip = clip_from_arrays(tiny_arrays())
    loaded = load_clip(save_clip(tmp_path / "c.npz", clip))
    for name, value in clip_to_arrays(clip).items():
        if name != "meta":
            np.testing.assert_array_equal(value, clip_to_arrays(loaded)[name])
    assert loaded.meta == clip.meta
    with pytest.raises(TypeError, match=r"save_clip\(path, clip\): the path comes first; got Clip"):
        save_clip(clip, tmp_path / "d.npz")
    with pytest.raises(TypeError, match=r"save_batch\(path, clips\): the path comes first; got list"):
        save_batch([clip], tmp_path / "e.npz")


def test_a_clip_file_stores_float_depth_deflate_cannot_halve_and_deflates_the_rest(tmp_path):
    arrays = tiny_arrays(T=4, H=128, W=640)  # depth uniform in [1, 5): ~0.85 of its size deflated
    arrays["K"] = np.array([[500.0, 0, 320], [0, 500.0, 64], [0, 0, 1]])
    arrays["track_prev"] *= [90, 18]  # spread over the image, as the content checks expect
    arrays["frames"] = np.random.default_rng(1).integers(0, 256, (4, 128, 640, 3), dtype=np.uint8)
    clip = clip_from_arrays(arrays)
    quantised = dataclasses.replace(clip, depth=np.round(clip.depth * 2) / 2)  # a sensor's steps
    written = save_clip(tmp_path / "a.npz", clip)
    with zipfile.ZipFile(written) as archive:
        kinds = {info.filename: info.compress_type for info in archive.infolist()}
    assert kinds["depth.npy"] == zipfile.ZIP_STORED and kinds["static_mask.npy"] == zipfile.ZIP_DEFLATED
    assert kinds["frames.npy"] == zipfile.ZIP_DEFLATED  # not read when scoring: deflated whatever it saves
    with zipfile.ZipFile(save_clip(tmp_path / "q.npz", quantised)) as archive:
        assert archive.getinfo("depth.npy").compress_type == zipfile.ZIP_DEFLATED
    with np.load(written) as data:  # numpy reads it; the same arrays give the same bytes
        np.testing.assert_array_equal(data["depth"], clip.depth)
    assert save_clip(tmp_path / "b.npz", clip).read_bytes() == written.read_bytes()
    assert save_clip(tmp_path / "c", clip) == tmp_path / "c.npz"  # the suffix added, as np.savez adds it


def test_batch_file_round_trip_with_mixed_sizes(tmp_path):
    small = clip_from_arrays(tiny_arrays(T=3, H=8, W=10, P=12), clip_id="small")
    arrays = tiny_arrays(T=5, H=9, W=12, P=20, seed=1)
    del arrays["static_mask"]
    big = clip_from_arrays(arrays, clip_id="big")
    path = save_batch(tmp_path / "batch.npz", [small, big])
    entries = discover_clips(path)
    assert [e.clip_id for e in entries] == ["small", "big"]
    loaded = list(load_clips(path))
    for original, back in zip((small, big), loaded):
        assert back.depth.shape == original.depth.shape and back.n_tracks == original.n_tracks
        np.testing.assert_array_equal(back.track_curr, original.track_curr)
        assert back.mask_source == original.mask_source
    with np.load(path) as data:
        assert list(data["n_frames"]) == [3, 5] and list(data["n_tracks"]) == [12, 20]


def test_sources_directories_globs_and_mappings(tmp_path):
    for i in range(3):
        save_clip(tmp_path / f"c{i}.npz", clip_from_arrays(tiny_arrays(seed=i), clip_id=f"c{i}"))
    assert len(discover_clips(tmp_path)) == 3
    assert len(discover_clips(str(tmp_path / "c[01].npz"))) == 2
    assert len(discover_clips([tiny_arrays(), tmp_path / "c2.npz"])) == 2
    with pytest.raises(FileNotFoundError, match="nothing_here"):
        discover_clips(tmp_path / "nothing_here")


def test_a_clip_repr_is_one_short_line():
    clip = synth_clip(seed=0, clip_id="a", group="g", n_frames=3, height=24, width=32, n_tracks=64)
    assert repr(clip) == "Clip('a', group 'g': 3 frames, 24x32, 64 tracks per pair, masks from static_mask, with frames)"
