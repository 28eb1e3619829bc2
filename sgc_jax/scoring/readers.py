"""Reading clips ahead of the device (docs/semantics.md §4.1): hash, read, validate and prepare
one entry (``read_entry``), in a thread or in a reader process (``ReaderProcesses``).

Reading a standard clip is 60-200 ms of NumPy and zlib, much of it holding Python's GIL, so
reader threads keep only about four cores busy however many there are (bench/history/issue-21.md, "1,000 standard clips from disk on a GPU"): too
few to feed a GPU. Reader processes are plain subprocesses (``serve``) that
talk pickle over their stdin and stdout, each driven by one thread of a pool. Not
``multiprocessing``: its spawned children import the caller's ``__main__`` script again, which
runs a script without an ``if __name__ == "__main__"`` guard once more in every reader, and
forking would copy a process that runs XLA's threads.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import mmap
import os
import pickle
import signal
import subprocess
import sys
import tempfile
import threading
import warnings
from pathlib import Path
from typing import Any, BinaryIO, Callable, Container, NamedTuple

from ..config import SGCConfig
from ..io.checks.problems import clip_warnings_as_lines
from ..io.clip import Clip, ClipFormatError
from ..io.loading import ClipEntry
from .devices import host_cores
from .engine_steps import prepare_step
from .journal import FileDigests
from .options import READ_IN

# "auto" reads clip files in processes on hosts of more cores than this; on smaller ones (the
# 2-core box) THREAD_READERS threads keep up with the device.
PROCESS_READING_CORES = 4
THREAD_READERS = 2


def reading_plan(readers: int | None = None, read_in: str = "auto", cores: int | None = None) -> tuple[int, bool]:
    """(how many readers, whether they are processes): ``read_in`` "threads", "processes", or
    "auto" (processes with more than PROCESS_READING_CORES ``cores``, by default the host's).
    ``readers`` by default: THREAD_READERS threads, or one process per core but two (for the
    scoring threads)."""
    if read_in not in READ_IN:
        raise ValueError(f"read_in must be one of {READ_IN}, got {read_in!r}")
    if readers is not None and readers < 1:
        raise ValueError(f"readers must be at least 1, got {readers}")
    cores = cores or host_cores()
    processes = read_in == "processes" or (read_in == "auto" and cores > PROCESS_READING_CORES)
    if readers is None:
        readers = max(1, cores - 2) if processes else THREAD_READERS
    return readers, processes


class Identity(NamedTuple):
    """What a result needs of its clip besides the per-pair arrays."""

    clip_id: str
    group: str
    mask_source: str
    warnings: str = ""  # the loader's warning codes, ";"-joined


class Read(NamedTuple):
    """A reader's work on one entry: the file's SHA-256 ("" for a clip given in memory), and the
    prepared clip, or the reason it cannot be scored, or ``resumed`` (an earlier run scored it)."""

    entry: ClipEntry
    sha256: str
    identity: Identity | None = None
    prepared: Any = None
    error: ClipFormatError | None = None
    resumed: bool = False


def read_entry(entry: ClipEntry, prepare: Callable[[Clip], Any], digests: FileDigests,
               done: Container[tuple[str, str]]) -> Read:
    """Hash, then (unless (clip_id, sha256) is in ``done``) read, validate and prepare one entry.
    Raises only what is not a :class:`ClipFormatError`."""
    try:
        sha256 = digests.of(entry.path) if entry.path is not None else ""
    except OSError:  # a dangling link, say: reading the clip names the problem
        sha256 = ""
    if sha256 and (entry.clip_id, sha256) in done:
        return Read(entry, sha256, resumed=True)
    try:
        clip = entry.read_clip(for_scoring=True)
    except ClipFormatError as exc:
        return Read(entry, sha256, error=exc)
    return Read(entry, sha256, Identity(clip.clip_id, clip.group, clip.mask_source, ";".join(clip.warnings)),
                prepare(clip))


# The pipe a reader process replies through, enlarged where Linux allows (its default 64 KB): the
# receiving thread takes back Python's GIL after each read of a pipe's fill, each time behind the
# threads that hold it, so a 12 MB prepared clip through 64 KB took 0.8 s beside one busy thread,
# 0.09 s through 1 MB (bench/history/issue-61.md "Clips from reader processes")
PIPE_BYTES = 1 << 20


def _enlarge_pipe(channel: BinaryIO) -> None:
    try:
        import fcntl  # not on Windows

        fcntl.fcntl(channel.fileno(), fcntl.F_SETPIPE_SZ, PIPE_BYTES)
    except (ImportError, AttributeError, OSError):  # not Linux, or above the host's pipe-max-size: as it is
        pass


def _send(channel: BinaryIO, value: Any) -> None:
    data = pickle.dumps(value, protocol=pickle.HIGHEST_PROTOCOL)  # whole, so a failure sends nothing
    channel.write(data)
    channel.flush()


# A reply's arrays of SHARED_MIN_BYTES or more travel through a file in SHARED_DIR (memory, on
# Linux) that the caller maps and unlinks, not through the pipe: the pipe's copy into the scoring
# process cost it 5-12 ms of its one GIL a standard clip (bench/history/issue-61.md "Clips handed
# over in shared memory"). Where the directory is missing or full, the reply goes whole as before.
SHARED_DIR = Path("/dev/shm")
SHARED_MIN_BYTES = 1 << 16


def _send_reply(channel: BinaryIO, value: Any) -> str | None:
    """``value`` to the caller, its large arrays' bytes in a file of SHARED_DIR where one can be
    written; that file's path (the caller unlinks it once mapped), else None."""
    large: list[pickle.PickleBuffer] = []
    data = pickle.dumps(value, protocol=5, buffer_callback=lambda b: b.raw().nbytes < SHARED_MIN_BYTES or large.append(b))
    if not large:
        _send(channel, ("whole", data))
        return None
    path = None
    try:
        fd, path = tempfile.mkstemp(prefix="sgc-jax-read-", dir=SHARED_DIR)
        spans, offset = [], 0
        with os.fdopen(fd, "wb") as shared:
            for buffer in large:
                raw = buffer.raw()
                shared.write(raw)
                spans.append((offset, raw.nbytes))
                offset += raw.nbytes
    except OSError:
        if path is not None:
            Path(path).unlink(missing_ok=True)
        _send(channel, ("whole", pickle.dumps(value, protocol=5)))
        return None
    try:
        _send(channel, ("shared", (path, spans, data)))
    except BaseException:  # the caller is gone: nobody will unlink it
        Path(path).unlink(missing_ok=True)
        raise
    return path


def _receive_reply(channel: BinaryIO) -> Any:
    """A value ``_send_reply`` sent: its large arrays are views of the mapped file (copy on write),
    which is unlinked at once and freed with the last of them."""
    kind, payload = pickle.load(channel)
    if kind == "whole":
        return pickle.loads(payload)
    path, spans, data = payload
    try:
        with open(path, "rb") as shared:
            mapped = mmap.mmap(shared.fileno(), 0, access=mmap.ACCESS_COPY)
    finally:
        os.unlink(path)
    view = memoryview(mapped)
    return pickle.loads(data, buffers=[view[offset:offset + size] for offset, size in spans])


class ReaderProcesses:
    """``count`` reader processes of clip files for ``engine`` and ``config``, started as they are
    first needed and kept until ``close`` (so a Ray scorer reuses them from shard to shard).
    ``submit`` returns a future of the entry's :class:`Read` (its ``entry`` a copy: the caller's
    entry holds the run's id registry, which stays here). Use as a context manager."""

    def __init__(self, count: int, engine: str, config: SGCConfig) -> None:
        self.setup = (engine, config)
        self._threads = concurrent.futures.ThreadPoolExecutor(count, thread_name_prefix="sgc-read-process")
        self._local = threading.local()
        self._lock = threading.Lock()
        self._workers: list[subprocess.Popen] = []

    def submit(self, entry: ClipEntry, done_sha256: frozenset[str] = frozenset()) -> concurrent.futures.Future:
        """Read ``entry``, unless its file's SHA-256 is among ``done_sha256`` (``Read.resumed``)."""
        return self._threads.submit(self._read, dataclasses.replace(entry, id_owners=None), done_sha256)

    def _worker(self) -> subprocess.Popen:
        worker = getattr(self._local, "worker", None)
        if worker is None:
            # the child imports sgc_jax from where this process did, and keeps off any GPU
            here = str(Path(__file__).resolve().parents[2])
            path = os.pathsep.join([here, *filter(None, [os.environ.get("PYTHONPATH")])])
            # -P: the working directory is not put before that path, where another sgc_jax may lie
            worker = subprocess.Popen([sys.executable, "-P", "-c", "from sgc_jax.scoring.readers import serve; serve()"],
                                      stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                      env=dict(os.environ, PYTHONPATH=path, JAX_PLATFORMS="cpu"))
            _enlarge_pipe(worker.stdout)
            with self._lock:
                self._workers.append(worker)
            self._local.worker = worker
            self._local.fresh = True
        return worker

    def _read(self, entry: ClipEntry, done_sha256: frozenset[str]) -> Read:
        worker = self._worker()
        try:
            if self._local.fresh:
                _send(worker.stdin, self.setup)
                self._local.fresh = False
            _send(worker.stdin, (entry, done_sha256))
            ok, value = _receive_reply(worker.stdout)
        except (EOFError, BrokenPipeError) as exc:
            raise RuntimeError(f"a reader process ended (exit code {worker.poll()}) while reading {entry.origin}; "
                               "its error, if any, is above on stderr") from exc
        if not ok:
            raise value
        return value

    def close(self) -> None:
        self._threads.shutdown(wait=True, cancel_futures=True)
        for worker in self._workers:
            worker.stdin.close()  # the reader's loop ends at the end of its input
        for worker in self._workers:
            try:
                worker.wait(timeout=10)
            except subprocess.TimeoutExpired:
                worker.kill()
            worker.stdout.close()

    def __enter__(self) -> "ReaderProcesses":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def serve() -> None:
    """A reader process: the setup (engine, config), then one (entry, SHA-256s already scored)
    after another on stdin; (True, Read) or (False, exception) for each on stdout."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C stops the caller, which then closes our input
    requests, replies = sys.stdin.buffer, os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)  # anything the reading prints goes to stderr, not into the replies
    warnings.showwarning = clip_warnings_as_lines("sgc-jax")
    engine, config = pickle.load(requests)
    prepare, digests = prepare_step(engine, config), FileDigests()
    shared = None  # the last reply's file: the caller unlinks it, unless it ended before reading it
    while True:
        try:
            entry, done_sha256 = pickle.load(requests)
        except EOFError:
            if shared is not None:
                Path(shared).unlink(missing_ok=True)
            return
        try:
            done = {(entry.clip_id, sha256) for sha256 in done_sha256}
            reply = (True, read_entry(entry, prepare, digests, done))
        except Exception as exc:  # noqa: BLE001  handed to the caller, who raises it
            reply = (False, exc)
        try:
            shared = _send_reply(replies, reply)
        except (pickle.PicklingError, TypeError, AttributeError) as exc:
            shared = _send_reply(replies, (False, RuntimeError(f"reading {entry.origin}: {reply[1]!r} ({exc})")))
