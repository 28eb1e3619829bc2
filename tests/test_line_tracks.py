"""Tracks that slide along lines (docs/semantics.md §1.7): the image structure tells a line from a
corner, and leaving the line-like tracks out takes back what sliding along them added to a rigid
scene's score."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sgc_jax import score_batch
from sgc_jax.adapters import LINE_RATIO, leave_out_line_tracks, line_structure

SLIDE_PX = 4.0  # how far the line-like tracks slide: an LK failure of tartan_000080's size (§1.7)


def _image(kind: str) -> np.ndarray:
    image = np.zeros((64, 64), np.float32)
    if kind == "edge":
        image[:, 32:] = 255.0
    elif kind == "corner":
        image[32:, 32:] = 255.0
    return image


@pytest.mark.parametrize("kind, lowest, highest", [("edge", 0.0, 1e-6), ("flat", 0.0, 0.0), ("corner", 0.3, 1.0)])
def test_the_structure_ratio_is_zero_on_an_edge_and_a_uniform_patch_and_high_at_a_corner(kind, lowest, highest):
    ratio, _ = line_structure(_image(kind), np.array([[32.0, 32.0]]))
    assert lowest <= ratio[0] <= highest


def test_the_weak_direction_runs_along_the_edge():
    _, along = line_structure(_image("edge"), np.array([[32.0, 20.0]]))
    np.testing.assert_allclose(np.abs(along[0]), [0.0, 1.0], atol=1e-6)  # a vertical edge: along y


def test_only_the_line_like_tracks_are_left_out(rigid_clip):
    out = leave_out_line_tracks(rigid_clip)
    for pair in range(rigid_clip.n_pairs):
        ratio, _ = line_structure(rigid_clip.frames[pair], rigid_clip.track_prev[pair].astype(np.float64))
        np.testing.assert_array_equal(out.track_vis[pair], rigid_clip.track_vis[pair] & (ratio >= LINE_RATIO))
    left_out = 1.0 - out.track_vis.sum() / rigid_clip.track_vis.sum()
    assert 0.05 < left_out < 0.95  # the scene's stripes and checkers hold both kinds
    np.testing.assert_array_equal(out.track_curr, rigid_clip.track_curr)


def test_leaving_out_the_tracks_that_slid_along_lines_takes_back_what_they_added(rigid_clip):
    slid = rigid_clip.track_curr.copy()
    for pair in range(rigid_clip.n_pairs):
        ratio, along = line_structure(rigid_clip.frames[pair], rigid_clip.track_prev[pair].astype(np.float64))
        line = ratio < LINE_RATIO
        slid[pair][line] += SLIDE_PX * along[line]
    sliding = dataclasses.replace(rigid_clip, clip_id="slid", track_curr=slid)
    rigid, slid, cleaned = score_batch([rigid_clip, sliding, leave_out_line_tracks(sliding)], progress=False).clips
    assert slid.sgc > 0.1 > 10 * rigid.sgc
    # the rigid scene's own score is its clean depth error's (above the calibration's zero), which
    # reads the tracks only through the translation scale s (§3.4)
    assert cleaned.sgc == pytest.approx(rigid.sgc, abs=1e-4)


def test_it_reads_the_frames_and_says_so_without_them(rigid_clip):
    with pytest.raises(ValueError, match="rigid.*frames"):
        leave_out_line_tracks(dataclasses.replace(rigid_clip, frames=None))
    with pytest.raises(ValueError, match="max_ratio"):
        leave_out_line_tracks(rigid_clip, max_ratio=1.5)
