"""JAX's persistent compilation cache, per machine, so a second run skips most of the compile.

The JAX engine compiles one executable per shape bucket and config (tens of seconds on a small
CPU). With the cache on, later processes load those executables from disk; what remains of the
cold start is JAX's tracing in Python. The ``sgc-jax`` commands turn it on by default; library
users call ``enable_compilation_cache()`` once, before scoring.

Where: ``$SGC_JAX_COMPILATION_CACHE`` if set (``off`` disables it), else
``$XDG_CACHE_HOME/sgc_jax/xla/<host>`` (``~/.cache`` without XDG). ``<host>`` names the
architecture and a hash of the CPU's feature flags: XLA:CPU executables are native code, and one
built for another CPU of a shared home directory may not run here. A cache directory someone
else can write to lets them run code as you (JAX's warning): keep it private.
"""

from __future__ import annotations

import hashlib
import os
import platform
from pathlib import Path

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
    """A clause for the compile message: how to keep compiled programs between runs, or "" when
    the persistent cache is on."""
    import jax

    if jax.config.jax_compilation_cache_dir:
        return ""
    return "; sgc_jax.enable_compilation_cache() keeps them for later runs"
