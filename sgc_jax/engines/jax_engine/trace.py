"""The function each stage's program traces: imported only to trace, never to run a kept program."""

from __future__ import annotations

from ...config import SGCConfig
from .finish_stage import finish_stage
from .pixel_stage import pixel_stage
from .pose_stage import pose_stage
from .stages import PixelInputs, PoseInputs, ProgramConfig


def run_stage(stage: str, inputs: tuple, key, config) -> dict:
    """One stage on its flat inputs (``stages.stage_inputs``)."""
    if stage == "pixel":
        return pixel_stage(PixelInputs(*inputs), config)
    if stage == "pose":
        return pose_stage(PoseInputs(*inputs), key, config)
    return finish_stage(*inputs, config)


def stage_program(inputs: tuple, key, values, stage: str, static: SGCConfig, vectorized: bool = False) -> dict:
    """A stage as its compiled program runs it: flat inputs, the RANSAC key, the value fields
    (``stages.program_values``), the static config and ``vectorized`` (both jit-static)."""
    return run_stage(stage, inputs, key, ProgramConfig(static, values, stage, vectorized))
