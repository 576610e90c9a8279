"""Exceptions raised by facetex.

Every failure a user can cause (a bad file, no face, not enough memory) raises a
subclass of :class:`FacetexError` whose message is one line naming the file (when
there is one), what is wrong and, where it helps, what to do. The CLI prints that
line and exits non-zero; tracebacks are shown only with ``--debug``.

Each class also derives from the built-in exception a Python user already catches:
bad input is a :class:`ValueError`, an output that cannot be written an :class:`OSError`,
a missing input file or model a :class:`FileNotFoundError` (``except FileNotFoundError``
catches ``facetex.read_image("missing.jpg")``; ``except facetex.BadImageError`` too).
"""

from __future__ import annotations

import inspect
import os


_PARAMETERS = """

Parameters
----------
message : str
    The cause, one line.
path : str or os.PathLike, optional
    The offending file; the message starts with it."""


class FacetexError(Exception):
    """Base class of all facetex errors. ``path`` is the offending file, if any."""

    exit_code = 2

    def __init_subclass__(cls, **kwargs):
        # every error class documents the constructor it inherits (numpydoc's sections)
        super().__init_subclass__(**kwargs)
        if cls.__doc__ and "Parameters\n" not in cls.__doc__ and "__init__" not in cls.__dict__:
            cls.__doc__ = inspect.cleandoc(cls.__doc__) + _PARAMETERS

    def __init__(self, message: str, path: str | os.PathLike | None = None):
        self.path = None if path is None else os.fspath(path)
        self.message = message
        super().__init__(f"{self.path}: {message}" if self.path else message)

    def __reduce__(self):  # pickled with its path (errors cross process boundaries)
        return self.__class__, (self.message, self.path)


class BadInputError(FacetexError, ValueError):
    """Any other invalid argument (empty folder, bad landmark file, bad option value)."""


class BadImageError(BadInputError):
    """An image file is missing, unreadable, corrupt, or of an unusable size (or an image
    array of the wrong shape, type or range)."""


class BadVideoError(BadInputError):
    """A video file is missing, unreadable or has no video stream."""


class NoFaceError(FacetexError, ValueError):
    """No (usable) face was found in an image or video."""


class OutputError(FacetexError, OSError):
    """An output cannot be written (missing folder, read-only, exists without --overwrite)."""


class ModelNotFoundError(FacetexError, FileNotFoundError):
    """A model file (network weights, landmark predictor) is not installed."""


class MemoryBudgetError(FacetexError):
    """The estimated peak memory of a job exceeds the allowed budget."""


class BadPersonaError(BadInputError):
    """A .persona file is corrupt, of an unknown version, or otherwise unreadable."""


class UsageError(FacetexError):
    """A command line that does not parse (unknown option, missing or malformed value)."""


# A missing input file is both the input's error class and a FileNotFoundError.
class InputNotFoundError(BadInputError, FileNotFoundError):
    """An input file or folder does not exist."""


class ImageNotFoundError(BadImageError, FileNotFoundError):
    """An image file does not exist."""


class VideoNotFoundError(BadVideoError, FileNotFoundError):
    """A video file does not exist."""


class PersonaNotFoundError(BadPersonaError, FileNotFoundError):
    """A .persona file does not exist."""


_NOT_FOUND = {BadInputError: InputNotFoundError, BadImageError: ImageNotFoundError,
              BadVideoError: VideoNotFoundError, BadPersonaError: PersonaNotFoundError}


def not_found_error(error: type) -> type:
    """The "file does not exist" variant of ``error`` (also a FileNotFoundError), or
    ``error`` itself when it has none."""
    return _NOT_FOUND.get(error, error)


FacetexError.__doc__ = inspect.cleandoc(FacetexError.__doc__) + _PARAMETERS
