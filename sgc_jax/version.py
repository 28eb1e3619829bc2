"""The package version, recorded with every run's results (docs/semantics.md §4.1)."""

__version__ = "0.1.0"
