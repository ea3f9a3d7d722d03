"""Progress bars for long work (tqdm on stderr), one policy for the CLI and the API.

Every long-running call (diagnosis candidates and folds, emcee chains, sag maps, FRF
sweeps, workspace sweeps) takes ``progress=None | bool`` and draws its bar with
:func:`bar`:

- ``progress=True`` / ``False``: always / never;
- ``progress=None`` (the default, "auto"): only when standard error is a terminal and
  the process is not in quiet mode (:func:`set_quiet`, set by the CLI's ``--quiet``).

So output piped to a file, a CI log or a test never carries bars.

**Heartbeat.** Where the command line runs without a terminal (a CI log, ``nohup``, a pipe),
the bars are not drawn; a status line on stderr every :data:`HEARTBEAT_S` seconds says
instead what the command is doing: the step and how far an auto bar (``progress=None``) is
(``diagnose: round 1 candidates, 3 of 12 (25 s)``), or between bars (loading, compiling)
that it is still working and after which step (``diagnose: working (40 s), after round 1
candidates``), so a long run is never silent for a minute. The command line turns it on
(:func:`set_heartbeat`, not under ``--quiet``); the library alone prints nothing.
``CSTIFFJAX_PROGRESS_EVERY`` sets the interval in seconds (``off`` or ``0``: no heartbeat).
"""

import contextlib
import math
import os
import sys
import threading
import time

from tqdm import tqdm

from cstiffjax.core.text import terminal

HEARTBEAT_S = 10.0
"""Seconds between two heartbeat lines of one bar (the first comes after as long)."""
HEARTBEAT_ENV = "CSTIFFJAX_PROGRESS_EVERY"

_state = {"quiet": False, "heartbeat": None}
_clock = time.monotonic  # the heartbeat's clock (seconds); a test replaces it


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


def set_heartbeat(label: str | None, write=None) -> str | None:
    """Process-wide heartbeat (module doc): from now on, a status line prefixed with ``label``
    (the command's name) whenever nothing was reported for :func:`heartbeat_every` seconds,
    from a daemon thread, handed to ``write`` (the command line's: the library prints nothing);
    ``None`` stops it. **Returns:** the previous label."""
    old = _state["heartbeat"]
    if old is not None:
        old.stop()
    every = heartbeat_every() if label else None
    _state["heartbeat"] = Pulse(label, write, every) if every else None
    if _state["heartbeat"] is not None:
        _state["heartbeat"].start_thread()
    return None if old is None else old.label


def heartbeat_every(environ=None) -> float | None:
    """The heartbeat interval in seconds: ``CSTIFFJAX_PROGRESS_EVERY`` when it is a positive
    number, ``None`` (no heartbeat) for ``0``/``off``/``no``/``false``, else :data:`HEARTBEAT_S`."""
    text = (os.environ if environ is None else environ).get(HEARTBEAT_ENV, "").strip().lower()
    if text in ("0", "off", "no", "false", "none"):
        return None
    try:
        value = float(text)
    except ValueError:
        return HEARTBEAT_S
    return value if math.isfinite(value) and value > 0 else HEARTBEAT_S


class Pulse:
    """The heartbeat of one command (module doc): the innermost running bar's step and count,
    or, between bars (loading, compiling), that it is still working and after which step.

    **Arguments:** ``label``: the command; ``write``: called with each line (the command line
    prints it on stderr); ``every``: seconds between lines; ``clock``: seconds (default
    ``time.monotonic``; a test passes its own).

    Bars not drawn register in :attr:`bars` while they run (:func:`bar`); each needs tqdm's
    ``n``, ``total``, ``desc``, ``unit`` and ``postfix`` and a ``started`` time.
    """

    def __init__(self, label: str, write, every: float = HEARTBEAT_S, clock=None):
        self.label, self.write, self.every, self.clock = label, write, float(every), clock or _clock
        self.start = self.last = self.clock()
        self.bars: list = []
        self.after: str | None = None  # the step of the last bar that finished
        self._stop = threading.Event()

    def line(self, now: float) -> str:
        """``"LABEL: STEP, N of TOTAL (T s)"`` for the innermost bar (``N UNIT`` without a total,
        its postfix after it), else ``"LABEL: working (T s), after STEP"`` (escaped)."""
        if not self.bars:
            after = f", after {self.after}" if self.after else ""
            return terminal(f"{self.label}: working ({now - self.start:.0f} s){after}")
        b = self.bars[-1]
        done = f"{b.n} of {b.total}" if b.total else f"{b.n} {getattr(b, 'unit', 'it')}"
        tail = f", {b.postfix}" if getattr(b, "postfix", None) else ""
        return terminal(f"{self.label}: {b.desc or 'working'}, {done} ({now - b.started:.0f} s){tail}")

    def beat(self) -> str | None:
        """Write (and return) a line when :attr:`every` seconds have passed since the last one
        (or the start); else nothing."""
        now = self.clock()
        if now - self.last < self.every:
            return None
        self.last = now
        text = self.line(now)
        self.write(text)
        return text

    def started(self, b) -> None:
        """``b`` runs (innermost): the lines report it."""
        b.started = self.clock()
        self.bars.append(b)

    def finished(self, b) -> None:
        if b in self.bars:
            self.bars.remove(b)
            self.after = b.desc or self.after

    def start_thread(self) -> None:
        """Beat from a daemon thread (checked every second) until :meth:`stop`."""
        def run():
            while not self._stop.wait(min(1.0, self.every)):
                try:
                    self.beat()
                except (OSError, ValueError):  # stderr closed or gone (a reader of a pipe left): stop quietly
                    return

        threading.Thread(target=run, name="cstiffjax-heartbeat", daemon=True).start()

    def stop(self) -> None:
        self._stop.set()


class _Unseen:
    """A stream that discards what a bar draws (the heartbeat reads the bar instead)."""

    def write(self, text) -> int:
        return len(text)

    def flush(self) -> None:
        pass


class _HeartbeatBar(tqdm):
    """A tqdm bar drawn nowhere whose progress the command's :class:`Pulse` reports while it runs."""

    def __init__(self, *args, pulse: Pulse, **kwargs):
        super().__init__(*args, **kwargs)
        self.pulse = pulse
        pulse.started(self)

    def display(self, *args, **kwargs):  # drawn nowhere: the count alone is kept (every step, miniters=1)
        return True

    def close(self):
        pulse = getattr(self, "pulse", None)
        if pulse is not None:
            pulse.finished(self)
        super().close()


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

    **Returns:** the bar (use it as an iterator or call ``update(n)``); one that is not drawn
    but reports a heartbeat (module doc) when the command line turned it on.
    """
    pulse = _state["heartbeat"]
    if progress is None and pulse is not None and not _state["quiet"] and not enabled(progress):
        return _HeartbeatBar(iterable, total=total, desc=desc, unit=unit, leave=False, file=_Unseen(),
                             **{**kwargs, "mininterval": 0, "miniters": 1}, pulse=pulse)
    return tqdm(iterable, total=total, desc=desc, unit=unit, leave=leave, disable=not enabled(progress),
                file=sys.stderr, dynamic_ncols=True, **kwargs)


__all__ = ["HEARTBEAT_S", "Pulse", "bar", "enabled", "heartbeat_every", "is_quiet", "quiet", "set_heartbeat",
           "set_quiet"]

