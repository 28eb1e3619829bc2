"""Scoring as a stream, results written as clips finish, and resuming a run (docs/semantics.md §4.1)."""

import csv
import dataclasses
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from scenes import SCENE

from sgc_jax import CLIP_COLUMNS, iter_scores, read_scores, save_clip, score_batch
from sgc_jax.calibration.formula import NUMERICAL_FLOOR
from sgc_jax.io.tables import read_table_text
from sgc_jax.research.synth import synth_clip
from sgc_jax.scoring.streaming import StreamStats

CLI = [sys.executable, "-m", "sgc_jax.cli"]
# slow enough under the reference engine (about a second each on the 2-core box) to kill a run
# part-way by watching its output grow
KILLED_SCENE = dict(SCENE, n_frames=3)


def _rows(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


@pytest.fixture(scope="module")
def clip_files(tmp_path_factory, rigid_clip, moving_clip, noisy_clip, drift_clip):
    folder = tmp_path_factory.mktemp("stream")
    for clip in (rigid_clip, moving_clip, noisy_clip, drift_clip):
        save_clip(folder / f"{clip.clip_id}.npz", clip)
    return folder


@pytest.fixture(scope="module")
def uninterrupted(clip_files, tmp_path_factory):
    out = tmp_path_factory.mktemp("whole") / "scores.csv"
    result = score_batch(clip_files, out=out, pairs_out=out.with_name("pairs.csv"), progress=False)
    return result, out


def test_results_from_files_equal_those_of_the_same_clips_in_memory(uninterrupted, rigid_clip, moving_clip,
                                                                     noisy_clip, drift_clip):
    from_files, _ = uninterrupted
    in_memory = score_batch([rigid_clip, moving_clip, noisy_clip, drift_clip], progress=False)
    by_id = {c.clip_id: c for c in in_memory}
    for clip in from_files:
        assert clip.sgc == by_id[clip.clip_id].sgc and clip.components == by_id[clip.clip_id].components


def test_clips_scored_at_once_in_lanes_give_the_numbers_of_one_at_a_time(clip_files, uninterrupted):
    one_lane = score_batch(clip_files, lanes=1, progress=False)
    three_lanes = score_batch(clip_files, lanes=3, chunk_size=1, progress=False)
    for result in (one_lane, three_lanes):
        assert result.table() == uninterrupted[0].table()
        for clip, whole in zip(result, uninterrupted[0]):
            for a, b in zip(dataclasses.astuple(clip.pairs), dataclasses.astuple(whole.pairs)):
                np.testing.assert_array_equal(a, b)  # bit for bit, NaN where both are NaN


def test_iter_scores_hands_on_each_clip_in_input_order(clip_files, uninterrupted):
    stats = StreamStats()
    streamed = list(iter_scores(clip_files, chunk_size=1, readers=3, progress=False, stats=stats))
    assert [c.clip_id for c in streamed] == uninterrupted[0].clip_ids
    assert [c.sgc for c in streamed] == list(uninterrupted[0].sgc)
    assert stats.scored == len(streamed)


def test_an_unknown_keyword_names_the_config_fields_and_the_run_options(clip_files):
    for call in (score_batch, lambda source, **kw: next(iter_scores(source, **kw))):
        with pytest.raises(TypeError, match=r"unknown option\(s\) \['chunksize'\].*chunk_size"):
            call(clip_files, chunksize=1, progress=False)


def test_the_output_records_its_inputs_and_run(uninterrupted, clip_files):
    _, out = uninterrupted
    rows = _rows(out)
    assert tuple(rows[0]) == CLIP_COLUMNS
    run = out.with_name("scores.csv.run.json").read_text()
    for key in ("sgc_jax_version", "config", "calibration", "engine"):
        assert f'"{key}"' in run
    assert {r["run_id"] for r in rows} == {run.split('"run_id": "')[1][:16]}
    assert all(len(r["input_sha256"]) == 64 and r["origin"].startswith(str(clip_files)) for r in rows)


def test_a_resumed_run_keeps_complete_rows_and_scores_the_rest(uninterrupted, clip_files, tmp_path):
    _, whole = uninterrupted
    out, pairs = tmp_path / "scores.csv", tmp_path / "pairs.csv"
    text = whole.read_text()
    lines = text.splitlines(keepends=True)
    out.write_text("".join(lines[:3]) + lines[3][:40])  # two rows and half a line: a run killed mid-write
    pairs.write_text(whole.with_name("pairs.csv").read_text())  # pairs of every clip: only the kept ones stay
    stats = StreamStats()
    score_batch(clip_files, out=out, pairs_out=pairs, resume=True, progress=False, stats=stats)
    assert (stats.resumed, stats.scored) == (2, 2)
    assert out.read_text() == text
    assert pairs.read_text() == whole.with_name("pairs.csv").read_text()


def test_resume_scores_again_what_changed_input_or_run(uninterrupted, clip_files, tmp_path, rigid_clip):
    _, whole = uninterrupted
    folder = tmp_path / "clips"
    folder.mkdir()
    for path in sorted(clip_files.iterdir()):
        (folder / path.name).write_bytes(path.read_bytes())
    out = tmp_path / "scores.csv"
    score_batch(folder, out=out, progress=False)
    save_clip(folder / "rigid.npz", dataclasses.replace(rigid_clip, meta={**rigid_clip.meta, "group": "relabelled"}))  # other bytes, same id
    stats = StreamStats()
    score_batch(folder, out=out, resume=True, progress=False, stats=stats)
    assert (stats.resumed, stats.scored) == (3, 1)
    assert {r["clip_id"]: r["group"] for r in _rows(out)}["rigid"] == "relabelled"
    stats = StreamStats()
    score_batch(folder, out=out, resume=True, progress=False, stats=stats, inlier_px=6.0)
    assert (stats.resumed, stats.scored) == (0, 4)


def test_a_killed_scoring_process_resumed_gives_the_uninterrupted_table(tmp_path):
    folder = tmp_path / "clips"
    for seed in range(8):
        save_clip(folder / f"c{seed}.npz", synth_clip(seed=seed, clip_id=f"c{seed}", **KILLED_SCENE))
    args = [str(folder), "--engine", "reference", "--compat", "authors", "-q"]  # fast: what is tested is the output
    whole = tmp_path / "whole.csv"
    assert subprocess.run([*CLI, "score", *args, "--out", str(whole), "--pairs", str(tmp_path / "whole_pairs.csv")],
                          capture_output=True, timeout=600).returncode == 0
    out, pairs = tmp_path / "scores.csv", tmp_path / "pairs.csv"
    command = [*CLI, "score", *args, "--out", str(out), "--pairs", str(pairs), "--resume"]
    process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline and process.poll() is None:
        if out.exists() and out.read_text().count("\n") >= 3:  # header and two clips
            break
        time.sleep(0.02)
    os.kill(process.pid, signal.SIGKILL)
    process.wait()
    kept = len(_rows(out))
    assert 2 <= kept < 8, kept
    resumed = subprocess.run(command, capture_output=True, text=True, timeout=600)
    assert resumed.returncode == 0, resumed.stderr
    assert f"resumed: {kept} clip(s) kept from {out}, {8 - kept} read and scored" in resumed.stderr
    assert out.read_text() == whole.read_text()
    assert pairs.read_text() == (tmp_path / "whole_pairs.csv").read_text()
    assert np.isfinite([float(r["ecd"]) for r in _rows(out)]).all()


# The two-device compile fuses differently: sums over a region's points are added in another
# order, so local poses move by float32 roundoff (1.5e-8 in rotation-matrix entries and
# translations of ~1 % of D, measured) and tiny components with them (1.5e-10 (% of D)^2 at most, a
# float32 cancellation, far below the float32 floor the score ignores); every decision is the same
# (statuses bitwise equal). A clip whose depth error lies above the calibration's zero carries the
# pixel mean's float32 roundoff into its SGC (1.0e-7 measured).
SHARDED_POSE_ROUNDOFF = 1e-6
SHARDED_ROUNDOFF = NUMERICAL_FLOOR
SHARDED_SGC_ROUNDOFF = 1e-6
TWO_DEVICES = """
import json, sys
sys.path.insert(0, sys.argv[1])  # the tests folder: scenes.py
from scenes import SCENE
from sgc_jax import score_batch
from sgc_jax.research.synth import synth_clip
import jax
assert len(jax.devices()) == 2, jax.devices()
clips = [synth_clip(seed=s, clip_id=f"c{s}", **SCENE) for s in range(3)]  # odd: the last group is filled
spread = score_batch(clips, progress=False)
print(json.dumps({"rows": [[float(v) for v in (c.sgc, *c.pairs.region_status.ravel())] for c in spread],  # NaN as NaN
                  "poses": [[float(v) for v in (*c.pairs.R_local.ravel(), *c.pairs.t_local.ravel())] for c in spread],
                  "components": [list(c.components.values()) for c in spread]}))
"""


def test_two_forced_host_devices_give_the_numbers_of_one():
    # The one-device numbers come from this process: XLA's cache key holds the client's device
    # count, so a two-device process would compile the one-device programs again.
    env = {**os.environ, "XLA_FLAGS": os.environ.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=2"}
    done = subprocess.run([sys.executable, "-c", TWO_DEVICES, str(Path(__file__).parent)], capture_output=True,
                          text=True, env=env, timeout=900)
    assert done.returncode == 0, done.stderr
    assert "one clip on each of 2 devices" in done.stderr
    spread = json.loads(done.stdout.strip().splitlines()[-1])
    single = score_batch([synth_clip(seed=s, clip_id=f"c{s}", **SCENE) for s in range(3)], progress=False)
    rows = np.array(spread["rows"])  # NaN where both are NaN
    np.testing.assert_array_equal(rows[:, 1:], np.array([c.pairs.region_status.ravel() for c in single]))
    np.testing.assert_allclose(rows[:, 0], [c.sgc for c in single], rtol=0, atol=SHARDED_SGC_ROUNDOFF)
    np.testing.assert_allclose(np.array(spread["poses"]),
                               np.array([[*c.pairs.R_local.ravel(), *c.pairs.t_local.ravel()] for c in single]),
                               rtol=0, atol=SHARDED_POSE_ROUNDOFF)
    np.testing.assert_allclose(np.array(spread["components"]), np.array([list(c.components.values()) for c in single]),
                               rtol=1e-6, atol=SHARDED_ROUNDOFF)


def test_a_parquet_output_resumes_from_its_log_and_from_the_finished_table(uninterrupted, clip_files, tmp_path):
    _, whole = uninterrupted
    out = tmp_path / "scores.parquet"
    log = tmp_path / "scores.parquet.journal.csv"
    log.write_text("".join(whole.read_text().splitlines(keepends=True)[:3]))  # killed after two clips
    stats = StreamStats()
    score_batch(clip_files, out=out, resume=True, progress=False, stats=stats)
    assert (stats.resumed, stats.scored) == (2, 2)
    assert read_table_text(out) == read_table_text(whole) and not log.exists()
    stats = StreamStats()
    score_batch(clip_files, out=out, resume=True, progress=False, stats=stats)
    assert (stats.resumed, stats.scored) == (4, 0)
    assert read_table_text(out) == read_table_text(whole)
    from_parquet, from_csv = read_scores(out), read_scores(whole)  # typed columns read alike
    assert [(r["clip_id"], r["sgc"], r["n_pairs"]) for r in from_parquet] == \
        [(r["clip_id"], r["sgc"], r["n_pairs"]) for r in from_csv]


# ----------------------------------------------------------------------------- Ray


@pytest.fixture(scope="module")
def ray_cluster():
    """A local Ray cluster started for these tests, two CPUs (two scorer processes); its address.
    Its workers inherit the suite's compilation cache (SGC_JAX_COMPILATION_CACHE), so they load
    the programs the suite compiled."""
    import ray

    ray.init(num_cpus=2, include_dashboard=False)
    try:
        yield ray.get_runtime_context().gcs_address
    finally:
        ray.shutdown()


# the CLI subprocess is forked from a process running JAX and execs at once: JAX's fork warning does not apply
@pytest.mark.filterwarnings("ignore:os.fork\\(\\) was called:RuntimeWarning")
def test_the_ray_path_on_a_local_cluster_writes_the_table_of_one_process(ray_cluster, clip_files, uninterrupted,
                                                                         tmp_path):
    _, whole = uninterrupted
    out, pairs = tmp_path / "scores.parquet", tmp_path / "pairs.parquet"
    run = subprocess.run([*CLI, "score", str(clip_files), "--ray", ray_cluster, "--ray-scorers", "2",
                          "--out", str(out), "--pairs", str(pairs), "-q"], capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    assert read_table_text(out) == read_table_text(whole)
    assert read_table_text(pairs) == read_table_text(whole.with_name("pairs.csv"))
    assert not out.with_name("scores.parquet.journal.csv").exists()  # the log is gone once the table is written


def test_a_ray_run_claims_ids_in_input_order_and_resumes_like_one_process(ray_cluster, clip_files, tmp_path):
    copy = tmp_path / "copy" / "rigid_again.npz"
    copy.parent.mkdir()
    shutil.copy(clip_files / "rigid.npz", copy)
    inputs = [str(clip_files), str(copy)]  # the copy, listed last, is a duplicate of rigid
    here, out = tmp_path / "here.csv", tmp_path / "ray.csv"
    score_batch(inputs, out=here, progress=False)
    score_batch(inputs, out=out, ray_address=ray_cluster, chunk_size=1, progress=False)
    assert out.read_text() == here.read_text()
    assert "duplicate: first seen in" in _rows(out)[-1]["reason"]
    out.write_text("".join(here.read_text().splitlines(keepends=True)[:3]))  # killed after two clips
    stats = StreamStats()  # resumed with reader processes, which each scorer keeps from shard to shard
    score_batch(inputs, out=out, resume=True, ray_address=ray_cluster, chunk_size=1, read_in="processes",
                progress=False, stats=stats)
    assert out.read_text() == here.read_text()
    assert (stats.resumed, stats.scored, stats.errors) == (2, 2, 1)


def test_reader_processes_give_the_table_of_reader_threads(clip_files, uninterrupted, tmp_path):
    whole, whole_out = uninterrupted
    by_id = {clip.clip_id: clip for clip in whole}
    folder = tmp_path / "clips"
    shutil.copytree(clip_files, folder)
    shutil.copyfile(folder / "rigid.npz", folder / "rigid_again.npz")  # the same id: a duplicate
    (folder / "broken.npz").write_bytes(b"not a zip file")
    tables = {}
    for read_in in ("threads", "processes"):
        out = tmp_path / read_in / "scores.csv"
        result = score_batch(folder, out=out, read_in=read_in, readers=2, chunk_size=3, progress=False)
        tables[read_in] = out.read_text()
        for clip in result:
            if clip.status != "error":
                for a, b in zip(dataclasses.astuple(clip.pairs), dataclasses.astuple(by_id[clip.clip_id].pairs)):
                    np.testing.assert_array_equal(a, b)
    assert tables["processes"] == tables["threads"]
    rows = _rows(tmp_path / "processes" / "scores.csv")
    assert [r["status"] == "error" for r in rows] == [True, False, False, False, False, True]
    assert "duplicate: first seen in" in rows[-1]["reason"]
    # resuming in processes keeps what the output holds, as in threads
    out = tmp_path / "resumed.csv"
    out.write_text("".join(whole_out.read_text().splitlines(keepends=True)[:3]))
    stats = StreamStats()
    score_batch(clip_files, out=out, resume=True, read_in="processes", readers=2, progress=False, stats=stats)
    assert (stats.resumed, stats.scored) == (2, 2)
    assert out.read_text() == whole_out.read_text()


def test_reader_processes_do_not_run_the_callers_script_again(clip_files, tmp_path):
    script = tmp_path / "unguarded.py"  # no `if __name__ == "__main__"`, as many research scripts
    script.write_text("from sgc_jax import score_batch\n"
                      f"result = score_batch({str(clip_files / 'rigid.npz')!r}, engine='reference', "
                      "read_in='processes', readers=2, progress=False)\n"
                      "print('scored', len(result))\n")
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["scored", "1"]


def test_the_cli_reads_in_processes_or_threads_as_told(clip_files, tmp_path):
    outputs = []
    for read_in in ("processes", "threads"):
        out = tmp_path / f"{read_in}.csv"
        done = subprocess.run([*CLI, "score", str(clip_files), "--engine", "reference", "--compat", "authors",
                               "--read-in", read_in, "--readers", "2", "--out", str(out), "-q"],
                              capture_output=True, text=True, timeout=600)
        assert done.returncode == 0, done.stderr[-3000:]
        outputs.append(read_table_text(out))
    assert outputs[0] == outputs[1]


def test_reading_in_processes_is_the_default_on_hosts_of_many_cores(monkeypatch):
    from sgc_jax.scoring.readers import PROCESS_READING_CORES, THREAD_READERS, reading_plan

    for cores, plan in ((2, (THREAD_READERS, False)), (PROCESS_READING_CORES, (THREAD_READERS, False)),
                        (16, (14, True))):
        monkeypatch.setattr("sgc_jax.scoring.readers.host_cores", lambda n=cores: n)
        assert reading_plan() == plan, cores
    assert reading_plan(3, "threads") == (3, False) and reading_plan(None, "processes") == (14, True)
    with pytest.raises(ValueError, match="read_in must be one of"):
        reading_plan(None, "fibres")


def test_a_reader_process_replies_through_a_pipe_enlarged_as_far_as_linux_allows(clip_files):
    import fcntl

    from sgc_jax import SGCConfig
    from sgc_jax.io.loading import entries_from_file
    from sgc_jax.scoring.readers import PIPE_BYTES, ReaderProcesses

    allowed = int(Path("/proc/sys/fs/pipe-max-size").read_text())
    with ReaderProcesses(1, "reference", SGCConfig()) as processes:
        read = processes.submit(entries_from_file(clip_files / "rigid.npz", SGCConfig())[0]).result()
        assert read.error is None and read.prepared is not None
        [worker] = processes._workers
        size = fcntl.fcntl(worker.stdout.fileno(), fcntl.F_GETPIPE_SZ)
    assert size >= min(PIPE_BYTES, allowed) > 64 << 10  # the prepared clips of a GPU host's readers


@pytest.mark.parametrize("shared_dir", ["memory", "missing"])
def test_a_reply_hands_its_large_arrays_over_in_shared_memory_and_leaves_no_file(tmp_path, monkeypatch, shared_dir):
    from sgc_jax.scoring import readers

    folder = tmp_path / "shm"
    if shared_dir == "memory":
        folder.mkdir()
    monkeypatch.setattr(readers, "SHARED_DIR", folder)  # missing: the reply goes whole through the pipe
    depth = np.arange(4 * 96 * 128, dtype=np.float32).reshape(4, 96, 128)
    reply = (True, {"depth": depth, "small": np.arange(3), "order": np.asfortranarray(depth[0])})
    with open(tmp_path / "channel", "wb") as sending:  # a file for the pipe: one thread sends and receives
        path = readers._send_reply(sending, reply)
    assert (path is not None) == (shared_dir == "memory") and (path is None or Path(path).parent == folder)
    with open(tmp_path / "channel", "rb") as receiving:
        ok, value = readers._receive_reply(receiving)
    assert ok and all(np.array_equal(value[k], v) for k, v in reply[1].items())
    assert value["depth"].flags.writeable  # a copy on write: the reader's arrays as they were
    assert not folder.exists() or list(folder.iterdir()) == []


def test_default_lanes_divide_the_cpu_cores_and_keep_two_clips_in_flight_on_an_accelerator(monkeypatch):
    from types import SimpleNamespace

    from sgc_jax.scoring.devices import ACCELERATOR_LANES, CPU_LANES, default_lanes

    cpu, gpu = SimpleNamespace(platform="cpu"), SimpleNamespace(platform="gpu")
    assert default_lanes([gpu]) == default_lanes([gpu, gpu]) == ACCELERATOR_LANES == 2
    for cores, devices, lanes in ((1, 1, 1), (2, 1, 2), (16, 1, CPU_LANES), (2, 2, 1), (8, 2, 2)):
        monkeypatch.setattr("os.sched_getaffinity", lambda pid, n=cores: set(range(n)), raising=False)
        assert default_lanes([cpu] * devices) == lanes, (cores, devices)


def test_clips_named_by_url_score_and_resume_as_the_same_files_on_disk(clip_files, uninterrupted, tmp_path):
    whole, whole_out = uninterrupted
    url = clip_files.as_uri()  # file:///...: the same pyarrow filesystem code as s3:// or gs://
    out = tmp_path / "scores.csv"
    by_url = score_batch(url + "/", out=out, progress=False)
    assert [c.origin for c in by_url] == [f"{url}/{c.clip_id}.npz" for c in whole]
    for clip, expected in zip(by_url, whole):
        assert (clip.clip_id, clip.sgc, clip.components, clip.input_sha256) == (
            expected.clip_id, expected.sgc, expected.components, expected.input_sha256)
    stats = StreamStats()
    resumed = score_batch(url, out=out, resume=True, progress=False, stats=stats)
    assert (stats.resumed, stats.scored) == (len(whole), 0)
    assert [c.sgc for c in resumed] == [c.sgc for c in whole]


def test_a_url_that_names_no_clip_says_so(clip_files):
    from sgc_jax.io.loading import list_clip_files

    url = clip_files.as_uri()
    assert list_clip_files(url + "/rigid*") == [f"{url}/rigid.npz"]
    for source, words in ((url + "/none.npz", "no clip file or directory"), ("nosuch://bucket/clips", "no filesystem")):
        with pytest.raises(FileNotFoundError, match=words):
            list_clip_files(source)
    done = subprocess.run([*CLI, "score", url + "/none.npz"], capture_output=True, text=True)
    assert done.returncode == 2 and "no clip file or directory" in done.stderr
