"""docs/semantics.md §1.4: bad input is a ClipFormatError naming clip, array and expectation,
raised before any engine runs; it never stops a directory and never changes the other clips' scores."""

import dataclasses
import io
import pickle
import struct
import tempfile
import warnings
import zipfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st
from scenes import MICRO

from sgc_jax import ClipFormatError, batch_of, load_clips, save_batch, save_clip, score_batch
from sgc_jax.io.clip import clip_to_arrays
from sgc_jax.io.loading import discover_clips, validate_paths
from sgc_jax.io.npz import NpzError, read_npz
from sgc_jax.research.synth import synth_clip

# Tiny scenes: loading takes milliseconds and the reference engine scores one in ~0.3 s.
TINY = MICRO
VICTIM = synth_clip(seed=0, clip_id="victim", **TINY)
PARTNER = synth_clip(seed=1, clip_id="partner", **TINY)
CONTROLS = [synth_clip(seed=10 + i, clip_id=f"ctrl{i}", **TINY) for i in range(2)]
SINGLE = clip_to_arrays(VICTIM)


def batch_arrays() -> dict[str, np.ndarray]:
    with tempfile.TemporaryDirectory() as folder:
        path = save_batch(Path(folder) / "b.npz", [VICTIM, PARTNER])
        with np.load(path) as data:
            return {k: data[k] for k in data.files}


BATCH = batch_arrays()


def npz_bytes(arrays: dict, compressed: bool = False) -> bytes:
    """The archive np.savez writes; object arrays are pickled into it, as an attacker's file would be."""
    buffer = io.BytesIO()
    (np.savez_compressed if compressed else np.savez)(buffer, **arrays)
    return buffer.getvalue()


@pytest.fixture()
def no_unpickling(monkeypatch):
    """Fail the test if anything is unpickled while it runs."""
    calls = []

    def refuse(*args, **kwargs):
        calls.append(args)
        raise AssertionError("something was unpickled")

    monkeypatch.setattr(pickle, "load", refuse)
    monkeypatch.setattr(pickle, "loads", refuse)
    yield calls
    assert not calls


def load_error(source) -> ClipFormatError:
    """The ClipFormatError loading ``source`` raises (any other exception fails the test)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(ClipFormatError) as info:
            list(load_clips(source))
    return info.value


# ----------------------------------------------------------------------------- malformed arrays, one kind each


def changed(**changes):
    def change(arrays):
        arrays = dict(arrays)
        for name, value in changes.items():
            if value is None:
                arrays.pop(name)
            else:
                arrays[name] = value(arrays[name]) if callable(value) else value
        return arrays
    return change


def singular_K(K):
    K = K.copy()
    K[:, 2, 2] = 0
    return K


def structured(a):
    out = np.zeros(a.shape, dtype=[("v", "f8")])
    out["v"] = a
    return out


FRAMES_T1 = {name: (lambda a: a[:1]) for name in ("depth", "K", "R_wc", "t_wc", "static_mask")}
TRACKS_P0 = {name: (lambda a: a[:, :0]) for name in ("track_prev", "track_curr", "track_vis", "track_conf")}
IMAGES = ("depth", "static_mask")

ARRAY_KINDS = {  # kind: (change, array blamed, words of the message)
    "missing_array": (changed(track_vis=None), "track_vis", "no such array"),
    "channel_axis_depth": (changed(depth=lambda a: a[:, None]), "depth", "give depth.squeeze(1)"),
    "channel_axis_mask": (changed(static_mask=lambda a: a[..., None]), "static_mask", "give static_mask.squeeze(3)"),
    "one_K_with_a_leading_axis": (changed(K=lambda a: a[:1]), "K", "give K[0]"),
    "tracks_of_the_whole_video": (lambda arrays: changed(track_prev=None, track_curr=None)(dict(
        arrays, tracks=np.concatenate([arrays["track_prev"][:1], arrays["track_curr"]]))),
        "track_prev", "track_prev = tracks[:-1], track_curr = tracks[1:]"),
    "object_array": (changed(depth=lambda a: a.astype(object)), "depth", "nothing is unpickled"),
    "string_array": (changed(track_vis=lambda a: a.astype(str)), "track_vis", "dtype <U"),
    "string_depth": (changed(depth=lambda a: a.astype(str)), "depth", "dtype <U"),
    "bytes_array": (changed(track_conf=lambda a: a.astype("S8")), "track_conf", "dtype |S8"),
    "complex_depth": (changed(depth=lambda a: a + 1j), "depth", "dtype complex"),
    "complex_tracks": (changed(track_curr=lambda a: a + 0j), "track_curr", "dtype complex"),
    "bool_depth": (changed(depth=lambda a: a > 5), "depth", "dtype bool"),
    "structured_dtype": (changed(K=structured), "K", "structured dtype"),
    "zero_height": (changed(**{n: (lambda a: a[:, :0]) for n in IMAGES}), "depth", "H >= 1"),
    "zero_width": (changed(**{n: (lambda a: a[:, :, :0]) for n in IMAGES}), "depth", "W >= 1"),
    "one_frame": (changed(**FRAMES_T1, **{n: (lambda a: a[:0]) for n in TRACKS_P0}), "depth", "T = 1"),
    "zero_tracks": (changed(**TRACKS_P0), "track_prev", "P >= 1"),
    "depth_wrong_length": (changed(depth=lambda a: np.concatenate([a, a[:1]])), "depth", "shape (3, 24, 32)"),
    "depth_wrong_size": (changed(depth=lambda a: a[:, :20]), "depth", "shape (3, 24, 32)"),
    "mask_wrong_size": (changed(static_mask=lambda a: a[:, :20]), "static_mask", "shape (3, 24, 32)"),
    "singular_K": (changed(K=singular_K), "K", "singular"),
    "non_finite_K": (changed(K=lambda a: a * np.nan), "K", "finite"),
    "transposed_K": (changed(K=lambda a: np.swapaxes(a, -1, -2)), "K", "looks transposed"),
    "K_scaled_as_a_whole": (changed(K=lambda a: 2.0 * a), "K", "K[2, 2] is not 1"),
    "wrong_rank": (changed(track_prev=lambda a: a[..., 0]), "track_prev", "shape (2, 64)"),
    "scalar_array": (changed(t_wc=np.float64(1.0)), "t_wc", "shape ()"),
}


@pytest.mark.parametrize("kind", sorted(ARRAY_KINDS))
def test_each_malformed_array_is_a_format_error_naming_clip_and_array(tmp_path, no_unpickling, kind):
    change, array, words = ARRAY_KINDS[kind]
    path = tmp_path / "victim.npz"
    path.write_bytes(npz_bytes(change(SINGLE)))
    error = load_error(path)
    assert (error.clip_id, error.array) == ("victim", array), str(error)
    assert words in str(error)


def test_arrays_given_in_memory_are_checked_the_same_way():
    ragged = dict(SINGLE, track_conf=[[0.5] * 64, [0.5] * 3])
    assert load_error(ragged).array == "track_conf"
    text = dict(SINGLE, depth=[["1.0", "x"]])
    assert load_error(text).array == "depth" and "dtype <U" in str(load_error(text))


def _reflected(R):
    R = R.copy()
    R[1] = R[1] @ np.diag([1.0, 1.0, -1.0])
    return R


@pytest.mark.parametrize("array, changed", [
    ("t_wc", lambda c: dataclasses.replace(c, t_wc=np.where(np.arange(c.n_frames)[:, None] == 1, np.nan, c.t_wc))),
    ("R_wc", lambda c: dataclasses.replace(c, R_wc=_reflected(c.R_wc))),
    ("K", lambda c: dataclasses.replace(c, K=c.K * np.array([0.0, 1.0, 1.0])[:, None])),
    ("K", lambda c: dataclasses.replace(c, K=np.swapaxes(c.K, 1, 2))),
])
def test_clips_given_in_memory_have_their_cameras_checked(array, changed):
    broken = dataclasses.replace(changed(VICTIM), clip_id="broken")
    result = score_batch([broken, CONTROLS[0]], engine="reference", progress=False)
    assert result.clips[0].status == "error" and f"array {array!r}" in result.clips[0].reason
    assert result.clips[1].status != "error"


@pytest.mark.parametrize("array, changed", [
    ("track_vis", lambda c: dataclasses.replace(c, track_vis=c.track_vis[:, :-1])),
    ("track_curr", lambda c: dataclasses.replace(c, track_curr=c.track_curr[..., :1])),
    ("static_mask", lambda c: dataclasses.replace(c, static_mask=c.static_mask[:, 1:])),
    ("track_prev", lambda c: dataclasses.replace(c, track_prev=None)),
])
def test_clips_given_in_memory_have_their_arrays_checked(array, changed):
    broken = dataclasses.replace(changed(VICTIM), clip_id="broken")
    result = score_batch([broken, CONTROLS[0]], engine="reference", progress=False)
    assert result.clips[0].status == "error" and f"array {array!r}" in result.clips[0].reason
    assert result.clips[1].status != "error"
    with pytest.raises(ClipFormatError, match=array):
        batch_of([broken])


@pytest.mark.parametrize("array, expected, changed", [
    ("K", "positive focal lengths", lambda c: dataclasses.replace(c, K=c.K * np.array([-1.0, 1.0, 1.0])[:, None])),
    ("K", "focal lengths within", lambda c: dataclasses.replace(c, K=c.K / np.array([c.image_size[1], c.image_size[0],
                                                                                      1.0])[:, None])),
    ("track_prev/track_curr", "positions inside", lambda c: dataclasses.replace(c, track_prev=2 * c.track_prev + 40,
                                                                                 track_curr=2 * c.track_curr + 40)),
])
def test_clips_given_in_memory_fail_on_cameras_or_tracks_of_another_grid_as_their_files_do(tmp_path, array, expected,
                                                                                           changed):
    broken = dataclasses.replace(changed(VICTIM), clip_id="broken")
    in_memory = score_batch([broken, CONTROLS[0]], engine="reference", progress=False)
    from_file = score_batch([save_clip(tmp_path / "broken.npz", broken)], engine="reference", progress=False)
    assert in_memory.clips[0].status == from_file.clips[0].status == "error"
    assert in_memory.clips[0].reason == from_file.clips[0].reason
    assert f"array {array!r}" in in_memory.clips[0].reason and expected in in_memory.clips[0].reason
    assert in_memory.clips[1].status != "error"
    with pytest.raises(ClipFormatError, match=expected):
        batch_of([broken])


def test_a_clip_given_in_memory_without_confidences_scores_as_one_with_confidence_one():
    without = dataclasses.replace(VICTIM, track_conf=None, clip_id="without")
    ones = dataclasses.replace(VICTIM, track_conf=np.ones_like(VICTIM.track_conf), clip_id="ones")
    result = score_batch([without, ones], engine="reference", progress=False)
    assert result.clips[0].status == result.clips[1].status != "error"
    assert result.clips[0].sgc == result.clips[1].sgc
    np.testing.assert_array_equal(batch_of([without])["track_conf"], batch_of([ones])["track_conf"])


# ----------------------------------------------------------------------------- broken files


def member_data_offset(data: bytes, name: str) -> tuple[int, int]:
    """(offset, size) of member ``name``'s stored bytes in a zip archive."""
    with zipfile.ZipFile(io.BytesIO(data)) as archive:
        info = archive.getinfo(name)
    name_len, extra_len = struct.unpack("<HH", data[info.header_offset + 26:info.header_offset + 30])
    return info.header_offset + 30 + name_len + extra_len, info.compress_size


def flip(data: bytes, offset: int) -> bytes:
    return data[:offset] + bytes([data[offset] ^ 0xFF]) + data[offset + 1:]


def bad_crc(_):
    data = npz_bytes(SINGLE)
    start, size = member_data_offset(data, "depth.npy")
    return flip(data, start + size // 2)  # inside the array data: the header still reads, the CRC fails


def corrupt_deflate(_):
    data = npz_bytes(SINGLE, compressed=True)
    start, _ = member_data_offset(data, "depth.npy")
    return data[:start] + bytes([0b111]) + data[start + 1:]  # a final block of the reserved type 3: zlib refuses it


def huge_header(_):
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, {"descr": "<f4", "fortran_order": False,
                                                   "shape": (10**6, 10**6, 10**3)})  # 4 petabytes
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        for name, value in SINGLE.items():
            if name == "depth":
                archive.writestr("depth.npy", header.getvalue() + bytes(64))
            else:
                member = io.BytesIO()
                np.lib.format.write_array(member, np.asarray(value))
                archive.writestr(f"{name}.npy", member.getvalue())
    return buffer.getvalue()


def size_lie(_):
    data = npz_bytes(SINGLE, compressed=True)
    central = data.index(b"PK\x01\x02")  # the central directory entries: signature, fields, then the name at 46
    while data[central + 46:central + 46 + 9] != b"depth.npy":
        central = data.index(b"PK\x01\x02", central + 4)
    return data[:central + 24] + struct.pack("<I", 0xFFFFFFF0) + data[central + 28:]  # uncompressed size: 4 GB


def npy_file(_):
    buffer = io.BytesIO()
    np.save(buffer, SINGLE["depth"])
    return buffer.getvalue()


FILE_KINDS = {  # kind: (bytes of the file, array blamed, words of the message)
    "not_a_zip": (lambda _: b"clip_id,sgc\nvictim,0.1\n", "<file>", "not a zip file"),
    "empty_file": (lambda _: b"", "<file>", "not a zip file"),
    "npy_not_npz": (npy_file, "<file>", "not a zip file"),
    "truncated": (lambda _: npz_bytes(SINGLE)[:9000], "<file>", "BadZipFile"),
    "bad_crc": (bad_crc, "depth", "Bad CRC-32"),
    "corrupt_deflate": (corrupt_deflate, "depth", "invalid block type"),
    "huge_header": (huge_header, "depth", "a header claiming shape (1000000, 1000000, 1000)"),
    "size_lie": (size_lie, "depth", "a member recorded as 4294967280 bytes"),
}


@pytest.mark.parametrize("kind", sorted(FILE_KINDS))
def test_each_broken_file_is_a_format_error_naming_the_path(tmp_path, no_unpickling, kind):
    write, array, words = FILE_KINDS[kind]
    path = tmp_path / "victim.npz"
    path.write_bytes(write(None))
    error = load_error(path)
    assert error.array == array and words in str(error) and str(path) in str(error), str(error)


def test_stored_and_deflated_members_read_as_numpy_reads_them(tmp_path):
    rng = np.random.default_rng(0)
    arrays = {"c_order": rng.normal(size=(3, 5, 7)).astype(np.float32), "f_order": np.asfortranarray(
        rng.integers(0, 9, (4, 6))), "flags": rng.random((2, 3)) > 0.5, "scalar": np.float64(2.5),
        "empty": np.zeros((0, 3), np.float32), "text": np.asarray("a clip")}
    for compressed in (False, True):
        path = tmp_path / f"m{compressed}.npz"
        path.write_bytes(npz_bytes(arrays, compressed))
        read = read_npz(path)
        for name, value in arrays.items():
            assert read[name].dtype == np.asarray(value).dtype and np.array_equal(read[name], value), name
    data = npz_bytes(arrays)
    start, size = member_data_offset(data, "c_order.npy")
    path.write_bytes(data[:start + size - 8] + data[start + size:])  # the member's data cut short, the index kept
    with pytest.raises(NpzError, match="c_order"):
        read_npz(path)


@pytest.mark.parametrize("kind", ["dangling_link", "link_loop", "directory_named_npz"])
def test_paths_that_lead_nowhere_are_format_errors(tmp_path, kind):
    path = tmp_path / "victim.npz"
    if kind == "dangling_link":
        path.symlink_to(tmp_path / "gone.npz")
    elif kind == "link_loop":
        path.symlink_to(path)
    else:
        path.mkdir()
    # a directory named *.npz is a directory when named itself or matched by a glob: only its parent lists it as a file
    sources = (tmp_path,) if kind == "directory_named_npz" else (path, tmp_path, str(tmp_path / "*.npz"))
    for source in sources:
        entries = discover_clips(source)  # listing never raises for a bad file
        assert [e.clip_id for e in entries] == ["victim"]
        error = load_error(source)
        assert error.array == "<file>" and str(path) in str(error)
    words = "IsADirectoryError" if kind == "directory_named_npz" else "a link that leads nowhere"
    assert words in str(error)


# ----------------------------------------------------------------------------- batch files

# kind: (change, member that fails (None: the whole file; a tuple: each of them), array blamed, words of the
# message)
BATCH_KINDS = {
    "clip_id_shorter": (changed(clip_id=lambda a: a[:1]), None, "clip_id", "a (2,) array of text"),
    "clip_id_longer": (changed(clip_id=lambda a: np.append(a, "extra")), None, "clip_id", "found shape (3)"),
    "n_frames_more_members": (changed(n_frames=lambda a: np.append(a, 3)), None, "n_frames", "a (2,) array"),
    "n_tracks_more_members": (changed(n_tracks=lambda a: np.append(a, 64)), None, "n_tracks", "a (2,) array"),
    "n_frames_float": (changed(n_frames=lambda a: a.astype(float)), None, "n_frames", "of integers"),
    "n_tracks_missing": (changed(n_tracks=None), None, "n_tracks", "no such array"),
    "members_disagree": (changed(depth=lambda a: np.concatenate([a, a[:1]])), None, "depth", "B = 2"),
    "n_frames_beyond_padded": (changed(n_frames=lambda a: a + [0, 1]), 1, "n_frames", "at most the 3 frames"),
    "n_frames_negative": (changed(n_frames=lambda a: a * [-1, 1]), 0, "n_frames", "n_frames[0] = -3"),
    "n_tracks_beyond_stored": (changed(n_tracks=lambda a: a + [0, 1]), 1, "n_tracks", "at most the 64 tracks"),
    "n_tracks_negative": (changed(n_tracks=lambda a: a * [1, -1]), 1, "n_tracks", "n_tracks[1] = -64"),
    "n_tracks_zero": (changed(n_tracks=lambda a: a * [0, 1]), 0, "n_tracks", "n_tracks[0] >= 1"),
    "heights_beyond_padded": (changed(heights=lambda a: a + [5, 0]), 0, "heights", "at most the 24 rows"),
    "widths_zero": (changed(widths=lambda a: a * [1, 0]), 1, "widths", "widths[1] >= 1"),
    "K_one_text_per_member": (changed(K=lambda a: np.array(["fx", "fy"])), (0, 1), "K", "real numbers"),
}


@pytest.mark.parametrize("kind", sorted(BATCH_KINDS))
def test_batch_bookkeeping_is_checked_against_the_stored_arrays(tmp_path, no_unpickling, kind):
    change, member, array, words = BATCH_KINDS[kind]
    path = tmp_path / "batch.npz"
    path.write_bytes(npz_bytes(change(BATCH)))
    entries = discover_clips(path)
    outcomes = []
    for entry in entries:
        try:
            outcomes.append(entry.load())
        except ClipFormatError as exc:
            outcomes.append(exc)
    errors = [o for o in outcomes if isinstance(o, ClipFormatError)]
    if isinstance(member, tuple):  # every member: one error each, naming it
        assert [e.clip_id for e in errors] == ["victim", "partner"], outcomes
        assert all(e.array == array and words in str(e) for e in errors), outcomes
        return
    assert len(errors) == 1 and errors[0].array == array and words in str(errors[0]), outcomes
    if member is None:  # the file as a whole: one error, named after the file
        assert [e.clip_id for e in entries] == ["batch"] and errors[0].clip_id == "batch"
    else:  # one member: the other still loads, unchanged
        assert isinstance(outcomes[member], ClipFormatError) and errors[0].clip_id == ("victim", "partner")[member]
        other = outcomes[1 - member]
        np.testing.assert_array_equal(other.depth, (VICTIM, PARTNER)[1 - member].depth)


# ----------------------------------------------------------------------------- duplicate ids


def test_of_clip_files_sharing_an_id_the_first_that_loads_is_scored(tmp_path):
    save_clip(tmp_path / "a.npz", dataclasses.replace(VICTIM, K=singular_K(VICTIM.K)))  # broken: claims nothing
    save_clip(tmp_path / "b.npz", VICTIM)
    save_clip(tmp_path / "c.npz", VICTIM)
    save_batch(tmp_path / "d.npz", [VICTIM, PARTNER])
    result = score_batch(tmp_path, engine="reference", progress=False)
    status = [(c.origin.replace(f"{tmp_path}/", ""), c.status != "error") for c in result.clips]
    assert status == [("a.npz", False), ("b.npz", True), ("c.npz", False), ("d.npz[0]", False), ("d.npz[1]", True)]
    assert "'K'" in result.clips[0].reason
    for duplicate in (result.clips[2], result.clips[3]):
        assert "'clip_id'" in duplicate.reason and f"duplicate: first seen in {tmp_path / 'b.npz'}" in duplicate.reason
    reports = validate_paths([tmp_path])
    assert [[p.code for p in r.problems if p.severity == "error"] for r in reports] == [
        ["structure"], [], ["duplicate_clip_id"], ["duplicate_clip_id"], []]


def test_clips_given_in_memory_may_share_an_id(tmp_path):
    save_clip(tmp_path / "a.npz", VICTIM)
    clips = list(load_clips([tmp_path / "a.npz", VICTIM, VICTIM]))
    assert [c.clip_id for c in clips] == ["victim"] * 3


def test_the_same_file_listed_twice_is_a_duplicate(tmp_path):
    path = save_clip(tmp_path / "a.npz", VICTIM)
    assert "duplicate" in str(load_error([path, path]))


# ----------------------------------------------------------------------------- a run goes on


def scores(result):
    """What a clip's row says, except its origin: status, reason, sgc, components, per-pair arrays."""
    return {c.clip_id: (c.status, c.reason, c.sgc, c.components, c.reproj_error, c.ecd_trans, c.ecd_rot,
                        c.scale, c.depth_unit, dataclasses.asdict(c.pairs) if c.pairs is not None else None)
            for c in result.clips}


@pytest.fixture(scope="module")
def control_scores():
    return scores(score_batch(CONTROLS, engine="reference", progress=False))


def write_controls(folder: Path) -> None:
    for clip in CONTROLS:
        save_clip(folder / f"a_{clip.clip_id}.npz", clip)


def write_every_broken_kind(folder: Path) -> int:
    """One file per malformed kind above (b_ arrays, c_ files, d_ batches, e_ links); returns how many."""
    for kind, (change, _, _) in ARRAY_KINDS.items():
        (folder / f"b_{kind}.npz").write_bytes(npz_bytes(change(dict(SINGLE, meta=np.asarray(f'{{"clip_id": "{kind}"}}')))))
    for kind, (write, _, _) in FILE_KINDS.items():
        (folder / f"c_{kind}.npz").write_bytes(write(None))
    one_error = {kind: change for kind, (change, member, _, _) in BATCH_KINDS.items() if not isinstance(member, tuple)}
    for kind, change in one_error.items():  # one error row per file, so a batch's sound member is scored
        ids = np.array([f"{kind}0", f"{kind}1"])
        (folder / f"d_{kind}.npz").write_bytes(npz_bytes(change(dict(BATCH, clip_id=ids))))
    (folder / "e_dangling.npz").symlink_to(folder / "gone.npz")
    (folder / "e_loop.npz").symlink_to(folder / "e_loop.npz")
    return len(ARRAY_KINDS) + len(FILE_KINDS) + len(one_error) + 2


def test_a_directory_of_every_broken_kind_scores_its_controls_unchanged(tmp_path, control_scores, no_unpickling):
    write_controls(tmp_path)
    n_broken = write_every_broken_kind(tmp_path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = score_batch(tmp_path, engine="reference", progress=False)
    by_file: dict[str, list] = {}
    for clip in result.clips:
        by_file.setdefault(Path(clip.origin.split("[")[0]).name, []).append(clip)
    np.testing.assert_equal({k: v for k, v in scores(result).items() if k.startswith("ctrl")}, control_scores)
    broken = [name for name in by_file if not name.startswith("a_")]
    assert len(broken) == n_broken
    for name in broken:  # one error row per broken file; a batch's sound member is scored
        errors = [c for c in by_file[name] if c.status == "error"]
        assert len(errors) == 1, (name, [c.reason for c in by_file[name]])
    reports = validate_paths([tmp_path])
    assert sum(not r.ok for r in reports) == len(broken)


def test_an_engine_exception_is_not_disguised_as_bad_input(tmp_path, monkeypatch):
    from sgc_jax.engines import reference

    def broken_engine(clip, config):
        raise RuntimeError("a bug in the engine")

    monkeypatch.setattr(reference, "score_pairs", broken_engine)
    with pytest.raises(RuntimeError, match="a bug in the engine"):
        score_batch(CONTROLS, engine="reference", progress=False)


# ----------------------------------------------------------------------------- fuzz

TYPES = (object, str, "S4", np.complex128, bool, np.float16, np.int8, np.uint64)
EXTREMES = (1e30, -1e30, np.nan, np.inf, -np.inf, 0.0, -1.0, 1e300, 3.4e38)


class Broken:
    """A broken file's bytes, shown by the steps that made it (hypothesis prints failing examples)."""

    def __init__(self, data: bytes, steps: list[str]):
        self.data, self.steps = data, steps

    def __repr__(self) -> str:
        return f"Broken({'; '.join(self.steps)})"


@st.composite
def broken_files(draw) -> Broken:
    """A clip or batch file with one to three arrays dropped, cut, grown, reshaped, retyped or set to
    extreme values (batch bookkeeping included), possibly also with flipped bytes or cut short."""
    batch = draw(st.booleans())
    arrays, steps = dict(BATCH if batch else SINGLE), ["batch" if batch else "clip"]
    for _ in range(draw(st.integers(1, 3))):
        name = draw(st.sampled_from(sorted(arrays)))
        a = np.asarray(arrays[name])
        kind = draw(st.sampled_from(("drop", "cut", "grow", "reshape", "retype", "extreme", "scalar", "count")))
        axis = draw(st.integers(0, max(a.ndim - 1, 0)))
        steps.append(f"{kind} {name} axis {axis}")
        if kind == "drop":
            del arrays[name]
            continue
        if kind == "cut" and a.ndim:
            a = np.take(a, range(draw(st.integers(0, a.shape[axis]))), axis=axis)
        elif kind == "grow" and a.ndim and a.shape[axis]:
            a = np.concatenate([a, np.take(a, range(draw(st.integers(1, 2))), axis=axis, mode="wrap")], axis=axis)
        elif kind == "reshape":
            a = draw(st.sampled_from((a.reshape(-1), a[None], a.T, a[..., None])))
        elif kind == "retype":
            try:
                with warnings.catch_warnings(), np.errstate(all="ignore"):
                    warnings.simplefilter("ignore")
                    a = a.astype(draw(st.sampled_from(TYPES)))
            except (ValueError, TypeError):  # e.g. text that is no number
                pass
        elif kind == "extreme" and a.size and a.dtype.kind in "biuf":
            a = a.astype(np.float64)
            flat = a.reshape(-1)
            index = draw(st.lists(st.integers(0, a.size - 1), min_size=1, max_size=8))
            flat[index] = draw(st.sampled_from(EXTREMES))
            if draw(st.booleans()):  # a fifth of the array, not only a few entries
                flat[::5] = draw(st.sampled_from(EXTREMES))
        elif kind == "scalar":
            a = np.asarray(draw(st.sampled_from((0, -1, 2, 1e30, "x"))))
        elif kind == "count":  # bookkeeping-like integers, for any array
            a = np.asarray(draw(st.lists(st.integers(-3, 70), max_size=4)), dtype=np.int64)
        steps[-1] += f" -> {a.dtype}{a.shape}"
        arrays[name] = a
    compressed = draw(st.booleans())
    data = npz_bytes(arrays, compressed=compressed)
    damage = draw(st.sampled_from(("none", "none", "flip", "truncate")))
    if damage == "flip":
        offsets = draw(st.lists(st.integers(0, len(data) - 1), min_size=1, max_size=6))
        for offset in offsets:
            data = flip(data, offset)
        steps.append(f"flip bytes {offsets}")
    elif damage == "truncate":
        data = data[:draw(st.integers(0, len(data) - 1))]
        steps.append(f"truncate to {len(data)} bytes")
    steps.append("compressed" if compressed else "stored")
    return Broken(data, steps)


def load_everything(path: Path) -> list:
    """Each clip of ``path`` loaded, or its ClipFormatError; validate_paths must not raise either."""
    outcomes = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for entry in discover_clips(path):
            try:
                outcomes.append(entry.load())
            except ClipFormatError as exc:
                assert exc.clip_id and exc.array and exc.expected and exc.found, str(exc)
                outcomes.append(exc)
        validate_paths([path])
    return outcomes


@given(data=broken_files())
@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
def test_fuzzed_files_load_or_raise_only_format_errors_and_unpickle_nothing(data, no_unpickling):
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "victim.npz"
        path.write_bytes(data.data)
        assert load_everything(path)


@given(files=st.lists(broken_files(), min_size=1, max_size=3))
@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
def test_fuzzed_files_never_change_the_controls_scores(files, control_scores, no_unpickling):
    with tempfile.TemporaryDirectory() as folder, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        folder = Path(folder)
        write_controls(folder)
        for i, data in enumerate(files):
            (folder / f"b_broken{i}.npz").write_bytes(data.data)
        result = score_batch(folder, engine="reference", progress=False)
    rows = scores(result)
    np.testing.assert_equal({k: rows[k] for k in control_scores}, control_scores)
    origins = {Path(c.origin.split("[")[0]).name for c in result.clips}
    assert origins == {f"a_{c.clip_id}.npz" for c in CONTROLS} | {f"b_broken{i}.npz" for i in range(len(files))}


# ----------------------------------------------------------------------------- absurd values

def test_positions_beyond_one_image_size_outside_are_out_of_reach():
    from sgc_jax.io.clip import within_reach

    H, W = 24, 32
    inside = np.array([[-W, -H], [2 * W, 2 * H], [0.5, 0.5], [-1.0, 30.0]])
    outside = np.array([[-W - 0.01, 0], [0, 2 * H + 0.01], [1e30, 1.0], [np.nan, 1.0], [np.inf, 0.0]])
    assert within_reach(inside, H, W).all() and not within_reach(outside, H, W).any()


def test_depth_a_million_times_off_the_median_is_invalid():
    from sgc_jax.io.clip import DEPTH_RATIO_LIMIT, without_absurd_depth

    depth = np.full((2, 4, 4), 5.0, np.float32)
    depth[0, 0, :3] = (1e30, 5.0 * DEPTH_RATIO_LIMIT * 1.01, 5.0 / DEPTH_RATIO_LIMIT / 1.01)
    depth[0, 1, 0] = 5.0 * DEPTH_RATIO_LIMIT * 0.99  # far but not absurd
    kept = without_absurd_depth(depth)
    assert np.isnan(kept[0, 0, :3]).all() and np.isfinite(np.delete(kept.ravel(), [0, 1, 2])).all()
    assert without_absurd_depth(np.full((2, 4, 4), 5.0, np.float32)).dtype == np.float32


@pytest.mark.parametrize("engine", ["jax", "reference"])
def test_absurd_values_score_as_if_those_points_were_missing(rigid_clip, engine):
    """20% of track_curr at 1e30 and 20% of the depth at 1e30 score exactly as hidden tracks and
    invalid depth do, in both engines."""
    rng = np.random.default_rng(0)
    hit = rng.random(rigid_clip.track_vis.shape) < 0.2
    far = rng.random(rigid_clip.depth.shape) < 0.2
    absurd_tracks = dataclasses.replace(rigid_clip, clip_id="tracks_1e30",
                                        track_curr=np.where(hit[..., None], np.float32(1e30), rigid_clip.track_curr))
    hidden_tracks = dataclasses.replace(rigid_clip, clip_id="tracks_hidden", track_vis=rigid_clip.track_vis & ~hit)
    absurd_depth = dataclasses.replace(rigid_clip, clip_id="depth_1e30",
                                       depth=np.where(far, np.float32(1e30), rigid_clip.depth))
    missing_depth = dataclasses.replace(rigid_clip, clip_id="depth_nan",
                                        depth=np.where(far, np.float32(np.nan), rigid_clip.depth))
    result = scores(score_batch([absurd_tracks, hidden_tracks, absurd_depth, missing_depth],
                                engine=engine, progress=False))
    (absurd_t, *_), (hidden_t, *_) = result["tracks_1e30"], result["tracks_hidden"]
    assert absurd_t == hidden_t == "ok"
    np.testing.assert_equal(result["tracks_1e30"], result["tracks_hidden"])
    np.testing.assert_equal(result["depth_1e30"], result["depth_nan"])


def _stored_with_broken_frames(path: Path, arrays: dict) -> Path:
    """``arrays`` as an uncompressed .npz whose ``frames`` data (not its header) is damaged."""
    np.savez(path, **arrays)
    with zipfile.ZipFile(path) as archive:
        info = archive.getinfo("frames.npy")
    with open(path, "r+b") as f:
        f.seek(info.header_offset + 26)
        name_length, extra_length = struct.unpack("<HH", f.read(4))
        f.seek(info.header_offset + 30 + name_length + extra_length + info.compress_size - 1)  # its last byte
        last = f.read(1)
        f.seek(-1, 1)
        f.write(bytes([last[0] ^ 0xFF]))
    return path


def test_scoring_a_file_reads_the_headers_of_plot_arrays_not_their_data(tmp_path):
    framed = synth_clip(seed=0, clip_id="framed", **{**TINY, "with_frames": True})
    path = _stored_with_broken_frames(tmp_path / "framed.npz", clip_to_arrays(framed))
    (entry,) = discover_clips([path])
    with pytest.raises(ClipFormatError) as loading:  # loading reads every array
        entry.read_clip()
    assert loading.value.array == "frames"
    scored = entry.read_clip(for_scoring=True)
    assert scored.frames is None
    np.testing.assert_array_equal(scored.depth, framed.depth)
    (result,) = score_batch([path], engine="reference", progress=False).clips
    assert result.status != "error" and np.isfinite(result.sgc)


def test_scoring_a_file_still_checks_the_shape_of_plot_arrays(tmp_path):
    framed = synth_clip(seed=0, clip_id="framed", **{**TINY, "with_frames": True})
    arrays = clip_to_arrays(framed)
    arrays["frames"] = np.zeros(arrays["frames"].shape[:2] + (arrays["frames"].shape[2] + 1, 3), np.uint8)
    np.savez_compressed(tmp_path / "wide.npz", **arrays)
    (entry,) = discover_clips([tmp_path / "wide.npz"])
    with pytest.raises(ClipFormatError) as scoring:
        entry.read_clip(for_scoring=True)
    assert scoring.value.array == "frames"
