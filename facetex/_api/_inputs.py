"""Inputs of the public API: image-like arguments, iteration schedules and progress callbacks."""

from __future__ import annotations

from contextlib import contextmanager
from typing import TYPE_CHECKING, Callable, Iterator, Sequence, Union

import numpy as np

from ..errors import BadInputError

if TYPE_CHECKING:  # pragma: no cover

    pass


__all__ = [
    "ImageLike",
    "as_image",
    "parse_iters",
    "Progress",
]


from ..io import ImageLike, as_image  # noqa: E402  (re-exported: facetex.as_image)

Progress = Union[bool, Callable[..., None], None]

# --------------------------------------------------------------------------- inputs
_MAX_ITERS = 100_000
_MAX_LEVELS = 8


def parse_iters(iters: int | str | Sequence[int] | None, *, minimum: int = 1) -> tuple[int, ...] | None:
    """L-BFGS iterations per level from ``100``, ``"100,100,100"`` or ``(100, 100, 100)``.

    Parameters
    ----------
    iters : int, str, sequence of int or None
        One count (one level), comma-separated counts, or a sequence of counts.
    minimum : int
        Fewest iterations a level may have (the transfer functions accept 0: no L-BFGS step
        on that level, e.g. to look at the pre-warp alone).

    Returns
    -------
    tuple of int or None
        One count per resolution level (None when ``iters`` is None: the preset's).

    Raises
    ------
    ValueError
        (:class:`facetex.BadInputError`) not integers, a level below 1 iteration, more than
        8 levels or more than 100000 iterations in a level.

    Examples
    --------
    >>> import facetex
    >>> facetex.parse_iters("2,2,2")
    (2, 2, 2)
    """
    if iters is None:
        return None
    if isinstance(iters, str):
        parts = [p.strip() for p in iters.split(",")]
        try:
            vals = tuple(int(p) for p in parts)
        except ValueError:
            raise BadInputError(f"iters takes comma-separated integers such as '100,100,100', not {iters!r}") from None
    elif isinstance(iters, (int, np.integer)) and not isinstance(iters, bool):
        vals = (int(iters),)
    else:
        try:
            vals = tuple(iters)
        except TypeError:
            raise BadInputError(f"iters must be an integer, a list of integers or a string such as "
                                f"'100,100,100', not {iters!r}") from None
        if not all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) for v in vals):
            raise BadInputError(f"iters must hold integers, not {iters!r}")
        vals = tuple(int(v) for v in vals)
    if not vals or any(v < minimum for v in vals):
        raise BadInputError(f"every level needs at least {minimum} iteration{'s' if minimum != 1 else ''}, "
                            f"not {iters!r}")
    if len(vals) > _MAX_LEVELS or any(v > _MAX_ITERS for v in vals):
        raise BadInputError(f"at most {_MAX_LEVELS} levels of at most {_MAX_ITERS} iterations, not {iters!r}")
    return vals


@contextmanager
def _progress(progress: Progress, total: int | None, desc: str, unit: str) -> Iterator[Callable | None]:
    """``progress=True``: a tqdm bar on stderr that stays when done; a callable is passed
    through; False/None: nothing."""
    if progress is True:
        import sys

        from tqdm import tqdm

        bar = tqdm(total=total, desc=desc, unit=unit, file=sys.stderr, dynamic_ncols=True, leave=True)

        def update(n: int = 1, **postfix):
            shown = {k: (f"{v:.4g}" if isinstance(v, float) else v) for k, v in postfix.items()
                     if isinstance(v, (int, float, str))}
            if shown:
                bar.set_postfix(shown, refresh=False)
            if bar.total is not None and bar.n + n > bar.total:  # the total is an estimate
                bar.total = bar.n + n
            bar.update(n)

        try:
            yield update
            if bar.total is not None and bar.n < bar.total:  # finished early: end at 100 %
                bar.total = bar.n
                bar.refresh()
        finally:
            bar.close()
    elif progress is None or progress is False:
        yield None
    elif callable(progress):
        yield progress
    else:
        raise BadInputError(f"progress must be True, False or a callable, not {progress!r}")


