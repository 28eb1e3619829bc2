"""A run's progress bar, its rate counted from the end of the last compile: the clips per second and
time left it shows are those of scoring, not of compiling."""

from __future__ import annotations

import sys

from tqdm.auto import tqdm

from ..engines.jax_engine.compile_notice import compile_seconds


class Progress:
    def __init__(self, total: int, engine: str, show: bool | None, file=None):
        file = file or sys.stderr
        show = file.isatty() if show is None else show
        self.bar = tqdm(total=total, desc=f"sgc ({engine})", unit="clip", disable=not show, file=file)
        self.compiled_s = compile_seconds()

    def advance(self) -> None:
        """One more clip handed on."""
        if compile_seconds() == self.compiled_s or self.bar.disable:
            self.bar.update(1)
            return
        self.compiled_s = compile_seconds()  # a compile ended since the last clip: restart the clock
        done = self.bar.n + 1
        self.bar.reset()
        self.bar.n = self.bar.last_print_n = done
        self.bar.refresh()

    def __enter__(self) -> "Progress":
        return self

    def __exit__(self, *exc) -> None:
        self.bar.close()
