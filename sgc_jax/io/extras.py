"""The optional dependencies (pyproject's extras): an error that names the one a call needs."""

from __future__ import annotations


class MissingExtraError(ImportError):
    """A call needs an optional package that is not installed; the message says what to install.
    The command line reports it as a usage error (exit 2), not as a bug."""
