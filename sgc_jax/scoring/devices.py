"""Where a run's clips are scored: the local devices, how many clips are in flight at once on them
(lanes), and the host's cores for the readers (docs/semantics.md §4.1)."""

from __future__ import annotations

import os

import jax

# Clips scored at once on CPU devices, at most: XLA runs one clip's program on about 1.5 of the
# 2-core box's cores, a second fills the rest, a third gains nothing
# (bench/history/issue-21.md, "Lanes: two clips at once on a CPU").
CPU_LANES = 2
# On an accelerator: one clip computes while another lane fetches the last clip's results and
# sends the next clip's arrays.
ACCELERATOR_LANES = 2
# Clips per program call on each accelerator: one vectorized program poses all their pairs at
# once (docs/semantics.md §9.3). A size, not a measured optimum: no GPU run has compared others
# for score_batch (the Scorer's batch sizes: bench/history/issue-40.md, "The Scorer fills an
# accelerator"; bench/reward.py).
ACCELERATOR_CLIPS_PER_DEVICE = 16


def host_cores() -> int:
    """The CPU cores this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def default_lanes(devices: list) -> int:
    """Clips (or groups, ``clips_per_call``) in flight at once on ``devices``: on CPU devices
    one per core of each device's share, up to CPU_LANES; on an accelerator ACCELERATOR_LANES."""
    if devices and devices[0].platform == "cpu":
        return max(1, min(host_cores() // len(devices), CPU_LANES))
    return ACCELERATOR_LANES


def vectorizes(devices: list) -> bool:
    """Whether programs on ``devices`` run their clips, frames and pairs at once (accelerators) or
    one after another (CPU: unbatched scatters are faster, each loop stops at its own end)."""
    return bool(devices) and devices[0].platform != "cpu"


def clips_per_call(devices: list) -> int:
    """Clips scored by one program call over ``devices``: one per device on CPU,
    ACCELERATOR_CLIPS_PER_DEVICE per device where programs are vectorized."""
    return (ACCELERATOR_CLIPS_PER_DEVICE if vectorizes(devices) else 1) * len(devices)


def scoring_devices(limit: int | None = None) -> list:
    """The default backend's local devices clips are spread over: all, or the first ``limit``."""
    devices = jax.local_devices()
    if limit is not None and limit < 1:
        raise ValueError(f"devices must be at least 1, got {limit}")
    return devices[:limit] if limit else devices
