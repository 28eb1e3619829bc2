"""``Scorer``: SGC of a batch of clips already in memory or on a device, as one set of compiled
programs for a fixed shape, with no host round-trip (docs/semantics.md §9). For training and
sampling loops; ``score_batch`` stays the way to score files."""

from __future__ import annotations

import concurrent.futures
import functools
from typing import Any, Iterable, Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from ..calibration import Calibration
from ..config import SGCConfig
from ..engines.jax_engine.buckets import PaddedClips, bucket_for_shape
from ..engines.jax_engine.compile_cache import cache_hint, enable_compilation_cache
from ..engines.jax_engine.compile_notice import CompileNotice
from ..engines.jax_engine.device_prepare import ClipArrays, prepare_on_device
from ..engines.jax_engine.programs import pipeline, traced_pipeline
from ..engines.jax_engine.smooth_stage import check_differentiable, frozen_choices, smooth_stage
from ..io.arrays import checked_in_memory, mask_truth
from ..io.clip import Clip, ClipFormatError
from ..io.npz import shape_text
from ..stats import camera_dynamics
from .api import resolve_calibration, resolve_config
from .devices import default_lanes, vectorizes
from .reward import RewardOptions, reward
from .summary import summarize_on_device

#: name -> (its shape in terms of B, T, H, W, P; its kind: float, mask or count)
BATCH_ARRAYS = {
    "depth": (("B", "T", "H", "W"), "float"), "K": (("B", "T", 3, 3), "float"),
    "R_wc": (("B", "T", 3, 3), "float"), "t_wc": (("B", "T", 3), "float"),
    "static_mask": (("B", "T", "H", "W"), "mask"), "track_prev": (("B", "T-1", "P", 2), "float"),
    "track_curr": (("B", "T-1", "P", 2), "float"), "track_vis": (("B", "T-1", "P"), "mask"),
    "track_conf": (("B", "T-1", "P"), "float"), "n_frames": (("B",), "count"), "n_tracks": (("B",), "count"),
    "heights": (("B",), "count"), "widths": (("B",), "count"),
}
PROGRAM_DTYPES = {"float": jnp.float32, "mask": jnp.bool_, "count": jnp.int32}
OPTIONAL = {"track_conf": 1.0, "n_frames": "T", "n_tracks": "P", "heights": "H", "widths": "W"}
# max_tracks beyond this would overflow the int32 arithmetic of the track selection
MAX_SELECTED_TRACKS = 46340


def batch_of(clips: Iterable[Clip], shape: tuple[int, int, int, int] | None = None) -> dict[str, np.ndarray]:
    """Clips (any iterable, e.g. ``load_clips(dir)``'s generator) stacked into a Scorer's batch
    (NumPy), each padded with zeros to ``shape`` = (T, H, W, P) (default: the largest of each size)
    and its true sizes given. Each clip is read through the checks of a clip given in memory
    (``arrays.checked_in_memory``): a malformed one raises ClipFormatError naming its array."""
    clips = [checked_in_memory(clip) for clip in clips]
    if not clips:
        raise ValueError("batch_of needs at least one clip")
    T, H, W, P = shape or tuple(max(sizes) for sizes in zip(*[(c.n_frames, *c.image_size, c.n_tracks) for c in clips]))
    for clip in clips:
        sizes = (clip.n_frames, *clip.image_size, clip.n_tracks)
        if any(n > limit for n, limit in zip(sizes, (T, H, W, P))):
            raise ClipFormatError(clip.clip_id, "depth and tracks",
                                  f"at most the batch shape (T, H, W, P) = {(T, H, W, P)}", f"(T, H, W, P) = {sizes}")
    fields = {"depth": (T, H, W), "K": (T, 3, 3), "R_wc": (T, 3, 3), "t_wc": (T, 3), "static_mask": (T, H, W),
              "track_prev": (T - 1, P, 2), "track_curr": (T - 1, P, 2), "track_vis": (T - 1, P),
              "track_conf": (T - 1, P)}
    batch = {}
    for name, full in fields.items():
        stacked = np.zeros((len(clips), *full), getattr(clips[0], name).dtype)
        for b, clip in enumerate(clips):
            value = getattr(clip, name)
            stacked[(b, *(slice(0, n) for n in value.shape))] = value
        batch[name] = stacked
    batch.update(n_frames=np.array([c.n_frames for c in clips], np.int32),
                 n_tracks=np.array([c.n_tracks for c in clips], np.int32),
                 heights=np.array([c.image_size[0] for c in clips], np.int32),
                 widths=np.array([c.image_size[1] for c in clips], np.int32))
    return batch


batch_camera_dynamics = jax.jit(functools.partial(camera_dynamics, xp=jnp))


def _traced(clips: ClipArrays) -> bool:
    return any(isinstance(leaf, jax.core.Tracer) for leaf in clips)


def _dtype_kind(array) -> str:
    dtype = np.dtype(array.dtype)
    return "bool" if dtype == bool else dtype.kind  # f float, i/u integer


class Scorer:
    """SGC of batches of B clips of one shape: ``Scorer((B, T, H, W, P))(batch)`` -> a dict of
    ``jax.Array`` (B,) (docs/semantics.md §9). ``batch`` holds the clip arrays of §1.2 stacked on
    a leading B axis (NumPy or ``jax.Array``); a clip smaller than the shape gives its true sizes
    in ``n_frames``, ``n_tracks``, ``heights``, ``widths`` and pads the rest with anything.
    Compiled when constructed; callable inside ``jax.jit``."""

    def __init__(self, shape: tuple[int, int, int, int, int], config: SGCConfig | dict | None = None,
                 calibration: Calibration | str | None = None, reward_options: RewardOptions | None = None,
                 *, devices: Sequence[jax.Device] | None = None, vectorized: bool | None = None,
                 differentiable: bool = False):
        if len(shape) != 5 or not all(isinstance(s, (int, np.integer)) and s >= 1 for s in shape) or shape[1] < 2:
            raise ValueError(f"shape must be (B, T, H, W, P) of positive ints with T >= 2, got {shape!r}")
        self.shape = B, T, H, W, P = tuple(int(s) for s in shape)
        self.config = config = resolve_config(config, {})
        if P > config.max_tracks > MAX_SELECTED_TRACKS:
            raise ValueError(f"max_tracks={config.max_tracks}: the Scorer selects at most {MAX_SELECTED_TRACKS}")
        self.calibration = resolve_calibration(calibration, config)
        self.reward_options = reward_options or RewardOptions()
        self.differentiable = bool(differentiable)
        if self.differentiable:
            check_differentiable(config)
        self.bucket = bucket_for_shape(T, H, W, min(P, config.max_tracks))
        # where the batch runs (docs/semantics.md §9.3): an accelerator's clips in one vectorized
        # program sharded over the local devices; on CPU one clip after another, the batch split
        # into lanes that run at once in threads (one program keeps ~1.5 of 2 cores busy)
        cpu = jax.default_backend() == "cpu"
        self.devices = list(devices) if devices else jax.local_devices()[:1 if cpu else None]
        self.vectorized = vectorizes(self.devices) if vectorized is None else bool(vectorized)
        one_cpu = self.devices[0].platform == "cpu" and len(self.devices) == 1
        # lanes are threads of compiled programs; a differentiable batch runs as one program
        self.lanes = min(B, default_lanes(self.devices)) if one_cpu and not self.differentiable else 1
        # the clips of one program call: a lane's share, or B filled up to a multiple of the devices
        n = len(self.devices)
        self.call_size = -(-B // self.lanes) if self.lanes > 1 else -(-B // n) * n
        # one program over exactly the B clips: its outputs, ECD included, need no mending
        self._one_program = self.lanes == 1 and n == 1
        # on the default device, a CPU, the clips of a call run one after another anyway
        # (``lax.map``): run them through score_batch's one-clip stage programs, so that the two
        # share their compile
        self._clip_by_clip = (one_cpu and self.devices[0] == jax.local_devices()[0] and not self.vectorized
                              and not self.differentiable)
        self._mesh = jax.sharding.Mesh(np.array(self.devices), ("clips",))
        self._traced = self._traceable_programs()
        enable_compilation_cache()
        self._compiled = self._compile()
        self._pool = concurrent.futures.ThreadPoolExecutor(self.lanes, "sgc-scorer") if self.lanes > 1 else None

    def __repr__(self) -> str:
        return f"Scorer(shape={self.shape}, compat={self.config.compat!r}, calibration={self.calibration.name!r})"

    # ------------------------------------------------------------------ programs

    def _traceable_programs(self) -> dict:
        """Each step as a jitted function: prepare, the stages' pipeline (each device runs it on its
        share of the clips, as ``score_batch``'s groups do), summarize."""
        bucket, config, mesh = self.bucket, self.config, self._mesh
        steps = {"prepare": lambda clips: prepare_on_device(clips, bucket, config), "summarize": self._summarize}
        if len(self.devices) == 1:
            steps = {name: jax.jit(step) for name, step in steps.items()}
        else:
            clips = jax.sharding.PartitionSpec("clips")
            in_specs = {"prepare": (clips,), "summarize": (clips,) * 5}
            steps = {name: jax.jit(jax.shard_map(step, mesh=mesh, in_specs=in_specs[name], out_specs=clips,
                                                 check_vma=False))
                     for name, step in steps.items()}
        steps["stages"] = traced_pipeline(config, bucket, self.devices, self.vectorized)
        if self.differentiable:
            steps["smooth"] = jax.jit(lambda clips, frozen: smooth_stage(clips, frozen, bucket, config,
                                                                         self.calibration))
        return steps

    def _summarize(self, out: dict, pair_valid, depth_unit, K, image_hw) -> dict:
        summary = summarize_on_device(out, pair_valid, depth_unit, K, image_hw, self.calibration, self.config.compat,
                                      self.reward_options.evidence)
        return {**summary, **reward(summary, self.calibration, self.reward_options)}

    def _compile(self) -> dict:
        """Each step compiled for one call's clips; the stages are ``score_batch``'s pipeline: its
        one-clip programs on one CPU (shared with it, in this process and in the persistent cache),
        else its programs for groups of this size."""
        B, T, H, W, P = self.shape
        n = len(self.devices)
        spread = f" in {self.lanes} lanes of {self.call_size}" if self.lanes > 1 else \
            f" over {n} devices" if n > 1 else ""
        what = f"a Scorer of {B} clip{'s' if B > 1 else ''}{spread} of {T} frames, {H}x{W} px, {P} tracks per pair"
        with CompileNotice(what, "prepare", loading=False, hint=cache_hint()):
            prepare = self._traced["prepare"].lower(self._example()).compile()
        padded = PaddedClips(*prepare.out_info)
        if self._clip_by_clip:
            stages = pipeline(self.config, self.bucket, PaddedClips(*(_one_clip(leaf) for leaf in padded)))
            out = {name: _one_clip(leaf, self.call_size) for name, leaf in stages.programs[-1].out_info.items()}
        else:
            stages = pipeline(self.config, self.bucket, padded, self.devices, self.vectorized)
            out = stages.programs[-1].out_info
        summarize = self._traced["summarize"].lower(out, *summary_inputs(padded)).compile()  # small
        compiled = {"prepare": prepare, "stages": stages, "summarize": summarize}
        if self.differentiable:
            with CompileNotice(what, "differentiable score", loading=False, hint=cache_hint()):
                frozen = jax.eval_shape(frozen_choices, *(program.out_info for program in stages.programs),
                                        padded.pair_valid, summarize.out_info)
                compiled["smooth"] = self._traced["smooth"].lower(self._example(), frozen).compile()
        return compiled

    def _example(self) -> ClipArrays:
        """One call's ClipArrays as shapes, the dtypes ``clip_arrays`` casts to and the sharding
        the call puts them in."""
        sizes = self._sizes(self.call_size)
        return ClipArrays(**{name: jax.ShapeDtypeStruct(tuple(sizes.get(d, d) for d in dims), PROGRAM_DTYPES[kind],
                                                        sharding=self._sharding())
                             for name, (dims, kind) in BATCH_ARRAYS.items()})

    def _sharding(self):
        if len(self.devices) == 1:
            return jax.sharding.SingleDeviceSharding(self.devices[0])
        return jax.sharding.NamedSharding(self._mesh, jax.sharding.PartitionSpec("clips"))

    def _sizes(self, B: int) -> dict[str, int]:
        _, T, H, W, P = self.shape
        return {"B": B, "T": T, "T-1": T - 1, "H": H, "W": W, "P": P}

    # ------------------------------------------------------------------ calls

    def clip_arrays(self, batch: Mapping[str, Any]) -> ClipArrays:
        """``batch`` checked against the Scorer's shape (``ClipFormatError`` naming the array) and
        cast to the dtypes the programs take; works on tracers."""
        if not isinstance(batch, Mapping):
            raise TypeError(f"a Scorer takes a dict of clip arrays, got {type(batch).__name__}")
        sizes = self._sizes(self.shape[0])
        unknown = sorted(set(batch) - set(BATCH_ARRAYS))
        if unknown:
            raise ClipFormatError("<batch>", unknown[0], f"one of {sorted(BATCH_ARRAYS)}", "an unknown name")
        arrays = {}
        for name, (dims, kind) in BATCH_ARRAYS.items():
            expected = tuple(sizes.get(d, d) for d in dims)
            if name not in batch:
                if name not in OPTIONAL:
                    raise ClipFormatError("<batch>", name, f"shape {shape_text(expected)}", "no such array")
                default = OPTIONAL[name]
                arrays[name] = jnp.full(expected, sizes[default] if isinstance(default, str) else default,
                                        PROGRAM_DTYPES[kind])
                continue
            value = batch[name]
            if not hasattr(value, "shape") or not hasattr(value, "dtype"):
                value = np.asarray(value)
            if tuple(value.shape) != expected:
                raise ClipFormatError("<batch>", name, f"shape {shape_text(expected)} for the Scorer's "
                                      f"(B, T, H, W, P) = {self.shape}", f"shape {shape_text(value.shape)}")
            found = _dtype_kind(value)
            allowed = {"float": "f", "mask": "bfiu", "count": "iu"}[kind]
            if found == "bool" and "b" not in allowed or found != "bool" and found not in allowed:
                raise ClipFormatError("<batch>", name, {"float": "a float dtype", "mask": "bool or numbers",
                                                        "count": "an integer dtype"}[kind], f"dtype {value.dtype}")
            if kind == "mask":  # as the loader reads them: a float track_vis is visible where > 0, a static
                # mask by the loader's own reading (mask_truth)
                arrays[name] = value if found == "bool" else (
                    jnp.asarray(value) > 0 if name == "track_vis" else mask_truth(jnp.asarray(value)))
            else:
                arrays[name] = jnp.asarray(value, PROGRAM_DTYPES[kind])
        return ClipArrays(**arrays)

    def __call__(self, batch: Mapping[str, Any]) -> dict[str, jax.Array]:
        """The per-clip outputs (B,) of docs/semantics.md §9.3, as device arrays (not waited for;
        on CPU lanes, once the lanes are done)."""
        clips = self.clip_arrays(batch)
        B, n = self.shape[0], len(self.devices)
        if self.differentiable:  # the forward pass makes the choices; only sgc_smooth carries gradients
            # placed alike whatever the caller's arrays carry (a descent's inputs come from earlier
            # outputs, which hold the mesh's sharding): one program for every call
            live = jax.device_put(self._rows(clips, 0, self.call_size), self._sharding())
            fixed = jax.lax.stop_gradient(live)  # concrete under an eager jax.grad: the compiled forward runs
            return self._whole(self._run(self._traced if _traced(fixed) else self._compiled, fixed, live))
        if _traced(clips):  # inside a user's jit: one program
            return self._whole(self._run(self._traced, self._rows(clips, 0, -(-B // n) * n)))
        parts = [jax.device_put(self._rows(clips, start, self.call_size), self._sharding())
                 for start in range(0, B, self.call_size)]
        if self._pool is None:
            return self._whole(self._run(self._compiled, parts[0]))
        # each lane waits for its programs, so that the lanes' work overlaps
        lanes = list(self._pool.map(lambda part: jax.block_until_ready(self._run(self._compiled, part)), parts))
        return self._whole({name: jnp.concatenate([lane[name] for lane in lanes]) for name in lanes[0]})

    def choices(self, batch: Mapping[str, Any]):
        """What the forward pass of ``batch`` chose (``smooth_stage.Frozen``, leading axis B), the
        choices ``sgc_smooth`` holds fixed (docs/semantics.md §10.1)."""
        clips = jax.device_put(self._rows(self.clip_arrays(batch), 0, self.call_size), self._sharding())
        padded, outs = self._stages(self._compiled, clips, every=True)
        summary = self._compiled["summarize"](outs[-1], *summary_inputs(padded))
        frozen = frozen_choices(*outs, padded.pair_valid, summary)
        return jax.tree.map(lambda leaf: leaf[:self.shape[0]], frozen)

    def _rows(self, clips: ClipArrays, start: int, size: int) -> ClipArrays:
        """Clips start .. start + size - 1 of the batch, those past its end copies of its last clip."""
        B = self.shape[0]
        if start == 0 and size == B:
            return clips
        index = np.minimum(np.arange(start, start + size), B - 1)
        return ClipArrays(*(leaf[index] for leaf in clips))

    def _whole(self, out: dict) -> dict:
        """The outputs of the batch's B clips, without filled copies, ECD over exactly them (not
        over a lane's or a device's share)."""
        if self._one_program:
            return out
        B = self.shape[0]
        out = {name: value[:B] for name, value in out.items()}
        return {**out, "ecd": batch_camera_dynamics(out["ecd_trans"], out["ecd_rot"])}

    def _stages(self, programs: dict, clips: ClipArrays, every: bool = False) -> tuple:
        """(the padded clips, the three stages' outputs); clip by clip where the Scorer runs so,
        only the finish's put together unless ``every``."""
        padded = programs["prepare"](clips)
        if programs is self._traced or not self._clip_by_clip:  # traced: one program over the batch
            return padded, programs["stages"].outputs(padded)
        per_clip = [programs["stages"].outputs(PaddedClips(*(leaf[i:i + 1] for leaf in padded)))
                    for i in range(self.call_size)]
        by_stage = list(zip(*per_clip))
        joined = lambda outs: {name: jnp.concatenate([out[name] for out in outs]) for name in outs[0]}  # noqa: E731
        return padded, [joined(outs) if every or stage == len(by_stage) - 1 else None
                        for stage, outs in enumerate(by_stage)]

    def _run(self, programs: dict, clips: ClipArrays, live: ClipArrays | None = None) -> dict:
        """The steps on one call's clips; with ``live`` (the differentiable form: the same clips
        with their gradients), sgc_smooth from the stages' choices."""
        padded, outs = self._stages(programs, clips)
        summary = programs["summarize"](outs[-1], *summary_inputs(padded))
        if live is None:
            return summary
        smooth = self._traced["smooth"] if _traced(live) else programs["smooth"]
        return {**summary, "sgc_smooth": smooth(live, frozen_choices(*outs, padded.pair_valid, summary))}


def _one_clip(spec, clips: int = 1):
    """A program's (B, ...) input or output shape with ``clips`` clips instead of B."""
    return jax.ShapeDtypeStruct((clips,) + tuple(spec.shape[1:]), spec.dtype)


def summary_inputs(padded: PaddedClips) -> tuple:
    """What the summary reads of the padded clips besides the stages' output."""
    return padded.pair_valid, padded.depth_unit, padded.K, padded.image_hw
