"""sgc_jax.engines.compile_cache: the CLI's compiled programs persist between runs, per machine."""

import os
import subprocess
import sys

import pytest

from sgc_jax import save_clip
from sgc_jax.engines import compile_cache
from sgc_jax.research.synth import synth_clip


def test_cache_directory_follows_the_environment(monkeypatch, tmp_path):
    monkeypatch.setenv(compile_cache.ENV_VAR, "off")
    assert compile_cache.default_cache_dir() is None
    monkeypatch.setenv(compile_cache.ENV_VAR, str(tmp_path / "mine"))
    assert compile_cache.default_cache_dir() == tmp_path / "mine"
    monkeypatch.delenv(compile_cache.ENV_VAR)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    default = compile_cache.default_cache_dir()
    assert default.parent == tmp_path / "sgc_jax" / "xla"
    assert default.name == compile_cache.host_key()  # one cache per kind of CPU


def _score_in_a_fresh_process(clip_path, out_csv, cache_dir):
    # Every program is cached (no 1 s minimum), so a second run must compile nothing new.
    env = dict(os.environ, SGC_JAX_COMPILATION_CACHE=str(cache_dir), JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS="0")
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    done = subprocess.run([sys.executable, "-m", "sgc_jax.cli", "score", str(clip_path), "--out", str(out_csv), "-q"],
                          env=env, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr
    return done.stderr, {p.relative_to(cache_dir).as_posix(): p.stat().st_mtime_ns for p in cache_dir.rglob("*")}


@pytest.mark.slow
def test_a_second_cli_run_loads_every_program_from_the_cache(tmp_path):
    clip_path = save_clip(tmp_path / "tiny.npz", synth_clip(seed=5, clip_id="tiny", height=48, width=64, n_tracks=256,
                                                            n_frames=3, n_layers=2, static_spheres=2))
    cache_dir = tmp_path / "cache"
    said, first = _score_in_a_fresh_process(clip_path, tmp_path / "first.csv", cache_dir)
    assert any(name.startswith("jit_") for name in first) and "compiling the JAX program" in said
    assert any(name.endswith(".jaxexport") for name in first)  # the traced program, kept
    said, second = _score_in_a_fresh_process(clip_path, tmp_path / "second.csv", cache_dir)
    assert second == first  # nothing traced or compiled anew, nothing rewritten
    assert "loading the JAX program" in said and "compiling" not in said
    assert (tmp_path / "second.csv").read_text() == (tmp_path / "first.csv").read_text()


def test_a_program_being_compiled_is_locked_against_other_processes(tmp_path):
    # Processes sharing a cache compile each program once: the others wait for the lock, then load it.
    path = tmp_path / "sgc_programs" / "stage.jaxexport"
    probe = "import fcntl, sys; fcntl.flock(open(sys.argv[1], 'a'), fcntl.LOCK_EX | fcntl.LOCK_NB)"

    def another_process_can_lock() -> bool:
        return subprocess.run([sys.executable, "-c", probe, str(path.with_suffix(".lock"))]).returncode == 0

    lock = compile_cache.ProgramLock(path)
    held = another_process_can_lock()
    lock.release()
    assert not held and another_process_can_lock()


class _Lowered:
    """A stand-in for ``jax.stages.Lowered`` that records the options it was compiled with."""

    def __init__(self, known_options=()):
        self.known, self.calls = set(known_options), []

    def compile(self, compiler_options=None):
        self.calls.append(compiler_options)
        unknown = set(compiler_options or ()) - self.known
        if unknown:
            raise RuntimeError(f"INVALID_ARGUMENT: No such compile option: '{sorted(unknown)[0]}'")
        return "executable"


def test_the_pose_stage_compiles_with_its_cpu_options_and_without_them_where_xla_lacks_them():
    from sgc_jax.engines.jax_engine import CPU_COMPILER_OPTIONS, compile_stage

    options = CPU_COMPILER_OPTIONS["pose"]
    knows = _Lowered(options)
    assert compile_stage(knows, "pose", "cpu") == "executable" and knows.calls == [options]
    lacks = _Lowered()
    assert compile_stage(lacks, "pose", "cpu") == "executable" and lacks.calls == [options, None]
    elsewhere = _Lowered()
    assert compile_stage(elsewhere, "pose", "gpu") == "executable" and elsewhere.calls == [None]
    assert compile_stage(elsewhere, "pixel", "cpu") == "executable" and elsewhere.calls == [None, None]
