"""What a check finds: a :class:`Problem` line of one severity, and the errors and warnings it becomes."""

from __future__ import annotations

import dataclasses
import sys
import warnings

import numpy as np

from ..clip import Clip, ClipFormatError

SEVERITIES = ("error", "warning", "info")


class ClipValidationError(ClipFormatError):
    """A clip whose content cannot be right (units or resolutions that do not fit)."""


class ClipWarning(UserWarning):
    """A clip that loads but looks wrong in a way that changes its score."""


def clip_warnings_as_lines(prefix: str, show_other=None):
    """A ``warnings.showwarning`` that prints a :class:`ClipWarning` as one line on stderr,
    "{prefix}: clip 'a': warning: ...", not Python's form with the file and source line that raised
    it; other warnings go to ``show_other`` (default: the current ``warnings.showwarning``)."""
    show_other = warnings.showwarning if show_other is None else show_other

    def show(message, category, filename, lineno, file=None, line=None):
        if issubclass(category, ClipWarning):
            print(f"{prefix}: {message}", file=sys.stderr if file is None else file)
        else:
            show_other(message, category, filename, lineno, file, line)
    return show


@dataclasses.dataclass(frozen=True)
class Problem:
    """One finding: ``array`` is the clip array concerned; ``message`` says what and how to fix it."""

    severity: str  # "error" | "warning" | "info"
    code: str
    array: str
    expected: str
    found: str
    fix: str = ""

    @property
    def message(self) -> str:
        text = f"expected {self.expected}, found {self.found}" if self.expected else self.found
        return text + (f"; {self.fix}" if self.fix else "")

    def line(self) -> str:
        return f"{self.severity}: {self.array}: {self.message}"


def frames_list(index: np.ndarray, total: int) -> str:
    shown = ", ".join(str(int(i)) for i in index[:5])
    return f"{len(index)}/{total} ({shown}{', ...' if len(index) > 5 else ''})"


def is_reference_compat(clip: Clip) -> bool:
    record = clip.meta.get("import")
    return isinstance(record, dict) and bool(record.get("reference_compat"))
