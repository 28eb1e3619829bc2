"""PyTorch tensors in and out of the Scorer (docs/semantics.md §9.5): ``TorchScorer`` takes a batch
of torch tensors on a CPU or a CUDA device, hands them to JAX through DLPack without a copy where
their layout allows, scores them on that device and returns torch tensors there; with
``differentiable=True`` its ``sgc_smooth`` is a torch autograd function, so ``loss.backward()``
reaches the tensors the batch came from. Needs ``pip install "sgc-jax[torch]"``."""

from __future__ import annotations

import warnings
from typing import Any, Mapping

import jax
import numpy as np
import torch

from .calibration import Calibration
from .config import SGCConfig
from .io.clip import ClipFormatError
from .scoring.reward import RewardOptions
from .scoring.scorer import BATCH_ARRAYS, Scorer

#: the batch arrays sgc_smooth is differentiable in (docs/semantics.md §10)
DIFFERENTIABLE = ("depth", "K", "R_wc", "t_wc", "track_prev", "track_curr", "track_conf")
# what JAX takes without x64: wider tensors are narrowed in torch, on their own device
NARROWED = {torch.float64: torch.float32, torch.int64: torch.int32}


class TensorCopyWarning(UserWarning):
    """A batch tensor had to be copied on its way to JAX (``TorchScorer.copies`` says which and why)."""


def jax_device_of(device: torch.device | str) -> jax.Device:
    """The JAX device holding the memory of torch ``device`` (``cpu`` or ``cuda:i``)."""
    device = torch.device(device)
    if device.type == "cpu":
        return jax.devices("cpu")[0]
    if device.type == "cuda":
        try:
            gpus = jax.devices("gpu")
        except RuntimeError:
            raise ValueError(f"torch device {device} is a CUDA device, but this JAX has no GPU backend "
                             "(install jax[cuda12] or jax[cuda13])") from None
        index = device.index if device.index is not None else torch.cuda.current_device()
        if index >= len(gpus):
            raise ValueError(f"torch device {device}: JAX sees {len(gpus)} GPU(s)")
        return gpus[index]
    raise ValueError(f"torch device {device}: a TorchScorer runs on a CPU or a CUDA device")


def to_jax(tensor: torch.Tensor, name: str, device: torch.device) -> tuple[jax.Array, str]:
    """One batch tensor as a ``jax.Array`` on the same memory where DLPack allows -> (array, why it
    was copied: '' when shared). Detached (the caller keeps the graph); float64 and int64 narrowed
    to 32 bits; non-compact strides made contiguous."""
    if not isinstance(tensor, torch.Tensor):
        raise ClipFormatError("<batch>", name, "a torch.Tensor", type(tensor).__name__)
    if tensor.device != device:
        raise ClipFormatError("<batch>", name, f"a tensor on {device} (the TorchScorer's device)",
                              f"a tensor on {tensor.device}")
    reasons = []
    tensor = tensor.detach()
    if tensor.dtype in NARROWED and not jax.config.jax_enable_x64:
        wide, tensor = tensor.dtype, tensor.to(NARROWED[tensor.dtype])
        reasons.append(f"narrowed from {wide} to {tensor.dtype} (JAX runs without x64)")
    try:
        array = jax.dlpack.from_dlpack(tensor)
    except (RuntimeError, BufferError, TypeError) as error:
        if "strid" not in str(error):  # JAX: "trivial (compact) striding"; torch: "stride"
            raise ClipFormatError("<batch>", name, "a tensor DLPack can export", f"dtype {tensor.dtype}",
                                  str(error).splitlines()[0]) from None
        tensor = tensor.contiguous()
        reasons.append("made contiguous (a slice or broadcast view has strides DLPack cannot share)")
        array = jax.dlpack.from_dlpack(tensor)
    if not reasons and tensor.numel() and array.unsafe_buffer_pointer() != tensor.data_ptr():
        reasons.append("copied by JAX (its memory is not aligned as XLA needs)")
    return array, "; ".join(reasons)


def to_torch(array: jax.Array) -> torch.Tensor:
    """A ``jax.Array`` as a torch tensor on the same memory."""
    return torch.from_dlpack(array)


class TorchScorer:
    """``Scorer`` for torch tensors: ``TorchScorer((B, T, H, W, P), device="cuda")(batch)`` -> a
    dict of torch tensors (B,) on ``device`` (docs/semantics.md §9.3, §9.5). ``batch`` holds the
    Scorer's arrays (§9.2) as torch tensors on ``device``; shapes and dtypes as the Scorer checks
    them (``ClipFormatError`` naming the array). Tensors are shared with JAX, not copied, where
    DLPack allows; ``copies`` names those that were not, and why, for the last call."""

    def __init__(self, shape: tuple[int, int, int, int, int], config: SGCConfig | dict | None = None,
                 calibration: Calibration | str | None = None, reward_options: RewardOptions | None = None,
                 *, device: torch.device | str = "cpu", differentiable: bool = False):
        self.device = torch.device(device)
        if self.device.type == "cuda" and self.device.index is None:
            self.device = torch.device("cuda", torch.cuda.current_device())
        self.scorer = Scorer(shape, config, calibration, reward_options, devices=[jax_device_of(self.device)],
                             differentiable=differentiable)
        self.copies: dict[str, str] = {}
        self._warned: set[tuple[str, str]] = set()

    def __repr__(self) -> str:
        return f"TorchScorer(shape={self.scorer.shape}, device={str(self.device)!r})"

    @property
    def shape(self) -> tuple[int, int, int, int, int]:
        return self.scorer.shape

    def arrays(self, batch: Mapping[str, torch.Tensor]) -> dict[str, jax.Array]:
        """The batch's tensors as ``jax.Array``s, shared where DLPack allows (``copies`` says the rest)."""
        if not isinstance(batch, Mapping):
            raise TypeError(f"a TorchScorer takes a dict of torch tensors, got {type(batch).__name__}")
        unknown = sorted(set(batch) - set(BATCH_ARRAYS))
        if unknown:
            raise ClipFormatError("<batch>", unknown[0], f"one of {sorted(BATCH_ARRAYS)}", "an unknown name")
        arrays, self.copies = {}, {}
        for name, tensor in batch.items():
            arrays[name], why = to_jax(tensor, name, self.device)
            if why:
                self.copies[name] = why
                if (name, why) not in self._warned:
                    self._warned.add((name, why))
                    warnings.warn(f"TorchScorer: {name!r} {why}", TensorCopyWarning, stacklevel=3)
        return arrays

    def __call__(self, batch: Mapping[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """The per-clip outputs (B,) of docs/semantics.md §9.3 as torch tensors on ``device``; with
        ``differentiable=True``, ``sgc_smooth`` carries gradients to the batch's float tensors."""
        arrays = self.arrays(batch)
        if not self.scorer.differentiable:
            return {name: to_torch(value) for name, value in self.scorer(arrays).items()}
        names = tuple(name for name in DIFFERENTIABLE if name in batch)
        fixed = {name: value for name, value in arrays.items() if name not in names}
        floats = {name: arrays[name] for name in names}
        outputs: dict[str, torch.Tensor] = {}
        smooth = _SmoothScore.apply(self.scorer, fixed, floats, outputs, *(batch[name] for name in names))
        return {**outputs, "sgc_smooth": smooth}


class _SmoothScore(torch.autograd.Function):
    """sgc_smooth (B,) of the batch's float arrays ``floats`` (the JAX forms of ``tensors``, in
    that order): the Scorer's forward pass in JAX, its ``jax.vjp`` for the backward, both on the
    tensors' device. The other outputs come back in ``outputs`` (not differentiable)."""

    @staticmethod
    def forward(ctx, scorer: Scorer, fixed: dict, floats: dict, outputs: dict, *tensors: torch.Tensor):
        def smooth(floats):
            out = scorer({**fixed, **floats})
            return out["sgc_smooth"], {k: v for k, v in out.items() if k != "sgc_smooth"}

        value, backward, rest = jax.vjp(smooth, floats, has_aux=True)
        outputs.update({name: to_torch(array) for name, array in rest.items()})
        ctx.backward, ctx.names, ctx.dtypes = backward, tuple(floats), [tensor.dtype for tensor in tensors]
        return to_torch(value)

    @staticmethod
    def backward(ctx, grad: torch.Tensor):
        # a sum's backward hands an expanded (stride 0) tensor: to_jax makes it contiguous
        (grads,) = ctx.backward(to_jax(grad, "sgc_smooth's gradient", grad.device)[0])
        inputs = [to_torch(grads[name]).to(dtype) if needed else None
                  for name, dtype, needed in zip(ctx.names, ctx.dtypes, ctx.needs_input_grad[4:])]
        return (None, None, None, None, *inputs)


def batch_tensors(batch: Mapping[str, Any], device: torch.device | str = "cpu") -> dict[str, torch.Tensor]:
    """A NumPy batch (``batch_of``'s) as torch tensors on ``device``, floats as float32 (what the
    Scorer computes in), in torch's own memory (aligned as XLA needs): tensors that reach JAX
    without a copy."""
    def tensor(value):
        value = np.asarray(value)
        return torch.tensor(value.astype(np.float32) if value.dtype == np.float64 else value, device=device)

    return {name: tensor(value) for name, value in batch.items()}


__all__ = ["DIFFERENTIABLE", "TensorCopyWarning", "TorchScorer", "batch_tensors", "jax_device_of", "to_jax",
           "to_torch"]
