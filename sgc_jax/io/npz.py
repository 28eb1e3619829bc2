"""Reading ``.npz`` archives of untrusted origin: nothing unpickled, nothing allocated unchecked;
and writing them (``write_npz``), each member deflated only where that pays.

Every ``.npy`` header is read first (``numpy.lib.format``) and checked against the bytes the
archive can hold for it, so a header claiming petabytes is refused before any allocation; object
arrays are refused (only pickle reads them). Every way a broken archive fails (zip structure, CRC,
zlib stream, truncation, encryption) becomes one :class:`NpzError` naming the array and the path.
"""

from __future__ import annotations

import contextlib
import math
import os
import struct
import threading
import tokenize
import zipfile
import zlib
from pathlib import Path
from typing import Any, BinaryIO, Container, Iterable

import numpy as np

from .remote import is_url, open_file

# Deflate expands data by at most 1032:1 (zlib's technical details), so a member whose recorded
# size exceeds that is lying; checking the npy header against it bounds what loading allocates.
DEFLATE_MAX_RATIO = 1032
# What reading a broken archive raises: zip structure and CRC (BadZipFile, struct.error), zlib
# streams, truncation (EOFError, ValueError from numpy), a garbled npy header (numpy tokenizes and
# literal_evals it), encryption and unsupported zip features (RuntimeError and its subclasses).
_READ_ERRORS = (OSError, EOFError, ValueError, zipfile.BadZipFile, zlib.error, struct.error, tokenize.TokenError,
                SyntaxError, RuntimeError, OverflowError, MemoryError)
FILE = "<file>"  # the array name given to problems of the archive as a whole
# numpy parses an npy header with ast.literal_eval, which CPython before 3.11.8 / 3.12.1 can fail
# with "SystemError: AST constructor recursion depth mismatch" when threads parse at once (cpython
# gh-106905; seen in the readers of score_batch): one header is parsed at a time.
_HEADER_LOCK = threading.Lock()
# A member that deflate does not halve is stored as it is: float depth whose mantissas vary from
# pixel to pixel (the synthetic corpora's deflates to 0.77-0.85 of its size) costs ~4 ms per MB of
# inflating at every read, ~0.6 s of a Wan-size clip (bench/history/issue-61.md "Clip files whose
# float depth is stored"). Sensor and ground-truth depth (0.14-0.21) and masks stay deflated, and so
# do the frames, which scoring does not read. Judged on SAMPLE_CHUNKS pieces spread over the member
# (a frame's top rows are often sky).
STORE_RATIO = 0.5
SAMPLE_CHUNKS, SAMPLE_BYTES = 16, 1 << 20
ALWAYS_DEFLATED = ("frames",)
_LOCAL_HEADER = struct.Struct("<4s22xHH")  # a zip local file header: signature, ..., name and extra lengths


class NpzError(ValueError):
    """An archive, or one array of it, that cannot be read: ``array`` (or ``<file>``), what was expected and found."""

    def __init__(self, path: str | os.PathLike, array: str, expected: str, found: str):
        self.path, self.array, self.expected, self.found = str(path), array, expected, found
        super().__init__(f"{self.path}: array {array!r}: expected {expected}, found {found}")


def shape_text(shape: Iterable[Any]) -> str:
    """A shape as text, e.g. ``(3, 24, 32)``, for error messages."""
    return "(" + ", ".join(str(s) for s in shape) + ")"


def _describe(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {exc}"


def _npy_header(fp: Any, path: Path, name: str) -> tuple[tuple[int, ...], bool, np.dtype]:
    """(shape, fortran_order, dtype) from the npy header at ``fp``, which is left at the array's
    data; formats 1.0 and 2.0, what np.save writes for plain dtypes."""
    version = np.lib.format.read_magic(fp)
    if version not in ((1, 0), (2, 0)):
        raise NpzError(path, name, "an .npy array of format 1.0 or 2.0", f"format {version}")
    read = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
    with _HEADER_LOCK:
        shape, fortran_order, dtype = read(fp)
    return tuple(shape), bool(fortran_order), dtype


def _npy_data(fp: Any, shape: tuple[int, ...], fortran_order: bool, dtype: np.dtype) -> np.ndarray:
    """The array whose data follows its header at ``fp`` (``np.lib.format.read_array`` without
    parsing the header again)."""
    size = math.prod(shape) * dtype.itemsize
    data, got = bytearray(size), 0
    view = memoryview(data)
    while got < size:
        n = fp.readinto(view[got:])
        if not n:
            raise ValueError(f"EOF: reading array data, expected {size} bytes got {got}")
        got += n
    array = np.frombuffer(data, dtype=dtype)
    return array.reshape(shape[::-1]).transpose() if fortran_order else array.reshape(shape)


def _check_header(path: Path, name: str, shape: tuple[int, ...], dtype: np.dtype, room: int) -> None:
    """Refuse Python objects (only pickle reads them), structured dtypes, and shapes whose bytes
    exceed ``room``, the bytes the member can hold after its header."""
    if dtype.hasobject:
        raise NpzError(path, name, "numbers or text (nothing is unpickled)", f"dtype {dtype} (Python objects)")
    if dtype.names is not None or dtype.subdtype is not None or dtype.kind == "V":
        raise NpzError(path, name, "a plain array of numbers or text", f"structured dtype {dtype}")
    if any(s < 0 for s in shape):
        raise NpzError(path, name, "sizes >= 0", f"shape {shape_text(shape)}")
    claimed = math.prod(shape) * max(dtype.itemsize, 1)
    if claimed > room:
        raise NpzError(path, name, f"at most the {room} bytes the archive holds for it",
                       f"a header claiming shape {shape_text(shape)} of {dtype} ({claimed} bytes)")


def _member_room(info: zipfile.ZipInfo, archive_bytes: int, path: Path, name: str) -> int:
    """The most bytes member ``info`` can expand to, from the sizes of the archive itself."""
    if info.compress_type not in (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED):
        raise NpzError(path, name, "a stored or deflated member (as np.savez writes)",
                       f"compression method {info.compress_type}")
    if info.header_offset + info.compress_size > archive_bytes:
        raise NpzError(path, name, f"{info.compress_size} compressed bytes", "a truncated member")
    most = info.compress_size * (DEFLATE_MAX_RATIO if info.compress_type == zipfile.ZIP_DEFLATED else 1)
    if info.file_size > most:
        raise NpzError(path, name, f"at most {most} bytes from {info.compress_size} compressed",
                       f"a member recorded as {info.file_size} bytes")
    return info.file_size


def _stored_data(raw: BinaryIO, info: zipfile.ZipInfo, header_bytes: int, shape: tuple[int, ...],
                 fortran_order: bool, dtype: np.dtype) -> np.ndarray:
    """The array of a stored member read from the archive's file ``raw`` straight into its buffer
    (zipfile's reader copies it through two others: ~6x the time), its CRC checked as zipfile checks it."""
    raw.seek(info.header_offset)
    signature, name_bytes, extra_bytes = _LOCAL_HEADER.unpack(raw.read(_LOCAL_HEADER.size))
    if signature != b"PK\x03\x04":
        raise zipfile.BadZipFile(f"bad local file header of {info.filename}")
    raw.seek(info.header_offset + _LOCAL_HEADER.size + name_bytes + extra_bytes)
    crc = zlib.crc32(raw.read(header_bytes))
    array = np.empty(shape[::-1] if fortran_order else shape, dtype)
    data = array.reshape(-1).view(np.uint8)
    if raw.readinto(data) != data.size:
        raise EOFError(f"reading array data, expected {data.size} bytes")
    crc = zlib.crc32(raw.read(info.file_size - header_bytes - data.size), zlib.crc32(data, crc))
    if crc != info.CRC:
        raise zipfile.BadZipFile(f"Bad CRC-32 for file {info.filename!r}")
    return array.transpose() if fortran_order else array


def _read_member(archive: zipfile.ZipFile, info: zipfile.ZipInfo, archive_bytes: int, path: Path, name: str,
                 headers_only: bool, raw: BinaryIO | None = None) -> Any:
    try:
        room = _member_room(info, archive_bytes, path, name)
        with archive.open(info) as fp:
            shape, fortran_order, dtype = _npy_header(fp, path, name)
            _check_header(path, name, shape, dtype, room - fp.tell())
            if headers_only:
                return shape, dtype
            if raw is not None and info.compress_type == zipfile.ZIP_STORED and dtype.kind in "biufc":
                return _stored_data(raw, info, fp.tell(), shape, fortran_order, dtype)
            array = _npy_data(fp, shape, fortran_order, dtype)
            fp.read()  # on to the member's end: zipfile checks the CRC only there
        return array
    except NpzError:
        raise
    except _READ_ERRORS as exc:
        raise NpzError(path, name, "an array readable from the archive", _describe(exc)) from None


def _read(path: str | os.PathLike, names: Iterable[str] | None, headers_only: bool,
          shape_only: Container[str] = ()) -> dict[str, Any]:
    url = is_url(path)
    path = os.fspath(path) if url else Path(path)  # a Path would fold a URL's "//"
    try:
        stream, archive_bytes = open_file(path) if url else (None, os.path.getsize(path))
        raw = None if url or headers_only else open(path, "rb")  # stored members are read from it directly
        with stream or contextlib.nullcontext(), raw or contextlib.nullcontext(), zipfile.ZipFile(stream or path) as archive:
            members = {info.filename[:-4]: info for info in archive.infolist() if info.filename.endswith(".npy")}
            wanted = list(members) if names is None else [n for n in names if n in members]
            return {n: _stand_in(*_read_member(archive, members[n], archive_bytes, path, n, True))
                    if n in shape_only and not headers_only
                    else _read_member(archive, members[n], archive_bytes, path, n, headers_only, raw) for n in wanted}
    except NpzError:
        raise
    except _READ_ERRORS as exc:
        if not url and os.path.islink(path) and not os.path.exists(path):
            found = "a link that leads nowhere (dangling, or a loop of links)"
        else:
            found = _describe(exc)
        raise NpzError(path, FILE, "a readable .npz archive of .npy arrays", found) from None


def _stand_in(shape: tuple[int, ...], dtype: np.dtype) -> np.ndarray:
    """A read-only array of ``shape`` and ``dtype`` that holds no data (zeros, one element broadcast)."""
    return np.broadcast_to(np.zeros((), dtype), shape)


def read_npz(path: str | os.PathLike, names: Iterable[str] | None = None,
             shape_only: Container[str] = ()) -> dict[str, np.ndarray]:
    """The arrays of an ``.npz`` by name (only ``names`` when given; absent names are skipped);
    those in ``shape_only`` from their headers alone, as zeros of their shape and dtype that hold
    no memory (their data is neither inflated nor checked).

    Raises :class:`NpzError` for anything that cannot be read as plain arrays.
    """
    return _read(path, names, headers_only=False, shape_only=shape_only)


def npz_headers(path: str | os.PathLike) -> dict[str, tuple[tuple[int, ...], np.dtype]]:
    """(shape, dtype) of every array of an ``.npz``, from the headers only; errors as :func:`read_npz`."""
    return _read(path, None, headers_only=True)


def _member_compression(name: str, array: np.ndarray) -> int:
    """ZIP_DEFLATED for a member that deflate halves (judged on a sample), a small one or one of
    ALWAYS_DEFLATED; ZIP_STORED for the others."""
    if array.nbytes <= SAMPLE_BYTES or name in ALWAYS_DEFLATED:
        return zipfile.ZIP_DEFLATED
    data = np.ravel(array).view(np.uint8)
    chunk = SAMPLE_BYTES // SAMPLE_CHUNKS
    starts = np.linspace(0, data.size - chunk, SAMPLE_CHUNKS).astype(np.int64)
    sample = b"".join(data[start:start + chunk].tobytes() for start in starts)
    return zipfile.ZIP_DEFLATED if len(zlib.compress(sample)) <= STORE_RATIO * len(sample) else zipfile.ZIP_STORED


def write_npz(path: str | os.PathLike, arrays: dict[str, Any]) -> Path:
    """Write ``arrays`` as an ``.npz`` that ``np.load`` reads (as ``np.savez_compressed``'s, without
    pickles), each member deflated or stored (``_member_compression``), under a fixed timestamp so
    that the same arrays give the same bytes. As ``np.savez``, appends ``.npz`` to a path without it;
    returns the path written."""
    path = Path(path)
    if path.suffix != ".npz":
        path = path.with_name(path.name + ".npz")
    with zipfile.ZipFile(path, "w", allowZip64=True) as archive:
        for name, value in arrays.items():
            array = np.asanyarray(value)
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = _member_compression(name, array)
            with archive.open(info, "w", force_zip64=True) as member:
                np.lib.format.write_array(member, array, allow_pickle=False)
    return path
