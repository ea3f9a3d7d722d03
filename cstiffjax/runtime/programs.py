"""Serialized programs: a warm run skips JAX's tracing of the largest programs.

JAX's persistent compilation cache (:mod:`cstiffjax.runtime.cache`) saves XLA *compilation*, but a
new process still traces and lowers every program before it can look the compiled one
up: for the diagnosis's fitting loop
(:func:`fitting.calibration.lm.masked_levenberg_marquardt` over the extended model) that is
~7 s of Python on a warm run of the bundled example, more than its arithmetic. Here a
program is traced once, exported (:func:`jax.export.export`, StableHLO) and written next to
the compilation cache; a later process deserializes it (milliseconds) and runs it through
``jax.jit(exported.call)``, whose compiled form the persistent cache then supplies.

**Keys.** A serialized program is found by the SHA-256 of: the source of every module of
``cstiffjax`` and ``fitting`` (any edit invalidates every program; modification times are
re-checked at most once a second, so an edit in a running session counts too), the
versions of jax, jaxlib, equinox, optimistix, lineax, jaxopt, jaxtyping, ml_dtypes and
numpy (every library whose code can end up in a traced program), the JAX settings that
change a trace (:data:`_TRACING`: ``jax_enable_x64``, matmul precision, dtype and rank
promotion, the PRNG), the default backend, the program's name, the tree structure of the
array arguments and of the static (non-array) ones, the static values, and the shape and
dtype of every array argument. Only code whose source or version is in the key may be static: a function or
class from elsewhere (a user's residual function, whose file may import others), a
module-level lambda, a static numpy array (its repr rounds) or a value whose text is not
reproducible (a closure) makes the call run as a plain ``jit``, as do weakly typed array
arguments (an export keeps no weak types), calls under a JAX transformation (tracer
arguments), a program that :func:`jax.export.export` refuses (a host callback), a
serialized program that will not run here (exported for another platform: from then on)
and every call while the folder is unset. An unreadable or corrupt file is ignored with a
warning and replaced; files are written atomically (two processes may share the folder;
:mod:`cstiffjax.runtime.store`). The output's tree
structure is not serialized: the caller gives it as an output-shaped value built without
tracing (``Program(like=...)``), checked against the traced output whenever a program is
traced. Results are those of the plain ``jit`` call bit for bit (the same traced program;
``tests/test_programs.py``), and committed to a device when an argument is, as the plain
``jit``'s (``jit(exported.call)`` commits them always: :func:`_uncommitted`). Size: ~0.6
MB for the bundled example's programs; old versions' files stay until the folder is
deleted.

Off unless a folder is set: :func:`cstiffjax.runtime.cache.enable_compilation_cache` sets
``<cache>/programs`` (so the command line has it by default and ``CSTIFFJAX_CACHE_DIR=off``
turns it off with the compilation cache).

**Log.** Each program that must be traced and compiled (none on disk) is an ``INFO`` record
of the logger ``cstiffjax.runtime.programs`` (a child of ``cstiffjax``), with the extra
attributes ``program`` (its name) and ``once = "compiling"``; nothing is printed. The command
line shows the first of them as one line on a terminal (:mod:`cstiffjax.commands.cli`).
"""

import contextlib
import dataclasses
import functools
import hashlib
import importlib.metadata
import logging
import threading
import time
import types
from pathlib import Path

import equinox as eqx
import jax
import numpy as np
from jax import export

from cstiffjax.core import config as _config
from cstiffjax.core import internals
from cstiffjax.runtime import store

_LOG = logging.getLogger(__name__)
_FOLDER: list[Path | None] = [None]
_MEMO: dict[str, object] = {}  # key -> jax.jit(exported.call), per process
_LOCK = threading.Lock()
_PACKAGES = ("jax", "jaxlib", "equinox", "optimistix", "lineax", "jaxopt", "jaxtyping", "ml_dtypes", "numpy")
_PLAIN = object()  # memo entry of a program that cannot be exported
_NOT_EXPORTABLE = (ValueError, NotImplementedError, TypeError)
_NOT_RUNNABLE = ValueError  # jax.export's refusal to call a program (platform, shapes)
FORMAT = 2  # the file format (in every key): 2, the serialized program followed by its SHA-256
# XLA options of every Program (per program: the kernels of cstiffjax keep XLA's defaults).
# The fitting programs work on small arrays (one row per sample and cable) in nested loops:
# SIMD code, LLVM's -O3 and the hoisting of loop invariants buy them nothing measurable,
# but cost compile time; results agree with the default options to rounding (measurements:
# benchmarks/LATENCY.md).
COMPILER_OPTIONS = {"xla_cpu_prefer_vector_width": 64, "xla_backend_optimization_level": 2,
                    "xla_disable_hlo_passes": "while-loop-invariant-code-motion"}
# Options for a program that runs a handful of times (a cold start of a few hundred samples,
# the one fit per round of the diagnosis's small-sag screen): LLVM without optimization
# compiles it in about half the time; it runs about twice as long, which such a program
# does not notice.
ONCE_OPTIONS = {"xla_backend_optimization_level": 0}
# Added for a program first built inside `concurrent_compiles()` (a diagnosis: its main thread
# and its compile-ahead thread, fitting.diagnosis.fitter.Ahead, compile at the same time): LLVM code
# generation on one thread. XLA splits it over the cores by default, so each compile would
# take both and slow the other thread's tracing and compiles. Not for the compiles of a
# single thread (there it is slower); only on a jaxlib where it was measured
# (benchmarks/LATENCY.md).
CONCURRENT_OPTIONS = {"xla_cpu_parallel_codegen_split_count": 1} if _config.tested_jaxlib() else {}


class _ThreadState(threading.local):
    concurrent = False  # inside concurrent_compiles(), in this thread


_THREAD = _ThreadState()


@contextlib.contextmanager
def concurrent_compiles():
    """Programs first built (memoized) inside this block, in this thread, compile with
    :data:`CONCURRENT_OPTIONS` too, for every later call from any thread: a diagnosis wraps
    its main thread's work and every job of its background thread in it. A program is built
    by the first thread to need it, which a diagnosis fixes (the same programs each run),
    so a warm run finds the cached compilations of the cold one. Serialized programs only
    (the plain ``jit`` path, with the cache off, keeps :data:`COMPILER_OPTIONS`: its call from
    outside the block would not find a program compiled with other options)."""
    before = _THREAD.concurrent
    _THREAD.concurrent = True
    try:
        yield
    finally:
        _THREAD.concurrent = before


def _options(concurrent: bool = True, extra=None) -> dict:
    """The compiler options of a serialized program built now, in this thread
    (``concurrent``: whether :func:`concurrent_compiles` applies to the program; ``extra``:
    the program's own, :class:`Program`'s ``compiler_options``)."""
    both = {**COMPILER_OPTIONS, **CONCURRENT_OPTIONS} if _THREAD.concurrent and concurrent else COMPILER_OPTIONS
    return {**both, **(extra or {})}


# code whose source (our packages) or version (_PACKAGES, the standard library) is in the key
_COVERED = {"cstiffjax", *_PACKAGES, "builtins", "collections", "functools", "math",
            "operator", "typing", "types", "enum", "dataclasses", "abc"}
# the packages whose source files are hashed into every key: cstiffjax itself, and each
# package above it that builds programs, registered by that package (:func:`cover`)
_SOURCES: dict[str, Path] = {"cstiffjax": Path(__file__).resolve().parent.parent}


class _Uncacheable(Exception):
    pass


def set_folder(folder) -> None:
    """Where serialized programs live (``None``: off). Called by
    :func:`cstiffjax.runtime.cache.enable_compilation_cache` / ``disable_compilation_cache``."""
    _FOLDER[0] = None if folder is None else Path(folder)


def folder() -> Path | None:
    """The folder in use, or ``None`` when serialized programs are off."""
    return _FOLDER[0]


def cover(package: str) -> None:
    """Hash the sources of ``package`` (an imported top-level package that builds programs,
    e.g. ``fitting``) into every key from now on, and let its functions and classes be
    static arguments of a serialized program. A package above cstiffjax calls this at import."""
    module = importlib.import_module(package)
    _SOURCES[package] = Path(module.__file__).resolve().parent
    _COVERED.add(package)
    _STAMP[1] = None


def _source_files() -> list[Path]:
    return sorted(p for root in _SOURCES.values() for p in root.rglob("*.py"))


@functools.lru_cache(maxsize=4)
def _source_digest_at(stamp: tuple) -> str:
    """SHA-256 of the files of ``stamp`` (``(path, mtime, size)``, the cache key) and the versions."""
    h = hashlib.sha256(f"format {FORMAT}".encode())
    root = Path(__file__).resolve().parent.parent.parent  # the folder holding the packages
    for path, _, _ in stamp:
        path = Path(path)
        h.update(str(path.relative_to(root) if path.is_relative_to(root) else path).encode())
        h.update(path.read_bytes())
    for name in _PACKAGES:
        try:
            h.update(f"{name} {importlib.metadata.version(name)}".encode())
        except importlib.metadata.PackageNotFoundError:
            h.update(f"{name} ?".encode())
    return h.hexdigest()


_STAMP: list = [0.0, None]  # [time of the last check, (path, mtime, size) of every source file]
_HELD = [False]  # inside sources_held(): no re-check after the first


def source_digest() -> str:
    """SHA-256 over the package sources and the versions that shape a traced program. The
    files' modification times are re-checked at most once a second, so an edit in a running
    session (a notebook's autoreload) gives new keys; inside :func:`sources_held`, once."""
    now = time.monotonic()
    if _STAMP[1] is None or (not _HELD[0] and now - _STAMP[0] > 1.0):
        _STAMP[1] = tuple((str(p), st.st_mtime_ns, st.st_size) for p in _source_files() for st in [p.stat()])
        _STAMP[0] = now
    return _source_digest_at(_STAMP[1])


@contextlib.contextmanager
def sources_held():
    """Inside this block :func:`source_digest` checks the source files once, on its first
    call, and keeps that answer (outside, it re-checks them at most once a second). For a
    process that runs the code it imported and reloads none, the command line: each re-check
    stats every source file (~120), and while another thread holds the interpreter lock (a
    diagnosis traces its next programs in the background) every stat waits for it to come
    back: 1.36 s of a cold bundled diagnosis's main thread went to them, against 0.02 s warm
    (``benchmarks/LATENCY.md``). Nestable; the previous behaviour is restored on exit."""
    before = _HELD[0]
    _HELD[0] = True
    _STAMP[1] = None  # the one check is made inside the block
    try:
        yield
    finally:
        _HELD[0] = before


def _static_text(x) -> str:
    """Reproducible text of a static argument value, or :class:`_Uncacheable`."""
    if isinstance(x, types.FunctionType) and x.__closure__ is None and "<locals>" not in x.__qualname__:
        return f"function {x.__module__}.{x.__qualname__}"
    text = repr(x)
    if " at 0x" in text or " object at " in text:
        raise _Uncacheable(text)
    return f"{type(x).__module__}.{type(x).__qualname__} {text}"


def _origin(obj) -> str:
    """Where the code of a function or class comes from: a module whose source or version
    is in the key (:data:`_COVERED`). Anything else (a user's residual function, whose file
    may import others, a module-level lambda) is :class:`_Uncacheable`: such calls run as a
    plain ``jit`` and always see the code as it is now."""
    mod = getattr(obj, "__module__", None) or ""
    if mod.split(".")[0] not in _COVERED or "<lambda>" in getattr(obj, "__qualname__", ""):
        raise _Uncacheable(f"{obj!r} is not code of cstiffjax, fitting or a versioned library")
    return mod


def _origins(x, out: list, depth: int = 0) -> None:
    """Append :func:`_origin` of every function and class reachable from the static value
    ``x`` (containers, dataclass and equinox fields, ``functools.partial``)."""
    if depth > 12:
        raise _Uncacheable("static value nested too deeply")
    if x is None or isinstance(x, (bool, int, float, complex, str, bytes, np.dtype, np.generic)):
        return
    if isinstance(x, np.ndarray):  # its repr rounds and abbreviates: not a key
        raise _Uncacheable("a numpy array among the static values")
    if isinstance(x, (tuple, list, set, frozenset)):
        for y in x:
            _origins(y, out, depth + 1)
        return
    if isinstance(x, dict):
        for k, v in x.items():
            _origins(k, out, depth + 1)
            _origins(v, out, depth + 1)
        return
    if isinstance(x, functools.partial):
        _origins((x.func, x.args, x.keywords), out, depth + 1)
        return
    if isinstance(x, (type, types.FunctionType, types.BuiltinFunctionType, types.MethodType)):
        out.append(_origin(getattr(x, "__func__", x)))
        return
    out.append(_origin(type(x)))
    if dataclasses.is_dataclass(x):
        for f in dataclasses.fields(x):
            _origins(getattr(x, f.name, None), out, depth + 1)


def _tree_origins(treedef, out: list) -> None:
    """:func:`_origins` of every node type and its static data in ``treedef``."""
    data = treedef.node_data()
    if data is not None:
        out.append(_origin(data[0]))
        _origins(data[1], out)
    for child in treedef.children():
        _tree_origins(child, out)


# JAX settings that change what a trace produces (read on every call: a notebook may change them)
_TRACING = ("jax_enable_x64", "jax_default_matmul_precision", "jax_numpy_dtype_promotion",
            "jax_numpy_rank_promotion", "jax_default_prng_impl", "jax_threefry_partitionable")


def _settings() -> tuple:
    return tuple(getattr(jax.config, name, None) for name in _TRACING)


_KEYS: dict = {}  # identity signature of a call -> (key or None, the static values it pins)
_OUTPUTS: dict = {}  # key -> the output's tree structure


def _key_of_call(name, impl, treedef, static, leaves) -> str:
    """:func:`_key`, memoized on the call's identity: the array tree, the static tree and the
    *identity* of every static value, the arrays' shapes and dtypes, and the sources'
    digest. The memo keeps the static values alive, so their ids are not reused while it
    holds them; any other call falls through to :func:`_key` (computing a key costs ~1 ms:
    the tree's text, the static values' reprs, their code origins; the diagnosis calls its
    fitting loop hundreds of times: ~0.7 s of a two-effect diagnosis). A static object
    changed in place keeps its key, as it keeps its entry in JAX's own jit cache (static
    values are compared by equality and hash, which default to identity)."""
    statics = jax.tree_util.tree_leaves(static)
    sig = (name, impl, treedef, jax.tree_util.tree_structure(static), tuple(map(id, statics)),
           tuple((x.shape, x.dtype, getattr(x, "weak_type", False)) for x in leaves), source_digest(), _settings())
    try:
        hash(sig)
    except TypeError:  # an unhashable static value in a tree node: no memo
        return _key(name, impl, treedef, static, leaves)
    with _LOCK:
        hit = _KEYS.get(sig)
    if hit is None:
        try:
            hit = (_key(name, impl, treedef, static, leaves), statics)
        except _Uncacheable:
            hit = (None, statics)
        with _LOCK:
            _KEYS[sig] = hit
    if hit[0] is None:
        raise _Uncacheable(name)
    return hit[0]


def _key(name, impl, treedef, static, leaves) -> str:
    tree = str(treedef)
    if " at 0x" in tree:  # a static field whose text is not reproducible
        raise _Uncacheable(tree)
    statics = jax.tree_util.tree_leaves(static)
    origins: list[str] = [_origin(impl)]
    _tree_origins(treedef, origins)
    _origins(statics, origins)
    if any(getattr(x, "weak_type", False) for x in leaves):  # export keeps no weak types
        raise _Uncacheable("a weakly typed array argument")
    parts = [source_digest(), f"settings {_settings()}", f"backend {jax.default_backend()}", name, tree,
             str(jax.tree_util.tree_structure(static)), *sorted(set(origins))]
    parts += [_static_text(s) for s in statics]
    parts += [f"{x.shape} {x.dtype}" for x in leaves]  # exported with these (weak types are not kept)
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()


def _load(path: Path):
    """The program in ``path``; ``None`` when missing, or unreadable (warned, deleted: traced again)."""
    return store.read(path, lambda data: export.deserialize(bytearray(store.unseal(data))), "serialized program",
                      "tracing")


def _save(path: Path, exported) -> None:
    try:
        data = exported.serialize()
    except _NOT_EXPORTABLE:  # an unserializable part: runs unsaved
        return
    store.save_program(path, store.seal(data))  # atomic, checksummed; a failed write (a full disk) warns once


def _traced(leaves) -> bool:
    """Whether this call is under a JAX trace (``jit``, ``vmap``, ``grad``, a loop body),
    seen from the trace state or from tracer arguments: compiler options, and so the
    serialized programs, are for top-level calls only."""
    return internals.trace_state_clean() is False or any(
        isinstance(x, jax.core.Tracer) for x in leaves)


def _program(name, impl, dyn, static, check=None, concurrent=True, extra=None):
    """``(jit(exported.call), flat array arguments)`` of ``impl(*combine(dyn, static))``,
    or ``None`` when the call is not cacheable. ``check(output tree structure)``: called
    when the program is traced here (the output's structure is not serialized)."""
    base = folder()
    if base is None:
        return None
    leaves, treedef = jax.tree_util.tree_flatten(dyn)
    if _traced(leaves):
        return None
    try:
        key = _key_of_call(name, impl, treedef, static, leaves)
    except _Uncacheable:
        return None
    with _LOCK:
        caller = _MEMO.get(key)
    if caller is None:
        path = base / f"{key}.jaxexport"
        exported = _load(path)
        if exported is None:
            _LOG.info("compiling (first run only, up to about a minute; kept in %s for later runs)", base.parent,
                      extra={"program": name, "once": "compiling"})

            def flat(*xs):
                out = impl(*eqx.combine(jax.tree_util.tree_unflatten(treedef, xs), static))
                if check is not None:
                    check(jax.tree_util.tree_structure(out))
                return jax.tree_util.tree_leaves(out)

            avals = [jax.ShapeDtypeStruct(x.shape, x.dtype) for x in leaves]
            try:
                exported = export.export(jax.jit(flat))(*avals)
            except _NOT_EXPORTABLE:  # e.g. a host callback: this program runs as a plain jit
                with _LOCK:
                    _MEMO[key] = _PLAIN
                return None
            _save(path, exported)
        caller = jax.jit(exported.call, compiler_options=_options(concurrent, extra))
        with _LOCK:
            caller = _MEMO.setdefault(key, caller)
    return None if caller is _PLAIN else (caller, leaves, key)


def _uncommitted(x):
    """``x``, an output of ``jit(exported.call)``, not committed to its device, as the plain
    ``jit`` returns it for arguments none of which is committed (:meth:`Program.rebuild`).
    A serialized program's outputs are committed, and JAX keys its compiled programs on
    whether each argument is: fed to another program (the discovery's transformed robot
    and data to the fitting loop, the fitted equilibria to the posterior's ensemble) they
    made jit compile that program a second time (the fitting loop: 3.7 s of a cold
    diagnosis of the bundled example, on its main thread). The same buffer, re-wrapped (no
    copy); where JAX's array type cannot do that, a copy through the host."""
    if not getattr(x, "committed", False) or len(x.sharding.device_set) != 1:
        return x  # (several devices: a plain jit's outputs are committed too)
    y = internals.uncommitted(x)
    return jax.device_put(np.asarray(x)) if y is None else y


def _any_committed(leaves) -> bool:
    return any(getattr(x, "committed", False) for x in leaves)


def _demote(key) -> None:
    """Run the program of ``key`` as a plain ``jit`` from now on (its serialized form
    failed to run here, e.g. exported for another platform)."""
    with _LOCK:
        _MEMO[key] = _PLAIN


class Program:
    """``eqx.filter_jit(impl)`` whose calls go through a serialized program when a folder
    is set (:func:`set_folder`), else through ``eqx.filter_jit(impl)``; both compiled with
    :data:`COMPILER_OPTIONS`. A call under a JAX trace (inside ``jit``, ``vmap``, a loop)
    is part of the caller's program: a plain ``eqx.filter_jit(impl)`` without options.

    **Arguments:**

    - ``impl``: the function; arrays in its arguments are data, everything else static
      (as for ``eqx.filter_jit``).
    - ``name``: the program's name in the key (default ``module.qualname`` of ``impl``).
    - ``like``: ``args -> a value with the output's tree structure`` (array leaves may be
      any placeholder, e.g. ``0``), built without tracing: the output's structure is not
      serialized, so a loaded program's arrays are put back into it (checked against the
      real output whenever the program is traced); default: a tuple of arrays.
    - ``concurrent``: whether a serialized program first built inside
      :func:`concurrent_compiles` takes :data:`CONCURRENT_OPTIONS` (default); ``False``
      keeps XLA's code generation over every core for it (a program that a diagnosis
      compiles while its main thread mostly waits: the posterior's ensemble).
    - ``compiler_options``: XLA options of this program on top of :data:`COMPILER_OPTIONS`
      (e.g. ``{"xla_backend_optimization_level": 0}`` for a program run once on a few
      samples, where compile time is all that counts).
    """

    def __init__(self, impl, *, name: str | None = None, like=None, concurrent: bool = True,
                 compiler_options: dict | None = None):
        self.concurrent, self.extra = concurrent, dict(compiler_options or {})
        self.impl, self.jitted = impl, eqx.filter_jit(impl, compiler_options={**COMPILER_OPTIONS, **self.extra})
        self.nested = eqx.filter_jit(impl)  # under a trace (JAX allows options on top-level jits only)
        self.name = name or f"{impl.__module__}.{impl.__qualname__}"
        self.like = like
        functools.update_wrapper(self, impl)

    def _structure(self, args, num_leaves: int):
        like = tuple(range(num_leaves)) if self.like is None else self.like(args)
        return jax.tree_util.tree_structure(like)

    def rebuild(self, leaves, args, key, committed=True):
        """The output of ``impl(*args)`` from its array leaves (a loaded program's output),
        uncommitted unless ``committed`` (whether an argument is: for the single-device
        programs here, a plain ``jit``'s outputs are committed then; :func:`_uncommitted`);
        ``key``: the program's key, which fixes the output's structure (memoized per key)."""
        with _LOCK:
            tree = _OUTPUTS.get(key)
        if tree is None:
            tree = self._structure(args, len(leaves))
            with _LOCK:
                _OUTPUTS[key] = tree
        return jax.tree_util.tree_unflatten(tree, leaves if committed else [_uncommitted(x) for x in leaves])

    def _get(self, args):
        dyn, static = eqx.partition(args, eqx.is_array)

        def check(tree):  # `like` must have the output's structure (a programming error otherwise)
            got = self._structure(args, tree.num_leaves)
            if got != tree:
                raise RuntimeError(f"Program {self.name}: `like` has the structure {got}, the function returns {tree}")

        return _program(self.name, self.impl, dyn, static, check, self.concurrent, self.extra)

    def __call__(self, *args):
        got = self._get(args)
        if got is not None:
            caller, leaves, key = got
            try:
                return self.rebuild(caller(*leaves), args, key, _any_committed(leaves))
            except _NOT_RUNNABLE:  # the serialized form does not run here: plain from now on
                _demote(key)
        return self._plain(args)(*args)

    def _plain(self, args):
        """The plain ``filter_jit``: with :data:`COMPILER_OPTIONS` when called with concrete
        arrays, without under a trace (the caller's program then sets the options)."""
        return self.nested if _traced(jax.tree_util.tree_leaves(args)) else self.jitted

    def lower(self, *args):
        """What ``__call__`` would compile for arguments of this structure (values ignored),
        lowered: ``.compile()`` puts it in the in-memory cache (thread-safe)."""
        got = self._get(args)
        if got is not None:
            caller, leaves, key = got
            try:
                return caller.lower(*leaves)
            except _NOT_RUNNABLE:
                _demote(key)
        return self._plain(args).lower(*args)

    def bind(self, *args, vary: int):
        """``f(x) = self(*args with args[vary] = x)`` for a ``vary`` argument that is one
        array of fixed shape and dtype: the other arguments are partitioned once (for the
        posterior's thousands of calls: ``filter_jit`` partitions every argument on every
        call)."""
        dyn, _ = eqx.partition(args, eqx.is_array)
        counts = [len(jax.tree_util.tree_leaves(d)) for d in dyn]
        if counts[vary] != 1:
            raise ValueError(f"Program.bind: argument {vary} must be one array, got {counts[vary]} arrays")

        plain = self._plain(args)  # the other arguments decide it (x is a concrete array)

        def f(x):
            a = list(args)
            a[vary] = x
            return plain(*a)

        got = self._get(args)
        if got is None:
            return f
        caller, leaves, key = got
        pos = sum(counts[:vary])
        dtype = leaves[pos].dtype
        committed = _any_committed(leaves[:pos] + leaves[pos + 1:])  # x: numpy, never committed

        def g(x):
            flat = list(leaves)
            flat[pos] = np.asarray(x, dtype=dtype)  # numpy: jit's C++ path converts it (faster than jnp)
            try:
                return self.rebuild(caller(*flat), args, key, committed)
            except _NOT_RUNNABLE:
                _demote(key)
                return f(x)
        return g
