"""The word while programs compile (docs/semantics.md §7.1): alive on a terminal, one line when piped,
and a progress bar whose rate starts after the compile."""

import io
import time

import pytest

from sgc_jax.engines.jax_engine import compile_notice
from sgc_jax.engines.jax_engine.compile_notice import CompileNotice
from sgc_jax.scoring.progress import Progress


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


@pytest.fixture(autouse=True)
def messages_on(monkeypatch):
    monkeypatch.delenv("SGC_JAX_COMPILE_MESSAGES", raising=False)


def test_on_a_terminal_the_elapsed_seconds_count_up():
    stream = Terminal()
    with CompileNotice("clips of up to 4 frames", "pose", loading=False, stream=stream):
        time.sleep(2.3)
    lines = stream.getvalue().split("\r\x1b[K")
    assert [line.rsplit(" ", 2)[-2:] for line in lines[2:4]] == [["1", "s"], ["2", "s"]]
    assert lines[-1].startswith("sgc-jax: compiling the JAX program for clips of up to 4 frames (pose;")
    assert lines[-1].endswith(" s\n") and stream.getvalue().count("\n") == 1


def test_on_a_narrow_terminal_each_rewrite_fits_one_row_and_the_last_line_is_whole(monkeypatch):
    monkeypatch.setenv("COLUMNS", "60")  # a wrapped row would stay behind at every rewrite
    stream = Terminal()
    with CompileNotice("clips of up to 4 frames, 288x512 px, 4096 tracks per pair", "pixel, pose, finish",
                       loading=False, stream=stream):
        time.sleep(1.2)
    *rewrites, last = stream.getvalue().split("\r\x1b[K")[1:]
    assert len(rewrites) >= 2 and all(len(line) < 60 for line in rewrites)
    assert rewrites[-1].endswith("... 1 s")
    assert last.startswith("sgc-jax: compiling the JAX program for clips of up to 4 frames, 288x512 px, 4096 tracks")
    assert "(pixel, pose, finish; once per shape bucket" in last and last.endswith(" s\n")


def test_piped_the_notice_is_one_line_with_the_seconds():
    stream = io.StringIO()
    with CompileNotice("clips of up to 4 frames", "pixel, pose", loading=True, stream=stream):
        time.sleep(0.1)
    text = stream.getvalue()
    assert text.startswith("sgc-jax: loading the JAX program for clips of up to 4 frames (pixel, pose) from the cache")
    assert text.count("\n") == 1 and "\r" not in text and text.endswith(" s\n")


def test_the_progress_rate_restarts_after_a_compile(monkeypatch):
    seconds = [0.0]
    monkeypatch.setattr("sgc_jax.scoring.progress.compile_seconds", lambda: seconds[0])
    with Progress(3, "jax", show=True, file=Terminal()) as progress:
        began = progress.bar.start_t
        time.sleep(0.05)
        seconds[0] = 60.0  # the first clip's program compiled meanwhile
        progress.advance()
        assert progress.bar.n == 1 and progress.bar.start_t > began  # the clock counts from now
        restarted = progress.bar.start_t
        progress.advance()
        assert progress.bar.n == 2 and progress.bar.start_t == restarted


def test_finished_compiles_are_counted(monkeypatch):
    before = compile_notice.compile_seconds()
    with CompileNotice("x", "pose", loading=False, stream=io.StringIO()):
        time.sleep(0.01)
    assert compile_notice.compile_seconds() > before
