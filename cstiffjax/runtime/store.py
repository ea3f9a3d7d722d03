"""The files of the persistent cache: atomic writes, unreadable entries, and which files are its own.

One cache folder (:mod:`cstiffjax.runtime.cache`) holds

- ``<module>-<64 hex digits>-cache``: XLA executables, JAX's persistent compilation cache
  (compressed; written and read by :class:`XlaStore`), with ``-atime`` files and a
  ``.lockfile`` when JAX's own size-bounded cache wrote there;
- ``programs/<64 hex digits>.jaxexport``: serialized traced programs
  (:mod:`cstiffjax.runtime.programs`);
- ``xla_gpu_per_fusion_autotune_cache_dir/``: XLA's GPU autotuning results (GPU back-ends only);
- ``*.<pid>.<thread>.tmp``: a write in progress (:func:`write_atomic`), or left by a killed
  process (removed once an hour old: :func:`remove_stale`).

:data:`OWN` is the one list of those names: ``cstiffjax cache info`` counts them and
``cstiffjax cache clear`` removes them and nothing else.

Several processes may share a folder (two commands started at once on an empty cache): every
file is written to a temporary name and renamed into place (:func:`write_atomic`), so a
reader sees a whole entry or none. An entry that cannot be read whole (truncated by a full
disk, overwritten with other bytes) is ignored with a warning, compiled again and written
anew. A serialized program carries its SHA-256 (:func:`seal`): a damaged one is deleted
here with a :class:`CacheWarning`. An XLA entry that does not start as a compressed one is
too; one cut short is found by JAX's decompression (JAX warns: "Error reading persistent
compilation cache entry"), which then compiles it, and :meth:`XlaStore.put` replaces it
(JAX's own file cache never replaces an entry: it would warn and compile on every run). A
write that fails (a full disk) leaves no temporary file and warns once per process and
folder; the run goes on without saving.
"""

import contextlib
import hashlib
import os
import re
import threading
import time
import warnings
from pathlib import Path

from cstiffjax.core.internals import CacheInterface, install_compilation_cache

PROGRAMS = "programs"
STALE_AFTER_S = 3600.0
"""Age (s) after which a temporary file is a leftover of a killed process, not a write in progress."""

_HEX = "[0-9a-f]{64}"
_TMP = r"\.\d+\.\d+\.tmp"
OWN = {
    "compiled": re.compile(rf".+-{_HEX}-cache"),  # XLA executables (JAX's persistent cache)
    "programs": re.compile(rf"{PROGRAMS}/{_HEX}\.jaxexport"),  # serialized traced programs
    "temporary": re.compile(rf"(.+-{_HEX}-cache|{PROGRAMS}/{_HEX}\.jaxexport){_TMP}|\.cstiffjax-probe-.+"),
    "other": re.compile(rf".+-{_HEX}-atime|\.lockfile|xla_gpu_per_fusion_autotune_cache_dir/.+"),
}
"""The cache's own files, by kind: a regular expression for each path relative to the folder."""


class CacheWarning(UserWarning):
    """The persistent cache could not be used, or held an unreadable entry; the run goes on."""


_WARNED: set = set()
_WARNED_LOCK = threading.Lock()


def warn(message: str, once=None) -> None:
    """Issue ``message`` as a :class:`CacheWarning`; with ``once`` (a hashable key), only the
    first time this process sees that key."""
    if once is not None:
        with _WARNED_LOCK:
            if once in _WARNED:
                return
            _WARNED.add(once)
    warnings.warn(message, CacheWarning, stacklevel=3)


def write_atomic(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through ``<path>.<pid>.<thread>.tmp`` renamed into place
    (readers never see a partial file; the last of two writers wins). The temporary file
    is removed when the write fails.

    **Raises:** ``OSError`` (a full disk, a read-only folder).
    """
    tmp = path.with_name(f"{path.name}.{os.getpid()}.{threading.get_ident()}.tmp")
    try:
        with open(tmp, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


def _write_failed(folder: Path, error: OSError) -> None:
    warn(f"could not write to the compilation cache {folder}: {error.strerror or error}; "
         "this run goes on without saving what it compiles", once=("write", str(folder)))


def read(path: Path, decode, what: str, redo: str):
    """``decode(bytes of path)``, or ``None`` when ``path`` is missing or unreadable. An entry
    that ``decode`` rejects (any exception: truncated, other bytes) is deleted, with a
    :class:`CacheWarning` naming it (``what``, e.g. ``"serialized program"``; ``redo``: how
    it is made again, e.g. ``"tracing"``)."""
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        return None
    except OSError as e:
        warn(f"could not read the {what} {path}: {e.strerror or e}; {redo} it again")
        return None
    try:
        return decode(data)
    except Exception:  # truncated, another format, other bytes
        pass
    warn(f"ignored the unreadable {what} {path} ({len(data)} bytes: truncated or corrupt); "
         f"{redo} it again and rewriting it")
    with contextlib.suppress(OSError):
        path.unlink()
    return None


_HEADERS = (b"\x28\xb5\x2f\xfd", b"\x78\x01", b"\x78\x5e", b"\x78\x9c", b"\x78\xda")  # zstd, zlib


def _compressed(data: bytes) -> bytes:
    """``data`` if it starts as a zstd frame or a zlib stream does (JAX's two compressions),
    else an exception. Cheap (no decompression: that costs ~10 ms per MB, and JAX does it next):
    a truncated entry that passes is caught by JAX, which warns, compiles and calls
    :meth:`XlaStore.put`, which rewrites it."""
    if not data.startswith(_HEADERS):
        raise ValueError("not a compressed entry")
    return data


def seal(data: bytes) -> bytes:
    """``data`` followed by its SHA-256 (32 bytes): :func:`unseal` tells a whole file from a
    truncated or altered one."""
    return data + hashlib.sha256(data).digest()


def unseal(sealed: bytes) -> bytes:
    """The ``data`` of :func:`seal`; ``ValueError`` when the checksum does not match."""
    data, digest = sealed[:-32], sealed[-32:]
    if len(sealed) < 32 or hashlib.sha256(data).digest() != digest:
        raise ValueError("checksum mismatch: truncated or altered")
    return data


def own_files(folder: Path) -> dict[str, list[Path]]:
    """The cache's own files in ``folder`` by kind (:data:`OWN`), and ``"foreign"``: every
    other file (never counted as the cache's, never removed). Missing folder: all empty."""
    found: dict[str, list[Path]] = {kind: [] for kind in (*OWN, "foreign")}
    if not folder.is_dir():
        return found
    for path in sorted(folder.rglob("*")):
        if path.is_dir():
            continue
        rel = path.relative_to(folder).as_posix()
        kind = next((k for k, pattern in OWN.items() if pattern.fullmatch(rel)), "foreign")
        found[kind].append(path)
    return found


def remove_stale(folder: Path, age_s: float = STALE_AFTER_S) -> int:
    """Remove the temporary files (:data:`OWN`) in ``folder`` and ``folder/programs`` older than
    ``age_s`` seconds (leftovers of a killed process; younger ones may be writes in
    progress). **Returns:** how many."""
    now, removed = time.time(), 0
    for path in (*folder.glob("*.tmp"), *(folder / PROGRAMS).glob("*.tmp")):
        if not OWN["temporary"].fullmatch(path.relative_to(folder).as_posix()):
            continue
        with contextlib.suppress(OSError):
            if now - path.stat().st_mtime > age_s:
                path.unlink()
                removed += 1
    return removed


class XlaStore(CacheInterface):
    """JAX's persistent compilation cache in ``folder``, as JAX's own file cache lays it out
    (``<key>-cache``, readable by either), with atomic writes, an entry that is not a
    compressed one ignored, deleted and warned about, every entry JAX compiles written anew
    (JAX's own cache never replaces an existing entry, e.g. one JAX could not load), and a
    failed write a warning instead of an error. No size bound: old entries stay until
    ``cstiffjax cache clear``."""

    def __init__(self, folder: Path):
        self._path = Path(folder)

    def get(self, key: str) -> bytes | None:
        """The entry of ``key``, or ``None`` (missing or unreadable: then JAX compiles)."""
        return read(self._path / f"{key}-cache", _compressed, "compilation cache entry", "compiling")

    def put(self, key: str, value: bytes) -> None:
        """Write the entry of ``key`` (replacing one that JAX could not load)."""
        try:
            write_atomic(self._path / f"{key}-cache", value)
        except OSError as e:
            _write_failed(self._path, e)


def install(folder: Path) -> bool:
    """Make :class:`XlaStore` at ``folder`` JAX's persistent cache (``jax_compilation_cache_dir``
    must name ``folder``). **Returns:** whether it is installed (else JAX's own file cache
    is used)."""
    return install_compilation_cache(XlaStore(folder))


def save_program(path: Path, data: bytes) -> None:
    """Write a serialized program (:func:`write_atomic`); a failure is a warning, once."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_atomic(path, data)
    except OSError as e:
        _write_failed(path.parent, e)
