"""``cstiffjax`` command line: one sub-command per command module.

Each command module defines ``HELP``, ``add_arguments(parser)`` and ``run(args) -> int``.
cstiffjax's own commands are listed in :data:`COMMANDS`; a package above cstiffjax (``fitting``:
``fit``, ``diagnose``, ``generate``) registers its commands under the entry-point group
``cstiffjax.commands`` (``name = "package.module"`` in its ``pyproject.toml``), so this layer
never imports the layers above it.

Every command gets ``--quiet`` (no progress bars, only the essential output, none of JAX's
own warnings or log messages; a command may define its own ``--quiet`` with more to say). The
persistent JAX compilation cache is on for the command line (:mod:`cstiffjax.runtime.cache`;
``CSTIFFJAX_CACHE_DIR=off`` turns it off; ``cstiffjax cache`` shows or clears it), except for a
command module that sets ``COMPILES = False``. A cache warning is one line on standard error.
The library prints nothing itself: its notes are records of the ``cstiffjax`` loggers, which
the command line shows on standard error (a note such as "compiling (first run only, ...)"
once, on a terminal, not under ``--quiet``). Without a terminal, a command gives a status
line on standard error every ~10 s instead of bars: its step and how far, or that it is still
working (:mod:`cstiffjax.core.progress`; not under ``--quiet``).
"""

import argparse
import ast
import atexit
import contextlib
import gc
import importlib
import importlib.machinery
import importlib.util
import logging
import os
import sys
import warnings
from pathlib import Path

from cstiffjax.commands.exits import EXIT_INTERRUPTED, EXIT_NO_ANSWER, EXIT_USAGE, EXIT_WRITE
from cstiffjax.core.errors import NoAnswerError, RecordingsError, RobotFileError
from cstiffjax.core.text import terminal
from cstiffjax.io.atomic import recorded

# Start-up: this module imports no JAX (nor NumPy): ``cstiffjax --version`` and ``--help`` answer
# from the package metadata and the command modules' sources (their ``HELP`` line, read with
# ``ast`` without importing them); a command imports its own module, and what that needs, only
# when it is the one that runs (benchmarks/LATENCY.md).

# The console script's cyclic garbage collector: a young collection every 50 000 container
# allocations instead of 700, so that full collections over the whole heap (JAX, NumPy,
# SciPy), which hold the interpreter lock both of a diagnosis's threads need, become rare.
# Cycles still die young, and a full collection still runs, only much later
# (measurements: benchmarks/LATENCY.md).
GC_THRESHOLDS = (50_000, 20, 100)

COMMANDS = {name: f"cstiffjax.commands.{name}"
            for name in ("check", "stiffness", "csjm", "css", "frf", "sag", "workspace", "tensions", "convert",
                         "cache", "statics")}
ENTRY_POINT_GROUP = "cstiffjax.commands"


def registered_commands() -> dict[str, str]:
    """Every sub-command: ``{name: module}``, cstiffjax's own then the registered ones (by name)."""
    from importlib.metadata import entry_points

    plugins = {ep.name: ep.value for ep in entry_points(group=ENTRY_POINT_GROUP)}
    clash = sorted(set(plugins) & set(COMMANDS))
    if clash:
        raise RuntimeError(f"entry points {ENTRY_POINT_GROUP!r} redefine built-in commands {clash}")
    return {**COMMANDS, **dict(sorted(plugins.items()))}


def _source(module: str) -> Path | None:
    """The source file of ``module`` found without importing it or its packages (``None`` when
    it is not a plain ``.py`` file on a path)."""
    top, *rest = module.split(".")
    try:
        spec = importlib.util.find_spec(top)  # a top-level name: found, not imported
        for i in range(len(rest)):
            if spec is None or not spec.submodule_search_locations:
                return None
            name = ".".join([top, *rest[: i + 1]])
            spec = importlib.machinery.PathFinder.find_spec(name, list(spec.submodule_search_locations))
    except (ImportError, ValueError):
        return None
    origin = getattr(spec, "origin", None)
    return Path(origin) if origin and origin.endswith(".py") else None


def command_help(module: str) -> str:
    """The one-line ``HELP`` of a command module: read from its source when it is a plain
    string there (nothing is imported), else from the imported module."""
    path = _source(module)
    if path is not None:
        for node in ast.parse(path.read_text(encoding="utf-8")).body:
            if isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == "HELP" for t in node.targets):
                with contextlib.suppress(ValueError):
                    value = ast.literal_eval(node.value)
                    if isinstance(value, str):
                        return value
    return importlib.import_module(module).HELP


def _chosen(argv) -> str | None:
    """The sub-command ``argv`` names (its first word that is not an option), if any."""
    return next((a for a in argv if not a.startswith("-")), None)

_EPILOG = """\
examples:
  cstiffjax check robot.toml recordings.csv     validate and summarize a data set
  cstiffjax stiffness robot.toml --pose 0 0 0.5 0 0 0
                                                stiffness K, eigen-stiffnesses and directions
  cstiffjax cache info                          where the compilation cache is, and its size
  cstiffjax COMMAND --help                      options of one command

exit codes (every command):
  0    an answer
  1    usage: bad arguments or input files (a missing file, a key, a value, a unit); nothing computed
  2    no valid answer: infeasible tensions, a pose outside the anchors' frame, a failed solve
  3    results written, but part of them is missing or failed the command's own check
  4    an output could not be written (disk full, permission); an earlier output is unchanged,
       the outputs written before it are named
  130  interrupted (Ctrl-C); nothing half-written is left

Outputs appear whole or not at all; only regular files are replaced (a character device such
as /dev/null, or a FIFO, is written through; other special files are refused). Without a
terminal, a long run prints a status line on stderr every ~10 s (CSTIFFJAX_PROGRESS_EVERY).

Units are SI everywhere (m, N, N·m, rad, kg, s). Poses are [x y z rx ry rz]: the platform
reference point and the orientation as a rotation vector, both in the base frame.
Bundled examples: cstiffjax.examples (see `cstiffjax check --list-examples`).
"""


EXIT_CODES_HELP = ("exit codes: 0 an answer; 1 bad arguments or input files; 2 no valid answer (infeasible, "
                   "pose outside the frame, failed solve); 3 results written, part missing or failed its own check; "
                   "4 an output not written; 130 interrupted")
"""The exit-code table in one line, at the end of every command's ``--help``."""


class Parser(argparse.ArgumentParser):
    """``argparse.ArgumentParser`` whose usage errors (an unknown option, a missing or
    malformed argument) exit with :data:`~cstiffjax.commands.common.EXIT_USAGE` (1), like every
    other bad input, instead of argparse's 2 (which the command line keeps for "no valid
    answer"). Sub-command parsers are of this class too."""

    def error(self, message):
        self.print_usage(sys.stderr)
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message}\n")


def _version() -> str:
    """The installed package's version (``importlib.metadata``)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("cstiffjax")
    except PackageNotFoundError:  # run from a source tree that was never installed
        return "(version unknown: the package is not installed)"


def build_parser(only: str | None = None, complete: bool = True) -> argparse.ArgumentParser:
    """The ``cstiffjax`` parser. Every sub-command is listed (name and help line); its own
    options are added for all of them (``complete``), or only for the sub-command ``only``
    (:func:`main`: only that command's module is imported)."""
    parser = Parser(
        prog="cstiffjax",
        description="Stiffness, cable statics, calibration and mismatch diagnosis of cable-driven robots.",
        epilog=_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, module in registered_commands().items():
        if not complete and name != only:
            sub.add_parser(name, help=command_help(module))
            continue
        mod = importlib.import_module(module)
        p = sub.add_parser(name, help=mod.HELP, description=mod.__doc__, epilog=EXIT_CODES_HELP,
                           formatter_class=argparse.RawDescriptionHelpFormatter)
        mod.add_arguments(p)
        if not any("--quiet" in a.option_strings for a in p._actions):
            p.add_argument("--quiet", action="store_true", help="no progress bars, essential output only")
        p.set_defaults(_run=mod.run, _compiles=getattr(mod, "COMPILES", True),
                       _xla_threads=getattr(mod, "XLA_THREADS", None))
    return parser


_JAX_UNREADABLE = "Error reading persistent compilation cache entry for"


@contextlib.contextmanager
def _warnings_shown(command: str, quiet: bool):
    """Inside the block: a :class:`~cstiffjax.runtime.store.CacheWarning`, and JAX's warning
    about a cache entry it could not load (which is then compiled and rewritten), is one line
    ``cstiffjax COMMAND: warning: ...`` on standard error; with ``quiet``, JAX's other warnings
    (``warnings`` issued from ``jax``/``jaxlib`` modules) and log messages below ERROR (the
    ``jax`` logger: e.g. "An NVIDIA GPU may be present on this machine, but a CUDA-enabled
    jaxlib is not installed") are not shown. Warning filters, the display hook and the
    logger level are restored after it."""
    from cstiffjax.runtime.store import CacheWarning

    jax_logger = logging.getLogger("jax")
    level = jax_logger.level
    with warnings.catch_warnings():
        show = warnings.showwarning

        def showwarning(message, category, filename, lineno, file=None, line=None):
            text = str(message)
            if text.startswith(_JAX_UNREADABLE):  # a damaged entry: compiled again, rewritten (runtime.store)
                text = (f"ignored an unreadable compilation cache entry for{text.removeprefix(_JAX_UNREADABLE)}; "
                        "compiled it again and rewrote it")
            elif not issubclass(category, CacheWarning):
                show(message, category, filename, lineno, file, line)
                return
            print(f"cstiffjax {command}: warning: {text}", file=sys.stderr if file is None else file)

        warnings.showwarning = showwarning
        if quiet:
            warnings.filterwarnings("ignore", module=r"(jax|jaxlib)(\.|$)")
            warnings.filterwarnings("always", _JAX_UNREADABLE)  # a cache warning, shown as ours
            jax_logger.setLevel(logging.ERROR)
        try:
            yield
        finally:
            jax_logger.setLevel(level)


class _Notes(logging.Handler):
    """Shows the ``cstiffjax`` loggers' records on standard error, one line each, escaped: a
    warning or worse always; an ``INFO`` record (a note, such as the serialized programs'
    "compiling (first run only, ...)") under the progress bars' policy
    (:func:`cstiffjax.core.progress.enabled`: a terminal, not ``--quiet``), and of the records
    with the same ``once`` attribute only the first."""

    def __init__(self):
        super().__init__(logging.INFO)
        self.seen: set[str] = set()

    def emit(self, record: logging.LogRecord) -> None:
        from cstiffjax.core import progress

        once = getattr(record, "once", None)
        if record.levelno < logging.WARNING and (once in self.seen or not progress.enabled()):
            return
        if once is not None:
            self.seen.add(once)
        print(terminal(record.getMessage()), file=sys.stderr, flush=True)


@contextlib.contextmanager
def _notes_shown():
    """Inside the block, the library's log records (logger ``cstiffjax``, ``INFO`` and above)
    are shown by a :class:`_Notes` handler; the logger's handlers and level are restored
    after it."""
    logger = logging.getLogger("cstiffjax")
    level, handler = logger.level, _Notes()
    if logger.getEffectiveLevel() > logging.INFO:
        logger.setLevel(logging.INFO)
    logger.addHandler(handler)
    try:
        yield handler
    finally:
        logger.removeHandler(handler)
        logger.setLevel(level)


def _say(command: str, message: str) -> None:
    """One line on stderr, ``cstiffjax COMMAND: message``, with control characters escaped."""
    print(f"cstiffjax {command}: {terminal(message)}", file=sys.stderr)


def _status_line(line: str) -> None:
    """A heartbeat line (:func:`cstiffjax.core.progress.set_heartbeat`) on stderr, at once."""
    if sys.stderr is not None:  # None: started with stderr closed
        print(line, file=sys.stderr, flush=True)


def _write_error(e: OSError, written: list[str]) -> str:
    """The one line of an output that could not be written: the file and the system's reason,
    that it was not written (nothing half-written, an earlier one unchanged), and the outputs of
    this run that were written before it (``written``: :func:`cstiffjax.io.atomic.recorded`)."""
    where = f"{e.filename}: " if e.filename is not None else ""
    done = f"; written before it: {', '.join(written)}" if written else ""
    return (f"error: {where}{e.strerror or e} (not written: nothing of it was left half-written, an earlier output "
            f"there is unchanged{done})")


def main(argv=None) -> int:
    """Run one sub-command; returns its exit code (``cstiffjax.commands.common.EXIT_*``: 0 an answer,
    1 bad arguments or input files, 2 no valid answer, 3 results written with a problem, 4 an
    output not written, 130 interrupted). A usage error found by ``argparse`` raises
    ``SystemExit(1)``, ``--help`` and ``--version`` ``SystemExit(0)``."""
    os.environ.setdefault("MPLBACKEND", "Agg")  # figures go to files: no window, whatever the display
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(_chosen(argv), complete=False)
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 0
    from cstiffjax.core import progress
    from cstiffjax.core.config import xla_threads
    from cstiffjax.core.status import readable_errors
    from cstiffjax.runtime.cache import compilation_cache
    from cstiffjax.runtime.programs import sources_held

    was_quiet = progress.is_quiet()
    written: list[str] = []  # the outputs this run completed (named when a later one fails)
    quiet = bool(getattr(args, "quiet", False))
    progress.set_quiet(quiet)
    was_beating = progress.set_heartbeat(None if quiet else args.command, _status_line)  # lines without a terminal
    try:
        # a solve that failed inside jit: its message, not XLA's traceback
        # (xla_threads first, before anything starts JAX's backend: a command of many small programs,
        # cstiffjax.core.config; sources_held: the code this process runs is the code it imported)
        with xla_threads(args._xla_threads) if args._xla_threads else contextlib.nullcontext(), \
                _warnings_shown(args.command, quiet), _notes_shown(), readable_errors(), sources_held(), \
                recorded(written), compilation_cache() if args._compiles else contextlib.nullcontext():
            return int(args._run(args) or 0)
    except NoAnswerError as e:  # valid inputs, no valid answer (a SolverError too)
        _say(args.command, f"error: {e}")
        return EXIT_NO_ANSWER
    except (RobotFileError, RecordingsError, ValueError, FileNotFoundError) as e:
        _say(args.command, f"error: {e}")
        return EXIT_USAGE
    except KeyboardInterrupt:  # Ctrl-C: outputs are written atomically, nothing half-written is left
        _say(args.command, "interrupted (no output of this run was left half-written)")
        return EXIT_INTERRUPTED
    except BrokenPipeError:  # ``| head``: handled by console()
        raise
    except OSError as e:  # a full disk, a folder that became read-only: which file, no traceback
        _say(args.command, _write_error(e, written))
        return EXIT_WRITE
    finally:
        progress.set_quiet(was_quiet)  # main() called from Python leaves the process as it was
        progress.set_heartbeat(was_beating, _status_line)


def console() -> None:
    """The ``cstiffjax`` console script: :func:`main`, then the process ends at once.

    Every file a command writes is closed when :func:`main` returns; the ``atexit`` handlers
    run (logging's shutdown, JAX's own clean-up, a coverage tool's) as at a normal exit, and
    standard output and error are flushed. Only the interpreter's finalization
    is skipped (``os._exit``): with JAX loaded it destroys every compiled executable and
    the XLA client object by object, ~0.4 s of every command on the 2-core machine that
    nothing needs on the way out (benchmarks/LATENCY.md). Non-daemon threads are not joined:
    the command line starts none (a diagnosis's background compilation is a daemon thread
    that it waits for before it returns). ``main()`` called from Python keeps the process;
    an exception out of ``main()`` leaves by the normal exit. The process collects cyclic
    garbage less often (:data:`GC_THRESHOLDS`; ``main()`` from Python leaves the
    interpreter's settings alone)."""
    gc.set_threshold(*GC_THRESHOLDS)
    try:
        code = main()
    except BrokenPipeError:  # ``cstiffjax ... | head``: the reader went away, not an error to show
        code = 1
    except KeyboardInterrupt:  # Ctrl-C before the command started (while importing, parsing)
        print("cstiffjax: interrupted", file=sys.stderr)
        code = EXIT_INTERRUPTED
    atexit._run_exitfuncs()  # CPython's own exit sequence: the handlers, in reverse order
    for stream in (sys.stdout, sys.stderr):
        try:
            if stream is not None:  # None: started with the stream closed (``>&-``)
                stream.flush()
        except BrokenPipeError:  # the reader went away (``| head``): nothing more to say there
            code = code or 1
        except (OSError, ValueError) as e:  # e.g. a full disk: the output is incomplete, say so
            code = code or 1
            if stream is not sys.stderr and sys.stderr is not None:
                try:
                    print(f"cstiffjax: error: output incomplete: {e}", file=sys.stderr, flush=True)
                except (OSError, ValueError):
                    pass
    os._exit(code)


if __name__ == "__main__":
    console()
