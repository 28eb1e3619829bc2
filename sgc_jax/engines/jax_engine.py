"""The JAX engine (docs/semantics.md §3, §7.1): clips padded to bucketed shapes (``buckets``) and
scored one per call by three compiled stages (pixel, pose, finish; traced from ``stages``), each
compiled once per the bucket sizes and static config fields it depends on. This module keeps the
programs: it compiles them, keeps them in the persistent cache and loads them from it, and turns
their outputs into per-pair arrays. This is the one place that maps over clips.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import functools
import os
import sys
import threading
import time
from typing import Any, Callable, NamedTuple

import jax
import numpy as np

from ..codes import EXCLUDED_STATUSES, PAIR_REASONS, REGION_OK
from ..config import VALUE_FIELDS, SGCConfig
from ..io.clip import Clip
from ..io.result import PairArrays
from .buckets import STAGE_FIELDS, STAGES, Bucket, PaddedClips, bucket_for, pad_clip, stage_inputs
from .compile_cache import ProgramLock, cache_hint, compile_messages_on, load_program, program_path, save_program
from .units import in_depth_units


# ----------------------------------------------------------------------------- programs

@dataclasses.dataclass(frozen=True)
class StageKey:
    """One compiled program: a stage, its static config (``stage_config``) and the bucket sizes
    it depends on (pixel: T, H, W, P; pose: T, P; finish: T, H, W)."""

    stage: str
    static: SGCConfig
    shape: tuple[int, ...]

    def __str__(self) -> str:
        return f"{self.stage} {'x'.join(map(str, self.shape))}"


def stage_config(config: SGCConfig, stage: str) -> SGCConfig:
    """What ``stage``'s program depends on: ``config`` with every field but the stage's static
    fields at its default, so that configs differing only elsewhere share the program."""
    defaults, keep = SGCConfig(), set(STAGE_FIELDS[stage])
    return config.replace(**{f.name: getattr(defaults, f.name) for f in dataclasses.fields(SGCConfig)
                             if f.name not in keep})


def stage_key(config: SGCConfig, stage: str, bucket: Bucket) -> StageKey:
    """The program that runs ``stage`` for clips of ``bucket`` under ``config``."""
    T, H, W, P = bucket.T, bucket.H, bucket.W, bucket.P
    shape = {"pixel": (T, H, W, P), "pose": (T, P), "finish": (T, H, W)}[stage]
    return StageKey(stage, stage_config(config, stage), shape)


def program_values(config: SGCConfig) -> dict[str, np.ndarray]:
    """The value fields a program takes as arguments (int32 or float32 scalars; the seed goes in as the key)."""
    return {name: np.asarray(getattr(config, name), np.int32 if isinstance(getattr(config, name), int) else np.float32)
            for name in VALUE_FIELDS if name != "seed"}


# StageKey -> (executable taking (inputs, key, values), its output's shapes); cleared by release_programs
_programs: dict[StageKey, tuple[Callable, Any]] = {}
_compiles: list[tuple[StageKey, float]] = []  # every compile of this process, with its seconds
# Held while programs are compiled or loaded: scoring lanes (threads) that need the same program
# wait for the first one's compile instead of compiling it again. Programs already held are
# looked up without it, so a lane scoring a known bucket never waits for another's compile.
_compiling = threading.Lock()


class BucketProgram(NamedTuple):
    """The three compiled stages that score one padded clip of a bucket."""

    stages: tuple[Callable, ...]

    def __call__(self, batch: PaddedClips, key, values) -> dict:
        batch = PaddedClips(*jax.device_put(tuple(batch)))  # once, not per stage
        out = None
        for stage, program in zip(STAGES, self.stages):
            out = program(stage_inputs(stage, batch, out), key, values)
        return out


# XLA options per stage on CPU devices. XLA CPU's YNNPACK fusions run the pose stage's many small
# reductions and batched products slower than its own loops: without them that stage takes ~175
# against ~220 ms per standard clip and a fifth less CPU time (bench/RESULTS.md); the pixel and
# finish stages gain nothing. An XLA that no longer knows an option compiles without it.
CPU_COMPILER_OPTIONS = {"pose": {"xla_cpu_experimental_ynn_fusion_type": ""}}


def compile_stage(lowered, stage: str, platform: str):
    """``lowered.compile()`` with the stage's ``CPU_COMPILER_OPTIONS`` on a CPU ``platform``."""
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


def _lower(key: StageKey, path, args: tuple):
    """The stage lowered for ``args`` (shapes): from its kept ``jax.export`` file at ``path`` when
    the persistent cache has one, else traced (and kept there when the cache is on). Only tracing
    imports ``stages`` and the kernels."""
    exported = load_program(path) if path is not None else None
    if exported is None:
        from .stages import stage_program

        traced = jax.jit(functools.partial(stage_program, stage=key.stage, static=key.static))
        if path is None:
            return traced.lower(*args)
        exported = jax.export.export(traced)(*args)
        save_program(path, exported)
    return jax.jit(exported.call).lower(*args)


def compiled_program(config: SGCConfig, bucket: Bucket, example: PaddedClips) -> BucketProgram:
    """The stages that score one padded clip of ``bucket`` under ``config``, called as
    ``program(batch, key, values)``. Each stage is compiled once per ``StageKey`` (a line on
    stderr says so); while one compiles, the next is traced. With the persistent cache on, traced
    stages are kept (``compile_cache.program_path``), so a later process skips tracing too, and a
    stage another process is compiling is waited for (``ProgramLock``), then loaded."""
    keys = [stage_key(config, stage, bucket) for stage in STAGES]
    if not all(key in _programs for key in keys):
        with _compiling:
            _compile_missing(config, bucket, example, keys)
    return BucketProgram(tuple(_programs[key][0] for key in keys))


def _compile_missing(config: SGCConfig, bucket: Bucket, example: PaddedClips, keys: list[StageKey]) -> None:
    """``compiled_program``'s work: compile or load the stages of ``keys`` not yet held."""
    missing = [key for key in keys if key not in _programs]
    if missing:
        start = time.perf_counter()
        paths = {key: program_path(key) for key in missing}
        _announce(bucket, missing, all(p is not None and p.exists() for p in paths.values()))
        key_spec, values_spec = _spec(jax.random.PRNGKey(0)), _spec(program_values(config))
        batch_spec = PaddedClips(*_spec(tuple(example)))

        platform = jax.default_backend()

        def compile_one(key: StageKey, lowered, lowered_s: float, lock: ProgramLock):
            try:
                begin = time.perf_counter()
                return (compile_stage(lowered, key.stage, platform), lowered.out_info,
                        lowered_s + time.perf_counter() - begin)
            finally:
                lock.release()

        previous = None
        with concurrent.futures.ThreadPoolExecutor(max_workers=len(missing)) as pool:
            pending = {}
            for key in keys:
                if key in _programs:
                    previous = _programs[key][1]
                    continue
                begin = time.perf_counter()
                lock = ProgramLock(paths[key])  # another process may be compiling it
                try:
                    lowered = _lower(key, paths[key], (stage_inputs(key.stage, batch_spec, previous), key_spec,
                                                        values_spec))
                except BaseException:
                    lock.release()
                    raise
                previous = lowered.out_info
                pending[key] = pool.submit(compile_one, key, lowered, time.perf_counter() - begin, lock)
            for key, future in pending.items():  # logged in stage order, whichever compile ends first
                executable, out_info, seconds = future.result()
                _programs[key] = executable, out_info
                _compiles.append((key, seconds))
        if compile_messages_on():
            print(f" {time.perf_counter() - start:.1f} s", file=sys.stderr, flush=True)


def _announce(bucket: Bucket, missing: list[StageKey], kept: bool) -> None:
    if not compile_messages_on():
        return
    shape = f"clips of up to {bucket.T} frames, {bucket.H}x{bucket.W} px, {bucket.P} tracks per pair"
    stages = ", ".join(key.stage for key in missing)
    if kept:
        text = f"sgc-jax: loading the JAX program for {shape} ({stages}) from the cache ..."
    else:
        text = (f"sgc-jax: compiling the JAX program for {shape} ({stages}; once per shape bucket; tens of "
                f"seconds on a CPU{cache_hint()}) ...")
    print(text, end="", file=sys.stderr, flush=True)


def release_programs() -> int:
    """Drop every compiled stage (each holds its machine code in memory mappings); returns how many."""
    count = len(_programs) + len(STAGES) * len(_sharded)
    _programs.clear()
    _sharded.clear()
    return count


def compile_count() -> int:
    """Stage programs compiled (or loaded from the persistent cache) and held by this process."""
    return len(_programs)


def compile_log() -> list[tuple[StageKey, float]]:
    """Every stage program this process compiled (or loaded from the persistent cache), in order,
    with its seconds (tracing or loading included), released ones included."""
    return list(_compiles)


def _pair_arrays(out: dict, b: int, n_pairs: int, depth_unit: float, scale: float) -> PairArrays:
    """Clip b's arrays, with its depth unit D and the scale to report (depth units per pose unit)."""
    take = lambda name: np.asarray(out[name][b, :n_pairs])  # noqa: E731
    status = take("region_status")
    posed = (status == REGION_OK) | np.isin(status, EXCLUDED_STATUSES)
    R_local = np.where(posed[..., None, None], take("R_local"), np.nan).astype(np.float64)
    t_local = np.where(posed[..., None], take("t_local"), np.nan).astype(np.float64)
    per_region = lambda name: np.where(posed, take(name), np.nan).astype(np.float64)  # noqa: E731
    return PairArrays(
        **{name: take(name).astype(np.float64) for name in (
            "local_rot_var", "local_trans_var", "global_rot_var", "global_trans_var", "depth_error",
            "reproj_error", "t_g_norm", "R_g_angle_deg")},
        n_tracks=take("n_tracks"), n_regions=take("n_regions"), n_poses=take("n_poses"),
        n_ill_conditioned=take("n_ill_conditioned"),
        reason=np.array([PAIR_REASONS[c] for c in take("reason")], dtype=object),
        R_local=R_local, t_local=t_local, region_status=status, region_points=take("region_points"),
        region_reproj=per_region("region_reproj"), region_rot_std=per_region("region_rot_std"),
        region_trans_std=per_region("region_trans_std"),
        scale=scale, depth_unit=depth_unit)


class PreparedClip(NamedTuple):
    """A clip ready for the device: padded to its bucket (host arrays, ``prepare_clip``)."""

    n_pairs: int
    bucket: Bucket
    batch: PaddedClips
    depth_unit: float


def prepare_clip(clip: Clip, config: SGCConfig) -> PreparedClip:
    """The host side of scoring a clip: depth units and padding (NumPy only, safe in a thread)."""
    clip, unit = in_depth_units(clip, config)
    bucket = bucket_for(clip)
    return PreparedClip(clip.n_pairs, bucket, pad_clip(clip, bucket, config, unit), unit)


class Dispatched(NamedTuple):
    """Clips whose program has been called (one, ``dispatch``; one per device,
    ``dispatch_group``): ``out`` holds device arrays still being computed, clip b at index b."""

    prepared: list[PreparedClip]
    out: dict


def dispatch(prepared: PreparedClip, config: SGCConfig) -> Dispatched:
    """Start scoring a prepared clip on the default device and return without waiting for it
    (JAX dispatches asynchronously; a bucket's first clip compiles its program first)."""
    key, values = jax.random.PRNGKey(config.seed), program_values(config)
    program = compiled_program(config, prepared.bucket, prepared.batch)
    return Dispatched([prepared], program(prepared.batch, key, values))


def collect(dispatched: Dispatched, config: SGCConfig) -> list[PairArrays]:
    """Wait for dispatched clips; their per-pair arrays, in order (a filled group's copies dropped)."""
    out = jax.device_get(dispatched.out)
    results = []
    for b, prepared in enumerate(dispatched.prepared):
        # s (per unit of D inside) is reported in depth units per pose unit; 1 when no global
        # translation is scaled (the w/o-VGGT variant)
        scale = float(np.asarray(out["scale"][b])) * prepared.depth_unit if config.global_pose else 1.0
        results.append(_pair_arrays(out, b, prepared.n_pairs, prepared.depth_unit, scale))
    return results


def score_pairs_batch(clips: list[Clip], config: SGCConfig | None = None) -> list[PairArrays]:
    """Per-pair arrays of every clip, one program call per clip on the default JAX device; the
    next clip is dispatched before the previous one's outputs are fetched."""
    config = config or SGCConfig()
    results, pending = [], None
    for clip in clips:
        current = dispatch(prepare_clip(clip, config), config)
        if pending is not None:
            results.extend(collect(pending, config))
        pending = current
    if pending is not None:
        results.extend(collect(pending, config))
    return results


# ----------------------------------------------------------------------------- lanes and devices


# Clips scored at once on CPU devices, at most: XLA runs one clip's program on about 1.5 of the
# 2-core box's cores, and a second clip at once fills the rest; a third gains nothing there and a
# fourth loses (bench/RESULTS.md). Larger CPUs are unmeasured.
CPU_LANES = 2
# On an accelerator: one clip computes while the other lane fetches the previous clip's results
# and sends the next clip's arrays (the device runs one program at a time either way).
ACCELERATOR_LANES = 2


def host_cores() -> int:
    """The CPU cores this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def default_lanes(devices: list) -> int:
    """Clips (or groups of one clip per device) the streaming scorer keeps in flight at once on
    ``devices``: on CPU devices one per core of each device's share, up to CPU_LANES (forced host
    devices share the same cores); on an accelerator ACCELERATOR_LANES."""
    if devices and devices[0].platform == "cpu":
        return max(1, min(host_cores() // len(devices), CPU_LANES))
    return ACCELERATOR_LANES


def scoring_devices(limit: int | None = None) -> list:
    """The local devices of the default backend that clips are spread over: all of them, or the
    first ``limit``."""
    devices = jax.local_devices()
    if limit is not None and limit < 1:
        raise ValueError(f"devices must be at least 1, got {limit}")
    return devices[:limit] if limit else devices


# (stage keys, device ids) -> (the stages over a batch of one clip per device, the batch's sharding)
_sharded: dict[tuple, tuple["BucketProgram", Any]] = {}


def sharded_program(config: SGCConfig, bucket: Bucket, devices: list, example: PaddedClips) -> tuple:
    """The three stages over a batch of one clip per device (leading axis B = len(devices)),
    the clip axis sharded over ``devices`` (``jax.sharding``, ``shard_map``): each device runs
    the one-clip stage programs on its own clip, so the numbers are those of one device.
    Compiled once per bucket, static config and device set (a line on stderr says so); with the
    persistent cache on, JAX keeps the compiled stages and a later process only traces them.
    -> (BucketProgram, the batch's sharding)"""
    keys = tuple(stage_key(config, stage, bucket) for stage in STAGES)
    cache_key = (keys, tuple(d.id for d in devices))
    if cache_key not in _sharded:
        with _compiling:
            if cache_key not in _sharded:
                _sharded[cache_key] = _compile_sharded(config, bucket, devices, example, keys)
    return _sharded[cache_key]


def _compile_sharded(config: SGCConfig, bucket: Bucket, devices: list, example: PaddedClips, keys: tuple) -> tuple:
    """``sharded_program``'s compile -> (BucketProgram, the batch's sharding)."""
    from jax.sharding import Mesh, NamedSharding, PartitionSpec

    from .stages import stage_program

    mesh = Mesh(np.array(devices), ("clips",))
    clips, replicated = PartitionSpec("clips"), PartitionSpec()
    sharding = NamedSharding(mesh, clips)
    start = time.perf_counter()
    if compile_messages_on():
        print(f"sgc-jax: compiling the JAX program for clips of up to {bucket.T} frames, {bucket.H}x{bucket.W} "
              f"px, {bucket.P} tracks per pair, one clip on each of {len(devices)} devices (once per shape "
              "bucket) ...", end="", file=sys.stderr, flush=True)
    batch_spec = PaddedClips(*(jax.ShapeDtypeStruct(np.shape(a), a.dtype, sharding=sharding) for a in example))
    key_spec, values_spec = _spec(jax.random.PRNGKey(0)), _spec(program_values(config))
    stages, previous = [], None
    for key in keys:  # one program per stage, as on one device (the same fusions, the same numbers)
        # check_vma off: the kernels' loops start from constants that the per-device clip makes
        # device-varying, which the check would have every loop annotate
        spread = jax.shard_map(functools.partial(stage_program, stage=key.stage, static=key.static), mesh=mesh,
                               in_specs=(clips, replicated, replicated), out_specs=clips, check_vma=False)
        lowered = jax.jit(spread).lower(stage_inputs(key.stage, batch_spec, previous), key_spec, values_spec)
        previous = lowered.out_info
        stages.append(compile_stage(lowered, key.stage, devices[0].platform))
    if compile_messages_on():
        print(f" {time.perf_counter() - start:.1f} s", file=sys.stderr, flush=True)
    return BucketProgram(tuple(stages)), sharding


def dispatch_group(group: list[PreparedClip], config: SGCConfig, devices: list) -> Dispatched:
    """Start scoring up to len(devices) prepared clips of one bucket, one per device (a short
    group is filled with copies of its last clip, which ``collect`` leaves out)."""
    fill = [group[-1].batch] * (len(devices) - len(group))
    stacked = PaddedClips(*(np.concatenate(arrays) for arrays in zip(*[p.batch for p in group], *fill)))
    program, sharding = sharded_program(config, group[0].bucket, devices, stacked)
    key, values = jax.random.PRNGKey(config.seed), program_values(config)
    return Dispatched(group, program(PaddedClips(*jax.device_put(tuple(stacked), sharding)), key, values))
