"""The persistent cache of compiled programs, one per kind of CPU, so a later process starts in
seconds (docs/semantics.md §7.1).

Each traced stage is kept as a ``jax.export`` file under ``sgc_programs/`` and its executable in
JAX's persistent compilation cache beside it, so a later process neither traces nor compiles. The
scoring entry points and the ``sgc-jax`` commands turn it on (``enable_compilation_cache``).

Where: ``$SGC_JAX_COMPILATION_CACHE`` if set (``off`` turns it off), else
``$XDG_CACHE_HOME/sgc_jax/xla/<host>`` (``~/.cache`` without XDG), ``<host>`` the architecture
and a hash of the CPU's feature flags: XLA:CPU executables are native code, and one built for
another CPU of a shared home directory may not run here. A directory set through JAX's own
``JAX_COMPILATION_CACHE_DIR`` wins. Keep it private: JAX runs what it finds there.
"""

from __future__ import annotations

import functools
import hashlib
import os
import platform
import sys
from pathlib import Path

try:
    import fcntl
except ImportError:  # Windows: no lock, concurrent processes may compile the same program
    fcntl = None

ENV_VAR = "SGC_JAX_COMPILATION_CACHE"
_OFF = {"off", "0", "false", "no", "disabled"}


def _cpu_features() -> str:
    """The CPU's feature flags (Linux /proc/cpuinfo), else the processor name."""
    try:
        with open("/proc/cpuinfo") as cpuinfo:
            for line in cpuinfo:
                if line.startswith(("flags", "Features")):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor()


def host_key() -> str:
    """``<arch>-<12 hex digits>``: one cache per kind of CPU."""
    digest = hashlib.sha256(_cpu_features().encode()).hexdigest()[:12]
    return f"{platform.machine() or 'unknown'}-{digest}"


def default_cache_dir() -> Path | None:
    """The directory the ``sgc-jax`` commands use, or None where ``$SGC_JAX_COMPILATION_CACHE``
    turns the cache off."""
    chosen = os.environ.get(ENV_VAR, "").strip()
    if chosen.lower() in _OFF:
        return None
    if chosen:
        return Path(chosen).expanduser()
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "sgc_jax" / "xla" / host_key()


def enable_compilation_cache(path: str | os.PathLike | None = None) -> Path | None:
    """Turn on JAX's persistent compilation cache in ``path`` (default: ``default_cache_dir()``)
    and return the directory in use; None when it stays off.

    A directory already set through JAX (``JAX_COMPILATION_CACHE_DIR`` or ``jax.config``) is
    kept. Call before the first compile; later calls change nothing.
    """
    import jax

    current = jax.config.jax_compilation_cache_dir
    if current:
        return Path(current)
    target = Path(path).expanduser() if path is not None else default_cache_dir()
    if target is None:
        return None
    try:
        target.mkdir(parents=True, exist_ok=True, mode=0o700)
    except OSError:
        return None  # a read-only home: run without the cache rather than fail
    jax.config.update("jax_compilation_cache_dir", str(target))
    return target


def cache_hint() -> str:
    """A clause for the compile message: how to keep compiled programs, or "" when the cache is on."""
    import jax

    if jax.config.jax_compilation_cache_dir:
        return ""
    return "; the cache is off (SGC_JAX_COMPILATION_CACHE)"


# ----------------------------------------------------------------------------- traced programs

PROGRAMS_DIR = "sgc_programs"  # inside the persistent cache directory


@functools.lru_cache(maxsize=1)
def code_fingerprint() -> str:
    """sha256 of every sgc_jax source file and the jax / jaxlib versions: a traced program is
    reused only by the code that traced it."""
    import jax
    import jaxlib

    digest = hashlib.sha256(f"{jax.__version__} {jaxlib.__version__}".encode())
    package = Path(__file__).resolve().parents[2]
    for source in sorted(package.rglob("*.py")):
        digest.update(source.relative_to(package).as_posix().encode())
        digest.update(source.read_bytes())
    return digest.hexdigest()


def program_path(program_key) -> Path | None:
    """Where the traced program named by ``program_key`` (its repr: the stage, its static config
    and shape) is kept on this backend, or None while the persistent cache is off."""
    import jax

    cache_dir = jax.config.jax_compilation_cache_dir
    if not cache_dir:
        return None
    key = hashlib.sha256(f"{code_fingerprint()} {jax.default_backend()} {program_key!r}".encode())
    return Path(cache_dir) / PROGRAMS_DIR / f"{key.hexdigest()[:32]}.jaxexport"


class ProgramLock:
    """An exclusive lock on one kept program (``<path>.lock``), taken before it is traced and
    released once it is compiled: processes sharing the cache (xdist workers, several runs at
    once) compile each program once; the others wait, then load it. Does nothing without the
    cache (``path`` None), where ``fcntl`` is missing (Windows) or the cache is read-only."""

    def __init__(self, path: Path | None):
        self._file = None
        if path is None or fcntl is None:
            return
        try:
            path.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
            self._file = open(path.with_suffix(".lock"), "a")
            fcntl.flock(self._file, fcntl.LOCK_EX)
        except OSError:
            self.release()

    def release(self) -> None:
        if self._file is not None:
            self._file.close()  # closing the file drops the lock
            self._file = None


def load_program(path: Path):
    """The ``jax.export.Exported`` kept at ``path``, or None when there is none or it cannot be
    read (it is then traced again and replaced)."""
    import jax

    try:
        return jax.export.deserialize(bytearray(path.read_bytes()))
    except FileNotFoundError:
        return None
    except Exception as exc:  # a truncated or foreign file: not fatal, the program is rebuilt
        print(f"sgc-jax: ignoring the unreadable cached program {path} ({type(exc).__name__})", file=sys.stderr)
        return None


def save_program(path: Path, exported) -> None:
    """Keep ``exported`` at ``path`` (atomically: concurrent processes may write the same one)."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
        partial = path.with_suffix(f".{os.getpid()}.partial")
        partial.write_bytes(exported.serialize())
        os.replace(partial, path)
    except OSError as exc:  # a read-only cache: run without keeping it
        print(f"sgc-jax: could not keep the traced program in {path.parent} ({exc})", file=sys.stderr)
