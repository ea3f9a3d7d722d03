"""Helpers shared by the CLI commands: argument parsing, output-path checks, outputs written
atomically (:mod:`cstiffjax.io.atomic`), exit codes, problems reported on stderr."""

import argparse
import json
import math
import os
import sys
from pathlib import Path

import numpy as np

from cstiffjax.commands.exits import EXIT_CHECK as EXIT_CHECK
from cstiffjax.commands.exits import EXIT_INTERRUPTED as EXIT_INTERRUPTED
from cstiffjax.commands.exits import EXIT_NO_ANSWER as EXIT_NO_ANSWER
from cstiffjax.commands.exits import EXIT_OK as EXIT_OK
from cstiffjax.commands.exits import EXIT_USAGE as EXIT_USAGE
from cstiffjax.commands.exits import EXIT_WRITE as EXIT_WRITE
from cstiffjax.core.errors import OutputPathError
from cstiffjax.core.status import Status, describe
from cstiffjax.core.text import terminal
from cstiffjax.examples import HERE, example_path
from cstiffjax.io.atomic import best_effort as best_effort
from cstiffjax.io.atomic import output_folder as output_folder
from cstiffjax.io.atomic import refuse_special
from cstiffjax.io.atomic import write_text as write_text


def resolve_path(p: str) -> Path:
    """A user path, or the name of a bundled example (``prototype_8mm.toml``)."""
    path = Path(p)
    if path.exists():
        return path
    if not path.is_absolute() and (HERE / p).exists():
        return example_path(p)
    raise FileNotFoundError(f"{p}: no such file (and no bundled example of that name)")


def finite_float(text: str) -> float:
    """``argparse`` type of the poses and wrenches: a finite number (``nan`` and ``inf`` are
    refused, the value named: ``argument --pose: 'nan' is not a finite number``, exit 1)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text!r} is not a finite number")
    return value


def check_input_status(result, what: str) -> None:
    """Raise ``ValueError`` (the CLI's exit 1, a usage error) when ``result`` (a concrete
    :class:`~cstiffjax.core.status.Status`) says the input itself is unusable:
    ``invalid_input`` (a non-finite pose or wrench, a non-positive length) or
    ``zero_length`` (an attachment on its anchor). ``what`` names the input, e.g.
    ``"--pose 0 0 0.5 0 0 0"``. Other statuses (a solve that failed) are left to the command."""
    if result == Status.invalid_input or result == Status.zero_length:
        raise ValueError(f"{what}: {describe(result)}")


def pose_option(pose) -> str:
    """``"--pose X Y Z RX RY RZ"`` with the values of ``pose`` (6,), for messages."""
    return "--pose " + " ".join(f"{float(v):g}" for v in np.asarray(pose))


def add_robot_pose_arguments(p, robot_help: str = "robot description TOML (or a bundled example name)",
                             pose_help: str = "platform pose: position m, rotation vector rad") -> None:
    """The positional ``robot`` and the required ``--pose`` (6 numbers) of the one-pose commands."""
    p.add_argument("robot", help=robot_help)
    p.add_argument("--pose", nargs=6, type=finite_float, required=True, metavar=("X", "Y", "Z", "RX", "RY", "RZ"),
                   help=pose_help)


def add_pose_grid_arguments(p) -> None:
    """The ``--pose-grid`` (9 numbers: bounds in m and point counts) and ``--rotation``
    (rad) options of the commands that sweep a pose grid (read back by :func:`pose_grid`)."""
    p.add_argument("--pose-grid", nargs=9, type=finite_float, required=True,
                   metavar=("XMIN", "XMAX", "NX", "YMIN", "YMAX", "NY", "ZMIN", "ZMAX", "NZ"),
                   help="grid of positions (m) and point counts")
    p.add_argument("--rotation", nargs=3, type=finite_float, default=(0.0, 0.0, 0.0), metavar=("RX", "RY", "RZ"),
                   help="platform rotation vector for all grid poses, rad (default 0)")


def pose_grid(args):
    """The :class:`~cstiffjax.workspace.sweep.Grid` of ``args.pose_grid`` at ``args.rotation``.

    **Raises:** ``ValueError`` naming NX, NY or NZ when a point count is not a positive integer.
    """
    from cstiffjax.workspace.sweep import Grid  # lazy: only the grid commands pay for it

    g = args.pose_grid
    for k, name in ((2, "NX"), (5, "NY"), (8, "NZ")):
        if g[k] != int(g[k]) or g[k] < 1:
            raise ValueError(f"--pose-grid: {name} = {g[k]:g} must be a positive integer")
    return Grid.regular((g[0], g[1], int(g[2])), (g[3], g[4], int(g[5])), (g[6], g[7], int(g[8])),
                        rotation=args.rotation)


MAP_HALF_WIDTH = 0.5
"""Half-width (m) in x and y of the maps around ``--pose`` (``sag --map``, ``frf --sweep``)."""


def add_region_argument(p, option: str) -> None:
    """The ``--region XMIN XMAX YMIN YMAX`` option (m) of a command's x-y map (``option``
    names the map, e.g. ``"--map"``); read back by :func:`region_axes`."""
    p.add_argument("--region", nargs=4, type=finite_float, default=None, metavar=("XMIN", "XMAX", "YMIN", "YMAX"),
                   help=f"x-y region of {option}, m (default: the pose's x and y +- {MAP_HALF_WIDTH:g} m)")


def region_axes(region, pose, n: int, option: str) -> tuple[np.ndarray, np.ndarray]:
    """The x and y coordinates (m) of an ``n x n`` map: over ``region`` ``(xmin, xmax, ymin,
    ymax)`` when given, else centred on the pose's x and y, :data:`MAP_HALF_WIDTH` either side.

    **Arguments:** ``region``: the ``--region`` values or ``None``; ``pose``: ``--pose`` (6
    numbers, m and rad); ``n``: points per axis; ``option``: the map's option, for messages.

    **Returns:** ``(x, y)``, each ``(n,)``.

    **Raises:** ``ValueError`` naming the option when ``n < 2`` or the region is empty.
    """
    if int(n) != n or n < 2:
        raise ValueError(f"{option}: {n!r} points per axis; a map needs at least 2")
    if region is None:
        px, py = float(pose[0]), float(pose[1])
        region = (px - MAP_HALF_WIDTH, px + MAP_HALF_WIDTH, py - MAP_HALF_WIDTH, py + MAP_HALF_WIDTH)
    x0, x1, y0, y1 = (float(v) for v in region)
    if not (x1 > x0 and y1 > y0):
        raise ValueError(f"--region {x0:g} {x1:g} {y0:g} {y1:g}: need XMIN < XMAX and YMIN < YMAX (m)")
    return np.linspace(x0, x1, int(n)), np.linspace(y0, y1, int(n))


def _same_file(a: Path, b: Path) -> bool:
    """True when ``a`` and ``b`` name the same file (resolved symlinks, or hard links)."""
    if a.resolve() == b.resolve():
        return True
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def _writable_folder(option: str, folder: Path, what: str) -> None:
    """``folder`` (which will hold ``what``) exists, is a folder and is writable; or it can be created."""
    probe = folder
    while not probe.exists():  # nearest existing ancestor: the folder will be created below it
        if probe.parent == probe:
            break
        probe = probe.parent
    if probe.exists() and not probe.is_dir():
        raise OutputPathError(f"{option} {what}: {probe} is a file, not a folder")
    if not os.access(probe, os.W_OK | os.X_OK):
        raise OutputPathError(f"{option} {what}: folder {probe} is not writable")


def _missing_parent(option: str, path: Path) -> None:
    """Raise the error for a file output whose folder is not there: an ancestor that is a file
    (``a.json/k.json``) is named as such, else the folder is missing."""
    for up in path.parents:
        if up.exists() or up.is_symlink():
            if not up.is_dir():
                raise OutputPathError(f"{option} {path}: its parent {up} is a file, not a folder; give a path "
                                      f"inside a folder")
            break
    raise OutputPathError(f"{option} {path}: folder {path.parent} does not exist; create it first")


def check_outputs(inputs=(), files=None, folders=None) -> None:
    """Refuse, before any work, output paths that would lose data or fail late.

    **Arguments:**

    - ``inputs``: the paths the command reads (``None`` entries are skipped).
    - ``files``: ``{option: path}`` of file outputs (``--json OUT``); ``None`` paths skipped.
    - ``folders``: ``{option: (path, names)}`` of folder outputs (``--report DIR``) and the
      file names the command writes inside them.

    A file output must not be an input (resolved paths, symlinks and hard links
    compared), nor an existing folder, nor a special file other than a character device
    or a FIFO (which are written through, :mod:`cstiffjax.io.atomic`), and its parent
    folder must exist and be writable (it is not created: a mistyped folder fails at once;
    a parent that is a file is named as such). A folder output must not be an
    existing file; it may not exist yet (it is created later, with its parents) if its
    nearest existing ancestor is a writable folder; no file it will hold may be an input
    or an existing folder. Two outputs naming the same file are refused.

    **Raises:** :class:`~cstiffjax.core.errors.OutputPathError` naming the option and the path.
    """
    ins = [Path(p) for p in inputs if p is not None]
    targets = []  # (option, file path) of every file the command will write
    for option, (folder, names) in (folders or {}).items():
        if folder is None:
            continue
        folder = Path(folder)
        if folder.exists() and not folder.is_dir():
            raise OutputPathError(f"{option} {folder}: is a file, not a folder; give a folder name")
        _writable_folder(option, folder, "folder")
        for name in names:
            refuse_special(folder / name, option)
            if (folder / name).is_dir():
                raise OutputPathError(f"{option} {folder}: {folder / name} is a folder, but this command writes "
                                      f"the file {name} there")
            targets.append((option, folder / name))
    for option, path in (files or {}).items():
        if path is None:
            continue
        path = Path(path)
        if path.is_dir():
            raise OutputPathError(f"{option} {path}: is a folder; give a file name")
        made = any(path.parent.resolve() == Path(f).resolve() for f, _ in (folders or {}).values() if f is not None)
        if made:  # inside a folder output of this command (checked above; created before writing)
            targets.append((option, path))
            continue
        refuse_special(path, option)
        if not path.parent.is_dir():
            _missing_parent(option, path)
        if not os.access(path.parent, os.W_OK | os.X_OK) or (path.exists() and not os.access(path, os.W_OK)):
            raise OutputPathError(f"{option} {path}: cannot write there (permission denied)")
        targets.append((option, path))
    for option, target in targets:
        for src in ins:
            if _same_file(target, src):
                raise OutputPathError(f"{option}: {target} is an input of this command ({src}); writing it would "
                                      f"overwrite the input. Choose another output path")
    for i, (opt_a, a) in enumerate(targets):
        for opt_b, b in targets[i + 1:]:
            if _same_file(a, b):
                raise OutputPathError(f"{opt_a} and {opt_b} both write {a}; choose different paths")


def to_jsonable(obj):
    """Convert arrays/scalars in nested containers to plain Python for ``json``."""
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [to_jsonable(v) for v in obj]
    if hasattr(obj, "shape") or isinstance(obj, np.generic):
        a = np.asarray(obj)
        return a.item() if a.ndim == 0 else a.tolist()
    return obj


def say_replacing(text: str) -> None:
    """Print ``text`` (an earlier output about to be replaced, :func:`cstiffjax.io.atomic.output_folder`'s
    ``on_replace``) on stderr, escaped."""
    print(f"note: {terminal(text)}", file=sys.stderr, flush=True)


def write_json(path, payload) -> None:
    """Write ``payload`` (arrays allowed, :func:`to_jsonable`) as indented JSON to ``path``,
    atomically (:func:`cstiffjax.io.atomic.write_text`)."""
    write_text(path, json.dumps(to_jsonable(payload), indent=1) + "\n")


def report_problems(command: str, problems, notes=()) -> int:
    """Print each note and each problem of a command's own outputs on stderr (``cstiffjax
    COMMAND: warning: ...``, one line each), once its results are written.

    **Arguments:** ``problems``: what makes the outputs incomplete or inconsistent (a figure not
    drawn, a failed check of the command's own result); ``notes``: warnings that leave the
    answer usable (a parameter the data do not determine).

    **Returns:** :data:`EXIT_CHECK` when there is a problem, else :data:`EXIT_OK`.
    """
    for p in [*notes, *problems]:
        print(f"cstiffjax {command}: warning: {terminal(p)}", file=sys.stderr)
    return EXIT_CHECK if problems else EXIT_OK


def format_matrix(M, fmt="{:12.5g}") -> str:
    return "\n".join(" ".join(fmt.format(v) for v in row) for row in np.asarray(M))
