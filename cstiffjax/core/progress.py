"""Progress bars for long work (tqdm on stderr), one policy for the CLI and the API.

Every long-running call (diagnosis candidates and folds, emcee chains, sag maps, FRF
sweeps, workspace sweeps) takes ``progress=None | bool`` and draws its bar with
:func:`bar`:

- ``progress=True`` / ``False``: always / never;
- ``progress=None`` (the default, "auto"): only when standard error is a terminal and
  the process is not in quiet mode (:func:`set_quiet`, set by the CLI's ``--quiet``).

So output piped to a file, a CI log or a test never carries bars.
"""

import contextlib
import sys

from tqdm import tqdm

_state = {"quiet": False}


def set_quiet(quiet: bool = True) -> None:
    """Process-wide quiet mode: ``progress=None`` draws nothing (the CLI's ``--quiet``)."""
    _state["quiet"] = bool(quiet)


def is_quiet() -> bool:
    """Whether the process is in quiet mode (:func:`set_quiet`)."""
    return _state["quiet"]


@contextlib.contextmanager
def quiet():
    """Context manager: quiet mode inside the block, the previous mode after it."""
    old = _state["quiet"]
    _state["quiet"] = True
    try:
        yield
    finally:
        _state["quiet"] = old


def enabled(progress: bool | None = None) -> bool:
    """Whether a bar is drawn for a call given its ``progress`` argument (see module docstring)."""
    if progress is not None:
        return bool(progress)
    if _state["quiet"]:
        return False
    isatty = getattr(sys.stderr, "isatty", None)
    return bool(isatty and isatty())


def bar(iterable=None, *, total: int | None = None, desc: str | None = None, progress: bool | None = None,
        unit: str = "it", leave: bool = False, **kwargs):
    """A tqdm bar on stderr, or a silent stand-in with the same interface (``update``,
    ``set_postfix_str``, ``close``, iteration, context manager) when :func:`enabled` is false.

    **Arguments:** ``iterable`` to wrap (optional); ``total`` steps; ``desc`` label;
    ``progress`` the caller's argument; ``unit``; ``leave`` keep the finished bar;
    other keywords go to :class:`tqdm.tqdm`.

    **Returns:** the bar (use it as an iterator or call ``update(n)``).
    """
    return tqdm(iterable, total=total, desc=desc, unit=unit, leave=leave, disable=not enabled(progress),
                file=sys.stderr, dynamic_ncols=True, **kwargs)


__all__ = ["bar", "enabled", "is_quiet", "quiet", "set_quiet"]

