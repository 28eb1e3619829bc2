"""The Scorer (docs/semantics.md §9): score_batch's numbers for clips in memory, the same whatever
batch a clip sits in, inside a user's jit too; a status for every degenerate clip, and a reward
that ranks the clips the calibration scores 0 and pays nothing for a still camera."""

import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scenes import DEMO_BATCH_SHAPE, DEMO_SCENE, SMALL_SCENE
from tolerances import LM_SETTLE_RTOL

from sgc_jax import COMPONENTS, ClipFormatError, EvidenceLevels, RewardOptions, Scorer, SGCConfig, score_batch
from sgc_jax.adapters import leave_out_depth_ramps
from sgc_jax.calibration import DEFAULT_CALIBRATION, Calibration
from sgc_jax.codes import SCORER_STATUS_CODE
from sgc_jax.engines.jax_engine import device_prepare
from sgc_jax.io.arrays import subsample_tracks
from sgc_jax.io.clip import repeated_tracks, without_absurd_depth
from sgc_jax.io.tables import EVIDENCE_COLUMNS, FLOOR_COLUMNS, INTERVAL_COLUMNS
from sgc_jax.research.agreement import agreement_corpus
from sgc_jax.research.noise import enlarged_depth
from sgc_jax.research.synth import demo_corpus, synth_clip
from sgc_jax.scoring.result import camera_dynamics
from sgc_jax.scoring.reward import reward
from sgc_jax.scoring.scorer import batch_of
from sgc_jax.stats import exact_median

# The Scorer's per-pair arrays are score_batch's, bit for bit; its per-clip means over at most T-1
# pairs and the score formula run in float32 where the tables use float64: a few float32 roundings
# (2^-24 ~ 6e-8 each) of values of order 1-100.
CLIP_RTOL, CLIP_ATOL = 1e-5, 1e-6
# Inside a user's jit the steps fuse into one program that rounds differently: two roundings of one
# fit may settle LM_SETTLE_RTOL apart in the pose.
FUSED_RTOL, FUSED_ATOL = 2 * LM_SETTLE_RTOL, 1e-5
# The interval's bounds are percentiles of resampled excesses over the floors' band: a component near
# its band changes its excess by its own relative change times the component, not the excess, so
# the bounds of a clip scoring ~0.01 move by up to ~1e-4 in score units (measured 6e-5 on an Intel
# Xeon box, 4e-5 under XLA's older emitters on an AMD one).
FUSED_INTERVAL_ATOL = 1e-4
PER_CLIP = ("sgc", "sgc_lo", "sgc_hi", *COMPONENTS, *FLOOR_COLUMNS, "sgc_floor", "reproj_error", "ecd_trans",
            "ecd_rot", "sgc_unclipped", "camera_motion", "reward", "status", "n_pairs", "n_pairs_scored", "n_ill_conditioned",
            "depth_unit", *EVIDENCE_COLUMNS)
SHAPE = DEMO_BATCH_SHAPE


@pytest.fixture(scope="module")
def corpus():
    return demo_corpus()


@pytest.fixture(scope="module")
def scorer():
    return Scorer(SHAPE)


@pytest.fixture(scope="module")
def three():
    """A batch of 3: on CPU lanes it runs the programs of ``scorer``'s calls (the last call filled
    with a copy), so the suite compiles no other."""
    return Scorer((3, *SHAPE[1:]))


@pytest.fixture(scope="module")
def expected(corpus):
    return score_batch(corpus, progress=False)


def outputs(scorer, clips, shape=None) -> dict[str, np.ndarray]:
    return {k: np.asarray(v) for k, v in scorer(batch_of(clips, shape)).items()}


def test_scorer_gives_score_batchs_numbers_on_the_demo_corpus(scorer, corpus, expected):
    for start in range(0, len(corpus), SHAPE[0]):
        out = outputs(scorer, corpus[start:start + SHAPE[0]])
        rows = expected.clips[start:start + SHAPE[0]]
        for name in ("sgc", "sgc_lo", "sgc_hi", *COMPONENTS, *FLOOR_COLUMNS, "sgc_floor", "reproj_error",
                     "ecd_trans", "ecd_rot", *EVIDENCE_COLUMNS):
            want = [r.components[name] if name in COMPONENTS else r.floors[name] if name in FLOOR_COLUMNS
                    else getattr(r, name) for r in rows]
            np.testing.assert_allclose(out[name], want, rtol=CLIP_RTOL, atol=CLIP_ATOL, err_msg=name)
        np.testing.assert_allclose(out["ecd"], camera_dynamics([r.ecd_trans for r in rows], [r.ecd_rot for r in rows]),
                                   rtol=CLIP_RTOL, atol=CLIP_ATOL)
        np.testing.assert_array_equal(out["n_pairs_scored"], [r.n_pairs_scored for r in rows])
        np.testing.assert_array_equal(out["n_ill_conditioned"], [r.n_ill_conditioned for r in rows])
        np.testing.assert_allclose(out["depth_unit"], [r.depth_unit for r in rows], rtol=1e-7)
        assert [s in (SCORER_STATUS_CODE[r.status], SCORER_STATUS_CODE["static_camera"])
                for s, r in zip(out["status"], rows)] == [True] * len(rows)


# On one CPU (a process of its own that sees only the CPU, whatever this one runs on): score_batch,
# then a Scorer of the same bucket; the stage programs held before and after the Scorer.
ONE_CPU = """
import json
from sgc_jax import Scorer, score_batch
from sgc_jax.engines.jax_engine import programs
from sgc_jax.research.synth import demo_corpus
from sgc_jax.scoring.scorer import batch_of
clips = demo_corpus()[:2]
rows = score_batch(clips, progress=False).clips
held = programs.compile_count()
out = Scorer((2, *{shape!r}))(batch_of(clips))
print(json.dumps(dict(held=held, after=programs.compile_count(), scorer=out["sgc"].tolist(), batch=[r.sgc for r in rows])))
"""


def test_on_one_cpu_the_scorer_runs_score_batchs_stage_programs():
    """docs/semantics.md §9.3: its calls' clips one after another through score_batch's one-clip
    programs, so a Scorer of a bucket score_batch has compiled compiles no stage of its own."""
    env = {**os.environ, "JAX_PLATFORMS": "cpu"}
    done = subprocess.run([sys.executable, "-c", ONE_CPU.format(shape=SHAPE[1:])], capture_output=True, text=True,
                          env=env, timeout=900)
    assert done.returncode == 0, done.stderr
    got = json.loads(done.stdout.strip().splitlines()[-1])
    assert got["held"] > 0 and got["after"] == got["held"]
    np.testing.assert_allclose(got["scorer"], got["batch"], rtol=CLIP_RTOL, atol=CLIP_ATOL)


def test_the_tables_rewards_are_the_scorers(scorer, corpus, expected):
    """``BatchResult.rewards`` runs the Scorer's reward in float64 on the tables' columns."""
    host = expected.rewards()
    for start in range(0, len(corpus), SHAPE[0]):
        out = outputs(scorer, corpus[start:start + SHAPE[0]])
        part = slice(start, start + SHAPE[0])
        for name in ("reward", "sgc_unclipped", "camera_motion"):
            np.testing.assert_allclose(out[name], host[name][part], rtol=CLIP_RTOL, atol=CLIP_ATOL, err_msg=name)
        np.testing.assert_array_equal(out["status"], host["status"][part])


def test_evidence_levels_set_in_reward_options_reach_the_tables_rewards_too(corpus, expected):
    """A Scorer's levels move its evidence, status and reward; ``rewards`` with the same levels
    recomputes them from the clips' pairs (docs/semantics.md §3.11)."""
    options = RewardOptions(evidence=EvidenceLevels(full_tracks=4000.0))  # more than any demo pair holds
    out = outputs(Scorer(SHAPE, reward_options=options), corpus[:SHAPE[0]])
    host = expected.rewards(options)
    assert np.all(out["evidence"] < 0.5) and np.all(out["reward"] < 0.5 * expected.rewards()["reward"][:SHAPE[0]])
    np.testing.assert_allclose(out["reward"], host["reward"][:SHAPE[0]], rtol=CLIP_RTOL, atol=CLIP_ATOL)
    np.testing.assert_array_equal(out["status"], host["status"][:SHAPE[0]])


def test_scorer_gives_score_batchs_numbers_on_the_agreement_corpus(scorer):
    """Its clips of the demo corpus's image size and track count, 4 frames padded to the Scorer's 8:
    score_batch scores them in a bucket of 4 frames, whose sums round differently (the fused
    tolerance: the optimum's settling)."""
    clips = [c for c in agreement_corpus() if c.depth.shape[1:] == (SMALL_SCENE["height"], SMALL_SCENE["width"])]
    want = score_batch(clips, progress=False).clips
    out = {}
    for start in range(0, len(clips), SHAPE[0]):
        part = clips[start:start + SHAPE[0]]
        for name, values in outputs(scorer, part + part[-1:] * (SHAPE[0] - len(part)), SHAPE[1:]).items():
            out.setdefault(name, []).extend(values[:len(part)])
    assert len(clips) == 15 and len(out["sgc"]) == len(clips)
    for i, (clip, row) in enumerate(zip(clips, want)):
        np.testing.assert_allclose(out["sgc"][i], row.sgc, rtol=FUSED_RTOL, atol=FUSED_ATOL, err_msg=clip.clip_id)
        for name in COMPONENTS:
            np.testing.assert_allclose(out[name][i], row.components[name], rtol=FUSED_RTOL, atol=FUSED_ATOL,
                                       err_msg=f"{clip.clip_id} {name}")
        assert out["n_pairs_scored"][i] == row.n_pairs_scored


def test_a_clips_outputs_do_not_depend_on_its_place_or_neighbours_in_the_batch(scorer, corpus):
    a, b, c, d = corpus[0], corpus[3], corpus[5], corpus[7]
    forward, backward, alone = outputs(scorer, [a, b, c, d]), outputs(scorer, [d, c, b, a]), outputs(scorer, [a] * 4)
    for name in PER_CLIP:
        np.testing.assert_array_equal(forward[name], backward[name][::-1], err_msg=name)
        np.testing.assert_array_equal(alone[name], np.repeat(forward[name][0], 4), err_msg=name)


def test_a_clips_outputs_do_not_depend_on_the_batch_size(scorer, three, corpus):
    four, odd = outputs(scorer, corpus[4:8]), outputs(three, corpus[5:8])
    for name in PER_CLIP:
        np.testing.assert_array_equal(odd[name], four[name][1:], err_msg=name)


def test_the_scorer_runs_inside_a_users_jit(three, corpus):
    batch = batch_of(corpus[5:8])
    inside = jax.jit(lambda b: three(b))(batch)
    outside = three(batch)
    for name in PER_CLIP:
        atol = FUSED_INTERVAL_ATOL if name in INTERVAL_COLUMNS else FUSED_ATOL
        np.testing.assert_allclose(np.asarray(inside[name]), np.asarray(outside[name]), rtol=FUSED_RTOL,
                                   atol=atol, err_msg=name)


def test_a_smaller_clip_padded_into_the_batch_scores_as_itself(scorer, corpus):
    """7 of 8 frames and 1000 of 1024 tracks: the same shape bucket, so score_batch's numbers."""
    short = dataclasses.replace(corpus[1], depth=corpus[1].depth[:7], K=corpus[1].K[:7], R_wc=corpus[1].R_wc[:7],
                                t_wc=corpus[1].t_wc[:7], static_mask=corpus[1].static_mask[:7],
                                track_prev=corpus[1].track_prev[:6, :1000], track_curr=corpus[1].track_curr[:6, :1000],
                                track_vis=corpus[1].track_vis[:6, :1000], track_conf=corpus[1].track_conf[:6, :1000],
                                frames=None)
    want = score_batch([short], progress=False).clips[0]
    out = outputs(scorer, [short, *corpus[:3]])
    assert out["n_pairs"][0] == 6
    np.testing.assert_allclose(out["sgc"][0], want.sgc, rtol=CLIP_RTOL, atol=CLIP_ATOL)
    for name in COMPONENTS:
        np.testing.assert_allclose(out[name][0], want.components[name], rtol=CLIP_RTOL, atol=CLIP_ATOL, err_msg=name)


# The accelerator form (docs/semantics.md §9.3) on two forced host devices, in a process of its own:
# the Scorer's batch of 3 filled to 4 and split over both, and score_batch's group path on the same
# clips, both vectorized (which shares their stage programs).
ACCELERATOR_FORM = """
import json, sys
sys.path.insert(0, {tests!r})
import jax
from scenes import DEMO_SCENE
from sgc_jax import Scorer, SGCConfig
from sgc_jax.engines.jax_engine import dispatch
from sgc_jax.research.synth import demo_corpus
from sgc_jax.scoring.result import summarize_clip
from sgc_jax.scoring.scorer import batch_of
from sgc_jax.calibration import Calibration, default_calibration
clips, config, devices = demo_corpus()[{first}:{first} + 3], SGCConfig(), jax.local_devices()
scorer = Scorer((3, *{shape!r}), devices=devices, vectorized=True)
out = scorer(batch_of(clips))
group = dispatch.dispatch_group([dispatch.prepare_clip(c, config) for c in clips], config, devices, 4, vectorized=True)
calibration = Calibration.load(default_calibration(config.compat))
rows = [summarize_clip(c.clip_id, pairs, calibration) for c, pairs in zip(clips, dispatch.collect(group, config))]
print(json.dumps(dict(devices=len(devices), scorer={{k: out[k].tolist() for k in ("sgc", "local_rot_var", "status")}},
                      grouped=[r.sgc for r in rows])))
"""


def test_vectorized_programs_over_two_devices_give_the_numbers_of_one(expected):
    first = 4
    code = ACCELERATOR_FORM.format(tests=str(Path(__file__).parent), first=first, shape=SHAPE[1:])
    env = {**os.environ, "XLA_FLAGS": os.environ.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=2"}
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=900)
    assert done.returncode == 0, done.stderr
    assert "2 clips at once on each of 2 devices" in done.stderr
    got = json.loads(done.stdout.strip().splitlines()[-1])
    rows = expected.clips[first:first + 3]
    assert got["devices"] == 2
    np.testing.assert_allclose(got["scorer"]["sgc"], [r.sgc for r in rows], rtol=FUSED_RTOL, atol=FUSED_ATOL)
    np.testing.assert_allclose(got["scorer"]["local_rot_var"], [r.components["local_rot_var"] for r in rows],
                               rtol=FUSED_RTOL, atol=FUSED_ATOL)
    assert [s in (SCORER_STATUS_CODE[r.status], SCORER_STATUS_CODE["static_camera"])
            for s, r in zip(got["scorer"]["status"], rows)] == [True] * 3
    np.testing.assert_allclose(got["grouped"], [r.sgc for r in rows], rtol=FUSED_RTOL, atol=FUSED_ATOL)


def test_degenerate_clips_get_a_status_and_never_the_best_reward(scorer, corpus):
    rigid = corpus[0]
    no_tracks = dataclasses.replace(rigid, track_vis=np.zeros_like(rigid.track_vis))
    all_dynamic = dataclasses.replace(rigid, static_mask=np.zeros_like(rigid.static_mask))
    still = synth_clip(seed=3, **{**DEMO_SCENE, "rot_deg_per_frame": 0.0, "trans_per_frame": 0.0})
    out = outputs(scorer, [rigid, no_tracks, all_dynamic, still])
    assert list(out["status"]) == [SCORER_STATUS_CODE[s] for s in ("ok", "no_tracks", "no_static", "static_camera")]
    assert out["reward"][0] > 0 and out["reward"][0] == out["reward"].max()
    assert out["reward"][1] == out["reward"][2] == 0.0
    assert out["camera_motion"][3] < 0.05 and out["reward"][3] < 0.05 * out["reward"][0]
    assert not np.isnan(out["reward"]).any()


def test_the_reward_ranks_clips_the_calibration_scores_zero(scorer, corpus):
    by_id = {c.clip_id: c for c in corpus}
    out = outputs(scorer, [by_id[name] for name in ("moving-masked", "noisy-mild", "drift-0.05", "drift-0.20")])
    assert out["sgc"][0] == out["sgc"][1] == 0.0  # a tie in the score ...
    assert out["sgc_unclipped"][0] != out["sgc_unclipped"][1] and out["reward"][0] != out["reward"][1]  # ... not here
    assert out["reward"][3] < out["reward"][2] < min(out["reward"][:2])
    order = np.argsort(out["sgc_unclipped"])
    assert np.all(np.diff(out["reward"][order]) < 0)  # higher reward, lower unclipped score


def test_the_depth_error_counts_again_in_the_reward_only_above_its_zero():
    """§9.4: reward = σ(−(sgc_unclipped + a · M''_depth) / τ) · evidence, M''_depth >= 0."""
    calibration = Calibration.load(DEFAULT_CALIBRATION["spec"])
    zero = calibration.mu["depth_error"] + calibration.z_min["depth_error"] * calibration.sigma["depth_error"]
    span = (calibration.z_max["depth_error"] - calibration.z_min["depth_error"]) * calibration.sigma["depth_error"]
    depth = np.array([zero - 0.2, zero + 0.5 * span])  # below the zero; M''_depth 0.5
    summary = {k: np.zeros(2) for k in (*COMPONENTS, *FLOOR_COLUMNS)} | dict(
        depth_error=depth, ecd_trans=np.full(2, 3.0), ecd_rot=np.full(2, 1.0), evidence=np.ones(2),
        status=np.full(2, SCORER_STATUS_CODE["ok"], np.int32))
    weighted = reward(summary, calibration, RewardOptions(), xp=np)
    plain = reward(summary, calibration, RewardOptions(depth_weight=0.0), xp=np)
    assert weighted["reward"][0] == plain["reward"][0]  # below the zero: no bonus
    s = plain["sgc_unclipped"][1]
    expected = 1 / (1 + np.exp((s + 0.2 * 0.5) / 0.25))
    np.testing.assert_allclose(weighted["reward"][1], expected, rtol=4 * np.finfo(np.float32).eps)  # a float32 output
    assert weighted["reward"][1] < plain["reward"][1]


def test_a_wrong_shape_or_dtype_raises_clip_format_error_at_the_call(scorer, corpus):
    batch = batch_of(corpus[:4])
    with pytest.raises(ClipFormatError, match="'depth'.*shape \\(4, 8, 96, 128\\)"):
        scorer({**batch, "depth": batch["depth"][:, :, :90]})
    with pytest.raises(ClipFormatError, match="'track_prev'.*float"):
        scorer({**batch, "track_prev": batch["track_prev"].astype(np.int32)})
    with pytest.raises(ClipFormatError, match="'K'.*no such array"):
        scorer({k: v for k, v in batch.items() if k != "K"})


def test_float_visibility_and_masks_are_read_as_the_loader_reads_them(scorer, corpus):
    batch = batch_of(corpus[:4])
    logits = np.where(batch["track_vis"], 3.0, -2.0).astype(np.float32)  # hidden below 0, as the loader reads
    probabilities = np.where(batch["static_mask"], 0.98, 0.03).astype(np.float32)  # static above 0.5
    read = scorer.clip_arrays({**batch, "track_vis": logits, "static_mask": probabilities})
    assert np.array_equal(np.asarray(read.track_vis), batch["track_vis"])
    assert np.array_equal(np.asarray(read.static_mask), batch["static_mask"])
    ids = scorer.clip_arrays({**batch, "static_mask": 7 * batch["static_mask"].astype(np.uint8)})  # any non-zero
    assert np.array_equal(np.asarray(ids.static_mask), batch["static_mask"])


def test_batch_of_pads_to_a_shape_and_names_a_clip_that_does_not_fit(corpus):
    batch = batch_of(corpus[:2], shape=(8, 100, 130, 1100))
    assert batch["depth"].shape == (2, 8, 100, 130) and batch["track_prev"].shape == (2, 7, 1100, 2)
    assert list(batch["heights"]) == [96, 96] and list(batch["n_tracks"]) == [1024, 1024]
    with pytest.raises(ClipFormatError, match=f"{corpus[0].clip_id}.*at most the batch shape"):
        batch_of(corpus[:1], shape=(8, 64, 128, 1024))
    with pytest.raises(ValueError, match="at least one clip"):
        batch_of([])


# ----------------------------------------------------------------------------- the host's preparation on the device


def test_device_depth_units_divide_as_float64_then_float32():
    rng = np.random.default_rng(0)
    x = rng.uniform(0.1, 50, 20000).astype(np.float32)
    a, b = np.float32(3.7), np.float32(3.7000003)  # their mean is no float32
    unit = (np.float64(a) + np.float64(b)) / 2
    want = (x.astype(np.float64) / unit).astype(np.float32)
    total, error = device_prepare.two_sum(jnp.float32(a), jnp.float32(b))
    got = jax.jit(device_prepare.divide_rounded)(jnp.asarray(x), (0.5 * total, 0.5 * error))
    np.testing.assert_array_equal(np.asarray(got), want)


def test_device_median_and_absurd_depth_match_the_hosts():
    rng = np.random.default_rng(1)
    depth = rng.uniform(1, 10, (3, 8, 10)).astype(np.float32)
    depth[0, 0, :3] = [1e9, 1e-8, np.nan]
    depth[1, 2, 4] = -1.0
    positive = np.isfinite(depth) & (depth > 0)
    hi, lo = jax.jit(device_prepare.masked_median)(jnp.asarray(depth), jnp.asarray(positive))
    assert np.float64(hi) + np.float64(lo) == exact_median(depth[positive].copy())
    valid = jax.jit(device_prepare.valid_without_absurd_depth)(jnp.asarray(depth), jnp.asarray(positive))
    host = without_absurd_depth(depth)
    np.testing.assert_array_equal(np.asarray(valid), np.isfinite(host) & (host > 0))


def test_device_repeated_tracks_match_the_hosts():
    rng = np.random.default_rng(2)
    prev = rng.uniform(0, 50, (3, 40, 2)).astype(np.float32)
    curr = (prev + rng.normal(0, 1, prev.shape)).astype(np.float32)
    usable = np.ones((3, 40), bool)
    expected = np.zeros((3, 40), bool)
    for later in (5, 9, 30):  # pair 1: three copies of track 2, each later one a repeat
        prev[0, later], curr[0, later] = prev[0, 2], curr[0, 2]
        expected[0, later] = True
    prev[1, 3], prev[1, 7] = (0.0, 4.0), (-0.0, 4.0)  # pair 2: -0.0 == 0.0
    curr[1, 7] = curr[1, 3]
    expected[1, 7] = True
    prev[2, 4], curr[2, 4] = prev[2, 1], np.nextafter(curr[2, 1], np.float32(np.inf))  # pair 3: one float32 step
    prev[2, 6], curr[2, 6] = prev[2, 0], curr[2, 0]  # an unusable copy is no earlier track, nor a repeat
    usable[2, 0] = False
    host = repeated_tracks(prev, curr, usable)
    np.testing.assert_array_equal(host, expected)
    device = jax.jit(jax.vmap(device_prepare.repeated_tracks))(jnp.asarray(prev), jnp.asarray(curr), jnp.asarray(usable))
    np.testing.assert_array_equal(np.asarray(device), host)
    # the cheap check that lets a batch skip the sort by coordinates: never False where one repeats
    may_hold = jax.jit(jax.vmap(device_prepare.may_hold_repeats))
    assert list(may_hold(prev[:, None], curr[:, None], usable[:, None])) == [True, True, False]


def test_a_track_given_again_counts_once_in_both_paths(scorer, corpus):
    clip = corpus[1]
    first = clip.n_tracks // 2
    again = lambda a: np.concatenate([a[:, :first], a[:, :clip.n_tracks - first]], axis=1)  # noqa: E731
    twice = dataclasses.replace(clip, clip_id="twice", track_prev=again(clip.track_prev), track_curr=again(clip.track_curr),
                                track_vis=again(clip.track_vis), track_conf=again(clip.track_conf))
    once = dataclasses.replace(twice, clip_id="once", track_vis=twice.track_vis & (np.arange(clip.n_tracks) < first))
    rows = score_batch([twice, once], progress=False).clips
    assert rows[0].sgc == rows[1].sgc and rows[0].components == rows[1].components
    out = outputs(scorer, [twice, once] * (SHAPE[0] // 2))
    for name, values in out.items():
        np.testing.assert_array_equal(values[0], values[1], err_msg=name)


def test_depth_edges_as_ramps_are_left_out_alike_in_both_paths(scorer, corpus):
    clip = corpus[1]
    smooth = dataclasses.replace(clip, clip_id="smooth", depth=enlarged_depth(clip.depth, 2))
    left_out = dataclasses.replace(leave_out_depth_ramps(smooth), clip_id="left_out")
    rows = score_batch([smooth, left_out], progress=False).clips
    assert rows[0].sgc == rows[1].sgc and rows[0].components == rows[1].components
    [kept] = score_batch([smooth], config=SGCConfig(smooth_depth_edges="keep"), progress=False).clips
    assert kept.components["depth_error"] > 2 * rows[0].components["depth_error"]
    out = outputs(scorer, [smooth, left_out] * (SHAPE[0] // 2))
    for name, values in out.items():
        np.testing.assert_array_equal(values[0], values[1], err_msg=name)
    np.testing.assert_allclose(out["sgc"][0], rows[0].sgc, rtol=CLIP_RTOL, atol=CLIP_ATOL)


def test_device_track_selection_matches_the_hosts(corpus):
    clip = corpus[2]  # 10 % low-confidence tracks: unusable ones in between
    config = SGCConfig(max_tracks=300)
    host = subsample_tracks(clip, config)
    usable = clip.usable_tracks(config.min_track_conf)
    index = jax.jit(jax.vmap(lambda row: device_prepare.select_tracks(row, 300)))(jnp.asarray(usable))
    np.testing.assert_array_equal(np.take_along_axis(clip.track_prev, np.asarray(index)[..., None], axis=1),
                                  host.track_prev)
