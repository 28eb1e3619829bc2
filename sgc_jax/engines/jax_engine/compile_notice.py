"""The word on stderr while programs compile: on a terminal one line whose elapsed seconds count
up (cut to the terminal's width while it counts: a wrapped line cannot be rewritten in place), piped
one line when it is done. ``SGC_JAX_COMPILE_MESSAGES=off`` silences it."""

from __future__ import annotations

import os
import shutil
import sys
import threading
import time

_OFF = {"off", "0", "false", "no", "disabled"}
_lock = threading.Lock()
_finished_s = 0.0  # seconds this process spent in finished compiles


def compile_messages_on() -> bool:
    return os.environ.get("SGC_JAX_COMPILE_MESSAGES", "").strip().lower() not in _OFF


def compile_seconds() -> float:
    """Seconds this process has spent compiling or loading programs (finished ones); a progress
    bar restarts its rate when this changes."""
    return _finished_s


class CompileNotice:
    """``with CompileNotice("clips of ...", "pixel, pose", loading=False):`` around a compile."""

    def __init__(self, what: str, stages: str, *, loading: bool, hint: str = "", stream=None):
        self.stream = stream or sys.stderr
        if loading:
            self.text = f"sgc-jax: loading the JAX program for {what} ({stages}) from the cache ..."
        else:
            self.text = (f"sgc-jax: compiling the JAX program for {what} ({stages}; once per shape bucket; tens "
                         f"of seconds on a CPU{hint}) ...")
        self.live = self.stream.isatty() if hasattr(self.stream, "isatty") else False
        self._stop = threading.Event()
        self._ticker: threading.Thread | None = None

    def _write(self, text: str) -> None:
        self.stream.write(text)
        self.stream.flush()

    def _fitted(self, suffix: str) -> str:
        """The text and ``suffix`` cut to one row of the terminal, so that ``\\r`` rewrites all of it."""
        try:
            columns = os.get_terminal_size(self.stream.fileno()).columns
        except (AttributeError, OSError, ValueError):
            columns = shutil.get_terminal_size().columns
        room = max(columns - 1 - len(suffix), 4)
        text = self.text if len(self.text) <= room else self.text[:room - 3] + "..."
        return text + suffix

    def _tick(self) -> None:
        while not self._stop.wait(1.0):
            self._write("\r\x1b[K" + self._fitted(f" {time.perf_counter() - self.start:.0f} s"))

    def __enter__(self) -> "CompileNotice":
        self.start = time.perf_counter()
        if compile_messages_on():
            self._write("\r\x1b[K" + self._fitted("") if self.live else self.text)
            if self.live:
                self._ticker = threading.Thread(target=self._tick, name="sgc-compile-notice", daemon=True)
                self._ticker.start()
        return self

    def __exit__(self, *exc) -> None:
        global _finished_s
        seconds = time.perf_counter() - self.start
        with _lock:
            _finished_s += seconds
        if self._ticker is not None:
            self._stop.set()
            self._ticker.join()
        if compile_messages_on():
            self._write((f"\r\x1b[K{self.text}" if self.live else "") + f" {seconds:.1f} s\n")
