"""How a run reads and spreads its clips (docs/semantics.md §4.1, §4.2). The numbers depend on none
of these; ``score_batch`` and ``iter_scores`` take them as keywords too."""

from __future__ import annotations

import dataclasses

from ..config import SGCConfig

READ_IN = ("auto", "threads", "processes")


@dataclasses.dataclass(frozen=True)
class RunOptions:
    chunk_size: int = 16  # clips read ahead of the device (memory is bounded by it); Ray: clips per task
    readers: int | None = None  # clip readers (default: two threads, or one process per core but two)
    read_in: str = "auto"  # "threads", "processes", or "auto": processes on hosts of more than 4 cores
    devices: int | None = None  # JAX engine: the first that many local devices (default all; devices.clips_per_call)
    lanes: int | None = None  # clips (groups) in flight at once (default: scoring.devices.default_lanes)
    ray_address: str | None = None  # score on a Ray cluster: "auto", "local" or an address
    ray_scorers: int | None = None  # Ray scorer actors (default one per GPU, else per node)

    def __post_init__(self) -> None:
        if self.read_in not in READ_IN:
            raise ValueError(f"read_in must be one of {READ_IN}, got {self.read_in!r}")
        for name in ("chunk_size", "readers", "devices", "lanes", "ray_scorers"):
            value = getattr(self, name)
            if value is not None and value < 1:
                raise ValueError(f"{name} must be at least 1, got {value}")

    @classmethod
    def split(cls, options: dict) -> tuple["RunOptions", dict]:
        """(the RunOptions among keyword ``options``, the SGCConfig fields among the rest); any
        other name raises TypeError naming both lists."""
        mine = {f.name for f in dataclasses.fields(cls)}
        fields = {f.name for f in dataclasses.fields(SGCConfig)}
        unknown = sorted(set(options) - mine - fields)
        if unknown:
            raise TypeError(f"unknown option(s) {unknown}: neither SGCConfig fields ({sorted(fields)}) nor run "
                            f"options ({sorted(mine)})")
        return cls(**{k: v for k, v in options.items() if k in mine}), {k: v for k, v in options.items()
                                                                        if k not in mine}
