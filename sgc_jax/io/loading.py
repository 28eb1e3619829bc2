"""Reading clips (docs/semantics.md §1): single-clip and batch files and clip sources (paths,
directories, globs, URLs, mappings, clips in memory) as :class:`ClipEntry` values read on demand,
and the reports of ``sgc-jax validate``. Arrays become a clip in :mod:`sgc_jax.io.arrays`; a batch
file's layout is :mod:`sgc_jax.io.batch_layout`'s.
"""

from __future__ import annotations

import dataclasses
import functools
import glob
import itertools
import os
import threading
from pathlib import Path
from typing import Any, Callable, Container, Iterable, Iterator, Mapping

import numpy as np

from ..config import SGCConfig
from .arrays import as_clip_array, checked_in_memory, clip_from_arrays, meta_clip_id, subsample_tracks, text_value
from .batch_layout import BOOKKEEPING, PLOTS_ONLY, batch_layout, batch_member, is_batch
from .checks.problems import Problem
from .clip import Clip, ClipFormatError
from .npz import NpzError, npz_headers, read_npz
from .remote import is_url, list_files
from .validate import check_clip


@dataclasses.dataclass
class ClipEntry:
    """A clip to be loaded lazily: its id, where it comes from, and how to read it.

    ``read`` returns the clip's arrays (docs/semantics.md §1.2), or the :class:`Clip` given in
    memory, and raises :class:`ClipFormatError` for a file that cannot give them. A file's entry
    pickles (without ``id_owners``), so a reader process can read it.
    """

    clip_id: str
    origin: str
    read: Callable[[], Mapping[str, Any] | Clip]
    config: SGCConfig = dataclasses.field(default_factory=SGCConfig)
    path: str | None = None  # the file it comes from; None for clips given in memory
    id_owners: dict[str, "ClipEntry"] | None = None  # clip id -> the entry that claimed it, shared by a run's files
    # ``read``, but PLOTS_ONLY arrays from their headers alone (a file's entry; None: ``read``)
    read_for_scoring: Callable[[], Mapping[str, Any]] | None = None

    def load(self) -> Clip:
        """The validated clip with its id claimed for the run (``read_clip``, then ``claim_id``);
        raises :class:`ClipFormatError` (only) for a bad input."""
        clip = self.read_clip()
        self.claim_id()
        return clip

    def read_clip(self, for_scoring: bool = False) -> Clip:
        """The validated clip, its id not yet claimed: safe to call from several threads, as long
        as ``claim_id`` is then called in input order (the first file with an id keeps it).
        ``for_scoring``: without PLOTS_ONLY arrays, whose shapes and dtypes are checked as usual
        but whose data a file's entry does not read."""
        read = self.read_for_scoring if for_scoring and self.read_for_scoring is not None else self.read
        source = read()
        if isinstance(source, Clip):
            clip = subsample_tracks(source, self.config)
        else:
            clip = clip_from_arrays(source, clip_id=self.clip_id, config=self.config)
        return dataclasses.replace(clip, **dict.fromkeys(PLOTS_ONLY)) if for_scoring else clip

    def claim_id(self) -> None:
        """Claim this clip's id for the run; raises :class:`ClipFormatError` when another clip file has it."""
        if self.id_owners is None:
            return
        owner = self.id_owners.setdefault(self.clip_id, self)
        if owner is not self:
            raise duplicate_error(self.clip_id, owner.origin)


def duplicate_error(clip_id: str, first_origin: str) -> ClipFormatError:
    return ClipFormatError(clip_id, "clip_id", "an id no other clip file of the run has",
                           f"a duplicate: first seen in {first_origin}",
                           "this clip is not scored; give it its own clip_id")


def _raise(exc: ClipFormatError) -> Any:
    raise exc


def _failing(exc: ClipFormatError) -> Callable[[], Any]:
    return functools.partial(_raise, exc)


def _read(path: Path, clip_id: str, names: Iterable[str] | None = None, headers: bool = False,
          shape_only: Container[str] = ()) -> dict[str, Any]:
    """:func:`sgc_jax.io.npz.read_npz` (or its headers) with its errors as :class:`ClipFormatError` of ``clip_id``."""
    try:
        return npz_headers(path) if headers else read_npz(path, names, shape_only)
    except NpzError as exc:
        raise ClipFormatError(clip_id, exc.array, exc.expected, exc.found, exc.path) from None


def entries_from_file(path: Path | str, config: SGCConfig) -> list[ClipEntry]:
    """The clips of one clip or batch ``.npz`` (a path or a URL); a file that cannot be listed is
    one failing entry."""
    origin, stem = os.fspath(path), Path(os.fspath(path)).stem
    try:
        headers = _read(path, stem, headers=True)
        if not is_batch(headers):
            clip_id = meta_clip_id(_read(path, stem, ["meta"]).get("meta")) or stem
            return [ClipEntry(clip_id, origin, functools.partial(_read, path, clip_id), config, origin,
                              read_for_scoring=functools.partial(_read, path, clip_id, shape_only=PLOTS_ONLY))]
        layout = batch_layout({k: shape for k, (shape, _) in headers.items()}, _read(path, stem, BOOKKEEPING), stem)
    except ClipFormatError as exc:
        return [ClipEntry(stem, origin, _failing(exc), config, origin)]
    listing = next(_LISTINGS)
    return [ClipEntry(layout.ids[b], f"{origin}[{b}]",
                      functools.partial(_read_batch_member, path, listing, b, layout.ids[b], stem), config, origin,
                      read_for_scoring=functools.partial(_read_batch_member, path, listing, b, layout.ids[b], stem,
                                                         PLOTS_ONLY))
            for b in range(len(layout))]


# A batch file's members are read one by one, each from the arrays of the whole file: the arrays of
# the batch read last are kept (one per process), so B members decompress the file once, not B
# times. Keyed by the listing that made the entries, so a file rewritten and listed again is read again.
_LISTINGS = itertools.count()
_LAST_BATCH: dict[tuple, dict[str, Any]] = {}
_LAST_BATCH_LOCK = threading.Lock()


def _read_batch_member(path: Path | str, listing: int, b: int, clip_id: str, stem: str,
                       shape_only: Container[str] = ()) -> dict[str, Any]:
    key = (os.fspath(path), listing, tuple(sorted(shape_only)))
    with _LAST_BATCH_LOCK:
        arrays = _LAST_BATCH.get(key)
    if arrays is None:
        arrays = _read(path, clip_id, shape_only=shape_only)
        with _LAST_BATCH_LOCK:
            _LAST_BATCH.clear()
            _LAST_BATCH[key] = arrays
    member = batch_member(arrays, b, batch_layout({k: a.shape for k, a in arrays.items()}, arrays, stem))
    # copies, as the kept arrays serve the other members; shape-only placeholders stay views (no memory)
    return {name: a if name in shape_only else np.array(a) for name, a in member.items()}


def _entries_from_mapping(source: Mapping[str, Any], config: SGCConfig) -> list[ClipEntry]:
    if not is_batch(source):
        clip_id = meta_clip_id(source.get("meta")) or text_value(source.get("clip_id")) or "clip"
        return [ClipEntry(clip_id, "<memory>", lambda: source, config)]
    try:
        arrays = {k: as_clip_array("batch", k, v, "an array") for k, v in source.items()}
        layout = batch_layout({k: a.shape for k, a in arrays.items()}, arrays, "batch")
    except ClipFormatError as exc:
        return [ClipEntry("batch", "<memory>", _failing(exc), config)]
    return [ClipEntry(layout.ids[b], f"<memory>[{b}]", lambda b=b: batch_member(arrays, b, layout), config)
            for b in range(len(layout))]


def _npz_in(directory: Path) -> list[Path]:
    try:
        return sorted(directory.glob("*.npz"))
    except OSError:  # an unreadable directory: reading it reports why
        return [directory]


def list_clip_files(source: str | os.PathLike, *, allow_empty: bool = False) -> list[Path | str]:
    """The ``.npz`` files a path names: a directory's ``*.npz`` (sorted), a file (or a link, even
    one that leads nowhere: reading it reports that), or a glob's ``.npz`` matches, directories
    among them expanded. Raises FileNotFoundError when it names nothing (or an empty directory, unless ``allow_empty``).
    A URL (``s3://bucket/clips/``, ``file:///...``; :mod:`sgc_jax.io.remote`) gives URLs: its
    directory's ``.npz`` files, the file, or a wildcard's matches in its last part.
    """
    text = os.fspath(source)
    files: list[Path | str]
    if is_url(text):
        files = list_files(text)
    elif os.path.isdir(text):
        files = _npz_in(Path(text))
    elif os.path.lexists(text):
        files = [Path(text)]
    else:
        # glob only where there are wildcards: a literal name is matched by os.path.lexists above
        matches = sorted(glob.glob(text)) if glob.has_magic(text) else []
        files = [f for m in matches for f in (_npz_in(Path(m)) if os.path.isdir(m) else [Path(m)])
                 if f.suffix.lower() == ".npz"]  # as in a directory: a glob's other files are not clips
        if not matches:
            raise FileNotFoundError(f"no clip file, directory or glob match for {text!r}")
    if not files and not allow_empty:
        raise FileNotFoundError(f"no .npz clips in {text}")
    return files


def guard_duplicate_ids(entries: list[ClipEntry]) -> None:
    """Give the clips from files one id registry (docs/semantics.md §1.4): of the clips with one id,
    the first that loads keeps it and later ones raise :class:`ClipFormatError` when loaded.

    Clips given in memory are left alone: variants of one clip (perturbed, rescaled) share its id on purpose.
    """
    owners: dict[str, ClipEntry] = {}
    for entry in entries:
        if entry.path is not None:
            entry.id_owners = owners


def _discover(source: Any, config: SGCConfig) -> list[ClipEntry]:
    if isinstance(source, Clip):
        return [ClipEntry(source.clip_id, "<memory>", lambda: checked_in_memory(source), config)]
    if isinstance(source, Mapping):
        return _entries_from_mapping(source, config)
    if isinstance(source, (list, tuple)):
        return [e for item in source for e in _discover(item, config)]
    return [e for path in list_clip_files(source) for e in entries_from_file(path, config)]


def discover_clips(source: Any, config: SGCConfig | None = None) -> list[ClipEntry]:
    """Expand a source into lazily loaded clips.

    ``source``: a clip or batch ``.npz`` path, a directory (its ``*.npz``, sorted), a glob, a
    :class:`Clip`, a mapping of arrays (single clip or batch), or a list of any of these. A broken
    file or batch member never raises here: its entry raises :class:`ClipFormatError` when loaded.
    Raises FileNotFoundError for a path, directory or glob that names no file.
    """
    entries = _discover(source, config or SGCConfig())
    guard_duplicate_ids(entries)
    return entries


def load_clips(source: Any, config: SGCConfig | None = None) -> Iterator[Clip]:
    """Load every clip of a source (raises :class:`ClipFormatError` on the first broken one; see :func:`discover_clips`)."""
    for entry in discover_clips(source, config):
        yield entry.load()


def load_clip(source: Any, config: SGCConfig | None = None) -> Clip:
    """Load exactly one clip from a path, mapping or :class:`Clip`."""
    entries = discover_clips(source, config)
    if len(entries) != 1:
        raise ValueError(f"expected one clip, {source!r} holds {len(entries)}")
    return entries[0].load()


@dataclasses.dataclass
class Report:
    """The findings for one clip of a source."""

    origin: str
    clip_id: str
    problems: list[Problem]

    @property
    def ok(self) -> bool:
        return not any(p.severity == "error" for p in self.problems)

    def lines(self, *, show_info: bool = False) -> list[str]:
        return [f"{self.origin}: {p.line()}" for p in self.problems if show_info or p.severity != "info"]


def validate_paths(sources: list[Any], config: SGCConfig | None = None) -> list[Report]:
    """Check every clip of clip / batch ``.npz`` files, directories or globs.

    A broken file or member is a report, never an exception; raises FileNotFoundError only for a
    path or glob that names nothing. Of clips with one id, the first without errors keeps it; later ones get a
    ``duplicate_clip_id`` error (docs/semantics.md §1.4).
    """
    config = config or SGCConfig()
    entries = [e for source in sources for path in list_clip_files(source, allow_empty=True)
               for e in entries_from_file(path, config)]
    guard_duplicate_ids(entries)
    reports = []
    for entry in entries:
        try:
            arrays = entry.read()
            clip = clip_from_arrays(arrays, clip_id=entry.clip_id, config=config, validate=False)
        except ClipFormatError as exc:
            code = "unreadable" if exc.array == "<file>" else "structure"
            reports.append(Report(entry.origin, entry.clip_id,
                                  [Problem("error", code, exc.array, exc.expected, exc.found, exc.detail)]))
            continue
        problems = check_clip(clip, config, arrays)
        if not any(p.severity == "error" for p in problems):  # as when scoring: the first clip that loads owns its id
            try:
                entry.claim_id()
            except ClipFormatError as exc:
                problems.insert(0, Problem("error", "duplicate_clip_id", exc.array, exc.expected, exc.found,
                                           exc.detail))
        reports.append(Report(entry.origin, clip.clip_id, problems))
    return reports
