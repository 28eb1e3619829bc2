"""Padding and bucketing (issue 3): padded frames, tracks and pixels are marked invalid and never
change a clip's numbers; clips of one bucket share one compiled executable."""

import dataclasses

import numpy as np

from sgc_jax import COMPONENTS, SGCConfig
from sgc_jax.engines import jax_engine


def test_padding_to_a_larger_bucket_does_not_change_the_score(noisy_clip, monkeypatch):
    # Noisy clip with 30% outliers: RANSAC's sampling must not depend on the padded track count.
    config = SGCConfig()
    natural = jax_engine.bucket_for(noisy_clip)
    larger = jax_engine.Bucket(T=natural.T + 4, H=natural.H + 64, W=natural.W + 64, P=2 * natural.P)
    [as_is] = jax_engine.score_pairs_batch([noisy_clip], config)
    monkeypatch.setattr(jax_engine, "bucket_for", lambda clip: larger)
    [padded] = jax_engine.score_pairs_batch([noisy_clip], config)
    assert list(padded.reason) == list(as_is.reason)
    np.testing.assert_array_equal(padded.n_tracks, as_is.n_tracks)
    np.testing.assert_array_equal(padded.n_regions, as_is.n_regions)
    np.testing.assert_array_equal(padded.region_status, as_is.region_status)
    for k in COMPONENTS:  # float32 reductions over longer padded axes reorder sums
        np.testing.assert_allclose(getattr(padded, k), getattr(as_is, k), rtol=1e-4, atol=1e-7, err_msg=k)


def test_a_second_batch_of_the_same_bucket_does_not_recompile(rigid_clip, drift_clip):
    config = SGCConfig()
    scorer = jax_engine.compiled_scorer(config)
    other = dataclasses.replace(drift_clip, clip_id="other")
    assert jax_engine.bucket_for(rigid_clip) == jax_engine.bucket_for(other)
    jax_engine.score_pairs_batch([rigid_clip, drift_clip], config)
    compiled = scorer._cache_size()  # executables so far (this bucket, and others of the session)
    assert compiled >= 1
    jax_engine.score_pairs_batch([other, rigid_clip], config)
    assert scorer._cache_size() == compiled


def test_clip_batches_take_few_sizes_and_keep_every_clip_once():
    sizes = set()
    for n in range(1, 40):
        groups = jax_engine.clip_groups(list(range(n)))
        assert [i for g in groups for i in g] == list(range(n))
        sizes.update(len(g) for g in groups)
    assert sizes == {1, 2, 4, jax_engine.MAX_CLIP_BATCH}
