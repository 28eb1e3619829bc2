"""Shared fixtures: small synthetic scenes reused across test files (built once per session)."""

import gc
import os
from pathlib import Path

import jax
import pytest

os.environ.setdefault("XLA_FLAGS", "--xla_cpu_multi_thread_eigen=true")
# The CLI tests run in this process: keep its compiled programs out of the user's cache
# (tests/test_compile_cache.py exercises the cache in subprocesses).
os.environ.setdefault("SGC_JAX_COMPILATION_CACHE", "off")

from sgc_jax.config import STATIC_FIELDS, SGCConfig  # noqa: E402
from sgc_jax.research.synth import synth_clip  # noqa: E402

# Well-conditioned scenes: two planar layers (one slanted) plus four static spheres, so every
# depth region is a curved 3D point set. Small planar patches are the ill-posed case where any
# PnP-RANSAC (OpenCV's included) may return the planar-ambiguity twin pose (docs/semantics.md §3.3).
SCENE = dict(n_layers=2, static_spheres=4, height=120, width=160, n_tracks=2048, n_frames=4)


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
        from sgc_jax.engines.jax_engine import release_programs

        release_programs()
        jax.clear_caches()
        gc.collect()


# Where the suite's time goes: the programs each test module compiled (printed at the end).
_COMPILES_BY_MODULE: dict[str, list] = {}


@pytest.fixture(scope="module", autouse=True)
def record_compiles(request):
    from sgc_jax.engines.jax_engine import compile_log

    before = len(compile_log())
    yield
    new = compile_log()[before:]
    if new:
        _COMPILES_BY_MODULE[request.module.__name__] = new


def pytest_terminal_summary(terminalreporter):
    if not _COMPILES_BY_MODULE:
        return
    defaults = SGCConfig()
    terminalreporter.section("JAX programs compiled, by test module")
    rows = sorted(_COMPILES_BY_MODULE.items(), key=lambda kv: -sum(c[1] for c in kv[1]))
    for module, compiles in rows:
        terminalreporter.write_line(f"{module}: {len(compiles)} stage program(s), {sum(c[1] for c in compiles):.0f} s")
        for key, seconds in compiles:
            changed = {f: getattr(key.static, f) for f in STATIC_FIELDS
                       if getattr(key.static, f) != getattr(defaults, f)}
            terminalreporter.write_line(f"    {key} {changed or ''} {seconds:.0f} s")
