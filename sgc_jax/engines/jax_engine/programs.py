"""The compiled stage programs this process holds: compiled once per ``StageKey`` (or loaded from
the persistent cache), for one device or for a batch spread over devices."""

from __future__ import annotations

import concurrent.futures
import functools
import threading
import time
from typing import Any, Callable, NamedTuple

import jax
import numpy as np

from ...config import SGCConfig
from .buckets import Bucket, PaddedClips
from .compile_cache import ProgramLock, cache_hint, load_program, program_path, save_program
from .compile_notice import CompileNotice
from .stages import STAGES, StageKey, program_values, stage_inputs, stage_key

# StageKey -> (executable taking (inputs, key, values), its output's shapes)
_programs: dict[StageKey, tuple[Callable, Any]] = {}
# (stage keys, device ids, clips in the batch) -> (the stages over the batch spread over those devices,
# the batch's sharding)
_sharded: dict[tuple, tuple["BucketProgram", Any]] = {}
_compiles: list[tuple[StageKey, float]] = []  # every compile or load of this process, with its seconds
# Held while programs are compiled or loaded: lanes that need the same program wait for the first
# one's compile. Held programs are looked up without it, so a lane never waits for another's.
_compiling = threading.Lock()

# XLA options per stage on CPU devices: XLA CPU's YNNPACK fusions run the pose stage's many small
# reductions slower than its own loops (~175 against ~220 ms per standard clip, bench/RESULTS.md).
# An XLA that no longer knows an option compiles without it.
CPU_COMPILER_OPTIONS = {"pose": {"xla_cpu_experimental_ynn_fusion_type": ""}}


class BucketProgram(NamedTuple):
    """The three compiled stages that score a padded batch of a bucket."""

    stages: tuple[Callable, ...]

    def __call__(self, batch: PaddedClips, key, values) -> dict:
        batch = PaddedClips(*jax.device_put(tuple(batch)))  # once, not per stage
        out = None
        for stage, program in zip(STAGES, self.stages):
            out = program(stage_inputs(stage, batch, out), key, values)
        return out


def compile_stage(lowered, stage: str, platform: str):
    """``lowered.compile()`` with the stage's CPU_COMPILER_OPTIONS on a CPU ``platform``."""
    options = CPU_COMPILER_OPTIONS.get(stage) if platform == "cpu" else None
    if options:
        try:
            return lowered.compile(compiler_options=options)
        except Exception as exc:  # an unknown option (a newer XLA); anything else is raised again
            if not any(name in str(exc) for name in options):
                raise
    return lowered.compile()


def _spec(tree):
    return jax.tree.map(lambda a: jax.ShapeDtypeStruct(np.shape(a), a.dtype), tree)


def _traced(key: StageKey):
    from .trace import stage_program  # only tracing imports the stages' modules and the kernels

    return jax.jit(functools.partial(stage_program, stage=key.stage, static=key.static, vectorized=key.vectorized))


def _lower(traced: Callable[[], Any], path, args: tuple):
    """A stage lowered for ``args`` (shapes, shardings): from its kept ``jax.export`` file when
    the cache has one, else ``traced()`` (its jitted function) traced, and kept there when the
    cache is on."""
    exported = load_program(path) if path is not None else None
    if exported is None:
        if path is None:
            return traced().lower(*args)
        exported = jax.export.export(traced())(*args)
        save_program(path, exported)
    return jax.jit(exported.call).lower(*args)


def compiled_program(config: SGCConfig, bucket: Bucket, example: PaddedClips) -> BucketProgram:
    """The stages scoring one padded clip of ``bucket``, called as ``program(batch, key, values)``;
    each compiled once per StageKey, a stage traced while the previous one compiles. With the
    persistent cache on, a stage another process is compiling is waited for, then loaded."""
    keys = [stage_key(config, stage, bucket) for stage in STAGES]
    if not all(key in _programs for key in keys):
        with _compiling:
            _compile_missing(config, bucket, example, keys)
    return BucketProgram(tuple(_programs[key][0] for key in keys))


def _compile_missing(config: SGCConfig, bucket: Bucket, example: PaddedClips, keys: list[StageKey]) -> None:
    missing = [key for key in keys if key not in _programs]
    if not missing:
        return
    paths = {key: program_path(key) for key in missing}
    kept = all(p is not None and p.exists() for p in paths.values())
    stages = ", ".join(key.stage for key in missing)
    key_spec, values_spec = _spec(jax.random.PRNGKey(0)), _spec(program_values(config))
    batch_spec = PaddedClips(*_spec(tuple(example)))
    platform = jax.default_backend()

    def compile_one(key: StageKey, lowered, lowered_s: float, lock: ProgramLock):
        try:
            begin = time.perf_counter()
            return compile_stage(lowered, key.stage, platform), lowered.out_info, lowered_s + time.perf_counter() - begin
        finally:
            lock.release()

    with CompileNotice(_bucket_text(bucket), stages, loading=kept, hint=cache_hint()), \
            concurrent.futures.ThreadPoolExecutor(max_workers=len(missing)) as pool:
        pending, previous = {}, None
        for key in keys:
            if key in _programs:
                previous = _programs[key][1]
                continue
            begin = time.perf_counter()
            lock = ProgramLock(paths[key])  # another process may be compiling it
            try:
                lowered = _lower(functools.partial(_traced, key), paths[key],
                                 (stage_inputs(key.stage, batch_spec, previous), key_spec, values_spec))
            except BaseException:
                lock.release()
                raise
            previous = lowered.out_info
            pending[key] = pool.submit(compile_one, key, lowered, time.perf_counter() - begin, lock)
        for key, future in pending.items():  # logged in stage order, whichever compile ends first
            executable, out_info, seconds = future.result()
            _programs[key] = executable, out_info
            _compiles.append((key, seconds))


def _bucket_text(bucket: Bucket, devices: int = 1, clips: int = 1) -> str:
    text = f"clips of up to {bucket.T} frames, {bucket.H}x{bucket.W} px, {bucket.P} tracks per pair"
    if devices == 1:
        return text if clips == 1 else f"{text}, {clips} at once"
    return f"{text}, {'one clip' if clips == 1 else f'{clips} clips at once'} on each of {devices} devices"


def sharded_program(config: SGCConfig, bucket: Bucket, devices: list, example: PaddedClips,
                    vectorized: bool = False) -> tuple:
    """The three stages over a batch whose leading axis B (a multiple of len(devices)) is sharded
    over ``devices`` (``shard_map``): each device runs the programs on its B / len(devices) clips,
    so the numbers are those of one device -> (BucketProgram, the batch's sharding)."""
    keys = tuple(stage_key(config, stage, bucket, vectorized) for stage in STAGES)
    cache_key = (keys, tuple(d.id for d in devices), np.shape(example.depth)[0])
    if cache_key not in _sharded:
        with _compiling:
            if cache_key not in _sharded:
                _sharded[cache_key] = _compile_sharded(config, bucket, devices, example, keys)
    return _sharded[cache_key]


def spread_stage(key: StageKey, mesh):
    """The stage's traced program over a batch whose clip axis is sharded over ``mesh``'s devices:
    each runs the one-device program on its share, so the numbers are those of one device."""
    from jax.sharding import PartitionSpec

    from .trace import stage_program

    clips, replicated = PartitionSpec("clips"), PartitionSpec()
    run = functools.partial(stage_program, stage=key.stage, static=key.static, vectorized=key.vectorized)
    # check_vma off: the kernels' loops start from constants the per-device clip makes
    # device-varying, which the check would have every loop annotate
    return jax.jit(jax.shard_map(run, mesh=mesh, in_specs=(clips, replicated, replicated), out_specs=clips,
                                 check_vma=False))


def _compile_sharded(config: SGCConfig, bucket: Bucket, devices: list, example: PaddedClips, keys: tuple) -> tuple:
    from jax.sharding import Mesh, NamedSharding, PartitionSpec

    mesh = Mesh(np.array(devices), ("clips",))
    sharding = NamedSharding(mesh, PartitionSpec("clips"))
    batch_spec = PaddedClips(*(jax.ShapeDtypeStruct(np.shape(a), a.dtype, sharding=sharding) for a in example))
    key_spec, values_spec = _spec(jax.random.PRNGKey(0)), _spec(program_values(config))
    stages, previous = [], None
    per_device = np.shape(example.depth)[0] // len(devices)
    # kept per mesh size and clips per device (a program over n devices runs on any n of them), and
    # only for the default backend's devices: a kept program is exported for the default platform
    default_platform = devices[0].platform == jax.devices()[0].platform
    paths = [program_path((key, len(devices), per_device)) if default_platform else None for key in keys]
    kept = all(p is not None and p.exists() for p in paths)
    with CompileNotice(_bucket_text(bucket, len(devices), per_device), ", ".join(STAGES), loading=kept,
                       hint=cache_hint()):
        # one program per stage, as on one device: the same fusions, the same numbers
        for key, path in zip(keys, paths):
            lock = ProgramLock(path)
            try:
                lowered = _lower(functools.partial(spread_stage, key, mesh), path,
                                 (stage_inputs(key.stage, batch_spec, previous), key_spec, values_spec))
                previous = lowered.out_info
                stages.append(compile_stage(lowered, key.stage, devices[0].platform))
            finally:
                lock.release()
    return BucketProgram(tuple(stages)), sharding


def release_programs() -> int:
    """Drop every compiled stage (each holds its machine code in memory mappings); how many."""
    count = len(_programs) + len(STAGES) * len(_sharded)
    _programs.clear()
    _sharded.clear()
    return count


def compile_count() -> int:
    """Stage programs compiled or loaded, and held, by this process."""
    return len(_programs)


def compile_log() -> list[tuple[StageKey, float]]:
    """Every one-device stage program this process compiled or loaded, in order, with its seconds
    (released ones too); ``sharded_program``'s are not listed."""
    return list(_compiles)
