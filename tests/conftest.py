"""Shared fixtures: small synthetic scenes reused across test files (built once per session)."""

import atexit
import dataclasses
import gc
import os
import shutil
import tempfile
from pathlib import Path

import jax
import pytest

os.environ.setdefault("XLA_FLAGS", "--xla_cpu_multi_thread_eigen=true")
# One persistent compilation cache for the test run, shared by this process, the CLI and notebook
# subprocesses and the other xdist workers: a stage compiled once is loaded (seconds) wherever it
# is needed again, also after the release below. A temporary directory, so the user's cache is
# left alone (tests/test_compile_cache.py exercises the cache with caches of its own). The
# controller makes it; workers inherit it through the environment.
if "SGC_JAX_COMPILATION_CACHE" not in os.environ:
    _RUN_CACHE = tempfile.mkdtemp(prefix="sgc_jax-test-cache-")
    atexit.register(shutil.rmtree, _RUN_CACHE, ignore_errors=True)
    os.environ["SGC_JAX_COMPILATION_CACHE"] = _RUN_CACHE

from scenes import SCENE  # noqa: E402

from sgc_jax import enable_compilation_cache  # noqa: E402
from sgc_jax.config import SGCConfig  # noqa: E402
from sgc_jax.research.synth import synth_clip  # noqa: E402

enable_compilation_cache()


@pytest.fixture(scope="session")
def rigid_clip():
    return synth_clip(seed=1, clip_id="rigid", group="rigid", **SCENE)


@pytest.fixture(scope="session")
def moving_clip():
    return synth_clip(seed=2, clip_id="moving", group="moving", moving_objects=2, **SCENE)


@pytest.fixture(scope="session")
def noisy_clip():
    return synth_clip(seed=3, clip_id="noisy", group="noisy", noise_px=1.0, outlier_frac=0.3, **SCENE)


@pytest.fixture(scope="session")
def drift_clip():
    return synth_clip(seed=1, clip_id="drift", group="drift", layer_drift=0.15, **SCENE)


# The suite's schedule. xdist hands whole files to its workers in collection order
# (pyproject.toml: --no-loadscope-reorder), so the longest files go first and the short ones fill
# in at the end; a file that compiles a program comes before the files that load it from the
# run's cache (the notebooks build the demo corpus's programs and the Scorers of test_scorer.py
# and test_gradients.py). The rest keep their order.
SCHEDULE = ("test_scorer.py", "test_engine_agreement.py", "test_gradients.py", "test_torch.py", "test_streaming.py",
            "test_notebooks.py", "test_scale_free.py", "test_cli.py", "test_demo.py", "test_study.py",
            "test_pnp.py", "test_region_quality.py", "test_compat.py")


assert all((Path(__file__).parent / name).is_file() for name in SCHEDULE), "SCHEDULE names a file that is gone"


def pytest_collection_modifyitems(items):
    rank = {name: i for i, name in enumerate(SCHEDULE)}
    items.sort(key=lambda item: rank.get(item.path.name, len(SCHEDULE)))  # stable: a file's tests keep their order


# Each XLA:CPU executable maps its machine code into a few dozen memory regions, and the suite
# compiles hundreds of programs (one scorer per config and bucket). Past the kernel's
# vm.max_map_count (65530 by default) the next compile segfaults inside XLA. Release the compiled
# programs between test modules once the process holds more than half that many mappings.
_MAPS = Path("/proc/self/maps")
_MAX_MAP_COUNT = Path("/proc/sys/vm/max_map_count")


def _memory_mappings() -> int:
    with _MAPS.open() as maps:
        return sum(1 for _ in maps)


@pytest.fixture(scope="module", autouse=True)
def release_compiled_programs_when_mappings_run_high():
    yield
    if not _MAPS.exists():
        return
    limit = int(_MAX_MAP_COUNT.read_text()) if _MAX_MAP_COUNT.exists() else 65530
    if _memory_mappings() > limit // 2:
        from sgc_jax.engines.jax_engine.programs import release_programs

        release_programs()
        jax.clear_caches()
        gc.collect()


# Where the suite's time goes: the programs each test module compiled (printed at the end; xdist
# workers send theirs to the controller).
_COMPILES_BY_MODULE: dict[str, list[tuple[str, dict, float]]] = {}


def _altered_fields(stage) -> dict:
    """A compiled stage's static fields that differ from the default config's."""
    from sgc_jax.engines.jax_engine.programs import split

    default = split(type(stage).of(SGCConfig(), stage.vectorized))[1]
    return {f.name: getattr(stage, f.name) for f in dataclasses.fields(stage)
            if getattr(stage, f.name) != getattr(default, f.name)}


@pytest.fixture(scope="module", autouse=True)
def record_compiles(request):
    from sgc_jax.engines.jax_engine.programs import compile_log

    before = len(compile_log())
    yield
    new = [(str(key), _altered_fields(key.stage), seconds) for key, seconds in compile_log()[before:]]
    if new:
        _COMPILES_BY_MODULE[request.module.__name__] = new


def pytest_sessionfinish(session):
    workeroutput = getattr(session.config, "workeroutput", None)
    if workeroutput is not None:  # an xdist worker: hand the log to the controller
        workeroutput["sgc_jax_compiles"] = _COMPILES_BY_MODULE


@pytest.hookimpl(optionalhook=True)
def pytest_testnodedown(node, error):
    _COMPILES_BY_MODULE.update(getattr(node, "workeroutput", {}).get("sgc_jax_compiles", {}))


def pytest_terminal_summary(terminalreporter):
    if not _COMPILES_BY_MODULE:
        return
    terminalreporter.section("JAX stage programs compiled or loaded, by test module")
    rows = sorted(_COMPILES_BY_MODULE.items(), key=lambda kv: -sum(c[2] for c in kv[1]))
    for module, compiles in rows:
        terminalreporter.write_line(f"{module}: {len(compiles)} stage program(s), {sum(c[2] for c in compiles):.0f} s")
        for key, changed, seconds in compiles:
            terminalreporter.write_line(f"    {key} {changed or ''} {seconds:.0f} s")
