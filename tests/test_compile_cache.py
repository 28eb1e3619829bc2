"""sgc_jax.engines.jax_engine.compile_cache: compiled programs persist between processes, per machine, for
the CLI and the Python API alike."""

import os
import subprocess
import sys
from pathlib import Path

import jax
import pytest
from scenes import SCENE

from sgc_jax import SGCConfig, save_clip
from sgc_jax.engines.jax_engine import compile_cache
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


def _fresh_process(code: str, cache_dir) -> str:
    """stderr of ``python -c code`` in a new process whose program cache is ``cache_dir``, as a user's is."""
    env = dict(os.environ, SGC_JAX_COMPILATION_CACHE=str(cache_dir))
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr
    return done.stderr


@pytest.mark.slow
def test_a_python_process_after_the_cli_loads_every_program_from_the_cache(tmp_path):
    """The CLI and the Python API share the persistent cache by default: once `sgc-jax score` ran
    (compiling or loading), a new process calling score_batch loads every program, traced and
    compiled, without calling enable_compilation_cache. The suite's run cache stands for the
    user's, so a bucket compiled by an earlier test is not compiled again here."""
    cache_dir = jax.config.jax_compilation_cache_dir
    clip_path = save_clip(tmp_path / "scene.npz", synth_clip(seed=5, clip_id="scene", **SCENE))
    _fresh_process(f"from sgc_jax.cli import main; main(['score', {str(clip_path)!r}, '-q', "
                   f"'--out', {str(tmp_path / 'cli.csv')!r}])", cache_dir)
    assert list(Path(cache_dir).glob("sgc_programs/*.jaxexport"))  # the traced programs, kept
    said = _fresh_process(f"import sgc_jax; sgc_jax.score_batch({str(clip_path)!r}, progress=False)"
                          f".to_csv({str(tmp_path / 'python.csv')!r})", cache_dir)
    assert "loading the JAX program" in said and "compiling" not in said
    assert (tmp_path / "python.csv").read_text().split("run_id")[0] == (tmp_path / "cli.csv").read_text().split(
        "run_id")[0]


SCORER_CALL = """
from scenes import DEMO_BATCH_SHAPE
from sgc_jax import Scorer, batch_of
from sgc_jax.research.synth import demo_corpus
print(float(Scorer(DEMO_BATCH_SHAPE)(batch_of(demo_corpus()[:4]))["sgc"][0]))
"""


@pytest.mark.slow
def test_a_scorer_in_a_new_process_loads_its_stages_from_the_cache(tmp_path):
    """The Scorer's stages (one program over its devices' clips) are kept traced, as score_batch's
    are: once a Scorer of this shape ran, a new process's Scorer neither traces nor compiles them
    (DEMO_BATCH_SHAPE, test_scorer.py's Scorer: usually the first process loads too)."""
    cache_dir = jax.config.jax_compilation_cache_dir
    code = f"import sys; sys.path.insert(0, {str(Path(__file__).parent)!r})" + SCORER_CALL
    _fresh_process(code, cache_dir)
    said = _fresh_process(code, cache_dir)
    assert "loading the JAX program" in said and "(pixel, pose, finish)" in said, said
    assert "compiling the JAX program for clips" not in said, said


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


def test_each_stage_compiles_with_its_cpu_options_and_without_them_where_xla_lacks_them():
    from sgc_jax.engines.jax_engine.programs import compile_stage, stages_of
    from sgc_jax.engines.jax_engine.stages import CPU_COMPILER_OPTIONS

    pixel, pose, finish = stages_of(SGCConfig())
    options = pose.cpu_compiler_options
    assert options.items() > CPU_COMPILER_OPTIONS.items()  # the pose stage has one more
    assert pixel.cpu_compiler_options == finish.cpu_compiler_options == CPU_COMPILER_OPTIONS
    knows = _Lowered(options)
    assert compile_stage(knows, pose, "cpu") == "executable" and knows.calls == [options]
    lacks = _Lowered()
    assert compile_stage(lacks, pose, "cpu") == "executable" and lacks.calls == [options, None]
    elsewhere = _Lowered()
    assert compile_stage(elsewhere, pose, "gpu") == "executable" and elsewhere.calls == [None]
    assert compile_stage(elsewhere, pixel, "gpu") == "executable" and elsewhere.calls == [None, None]


def test_an_xla_flag_the_user_sets_wins_over_a_stages_cpu_option(monkeypatch):
    from sgc_jax.engines.jax_engine.programs import stage_compiler_options, stages_of

    _, pose, finish = stages_of(SGCConfig())
    monkeypatch.setenv("XLA_FLAGS", "--xla_force_host_platform_device_count=2 --xla_cpu_prefer_vector_width=256")
    assert "xla_cpu_prefer_vector_width" not in stage_compiler_options(pose, "cpu")
    assert stage_compiler_options(pose, "cpu") == {"xla_cpu_experimental_ynn_fusion_type": ""}
    assert stage_compiler_options(finish, "cpu") == {}
    monkeypatch.setenv("XLA_FLAGS", "--xla_force_host_platform_device_count=2")
    assert stage_compiler_options(finish, "cpu") == finish.cpu_compiler_options
