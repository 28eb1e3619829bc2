"""Perturbations (SPEC §5): identity at severity 0, determinism, purity, and the targeted arrays
responding monotonically to severity and time. No scoring here (see test_study.py)."""

import dataclasses

import numpy as np
import pytest

from sgc_jax import load_clip, save_clip
from sgc_jax.research.perturb import (
    MASK_CORRUPTIONS,
    PERTURBATIONS,
    WARP_AMPLITUDE_FRAC,
    dilate,
    erode,
    false_negative,
    false_positive,
    morph_radius_px,
    perturb_clip,
    squeeze,
    time_ramp,
)
from sgc_jax.research.synth import synth_clip

KINDS = PERTURBATIONS + MASK_CORRUPTIONS
ARRAYS = ("depth", "K", "R_wc", "t_wc", "static_mask", "track_prev", "track_curr", "track_vis", "track_conf",
          "frames")
SEEDED = ("warp", "depth_warp", "false_positive", "false_negative")  # the others draw nothing


@pytest.fixture(scope="module")
def clip():
    """Small scene with two masked moving spheres (a dynamic mask to corrupt) and frames."""
    return synth_clip(seed=5, clip_id="base", n_frames=5, height=48, width=64, n_tracks=300, n_layers=2,
                      static_spheres=2, moving_objects=2)


@pytest.fixture(scope="module")
def bare_clip():
    """No frames and no masks (mask_source "none")."""
    return synth_clip(seed=6, clip_id="bare", n_frames=3, height=40, width=56, n_tracks=200, n_layers=1,
                      with_frames=False, with_mask=False)


def arrays_equal(a, b, names=ARRAYS):
    return {n: (getattr(a, n) is None and getattr(b, n) is None) or np.array_equal(getattr(a, n), getattr(b, n))
            for n in names}


def changed(a, b):
    return {n for n, same in arrays_equal(a, b).items() if not same}


def track_shift(base, out):
    """(T-1,) mean displacement of track_curr per pair, pixels."""
    return np.linalg.norm(out.track_curr - base.track_curr, axis=-1).mean(axis=1)


# ----------------------------------------------------------------------------- every kind


@pytest.mark.parametrize("kind", KINDS)
def test_severity_zero_is_exact_identity(clip, bare_clip, kind):
    for base in (clip, bare_clip):
        out = perturb_clip(base, kind, 0.0, seed=3)
        assert all(arrays_equal(base, out).values()), changed(base, out)
        assert out.mask_source == base.mask_source
        assert out.clip_id == f"{base.clip_id}~{kind}@0" and out.meta["perturbation"]["base"] == base.clip_id


@pytest.mark.parametrize("kind", KINDS)
def test_input_clip_is_not_modified(clip, kind):
    before = dataclasses.replace(clip, **{n: None if getattr(clip, n) is None else getattr(clip, n).copy()
                                          for n in ARRAYS})
    out = perturb_clip(clip, kind, 1.0, seed=1)
    assert all(arrays_equal(before, clip).values())
    assert changed(clip, out), f"{kind} at severity 1 changed nothing"


@pytest.mark.parametrize("kind", KINDS)
def test_same_seed_same_clip(clip, kind):
    a, b = perturb_clip(clip, kind, 0.7, seed=4), perturb_clip(clip, kind, 0.7, seed=4)
    assert all(arrays_equal(a, b).values())
    other = perturb_clip(clip, kind, 0.7, seed=5)
    assert bool(changed(a, other)) == (kind in SEEDED)


@pytest.mark.parametrize("kind", KINDS)
def test_a_clip_without_frames_or_masks_is_perturbed_without_inventing_them(bare_clip, kind):
    out = perturb_clip(bare_clip, kind, 1.0)
    assert out.frames is None and out.static_mask.shape == bare_clip.static_mask.shape
    # only false-positive noise can create a dynamic region where no mask was given
    assert out.mask_source == ("static_mask" if kind == "false_positive" else "none")


@pytest.mark.parametrize("kind", KINDS)
def test_perturbed_clip_round_trips_through_npz(clip, kind, tmp_path):
    out = perturb_clip(clip, kind, 0.5, seed=2)
    loaded = load_clip(save_clip(tmp_path / "p.npz", out))
    assert loaded.clip_id == out.clip_id and all(arrays_equal(out, loaded).values())
    assert loaded.meta["perturbation"] == {"base": "base", "kind": kind, "severity": 0.5, "seed": 2}


def test_invalid_arguments_raise(clip):
    with pytest.raises(ValueError, match="unknown perturbation"):
        perturb_clip(clip, "shear", 0.5)
    for severity in (-0.1, 1.5, float("nan")):
        with pytest.raises(ValueError, match="severity"):
            perturb_clip(clip, "warp", severity)
    with pytest.raises(TypeError):
        perturb_clip(clip, "warp", 0.5, amplitude=3)  # misspelled magnitude keyword
    with pytest.raises(ValueError, match="seed"):
        perturb_clip(clip, "warp", 0.5, seed=-1)
    for amplitude in (0.2, 0.15):  # 0.15: each component's slope 0.94 < 1, the two together 1.33
        with pytest.raises(ValueError, match="fold"):
            perturb_clip(clip, "depth_warp", 0.5, amplitude_frac=amplitude, wavelength_frac=1.0)


# ----------------------------------------------------------------------------- geometric


def test_time_ramp_is_linear_from_zero_to_severity():
    np.testing.assert_allclose(time_ramp(5, 0.8), [0.0, 0.2, 0.4, 0.6, 0.8])


@pytest.mark.parametrize("kind", PERTURBATIONS)
def test_displacement_grows_with_severity_and_time(clip, kind):
    shifts = np.array([track_shift(clip, perturb_clip(clip, kind, s)) for s in (0.25, 0.5, 0.75, 1.0)])
    assert np.all(np.diff(shifts.mean(axis=1)) > 0), shifts  # with severity
    assert np.all(np.diff(shifts[-1]) > 0), shifts[-1]  # with time: later pairs move more
    out = perturb_clip(clip, kind, 1.0)
    np.testing.assert_array_equal(out.track_prev[0], clip.track_prev[0])  # frame 0 is never moved


def test_warp_moves_tracks_and_frames_but_not_depth_or_masks(clip):
    out = perturb_clip(clip, "warp", 1.0)
    assert changed(clip, out) == {"track_prev", "track_curr", "frames"}
    np.testing.assert_array_equal(out.frames[0], clip.frames[0])
    diag = np.hypot(*clip.image_size)
    assert 0 < np.abs(out.track_curr - clip.track_curr).max() <= WARP_AMPLITUDE_FRAC * diag + 1e-3  # peak


def test_squeeze_compresses_rows_towards_the_principal_point(clip):
    out = squeeze(clip, 1.0, max_compression=0.5)
    assert changed(clip, out) == {"track_prev", "track_curr"}
    np.testing.assert_array_equal(out.track_curr[..., 0], clip.track_curr[..., 0])  # x untouched
    cy = clip.K[-1, 1, 2]
    np.testing.assert_allclose(out.track_curr[-1, :, 1] - cy, 0.5 * (clip.track_curr[-1, :, 1] - cy), atol=1e-4)


def test_depth_warp_moves_depth_with_the_tracks(clip):
    out = perturb_clip(clip, "depth_warp", 1.0)
    assert changed(clip, out) == {"depth", "static_mask", "frames", "track_prev", "track_curr"}
    # nearest-neighbour remap: no depth value is invented
    assert np.isin(out.depth[-1], clip.depth[-1]).all()
    # a moved track reads (nearly always) the depth its original position had: one map for both
    t = clip.n_frames - 1
    H, W = clip.image_size
    src = np.round(clip.track_curr[t - 1]).astype(int)
    dst = np.round(out.track_curr[t - 1]).astype(int)
    inside = ((src >= 0) & (src < [W, H]) & (dst >= 0) & (dst < [W, H])).all(-1) & clip.track_vis[t - 1]
    same = np.isclose(out.depth[t][dst[inside, 1], dst[inside, 0]], clip.depth[t][src[inside, 1], src[inside, 0]],
                      rtol=0.02)
    assert inside.sum() > 100 and same.mean() > 0.9
    moved = np.abs(out.depth[t] - clip.depth[t]) > 1e-6
    assert moved.mean() > 0.02  # depth boundaries have shifted


# ----------------------------------------------------------------------------- masks


def dynamic(c):
    return ~c.static_mask


def test_morphology_radius_scales_with_the_image_diagonal(clip):
    big = dataclasses.replace(clip, depth=np.zeros((clip.n_frames, 96, 128), np.float32))
    assert morph_radius_px(clip, 1.0) == round(0.05 * np.hypot(48, 64)) == 4
    assert morph_radius_px(big, 1.0) == 2 * morph_radius_px(clip, 1.0)
    assert morph_radius_px(clip, 0.0) == 0


def test_erode_and_dilate_are_nested_and_monotone(clip):
    base = dynamic(clip)
    assert base.any()
    eroded = [dynamic(erode(clip, s)) for s in (0.0, 0.5, 1.0)]
    dilated = [dynamic(dilate(clip, s)) for s in (0.0, 0.5, 1.0)]
    for smaller, larger in zip(eroded[1:], eroded[:-1]):
        assert not (smaller & ~larger).any()  # erosion only removes dynamic pixels
    for smaller, larger in zip(dilated[:-1], dilated[1:]):
        assert not (smaller & ~larger).any()
    sizes_e = [m.sum() for m in eroded]
    sizes_d = [m.sum() for m in dilated]
    assert sizes_e[0] > sizes_e[1] > sizes_e[2] and sizes_d[0] < sizes_d[1] < sizes_d[2]


def test_salt_and_pepper_flips_only_the_named_label(clip):
    base = dynamic(clip)
    fractions_fp, fractions_fn = [], []
    for s in (0.25, 0.5, 1.0):
        fp, fn = dynamic(false_positive(clip, s, seed=1)), dynamic(false_negative(clip, s, seed=1))
        assert not (base & ~fp).any() and not (fn & ~base).any()  # FP only adds, FN only removes
        fractions_fp.append((fp & ~base).sum() / (~base).sum())
        fractions_fn.append((base & ~fn).sum() / base.sum())
    # flip probability = severity * 0.5
    np.testing.assert_allclose(fractions_fp, [0.125, 0.25, 0.5], atol=0.02)
    np.testing.assert_allclose(fractions_fn, [0.125, 0.25, 0.5], atol=0.05)
    # the same seed at a higher severity flips a superset of the pixels
    low, high = dynamic(false_positive(clip, 0.25, seed=1)), dynamic(false_positive(clip, 1.0, seed=1))
    assert not (low & ~high).any()


@pytest.mark.parametrize("kind", MASK_CORRUPTIONS)
def test_mask_corruptions_leave_geometry_alone(clip, kind):
    assert changed(clip, perturb_clip(clip, kind, 1.0)) == {"static_mask"}
