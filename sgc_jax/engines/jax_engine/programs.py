"""The compiled stage programs this process holds, and the pipeline that chains them: each stage
compiled once per ``ProgramKey`` (or loaded from the persistent cache), on one device or over a
batch spread across devices, by one compile path."""

from __future__ import annotations

import concurrent.futures
import dataclasses
import os
import threading
import time
from typing import Any, Callable, NamedTuple, Sequence

import equinox as eqx
import jax
import numpy as np

from ...config import SGCConfig
from .buckets import Bucket, PaddedClips
from .compile_cache import ProgramLock, cache_hint, load_program, program_path, save_program
from .compile_notice import CompileNotice
from .finish_stage import FinishStage
from .pixel_stage import PixelStage
from .pose_stage import PoseStage
from .stages import Stage


@dataclasses.dataclass(frozen=True)
class ProgramKey:
    """One compiled program: a stage's static part (its value fields None), the bucket sizes it
    reads (pixel: T, H, W, P; pose: T, P; finish: T, H, W) and, for a batch spread over devices,
    (the mesh's size, clips per device). Its repr names the program in the persistent cache."""

    stage: Stage
    sizes: tuple[int, ...]
    spread: tuple[int, int] | None = None

    @property
    def name(self) -> str:
        return self.stage.name

    def __str__(self) -> str:
        vectorized = " vectorized" if self.stage.vectorized else ""
        spread = f" over {self.spread[0]} devices" if self.spread else ""
        return f"{self.name} {'x'.join(map(str, self.sizes))}{vectorized}{spread}"


def stages_of(config: SGCConfig, vectorized: bool = False) -> tuple[PixelStage, PoseStage, FinishStage]:
    """The three stages that score clips under ``config``, in the order they run."""
    return PixelStage.of(config, vectorized), PoseStage.of(config, vectorized), FinishStage.of(config, vectorized)


def split(stage: Stage) -> tuple[list, Stage]:
    """(the stage's value fields, the leaves a program takes; its static part)."""
    values, static = eqx.partition(stage, eqx.is_array)
    return jax.tree.leaves(values), static


# (ProgramKey, the device ids of a spread program or None) -> (executable taking (inputs, key,
# values), its output's shapes)
_programs: dict[tuple[ProgramKey, tuple | None], tuple[Callable, Any]] = {}
_compiles: list[tuple[ProgramKey, float]] = []  # every compile or load of this process, with its seconds
# Held while programs are compiled or loaded: lanes that need the same program wait for the first
# one's compile. Held programs are looked up without it, so a lane never waits for another's.
_compiling = threading.Lock()

class Pipeline(NamedTuple):
    """The stages that score padded clips of one bucket, with their programs (compiled, or jitted
    to be traced inside a caller's jit): ``pipeline(batch)`` -> the finish stage's output,
    ``outputs(batch)`` -> every stage's. ``values``: each stage's value fields, the leaves its
    program takes; ``sharding``: where a spread batch must lie (None on one device)."""

    stages: tuple[Stage, ...]
    programs: tuple[Callable, ...]
    values: tuple[list, ...]
    key: jax.Array  # RANSAC's key (config.seed)
    sharding: Any = None

    def outputs(self, batch: PaddedClips) -> list[dict]:
        outs, out = [], None
        for stage, program, values in zip(self.stages, self.programs, self.values):
            out = program(stage.inputs(batch, out), self.key, values)
            outs.append(out)
        return outs

    def __call__(self, batch: PaddedClips) -> dict:
        return self.outputs(batch)[-1]


def pipeline(config: SGCConfig, bucket: Bucket, example: PaddedClips, devices: Sequence | None = None,
             vectorized: bool = False) -> Pipeline:
    """The compiled stages scoring ``example``'s shapes of ``bucket`` under ``config``: on the
    default device (``devices`` None), or over a batch whose leading axis B (a multiple of
    len(devices)) is sharded over ``devices``, each running the one-device program on its B /
    len(devices) clips, so the numbers are those of one device. Each stage compiled once per
    ProgramKey, a stage traced while the previous one compiles; with the persistent cache on, a
    stage another process is compiling is waited for, then loaded."""
    stages = stages_of(config, vectorized)
    mesh = _mesh(devices)
    per_device = np.shape(example.depth)[0] // len(devices) if devices else 1
    spread = (len(devices), per_device) if devices else None
    values, statics = zip(*(split(stage) for stage in stages))
    keys = [ProgramKey(static, stage.sizes(bucket), spread) for stage, static in zip(stages, statics)]
    where = tuple(d.id for d in devices) if devices else None
    if not all((key, where) in _programs for key in keys):
        with _compiling:
            _compile_missing(stages, keys, where, mesh, bucket, example)
    sharding = _sharding(mesh) if devices else None
    return Pipeline(stages, tuple(_programs[key, where][0] for key in keys), values, jax.random.PRNGKey(config.seed),
                    sharding)


def traced_pipeline(config: SGCConfig, bucket: Bucket, devices: Sequence, vectorized: bool = False) -> Pipeline:
    """``pipeline``'s stages as jitted functions over ``devices`` (each running the one-device
    program on its share of the clips), to be traced inside a caller's ``jax.jit``."""
    stages = stages_of(config, vectorized)
    mesh = _mesh(devices)
    return Pipeline(stages, tuple(_traced(stage, mesh) for stage in stages), tuple(split(s)[0] for s in stages),
                    jax.random.PRNGKey(config.seed), _sharding(mesh))


def _mesh(devices: Sequence | None):
    return jax.sharding.Mesh(np.array(devices), ("clips",)) if devices else None


def _sharding(mesh):
    return jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("clips"))


def _traced(stage: Stage, mesh=None) -> Callable:
    """The stage as a jitted function of (inputs, key, values); over ``mesh`` (``shard_map``) each
    device runs it on its share of the clips."""
    treedef = jax.tree.structure(eqx.filter(stage, eqx.is_array))
    static = split(stage)[1]

    def run(inputs, key, values):
        return eqx.combine(jax.tree.unflatten(treedef, values), static)(inputs, key)

    if mesh is None:
        return jax.jit(run)
    clips, replicated = jax.sharding.PartitionSpec("clips"), jax.sharding.PartitionSpec()
    # check_vma off: the kernels' loops start from constants the per-device clip makes
    # device-varying, which the check would have every loop annotate
    return jax.jit(jax.shard_map(run, mesh=mesh, in_specs=(clips, replicated, replicated), out_specs=clips,
                                 check_vma=False))


def stage_compiler_options(stage: Stage, platform: str) -> dict[str, str] | None:
    """The stage's ``cpu_compiler_options`` on a CPU ``platform`` (None elsewhere), less those the
    user sets in ``XLA_FLAGS``: theirs win (e.g. ``--xla_cpu_prefer_vector_width=256``)."""
    if platform != "cpu":
        return None
    user_flags = os.environ.get("XLA_FLAGS", "")
    return {name: value for name, value in stage.cpu_compiler_options.items() if f"--{name}=" not in user_flags}


def compile_stage(lowered, stage: Stage, platform: str):
    """``lowered.compile()`` with ``stage_compiler_options``; an XLA that no longer knows an
    option compiles without it."""
    options = stage_compiler_options(stage, platform)
    if options:
        try:
            return lowered.compile(compiler_options=options)
        except Exception as exc:  # an unknown option (a newer XLA); anything else is raised again
            if not any(name in str(exc) for name in options):
                raise
    return lowered.compile()


def _spec(tree, sharding=None):
    return jax.tree.map(lambda a: jax.ShapeDtypeStruct(np.shape(a), a.dtype, sharding=sharding), tree)


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


def _compile_missing(stages: tuple[Stage, ...], keys: list[ProgramKey], where: tuple | None, mesh, bucket: Bucket,
                     example: PaddedClips) -> None:
    missing = [key for key in keys if (key, where) not in _programs]
    if not missing:
        return
    # a spread program is kept only for the default backend's devices: it is exported for the default platform
    platform = mesh.devices.flat[0].platform if mesh is not None else jax.default_backend()
    keep = platform == jax.default_backend()
    paths = {key: program_path(key) if keep else None for key in missing}
    kept = all(p is not None and p.exists() for p in paths.values())
    batch_spec = PaddedClips(*_spec(tuple(example), _sharding(mesh) if mesh is not None else None))
    key_spec = _spec(jax.random.PRNGKey(0))

    def compile_one(key: ProgramKey, lowered, lowered_s: float, lock: ProgramLock):
        try:
            begin = time.perf_counter()
            return compile_stage(lowered, key.stage, platform), lowered.out_info, lowered_s + time.perf_counter() - begin
        finally:
            lock.release()

    devices, clips = keys[0].spread or (1, 1)
    with CompileNotice(_bucket_text(bucket, devices, clips), ", ".join(key.name for key in missing), loading=kept,
                       hint=cache_hint()), \
            concurrent.futures.ThreadPoolExecutor(max_workers=len(missing)) as pool:
        pending, previous = {}, None
        for stage, key in zip(stages, keys):
            if (key, where) in _programs:
                previous = _programs[key, where][1]
                continue
            begin = time.perf_counter()
            lock = ProgramLock(paths[key])  # another process may be compiling it
            try:
                values_spec = _spec(split(stage)[0])
                lowered = _lower(lambda stage=stage: _traced(stage, mesh), paths[key],
                                 (stage.inputs(batch_spec, previous), key_spec, values_spec))
            except BaseException:
                lock.release()
                raise
            previous = lowered.out_info
            pending[key] = pool.submit(compile_one, key, lowered, time.perf_counter() - begin, lock)
        for key, future in pending.items():  # logged in stage order, whichever compile ends first
            executable, out_info, seconds = future.result()
            _programs[key, where] = executable, out_info
            _compiles.append((key, seconds))


def _bucket_text(bucket: Bucket, devices: int = 1, clips: int = 1) -> str:
    text = f"clips of up to {bucket.T} frames, {bucket.H}x{bucket.W} px, {bucket.P} tracks per pair"
    if devices == 1:
        return text if clips == 1 else f"{text}, {clips} at once"
    return f"{text}, {'one clip' if clips == 1 else f'{clips} clips at once'} on each of {devices} devices"


def release_programs() -> int:
    """Drop every compiled stage (each holds its machine code in memory mappings); how many."""
    count = len(_programs)
    _programs.clear()
    return count


def compile_count() -> int:
    """Stage programs compiled or loaded, and held, by this process."""
    return len(_programs)


def compile_log() -> list[tuple[ProgramKey, float]]:
    """Every stage program this process compiled or loaded, in order, with its seconds (released
    ones too)."""
    return list(_compiles)
