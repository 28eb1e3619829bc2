"""Clip files named by URL (``s3://bucket/clips/``, ``gs://``, ``hdfs://``, ``file:///``), read
through pyarrow's filesystems (docs/semantics.md §4.2; ``pip install 'sgc-jax[parquet]'``, which
``[ray]`` includes). Credentials and regions come from where pyarrow looks for them (for S3 the
AWS environment variables and files). Only inputs: outputs are local files.
"""

from __future__ import annotations

import fnmatch
import glob
import os
import posixpath
from typing import Any, BinaryIO

from .extras import MissingExtraError


def is_url(source: str | os.PathLike) -> bool:
    """Whether ``source`` is a ``scheme://...`` URL (a scheme of two or more letters, digits, +, -
    or .; a Windows drive letter is not one)."""
    scheme, sep, _ = os.fspath(source).partition("://")
    return bool(sep) and len(scheme) > 1 and scheme[0].isalpha() and all(c.isalnum() or c in "+-." for c in scheme)


def _filesystem(url: str) -> tuple[Any, str]:
    """(pyarrow filesystem, path within it) of ``url``; FileNotFoundError for one pyarrow cannot open."""
    try:
        import pyarrow
        import pyarrow.fs
    except ImportError:
        raise MissingExtraError(f"{url}: reading clips by URL needs pyarrow: pip install 'sgc-jax[parquet]'") from None
    try:
        return pyarrow.fs.FileSystem.from_uri(url)
    except (pyarrow.ArrowException, OSError) as exc:  # an unknown scheme, a malformed URL
        raise FileNotFoundError(f"{url}: no filesystem for this URL ({exc})") from None


def list_files(url: str) -> list[str]:
    """The ``.npz`` files a URL names, as URLs: a directory's (sorted by name), the file itself, or
    the matches of a wildcard in its last part. FileNotFoundError when it names nothing."""
    fs, path = _filesystem(url)
    import pyarrow.fs  # there: _filesystem names the extra when pyarrow is missing
    info = fs.get_file_info(path)
    if info.type == pyarrow.fs.FileType.File:
        return [url]
    if info.type == pyarrow.fs.FileType.Directory:
        pattern, directory_url, directory = "*.npz", url, path
    elif glob.has_magic(posixpath.basename(path.rstrip("/"))):
        pattern = posixpath.basename(path.rstrip("/"))
        directory_url, directory = url.rstrip("/").rsplit("/", 1)[0], posixpath.dirname(path.rstrip("/"))
    else:
        raise FileNotFoundError(f"no clip file or directory at {url}")
    children = fs.get_file_info(pyarrow.fs.FileSelector(directory))
    names = sorted(posixpath.basename(child.path) for child in children if child.type == pyarrow.fs.FileType.File)
    return [f"{directory_url.rstrip('/')}/{name}" for name in names
            if fnmatch.fnmatchcase(name.lower(), pattern.lower()) and name.lower().endswith(".npz")]


def open_file(url: str) -> tuple[BinaryIO, int]:
    """(a seekable binary file of ``url``, its size in bytes); close the file when done."""
    fs, path = _filesystem(url)
    stream = fs.open_input_file(path)
    return stream, stream.size()


def version_key(url: str) -> tuple[int, int]:
    """(size in bytes, modification time in ns; 0 where the filesystem keeps none) of ``url``: a
    changed file gets a new key."""
    fs, path = _filesystem(url)
    import pyarrow.fs
    info = fs.get_file_info(path)
    if info.type != pyarrow.fs.FileType.File:
        raise FileNotFoundError(f"no file at {url}")
    return int(info.size or 0), int(info.mtime_ns or 0)
