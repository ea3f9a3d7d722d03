"""Outputs that appear whole or not at all.

Every file and folder a command writes is first written under a temporary name beside its
destination and then renamed into place (a rename within one file system is atomic). A run
that stops part-way (Ctrl-C, ``kill -9``, a full disk, an error) leaves the previous complete
output, or the new complete output, never a half-written file; an existing output is not
removed before its replacement is complete.

- :func:`replacing` / :func:`write_text`: one file (``path.tmp-XXXX`` beside it, renamed
  onto it; a symbolic link is followed: the file it points to is replaced).
- :func:`output_folder`: a folder of files (a report, figures). The files are written into a
  new folder beside the destination; then the new folder takes the place of the old one in
  one step (``renameat2(RENAME_EXCHANGE)`` where the system has it, otherwise two renames a
  moment apart, the old folder kept under a temporary name until the new one is in place)
  and the old one is deleted. A folder that also holds files that are not this command's
  outputs (``--out .``), is a symbolic link, or whose parent cannot be written is updated file
  by file instead (each file replaced atomically; outputs of an earlier run that this run no
  longer writes are removed).
- :func:`best_effort`: a secondary output (a figure) whose failure is reported instead of
  discarding the primary results.

Only regular files are replaced. An output that is a character device (``/dev/null``,
``/dev/stdout`` on a terminal) or a FIFO (a named pipe) is written through: the output is
first made whole in a private temporary folder, then copied into the device or pipe (which
stays what it is; a pipe waits for its reader). Any other existing entry that is not a
regular file (a socket, a block device) is refused (:class:`~cstiffjax.core.errors.OutputPathError`)
before anything is written. The same holds for each file inside a folder output; a folder
holding such a file is updated file by file, and only regular files (and this command's
sub-folders) of an earlier run are ever removed.

:func:`recorded` lists the outputs completed inside a block (the command line names them when
a later output of the same run fails: which outputs were written and which not).

A run killed with ``kill -9`` may leave a hidden ``.NAME.tmp-XXXX`` file or folder beside
the output; it is never read and may be deleted.
"""

import contextlib
import errno
import fnmatch
import os
import shutil
import stat
import tempfile
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

from cstiffjax.core.errors import OutputPathError

_RECORDERS: list[list[str]] = []  # the lists of the open recorded() blocks


@contextlib.contextmanager
def recorded(into: list[str]) -> Iterator[list[str]]:
    """Context manager: inside the block, the path of every output completed by
    :func:`replacing` (a file, also :func:`write_text`) or :func:`output_folder` (``"DIR/"``) is
    appended to ``into``, once, in the order they were completed; files made inside a folder
    output's temporary folder are not outputs of their own and are left out.

    **Returns:** (as the context value) ``into``.
    """
    _RECORDERS.append(into)
    try:
        yield into
    finally:
        _RECORDERS.remove(into)


def _completed(path: Path, folder: bool = False) -> None:
    """Note ``path`` in every open :func:`recorded` list (not a file inside a temporary folder)."""
    if any(_is_temporary(part) for part in path.parts[:-1]):
        return
    name = f"{path}/" if folder else str(path)
    for into in _RECORDERS:
        if name not in into:
            into.append(name)


def target_kind(path) -> str:
    """What an output path names now, its symbolic links followed: ``"missing"``, ``"file"``
    (a regular file), ``"folder"``, ``"stream"`` (a character device or a FIFO: written
    through, never replaced) or ``"other"`` (a socket, a block device: refused)."""
    try:
        mode = os.stat(path).st_mode
    except (FileNotFoundError, NotADirectoryError):
        return "missing"
    if stat.S_ISREG(mode):
        return "file"
    if stat.S_ISDIR(mode):
        return "folder"
    return "stream" if stat.S_ISCHR(mode) or stat.S_ISFIFO(mode) else "other"


def refuse_special(path, option: str = "") -> None:
    """Raise :class:`~cstiffjax.core.errors.OutputPathError` when ``path`` exists and is neither a
    regular file, a folder, a character device nor a FIFO (``option`` names it in the message)."""
    if target_kind(path) == "other":
        where = f"{option} {path}" if option else str(path)
        raise OutputPathError(f"{where}: is neither a regular file, a character device nor a FIFO (a socket or a "
                              f"block device); cstiffjax writes only those. Choose another output path")


def _write_through(src: Path, device) -> None:
    """Copy the finished file ``src`` into the character device or FIFO ``device`` (opened for
    writing without creating or truncating anything else; a FIFO waits for its reader)."""
    try:
        with open(src, "rb") as fin, open(device, "wb") as fout:
            shutil.copyfileobj(fin, fout)
    except OSError as e:  # a write or the final flush (``/dev/full``): the error names the device
        if e.filename is not None:
            raise
        raise type(e)(e.errno, e.strerror, str(device)) from e


def _temporary_name(final: Path, folder: Path | None = None) -> Path:
    """A fresh hidden name beside ``final`` (or in ``folder``)."""
    return (final.parent if folder is None else folder) / f".{final.name}.tmp-{os.urandom(4).hex()}"


def _destination(path) -> Path:
    """``path`` with a symbolic link at its end followed (the file it points to is replaced)."""
    p = Path(path)
    return Path(os.path.realpath(p)) if p.is_symlink() else p


@contextlib.contextmanager
def replacing(path) -> Iterator[Path]:
    """Context manager: a temporary path beside ``path`` to write; on a normal exit it is
    renamed onto ``path`` (atomic), on an exception (also ``KeyboardInterrupt``) it is removed
    and ``path`` is left as it was.

    **Arguments:** ``path``: the destination file (its folder must exist).

    ``path`` may also be a character device or a FIFO: the finished temporary file (then in a
    private temporary folder) is copied into it (module doc); another kind of special file is
    refused before anything is written.

    **Returns:** (as the context value) the temporary path; nothing exists there yet.
    """
    refuse_special(path)
    if target_kind(path) == "stream":
        with _streamed(path) as tmp:
            yield tmp
        _completed(Path(path))
        return
    final = _destination(path)
    tmp = _temporary_name(final)
    try:
        yield tmp
        os.replace(tmp, final)
        _completed(Path(path))
    except BaseException as e:
        with contextlib.suppress(OSError):
            tmp.unlink()
        renamed = _named(e, tmp, final)
        if renamed is e:
            raise
        raise renamed from e


@contextlib.contextmanager
def _streamed(path) -> Iterator[Path]:
    """:func:`replacing` for a character device or FIFO ``path``: a temporary path in a private
    folder, copied into ``path`` on a normal exit; the folder is removed either way."""
    final = Path(path)
    folder = Path(tempfile.mkdtemp(prefix="cstiffjax-"))
    tmp = _temporary_name(final, folder)
    try:
        try:
            yield tmp
            _write_through(tmp, final)
        except OSError as e:
            renamed = _named(e, tmp, final)
            if renamed is e:
                raise
            raise renamed from e
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def write_text(path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically (:func:`replacing`), flushed to the disk
    before the rename; a new file gets the usual permissions (``0666`` less the umask)."""
    with replacing(path) as tmp:
        with open(tmp, "x", encoding="utf-8") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())


def _named(e: BaseException, tmp: Path, final: Path) -> BaseException:
    """``e``, or for an ``OSError`` about the temporary ``tmp`` (or a file in it) the same error
    about ``final``: a message names the output the user asked for, not a hidden name. An
    ``OSError`` naming no file (a write past a file-size limit, a full disk on the final flush)
    is made to name ``final``."""
    if not isinstance(e, OSError) or e.errno is None:
        return e
    if e.filename is None:
        where = str(final)
    elif str(e.filename).startswith(str(tmp)):
        where = str(final) + str(e.filename)[len(str(tmp)):]
    else:
        return e
    try:
        return type(e)(e.errno, e.strerror, where)
    except TypeError:  # a subclass with a constructor of its own
        return e


def _owned(name: str, patterns: Iterable[str]) -> bool:
    return any(fnmatch.fnmatchcase(name, p) for p in patterns)


def _is_temporary(name: str) -> bool:
    """A name made by :func:`_temporary_name` (left by a run that was killed)."""
    _, sep, tail = name.rpartition(".tmp-")
    return name.startswith(".") and bool(sep) and len(tail) == 8 and all(c in "0123456789abcdef" for c in tail)


def _exchange(a: Path, b: Path) -> bool:
    """Swap the names ``a`` and ``b`` in one step (Linux ``renameat2(RENAME_EXCHANGE)``);
    ``False`` where the system or file system does not offer it."""
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        fn = libc.renameat2
    except (OSError, AttributeError):
        return False
    at_fdcwd, rename_exchange = -100, 2
    if fn(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), rename_exchange) == 0:
        return True
    code = ctypes.get_errno()
    if code in (errno.ENOSYS, errno.EINVAL, errno.ENOTSUP, errno.EOPNOTSUPP):
        return False
    raise OSError(code, os.strerror(code), str(b))


def _swap_in(new: Path, final: Path) -> None:
    """Put the folder ``new`` in the place of the folder ``final`` and delete the old one."""
    if _exchange(new, final):
        shutil.rmtree(new, ignore_errors=True)  # ``new`` now names the old folder
        return
    old = _temporary_name(final)
    os.rename(final, old)
    try:
        os.rename(new, final)
    except BaseException:
        os.rename(old, final)  # put the old one back
        raise
    shutil.rmtree(old, ignore_errors=True)


def _merge(new: Path, final: Path, patterns: Iterable[str]) -> None:
    """Move every entry of ``new`` into the existing folder ``final`` (each replaced atomically,
    or copied into a character device or FIFO of that name) and delete the entries of ``final``
    that match ``patterns`` but that this run did not write (regular files, symbolic links and
    folders only)."""
    written = set()
    for entry in sorted(new.iterdir()):
        target = final / entry.name
        if entry.is_dir() and target.is_dir() and not target.is_symlink():
            _swap_in(entry, target)
        elif target_kind(target) == "stream":
            _write_through(entry, target)
        else:
            os.replace(entry, target)
        written.add(entry.name)
    for stale in final.iterdir():
        if stale.name not in written and not _is_temporary(stale.name) and _owned(stale.name, patterns):
            if stale.is_dir() and not stale.is_symlink():
                shutil.rmtree(stale)
            elif stale.is_symlink() or target_kind(stale) == "file":
                stale.unlink()


def _special_entries(final: Path, patterns: Iterable[str]) -> list[Path]:
    """The entries of the folder ``final`` matching ``patterns`` that are character devices or
    FIFOs (written through); raises :class:`~cstiffjax.core.errors.OutputPathError` for any
    other special file among them."""
    if not final.is_dir():
        return []
    found = []
    for e in sorted(final.iterdir()):
        if _owned(e.name, patterns):
            refuse_special(e)
            if target_kind(e) == "stream":
                found.append(e)
    return found


def _swappable(final: Path, patterns: Iterable[str]) -> bool:
    """Whether the existing folder ``final`` may be replaced as a whole: a real folder holding
    nothing but this command's outputs, and not the working folder or one above it."""
    if final.is_symlink() or not final.is_dir():
        return False
    here = Path.cwd().resolve()
    if final.resolve() in (here, *here.parents):
        return False
    return all(_owned(e.name, patterns) or _is_temporary(e.name) for e in final.iterdir())


def earlier_outputs(path, patterns: Iterable[str] = ()) -> list[str]:
    """The names of the entries of an existing folder ``path`` that a folder output with these
    ``patterns`` (:func:`output_folder`) will replace (``[]`` when the folder does not exist)."""
    final = Path(path)
    if not final.is_dir():
        return []
    patterns = tuple(patterns)
    return sorted(e.name for e in final.iterdir() if _owned(e.name, patterns) and not _is_temporary(e.name)
                  and target_kind(e) in ("file", "folder", "missing"))


@contextlib.contextmanager
def output_folder(path, patterns: Iterable[str] = (), on_replace: Callable[[str], object] | None = None
                  ) -> Iterator[Path]:
    """Context manager: a new empty folder to write a folder output into; on a normal exit its
    files become the folder ``path`` (see the module doc), on an exception (also
    ``KeyboardInterrupt``) it is deleted and ``path`` is left as it was.

    **Arguments:**

    - ``path``: the output folder (created with its parents when missing).
    - ``patterns``: names (``fnmatch`` patterns, e.g. ``"discovered_*.png"`` for a numbered
      family) of the entries this run writes into ``path``: give only those (``fit --plots``
      without ``--posterior`` gives ``residuals.png`` alone), since an existing folder
      holding only such entries is replaced as a whole, and in a folder that holds other
      things too, regular files matching them that this run did not write are removed (a
      numbered figure of an earlier run); nothing else there is ever touched.
    - ``on_replace``: called with one sentence (``"replacing N file(s) of an earlier run in
      PATH/: a, b, ..."``) before anything is written when ``path`` holds such entries (the
      commands print it on stderr), so no earlier output is replaced unannounced.

    **Returns:** (as the context value) the folder to write into.
    """
    final = Path(path)
    patterns = tuple(patterns)
    streams = _special_entries(final, patterns)  # refused before anything is written or announced
    earlier = earlier_outputs(final, patterns)
    if earlier and on_replace is not None:
        shown = ", ".join(earlier[:6]) + (", ..." if len(earlier) > 6 else "")
        on_replace(f"replacing {len(earlier)} file(s) of an earlier run in {final}/: {shown}")
    final.parent.mkdir(parents=True, exist_ok=True)
    whole = not final.exists() or (not streams and _swappable(final, patterns))
    where = final.parent if whole and os.access(final.parent, os.W_OK | os.X_OK) else None
    if where is None:  # the folder is updated file by file: the new files are made inside it
        whole = False
        final.mkdir(exist_ok=True)
        where = _destination(final)
    tmp = _temporary_name(final, where)
    os.mkdir(tmp)  # 0777 less the umask, as a folder made by mkdir
    try:
        try:
            yield tmp
        except OSError as e:
            renamed = _named(e, tmp, final)
            if renamed is e:
                raise
            raise renamed from e
        if not whole:
            _merge(tmp, _destination(final), patterns)
        elif not final.exists():
            try:
                os.rename(tmp, final)
            except OSError as e:  # made meanwhile by someone else: update it file by file
                if e.errno not in (errno.EEXIST, errno.ENOTEMPTY):
                    raise
                _merge(tmp, final, patterns)
        else:
            _swap_in(tmp, final)
        _completed(final, folder=True)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)


def not_written(name: str, error: Exception) -> str:
    """The line naming a secondary output that was left out: ``"NAME: not written (Error: message)"``."""
    return f"{name}: not written ({type(error).__name__}: {error})"


def best_effort(problems: list, path, write: Callable[[], object]) -> bool:
    """Run ``write()``, which writes the secondary output ``path`` (a figure); on an error other
    than an ``OSError`` (a full disk stops the command) delete what it left at ``path``, append
    ``"NAME: not written (Error: message)"`` (:func:`not_written`) to ``problems`` and go on.

    **Returns:** whether ``write()`` finished.
    """
    try:
        write()
        return True
    except OSError:
        raise
    except Exception as e:  # a figure that cannot be drawn must not discard the results
        with contextlib.suppress(OSError):
            Path(path).unlink()
        problems.append(not_written(Path(path).name, e))
        return False
