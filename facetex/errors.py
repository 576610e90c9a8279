"""Exceptions raised by facetex.

Every failure a user can cause (a bad file, no face, not enough memory) raises a
subclass of :class:`FacetexError` whose message is one line naming the file (when
there is one), what is wrong and, where it helps, what to do. The CLI prints that
line and exits non-zero; tracebacks are shown only with ``--debug``.
"""

from __future__ import annotations

import os


class FacetexError(Exception):
    """Base class of all facetex errors. ``path`` is the offending file, if any."""

    exit_code = 2

    def __init__(self, message: str, path: str | os.PathLike | None = None):
        self.path = None if path is None else os.fspath(path)
        self.message = message
        super().__init__(f"{self.path}: {message}" if self.path else message)


class BadImageError(FacetexError):
    """An image file is missing, unreadable, corrupt, or of an unusable size."""


class BadVideoError(FacetexError):
    """A video file is missing, unreadable or has no video stream."""


class NoFaceError(FacetexError):
    """No (usable) face was found in an image or video."""


class OutputError(FacetexError):
    """An output cannot be written (missing folder, read-only, exists without --overwrite)."""


class ModelNotFoundError(FacetexError):
    """A model file (network weights, landmark predictor) is not installed."""


class MemoryBudgetError(FacetexError):
    """The estimated peak memory of a job exceeds the allowed budget."""


class BadPersonaError(FacetexError):
    """A .persona file is corrupt, of an unknown version, or otherwise unreadable."""


class BadInputError(FacetexError):
    """Any other invalid argument (empty folder, bad landmark file, bad option value)."""


class UsageError(FacetexError):
    """A command line that does not parse (unknown option, missing or malformed value)."""
