"""Serialized programs (cstiffjax.runtime.programs): a warm process loads the traced program instead
of tracing it again, with the same results, and a changed key (source, shapes, static
values) never reuses a stale one."""

import contextlib
import logging
import os
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax import export

from cstiffjax.core import internals
from cstiffjax.runtime import cache, programs, store
from fitting.calibration import lm

from .helpers import forget_programs

TRACES = []


class Scale(eqx.Module):
    power: int = eqx.field(static=True)
    k: jax.Array


def _impl(mod, x, flag):
    TRACES.append(x.shape)  # runs only while JAX traces
    y = mod.k * x**mod.power
    return (y, jnp.sum(y)) if flag else (y * 0 + 1, jnp.sum(y))


def _fresh():
    """A new process's view: nothing in memory, the folder on disk as it is."""
    forget_programs()
    TRACES.clear()
    return programs.Program(_impl, name="tests.scale")


def _f(v):
    return jnp.asarray(v, dtype=jnp.float64)  # not weakly typed (a weak array is never serialized)


def _apply(f, x):
    return f(x)


def _double(x):
    return x * 2


@pytest.fixture
def folder(tmp_path, monkeypatch):
    # this file's functions and classes count as package code here (outside cstiffjax and
    # fitting, code runs as a plain jit: see test_code_from_elsewhere_runs_plainly)
    monkeypatch.setattr(programs, "_COVERED", programs._COVERED | {"tests"})
    programs.set_folder(tmp_path)
    yield tmp_path
    programs.set_folder(None)
    forget_programs()


def _files(folder):
    return sorted(p.name for p in folder.glob("*.jaxexport"))


def test_off_is_filter_jit():
    programs.set_folder(None)
    prog, x = _fresh(), jnp.arange(3.0)
    out = prog(Scale(2, _f(3.0)), x, True)
    np.testing.assert_array_equal(out[0], 3.0 * x**2)
    assert isinstance(out, tuple) and len(TRACES) == 1


def test_a_second_process_loads_instead_of_tracing(folder):
    mod, x = Scale(2, _f(3.0)), jnp.arange(4.0)
    ref = eqx.filter_jit(_impl)(mod, x, True)
    first = _fresh()(mod, x, True)
    assert len(TRACES) == 1 and len(_files(folder)) == 1
    prog = _fresh()
    again = prog(mod, x, True)
    assert TRACES == []  # loaded, not traced
    for a, b, c in zip(first, again, ref):
        np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(a, c)
    # new values of the same shapes: the same program, right answers
    y = prog(Scale(2, _f(-1.0)), jnp.full(4, 2.0, dtype=jnp.float64), True)
    np.testing.assert_array_equal(y[0], np.full(4, -4.0))
    assert TRACES == [] and len(_files(folder)) == 1


def test_every_part_of_the_key_makes_a_new_program(folder, monkeypatch):
    mod, x = Scale(2, _f(3.0)), jnp.arange(4.0)
    _fresh()(mod, x, True)
    _fresh()(mod, jnp.arange(5.0), True)  # shape
    _fresh()(mod, x.astype(jnp.float32), True)  # dtype
    _fresh()(Scale(3, _f(3.0)), x, True)  # static field
    out = _fresh()(mod, x, False)  # static argument
    np.testing.assert_array_equal(out[0], np.ones(4))
    assert len(_files(folder)) == 5
    monkeypatch.setattr(programs, "source_digest", lambda: "edited source")
    prog = _fresh()
    prog(mod, x, True)  # the same call after an edit of the package: traced again
    assert len(TRACES) == 1 and len(_files(folder)) == 6


def test_the_settings_that_change_a_trace_are_in_the_key(folder):
    """A call under another matmul precision or rank-promotion rule (a notebook's
    ``jax.config.update`` or context manager) is traced anew, in this process too."""
    mod, x = Scale(2, _f(3.0)), jnp.arange(4.0)
    prog = _fresh()
    prog(mod, x, True)
    with jax.default_matmul_precision("highest"):
        prog(mod, x, True)
    with jax.numpy_rank_promotion("warn"):
        prog(mod, x, True)
    prog(mod, x, True)  # back to the first settings: the first program
    assert len(TRACES) == 3 and len(_files(folder)) == 3


def test_source_digest_covers_both_packages_and_sees_edits(tmp_path, monkeypatch):
    d = programs.source_digest()
    assert len(d) == 64 and d == programs.source_digest()
    files = programs._source_files()
    assert any(p.name == "programs.py" for p in files) and any(p.parent.name == "fitting" for p in files)
    src = tmp_path / "module.py"
    src.write_text("x = 1\n")
    monkeypatch.setattr(programs, "_source_files", lambda: [src])
    monkeypatch.setattr(programs, "_STAMP", [0.0, None])
    first = programs.source_digest()
    src.write_text("x = 2\n")  # an edit in a running session (same size)
    programs._STAMP[0] = time.monotonic() + 60  # as if checked just now: not re-read yet
    assert programs.source_digest() == first  # checked at most once a second
    programs._STAMP[0] = 0.0
    os.utime(src, ns=(os.stat(src).st_atime_ns, os.stat(src).st_mtime_ns + 10**9))
    assert programs.source_digest() != first


def test_sources_held_checks_the_files_once(tmp_path, monkeypatch):
    """Inside ``sources_held`` (the command line) the sources are stat'ed once, on the first
    digest, and an edit after it changes no key; outside, the once-a-second re-check is back."""
    src = tmp_path / "module.py"
    src.write_text("x = 1\n")
    monkeypatch.setattr(programs, "_source_files", lambda: [src])
    monkeypatch.setattr(programs, "_STAMP", [0.0, None])
    outside = programs.source_digest()
    src.write_text("x = 2\n")
    os.utime(src, ns=(os.stat(src).st_atime_ns, os.stat(src).st_mtime_ns + 10**9))
    with programs.sources_held():
        held = programs.source_digest()  # the one check, made inside the block
        assert held != outside
        src.write_text("x = 3\n")
        os.utime(src, ns=(os.stat(src).st_atime_ns, os.stat(src).st_mtime_ns + 2 * 10**9))
        programs._STAMP[0] = 0.0  # a second and more have passed
        with programs.sources_held():  # nested: still held, and checked once more on entry
            nested = programs.source_digest()
            programs._STAMP[0] = 0.0
            src.write_text("x = 4\n")
            os.utime(src, ns=(os.stat(src).st_atime_ns, os.stat(src).st_mtime_ns + 3 * 10**9))
            assert programs.source_digest() == nested != held
        programs._STAMP[0] = 0.0
        assert programs.source_digest() == nested  # the outer block still holds
    programs._STAMP[0] = 0.0
    assert programs.source_digest() not in (outside, held, nested)  # re-checked after the block


def test_a_corrupt_file_is_replaced(folder):
    mod, x = Scale(2, _f(3.0)), jnp.arange(4.0)
    _fresh()(mod, x, True)
    (path,) = folder.glob("*.jaxexport")
    path.write_bytes(b"not a program")
    with pytest.warns(store.CacheWarning, match="ignored the unreadable serialized program"):
        out = _fresh()(mod, x, True)
    assert len(TRACES) == 1
    np.testing.assert_array_equal(out[0], 3.0 * np.arange(4.0) ** 2)
    assert programs._load(path) is not None  # rewritten


def test_unreproducible_statics_and_tracers_run_plainly(folder):
    x = jnp.arange(3.0)
    prog = programs.Program(_apply, name="tests.closure")
    k = 2.0
    np.testing.assert_array_equal(prog(lambda v: k * v, x), 2 * x)  # a closure: repr has an address
    assert _files(folder) == []
    mod = Scale(1, _f(2.0))
    grad = jax.grad(lambda s: _fresh()(Scale(1, s), x, True)[1])(_f(2.0))  # under a transformation
    assert float(grad) == pytest.approx(3.0) and _files(folder) == []
    np.testing.assert_array_equal(jax.jit(lambda x: _fresh()(mod, x, True)[0])(x), 2 * x)
    assert _files(folder) == []


def test_code_from_elsewhere_runs_plainly(folder, tmp_path, monkeypatch):
    """A static function from outside the packages (a user's model, which may import other
    files), a module-level lambda, code without a source file: never serialized, so an edit
    and reload always takes effect."""
    import importlib

    src = tmp_path / "cstiffjax_user_model.py"
    src.write_text("def f(x):\n    return x * 2\n\nh = lambda x: x - 1\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    mod = importlib.import_module("cstiffjax_user_model")
    prog, x = programs.Program(_apply, name="tests.user", like=lambda args: 0), jnp.arange(3.0)
    np.testing.assert_array_equal(prog(mod.f, x), 2 * x)
    src.write_text("def f(x):\n    return x * 3\n\nh = lambda x: x - 1\n")
    os.utime(src, ns=(os.stat(src).st_atime_ns, os.stat(src).st_mtime_ns + 10**9))
    importlib.reload(mod)
    np.testing.assert_array_equal(prog(mod.f, x), 3 * x)
    np.testing.assert_array_equal(prog(mod.h, x), x - 1)
    ns = {"__name__": "scratch"}
    exec("def g(x):\n    return x + 1\n", ns)
    np.testing.assert_array_equal(prog(ns["g"], x), x + 1)
    assert _files(folder) == []
    np.testing.assert_array_equal(prog(_double, x), 2 * x)  # this file's function: serialized
    assert len(_files(folder)) == 1


class Offset(eqx.Module):
    c: np.ndarray = eqx.field(static=True)


def _add_static(x, a, b):
    return x + (0.0 if a is None else a * 100.0) + (0.0 if b is None else b)


@pytest.mark.filterwarnings("ignore:A JAX array is being set as static")
def test_what_the_key_must_tell_apart(folder):
    """The reviewer's cases: static values in other positions, weak types (export keeps
    none), a numpy array in a static field (its repr rounds), all against the plain path."""
    x = jnp.zeros(2)
    prog = programs.Program(_add_static, name="tests.positions", like=lambda args: 0)
    np.testing.assert_array_equal(prog(x, None, 3), [3.0, 3.0])
    np.testing.assert_array_equal(prog(x, 3, None), [300.0, 300.0])
    assert len(_files(folder)) == 2
    g = programs.Program(lambda_free_add, name="tests.weak", like=lambda args: 0)
    weak, f32 = jnp.asarray(2.0), jnp.ones(2, jnp.float32)
    assert weak.weak_type and g(weak, f32).dtype == eqx.filter_jit(lambda_free_add)(weak, f32).dtype == jnp.float32
    off = programs.Program(_with_offset, name="tests.ndarray", like=lambda args: 0)
    a = off(Offset(np.array([1.000000001])), jnp.zeros(1))
    b = off(Offset(np.array([1.000000002])), jnp.zeros(1))
    assert float(b[0] - a[0]) == pytest.approx(1e-9, rel=1e-6)
    assert len(_files(folder)) == 2  # neither the weak call nor the numpy statics were serialized


def lambda_free_add(a, b):
    return a + b


def _with_offset(o, x):
    return x + o.c


def test_a_program_for_another_platform_falls_back(folder):
    prog, x = programs.Program(_double, name="tests.platform", like=lambda args: 0), \
        jnp.arange(3.0)
    prog(x)
    (path,) = folder.glob("*.jaxexport")
    path.write_bytes(store.seal(export.export(jax.jit(_double), platforms=["cuda"])(
        jax.ShapeDtypeStruct((3,), x.dtype)).serialize()))
    programs._MEMO.clear()
    np.testing.assert_array_equal(prog(x), 2 * x)  # the plain jit, from now on
    np.testing.assert_array_equal(prog.bind(x, vary=0)(np.ones(3)), [2.0, 2.0, 2.0])


def test_a_program_that_cannot_be_exported_runs_plainly(folder):
    def impl(x):  # a host callback: jax.export refuses it
        return jax.pure_callback(lambda v: np.asarray(v) * 2, jax.ShapeDtypeStruct(x.shape, x.dtype), x)

    prog = programs.Program(impl, name="tests.callback", like=lambda args: 0)
    for _ in range(2):
        np.testing.assert_array_equal(prog(jnp.arange(3.0)), [0.0, 2.0, 4.0])
    assert _files(folder) == []


def test_a_like_without_the_outputs_structure_is_an_error(folder):
    prog = programs.Program(_double, name="tests.single")  # returns an array, not a tuple
    with pytest.raises(RuntimeError, match="`like` has the structure"):
        prog(jnp.arange(3.0))
    single = programs.Program(_double, name="tests.single2", like=lambda args: 0)
    np.testing.assert_array_equal(single(jnp.arange(3.0)), [0.0, 2.0, 4.0])


def test_bind_varies_one_argument(folder):
    mod, x = Scale(2, _f(3.0)), jnp.arange(4.0)
    for on in (folder, None):
        programs.set_folder(on)
        f = _fresh().bind(mod, x, True, vary=1)
        for v in (np.ones(4), np.arange(4.0) - 1):
            got, want = f(v), _impl(mod, jnp.asarray(v), True)
            np.testing.assert_array_equal(got[0], want[0])
    with pytest.raises(ValueError, match="one array"):
        _fresh().bind(mod, x, True, vary=2)


def test_lower_compiles_the_program_a_call_runs(folder):
    mod, x = Scale(2, _f(3.0)), jnp.arange(4.0)
    prog = _fresh()
    prog.lower(mod, x, True).compile()
    assert len(_files(folder)) == 1 and len(TRACES) == 1
    prog(mod, x, True)
    assert len(TRACES) == 1


def test_outputs_are_uncommitted_as_plain_jits_are(folder):
    """A serialized program's outputs are not committed to a device, as those of the plain
    ``jit`` are (``jit(exported.call)`` commits them, and JAX keys its compiled programs on
    it): fed back into a program, traced or loaded, or to :meth:`Program.bind`, they
    compile nothing again. Before: the discovery's transformed robot and data made the
    fitting loop compile a second time (3.7 s of a cold diagnosis)."""
    compiles = []

    def listen(name, _secs, **_):
        if name.endswith("backend_compile_duration"):
            compiles.append(name)

    mod, x = Scale(1, _f(2.0)), jax.device_put(np.arange(5.0))
    plain = eqx.filter_jit(_impl)(mod, x, True)
    jax.monitoring.register_event_duration_secs_listener(listen)
    try:
        for fresh in (True, False):  # traced here, then loaded from the folder
            prog = _fresh() if fresh else programs.Program(_impl, name="tests.scale")
            if not fresh:
                forget_programs()
            y, total = prog(mod, x, True)
            assert [a.committed for a in (y, total)] == [a.committed for a in plain] == [False, False]
            np.testing.assert_array_equal(y, plain[0])
            before = len(compiles)
            again = prog(Scale(1, _f(2.0)), y, True)[0]  # its own output as the next input
            bound = prog.bind(mod, x, True, vary=1)(np.asarray(y))[0]
            assert len(compiles) == before, "an output fed back compiled the program again"
            np.testing.assert_array_equal(again, 2.0 * np.asarray(y))
            np.testing.assert_array_equal(bound, again)
            assert not again.committed and not bound.committed
        pinned = jax.device_put(x, jax.devices()[0])  # a committed argument: committed outputs, as jit's
        assert [a.committed for a in prog(mod, pinned, True)] == [a.committed for a in eqx.filter_jit(_impl)(
            mod, pinned, True)] == [True, True]
        pinned_mod = Scale(1, jax.device_put(_f(2.0), jax.devices()[0]))  # bind: a committed fixed argument
        assert [a.committed for a in prog.bind(pinned_mod, x, True, vary=1)(np.asarray(x))] == [
            a.committed for a in eqx.filter_jit(_impl)(pinned_mod, x, True)] == [True, True]
    finally:
        jax.monitoring.unregister_event_duration_listener(listen)


def test_uncommitted_keeps_the_buffer_and_passes_other_values(monkeypatch):
    """The output re-wrapped (JAX's array type, the same buffer), not the fallback's copy
    through the host (which, on the CPU, may share the pointer too: it is refused here)."""
    assert internals.uncommitted(jax.device_put(np.arange(3.0), jax.devices()[0])) is not None
    x = jax.device_put(np.arange(3.0), jax.devices()[0])
    assert x.committed
    with monkeypatch.context() as mp:
        mp.setattr(programs.jax, "device_put", lambda *a, **k: pytest.fail("copied through the host"))
        y = programs._uncommitted(x)
    assert not y.committed and y.dtype == x.dtype
    assert y.unsafe_buffer_pointer() == x.unsafe_buffer_pointer()  # no copy
    np.testing.assert_array_equal(y, x)
    z = jax.device_put(np.arange(3.0))
    assert programs._uncommitted(z) is z
    h = np.arange(3.0)
    assert programs._uncommitted(h) is h


@pytest.mark.parametrize("serialized", [False, True])
def test_the_compiler_options_reach_both_paths(folder, monkeypatch, serialized):
    """Every Program compiles with :data:`programs.COMPILER_OPTIONS`, plain or serialized:
    an option XLA does not know makes the compile fail, so a path that dropped the options
    would let the call succeed and fail this test."""
    monkeypatch.setattr(programs, "COMPILER_OPTIONS", {"xla_no_such_option": 1})
    if not serialized:
        programs.set_folder(None)
    prog = _fresh()
    with pytest.raises(Exception, match="No such compile option"):
        prog(Scale(3, _f(2.0)), jnp.arange(7.0), True)
    assert len(_files(folder)) == int(serialized)


@pytest.mark.parametrize("serialized", [False, True])
def test_a_programs_own_compiler_options_reach_both_paths(folder, serialized):
    """``Program(compiler_options=...)`` adds its options to every compile of that program,
    plain or serialized (an option XLA does not know makes the compile fail), and not to
    another program's; a valid one (``-O0``) gives the same values."""
    if not serialized:
        programs.set_folder(None)
    forget_programs()
    mod, x = Scale(2, _f(3.0)), jnp.arange(7.0)
    bad = programs.Program(_impl, name="tests.scale_bad", compiler_options={"xla_no_such_option": 1})
    with pytest.raises(Exception, match="No such compile option"):
        bad(mod, x, True)
    np.testing.assert_array_equal(_fresh()(mod, x, True)[0], 3.0 * x**2)  # not the other program's options
    o0 = programs.Program(_impl, name="tests.scale_o0", compiler_options={"xla_backend_optimization_level": 0})
    np.testing.assert_array_equal(o0(mod, x, True)[0], 3.0 * x**2)
    from fitting.calibration.models import _cold_starts

    assert _cold_starts.extra == {"xla_backend_optimization_level": 0}


@pytest.mark.parametrize("concurrent", [False, True])
@pytest.mark.parametrize("serialized", [True, False])
def test_a_program_compiled_ahead_is_not_compiled_again(folder, serialized, concurrent):
    """``lower(...).compile()`` (the diagnosis's background thread) compiles what the later
    call runs, with the same options, serialized or plain, built inside
    ``concurrent_compiles()`` (the real ``CONCURRENT_OPTIONS``) or not, and called outside
    it: the call compiles nothing."""
    if not serialized:
        programs.set_folder(None)
    compiles = []

    def listen(name, _secs, **_):
        if name.endswith("backend_compile_duration"):
            compiles.append(name)

    jax.monitoring.register_event_duration_secs_listener(listen)
    try:
        mod, x = Scale(2, _f(5.0)), jnp.arange(9.0 + serialized + 2 * concurrent)
        expected = 5.0 * np.asarray(x) ** 2
        prog = _fresh()
        with programs.concurrent_compiles() if concurrent else contextlib.nullcontext():
            prog.lower(mod, x, True).compile()
        before = len(compiles)
        assert before >= 1
        got = prog(mod, x, True)[0]
        assert len(compiles) == before
        np.testing.assert_array_equal(np.asarray(got), expected)
    finally:
        jax.monitoring.unregister_event_duration_listener(listen)


def test_concurrent_options_go_with_programs_built_in_the_block(folder, monkeypatch):
    """A serialized program first built inside ``concurrent_compiles()`` (a diagnosis, both
    of its threads) compiles with ``CONCURRENT_OPTIONS`` too, also when it is called later
    outside the block; one built outside does not (an unknown option makes XLA fail)."""
    monkeypatch.setattr(programs, "CONCURRENT_OPTIONS", {"xla_no_such_option": 1})
    mod, x = Scale(2, _f(4.0)), jnp.arange(5.0)
    prog = _fresh()
    np.testing.assert_array_equal(prog(mod, x, True)[0], 4.0 * x**2)  # built here: XLA's options
    with programs.concurrent_compiles():
        prog(mod, x, True)  # already built: keeps its options
        with pytest.raises(Exception, match="No such compile option"):
            prog.lower(mod, jnp.arange(6.0), True).compile()  # another shape: built here
    with pytest.raises(Exception, match="No such compile option"):
        prog(mod, jnp.arange(6.0), True)  # called outside: what the block built
    assert not programs._THREAD.concurrent  # the block ends


def test_a_program_can_keep_the_default_code_generation_in_the_block(folder, monkeypatch):
    """``Program(concurrent=False)`` (the posterior's ensemble) compiles with
    ``COMPILER_OPTIONS`` only, also when first built inside ``concurrent_compiles()``."""
    monkeypatch.setattr(programs, "CONCURRENT_OPTIONS", {"xla_no_such_option": 1})
    forget_programs()
    prog = programs.Program(_impl, name="tests.scale", concurrent=False)
    mod, x = Scale(2, _f(4.0)), jnp.arange(7.0)
    with programs.concurrent_compiles():
        prog.lower(mod, x, True).compile()  # built here, without the block's options
    np.testing.assert_array_equal(prog(mod, x, True)[0], 4.0 * x**2)
    from fitting.effects.model import walker_residuals

    assert walker_residuals.concurrent is False


@pytest.mark.parametrize("serialized", [True, False])
def test_a_call_inside_a_trace_with_concrete_arguments(folder, serialized):
    """A Program called inside ``jit`` or a loop body on arrays that are not tracers (closed
    over) is part of the caller's program (JAX refuses compiler options on a nested
    ``jit``): the right values, and the serialized form is not given up for later calls."""
    if not serialized:
        programs.set_folder(None)
    mod, x = Scale(2, _f(1.5)), jnp.arange(6.0)
    prog = _fresh()
    inside = jax.jit(lambda y: prog(mod, x, True)[1] + y)(_f(1.0))
    looped = jax.lax.fori_loop(0, 2, lambda i, c: c + prog(mod, x, True)[1], _f(0.0))
    total = float(jnp.sum(1.5 * x**2))
    assert float(inside) == total + 1.0 and float(looped) == 2 * total
    np.testing.assert_array_equal(prog(mod, x, True)[0], 1.5 * x**2)  # top level: its own program
    assert all(v is not programs._PLAIN for v in programs._MEMO.values())
    assert len(_files(folder)) == int(serialized)


def _rJ(theta, args):
    t, y = args
    r = theta[0] * jnp.exp(-theta[1] * t) - y
    J = jnp.stack([jnp.exp(-theta[1] * t), -theta[0] * t * jnp.exp(-theta[1] * t)], axis=1)
    return r, J, jnp.ones(t.shape, bool)


@pytest.mark.parametrize("covariance", [True, False])
def test_the_fitting_loop_gives_the_same_fit_from_a_serialized_program(folder, covariance):
    t = jnp.linspace(0.0, 2.0, 20)
    args = (t, 2.0 * jnp.exp(-0.7 * t) + 0.01 * jnp.sin(7 * t))
    programs.set_folder(None)
    plain = lm.masked_levenberg_marquardt(_rJ, jnp.array([1.0, 0.1]), args, covariance=covariance)
    programs.set_folder(folder)
    for _ in range(2):  # exported, then loaded
        programs._MEMO.clear()
        res = lm.masked_levenberg_marquardt(_rJ, jnp.array([1.0, 0.1]), args, covariance=covariance)
        assert isinstance(res, lm.LMResult) and res.converged
        for a, b in zip(jax.tree.leaves(plain), jax.tree.leaves(res)):
            np.testing.assert_array_equal(a, b)
        assert (res.covariance is None) == (not covariance)
    assert len(_files(folder)) == 1


def test_the_compilation_cache_switches_serialized_programs(tmp_path):
    assert programs.folder() is None
    with cache.compilation_cache(tmp_path / "c") as where:
        assert programs.folder() == where / "programs"
    assert programs.folder() is None
    with cache.compilation_cache(environ={"CSTIFFJAX_CACHE_DIR": "off"}):
        assert programs.folder() is None


def _exp_residual(theta, args):
    t, y = args
    return theta[0] * jnp.exp(-theta[1] * t) - y


class _Data(eqx.Module):
    def data(self, theta, args):
        from cstiffjax.core.status import Status
        r = _exp_residual(theta, args)
        return r, Status.where(jnp.all(jnp.isfinite(r)), Status.successful, Status.not_converged), None, None


def test_the_calibration_programs_give_the_same_results_from_serialized_programs(folder):
    """``fitting.calibration.least_squares``'s solve (an ``LSResult`` with a ``Status``) and the
    residuals at the fit, as ``cstiffjax fit`` runs them."""
    from fitting.calibration import least_squares as ls

    t = jnp.linspace(0.0, 2.0, 15)
    args = (t, 2.0 * jnp.exp(-0.7 * t) + 0.01 * jnp.cos(5 * t))
    outs = []
    for on in (None, folder, folder):  # plain, exported, loaded
        programs.set_folder(on)
        programs._MEMO.clear()
        res = ls.solve_least_squares(_exp_residual, jnp.array([1.0, 0.1]), args)
        r, status = ls._fitted_residuals(_Data(), res.theta, args)
        outs.append((res, r, status))
    assert len(_files(folder)) == 2
    (res0, r0, s0), *rest = outs
    for res, r, status in rest:
        assert type(res) is ls.LSResult and type(res.result) is type(res0.result)
        assert res.result == res0.result and status == s0
        for a, b in zip(jax.tree.leaves(res0), jax.tree.leaves(res)):
            np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(r, r0)


def test_the_key_is_computed_once_per_call_identity(folder, monkeypatch):
    """A repeated call with the same static values and array shapes reuses its key (the
    diagnosis calls its fitting loop hundreds of times; a key costs ~1 ms), also through
    another module object with the same static field; another static value or shape
    computes a new key and a new program."""
    computed = []
    real = programs._key
    monkeypatch.setattr(programs, "_key", lambda *a: computed.append(a[0]) or real(*a))
    prog, mod, x = _fresh(), Scale(2, _f(3.0)), jnp.arange(4.0)
    first = prog(mod, x, True)
    for _ in range(3):
        np.testing.assert_array_equal(prog(mod, x, True)[0], first[0])
    np.testing.assert_array_equal(prog(Scale(2, _f(5.0)), x, True)[0], 5.0 * x**2)
    assert computed == ["tests.scale"] and len(_files(folder)) == 1 and len(TRACES) == 1
    np.testing.assert_array_equal(prog(Scale(3, _f(3.0)), x, True)[0], 3.0 * x**3)
    prog(mod, jnp.arange(5.0), True)
    assert len(computed) == 3 and len(_files(folder)) == 3


def _plus_one(x):
    return x + 1


def test_a_cold_compile_is_logged_not_printed(folder, caplog, capsys):
    """Each program that must be traced and compiled (nothing on disk) is one INFO record of
    the ``cstiffjax`` loggers naming the folder; a program loaded from disk is none; the
    library prints nothing."""
    caplog.set_level(logging.INFO, logger="cstiffjax")
    x = jnp.arange(3.0)
    programs.Program(_double, name="tests.double", like=lambda a: 0)(x)
    programs.Program(_plus_one, name="tests.plus_one", like=lambda a: 0)(x)
    notes = [r for r in caplog.records if getattr(r, "once", None) == "compiling"]
    assert [(r.name, r.levelno, r.program) for r in notes] == [
        ("cstiffjax.runtime.programs", logging.INFO, "tests.double"),
        ("cstiffjax.runtime.programs", logging.INFO, "tests.plus_one")]
    assert all(r.getMessage().startswith("compiling (first run only") and str(folder.parent) in r.getMessage()
               for r in notes)
    caplog.clear()
    forget_programs()
    programs.Program(_double, name="tests.double", like=lambda a: 0)(x)  # loaded from disk: nothing to say
    assert caplog.records == []
    assert capsys.readouterr() == ("", "")


def test_the_command_line_shows_a_cold_compile_once(tmp_path, monkeypatch, capsys):
    """``cstiffjax COMMAND`` shows the first cold compile's note as one line on stderr, on a
    terminal; a warm run (loaded from disk), ``--quiet`` and a stderr that is not a terminal
    show none."""
    from cstiffjax.commands import cli, tensions
    from cstiffjax.core import progress

    monkeypatch.setattr(programs, "_COVERED", programs._COVERED | {"tests"})
    monkeypatch.setenv("CSTIFFJAX_CACHE_DIR", str(tmp_path / "cache"))
    names = []

    def run(args):  # the command: two programs, compiled cold unless on disk
        x = jnp.arange(3.0)
        programs.Program(_double, name=names[0], like=lambda a: 0)(x)
        programs.Program(_plus_one, name=names[1], like=lambda a: 0)(x)
        return 0

    monkeypatch.setattr(tensions, "run", run)
    argv = ["tensions", "tcpr8.toml", "--pose", "0", "0", "0.8", "0", "0", "0", "--method", "cfm"]

    def err_of(*extra, terminal=True):
        forget_programs()
        with monkeypatch.context() as m:
            if terminal:  # the bars' policy as on a terminal
                m.setattr(progress, "enabled", lambda p=None: not progress.is_quiet())
            assert cli.main([*argv, *extra]) == 0
        forget_programs()
        return capsys.readouterr().err

    names[:] = ["tests.cli_double", "tests.cli_plus_one"]
    err = err_of()
    assert err.count("compiling (first run only") == 1 and str(tmp_path / "cache") in err, err
    assert err.count("\n") == 1, err
    assert err_of() == ""  # warm: both loaded
    names[:] = ["tests.cli_double_quiet", "tests.cli_plus_one_quiet"]
    assert err_of("--quiet") == ""
    names[:] = ["tests.cli_double_pipe", "tests.cli_plus_one_pipe"]
    assert err_of(terminal=False) == ""
    assert len(list((tmp_path / "cache" / store.PROGRAMS).glob("*.jaxexport"))) == 6  # all compiled cold
    assert logging.getLogger("cstiffjax").handlers == []  # main() leaves the logger as it found it
