"""The diagnosis's background compilation (fitting.diagnosis.fitter.Ahead, fitting.calibration.lm.lower)."""

import logging
import threading
import time
from types import SimpleNamespace

import equinox as eqx
import jax
import numpy as np
import pytest

from cstiffjax import CableLaw
from fitting.calibration import lm
from fitting.diagnosis.fitter import Ahead, Fitter

from .helpers import lab_robot


def test_jobs_run_in_order_in_another_thread_and_errors_are_dropped():
    seen, gate = [], threading.Event()
    model_a, model_b = object(), object()

    def job(name, fail=False):
        def run():
            gate.wait(5)
            seen.append((name, threading.current_thread().name))
            if fail:
                raise RuntimeError("compile failed")
        return run

    ahead = Ahead()
    ahead.start([("fit", model_a, job("a", fail=True)), ("walkers", model_b, job("b"))])
    ahead.wait("fit", object())  # not one of the jobs: returns at once
    assert seen == []
    gate.set()
    ahead.wait()  # b is compiled, although a raised before it
    assert [s[0] for s in seen] == ["a", "b"]
    assert all(name == "cstiffjax-compile-ahead" for _, name in seen)
    assert ahead.thread is None and ahead.jobs == []


def test_a_caller_takes_a_job_the_thread_has_not_started():
    """``wait`` for a job still in the queue compiles it in the caller, as a concurrent
    compile (the options the thread would give it), while the thread goes on with its
    own; the job runs once; a job the thread has started is waited for, not run again,
    and while the caller waits for it, it compiles the jobs queued behind it."""
    from cstiffjax.runtime import programs

    seen, gate, started = [], threading.Event(), threading.Event()
    a, b, c = object(), object(), object()

    def job(name, block=False):
        def run():
            if block:
                started.set()
                gate.wait(5)
            seen.append((name, threading.current_thread().name, programs._THREAD.concurrent))
        return run

    ahead = Ahead()
    ahead.start([("fit", a, job("a", block=True)), ("walkers", b, job("b")), ("solutions", c, job("c"))])
    assert started.wait(5)  # the thread is inside a
    ahead.wait("solutions", c)  # not started: compiled here, before a ends
    assert seen == [("c", threading.current_thread().name, True)] and not programs._THREAD.concurrent
    waiter = threading.Thread(target=ahead.wait, args=("fit", a), name="waiter")  # started by the thread
    waiter.start()
    waiter.join(0.3)
    assert waiter.is_alive()  # blocked while the thread compiles a ...
    assert [s[:2] for s in seen[1:]] == [("b", "waiter")]  # ... having compiled b, queued behind it
    gate.set()
    waiter.join(5)
    assert not waiter.is_alive()
    ahead.wait()
    assert [s[:2] for s in seen[1:]] == [("b", "waiter"), ("a", "cstiffjax-compile-ahead")]  # each once


def test_jobs_build_their_programs_as_concurrent_compiles():
    """The thread's jobs run inside ``programs.concurrent_compiles()`` (one-thread code
    generation for the programs they build); the caller's thread is not affected."""
    from cstiffjax.runtime import programs

    seen, model = [], object()
    ahead = Ahead()
    ahead.start([("fit", model, lambda: seen.append((programs._THREAD.concurrent, threading.current_thread().name)))])
    ahead.wait()  # the thread's own run (wait("fit", model) might take the job first)
    assert seen == [(True, "cstiffjax-compile-ahead")] and not programs._THREAD.concurrent


def test_wait_blocks_until_that_job_is_done():
    ahead, done, started = Ahead(), [], threading.Event()
    model = object()
    name = threading.current_thread
    ahead.start([("fit", model, lambda: (started.set(), time.sleep(0.3), done.append(name().name)))])
    assert started.wait(5)  # in the thread: the caller waits for it, does not run it again
    ahead.wait("walkers", model)  # another program of the same model: no wait
    assert done == []
    ahead.wait("fit", model)
    assert done == ["cstiffjax-compile-ahead"]


def _signature(args):
    """What decides whether JAX reuses a compiled program: the tree of array leaves, their
    shapes and dtypes, whether each is committed to a device (a committed array's sharding
    enters jit's key: the device arrays a program returned were, and made the first
    ensemble call of a cold diagnosis compile again, 2.6 s), and the static (non-array)
    parts (eqx.filter_jit's partition)."""
    dyn, static = eqx.partition(args, eqx.is_array)
    leaves = [(x.shape, x.dtype, bool(getattr(x, "committed", False))) for x in jax.tree.leaves(dyn)]
    return jax.tree.structure(dyn), leaves, static


class _Stop(Exception):
    pass


class _Recorder:
    """Stands in for the compiled function ``name``: records the signature of the program
    its ``lower`` (the background thread) would compile under ``seen["ahead"]`` and that of
    a call (the main thread) under ``seen[call]``, then stops the caller."""

    def __init__(self, seen, name, call):
        self.seen, self.name, self.call = seen, name, call

    def lower(self, *args):
        self.seen["ahead"] = self.name, _signature(args)
        return SimpleNamespace(compile=lambda: None)

    def __call__(self, *args):
        self.seen[self.call] = self.name, _signature(args)
        raise _Stop

    def bind(self, *args, vary):  # cstiffjax.runtime.programs.Program.bind: a call with args[vary] varying
        self(*args)


def _same_program(a, b) -> bool:
    """Two :class:`_Recorder` records name the same function and signature (one program)."""
    (name_a, (tree_a, avals_a, static_a)), (name_b, (tree_b, avals_b, static_b)) = a, b
    return name_a == name_b and tree_a == tree_b and avals_a == avals_b and bool(eqx.tree_equal(static_a, static_b))


def test_the_diagnosis_compiles_in_a_concurrent_block(monkeypatch):
    """The main thread of a diagnosis builds its programs inside
    ``programs.concurrent_compiles()`` (its background thread compiles meanwhile); the
    block ends with the call."""
    from cstiffjax.runtime import programs
    from fitting.diagnosis.diagnose import diagnose

    robot, rec = lab_robot("example02")
    seen = []

    def lower_fit(self, names, model=None):
        seen.append(programs._THREAD.concurrent)
        raise _Stop

    monkeypatch.setattr(Fitter, "lower_fit", lower_fit)
    with pytest.raises(_Stop):
        diagnose(robot, rec.select(np.arange(12)))
    assert seen == [True] and not programs._THREAD.concurrent


def _fresh_fitter():
    """A Fitter of its own (``compile_ahead`` queues a model's loop once per Fitter)."""
    robot, rec = lab_robot("example02")
    return Fitter(robot, rec.select(np.arange(12)), CableLaw.spring, ())


def test_the_fitting_loop_compiled_ahead_is_the_one_the_fit_calls(monkeypatch):
    """The arguments the background thread lowers the fitting loop with and those of the
    main thread's fit have the same signature (a different one, e.g. ``must_succeed``
    None instead of a mask, would compile a second program: measured in
    ``test_the_main_thread_reuses_what_was_compiled_ahead``)."""
    seen = {}
    fitter = _fresh_fitter()
    monkeypatch.setattr(lm, "_run", _Recorder(seen, "_run", "fit"))
    fitter.compile_ahead([])  # the baseline model's fitting loop
    fitter.ahead.wait()
    weight = np.ones(fitter.n)
    weight[3] = 0.0  # an outlier left out: weights are data
    with pytest.raises(_Stop):
        fitter.fit([], weight)
    assert _same_program(seen["ahead"], seen["fit"])
    fitter.lower_fit([])  # what the diagnosis lowers on the main thread before the thread starts
    assert _same_program(seen["ahead"], seen["fit"])


def test_the_cable_mass_screen_compiled_ahead_is_the_one_its_candidate_fit_calls(monkeypatch):
    """On a spring baseline the thread compiles the small-sag screen's loop for the
    ``cable_mass`` candidate (not the catenary model's), with the signature of the round's
    screened fit: alone in round 1, on top of another effect later (masks are data)."""
    from fitting.effects import VOCABULARY

    robot, rec = lab_robot("example02")
    f = Fitter(robot, rec.select(np.arange(12)), CableLaw.spring, VOCABULARY)
    seen = {}
    monkeypatch.setattr(lm, "_run", _Recorder(seen, "_run", "fit"))
    monkeypatch.setattr(lm, "_run_quick", _Recorder(seen, "_run_quick", "fit"))  # the screen's (fitted once)
    f.compile_ahead(["cable_mass"], screen=True)
    f.ahead.wait()
    start = (f.models["base"], np.asarray(f.models["base"].start))
    with pytest.raises(_Stop):
        f.fit(["cable_mass"], np.ones(f.n), start, screen=True)
    assert _same_program(seen["ahead"], seen["fit"]) and seen["fit"][0] == "_run_quick"
    f.compile_ahead(["exit_friction", "cable_mass"], screen=True)  # the later rounds' screen
    f.compile_ahead(["length_offset", "cable_mass"], screen=True)  # the same model: not queued again
    f.ahead.wait()
    assert [k for k, m in f.ahead.done if m is f.models["screen+"]] == ["fit"]
    with pytest.raises(_Stop):
        f.fit(["exit_friction", "cable_mass"], np.ones(f.n), start, screen=True)
    assert _same_program(seen["ahead"], seen["fit"])
    with pytest.raises(_Stop):  # the same effects on the catenary: another program
        f.fit(["exit_friction", "cable_mass"], np.ones(f.n), start)
    assert not _same_program(seen["ahead"], seen["fit"])


def test_a_program_handed_to_the_thread_is_queued_once_without_waiting(monkeypatch):
    """``compile_walkers`` queues the posterior ensemble behind a compilation under way
    without blocking the caller; asked again for the same model it starts nothing; a new
    thread serves jobs queued after the last one finished."""
    from fitting.diagnosis import fitter as fx

    robot, rec = lab_robot("example02")
    f = Fitter(robot, rec.select(np.arange(12)), CableLaw.spring, ())
    gate, lowered = threading.Event(), []

    def lower(kind, block=False):
        def run(*a):
            if block:
                gate.wait(5)
            lowered.append(kind)
            return SimpleNamespace(compile=lambda: None)
        return run

    monkeypatch.setattr(lm, "_run", SimpleNamespace(lower=lower("fit", block=True)))
    monkeypatch.setattr(fx, "walker_residuals", SimpleNamespace(lower=lower("walkers")))
    monkeypatch.setattr(fx, "solutions", SimpleNamespace(lower=lower("solutions")))
    model = f.models["base"]
    f.compile_ahead([])
    f.compile_walkers(model)  # returns while the fitting loop is still "compiling"
    f.compile_walkers(model)
    assert lowered == [] and f.ahead.has("walkers", model)
    gate.set()
    f.ahead.wait()
    assert lowered == ["fit", "walkers", "solutions"]  # the ensemble, then the walkers' start
    assert f.ahead.thread is None and f.ahead.jobs == []
    other = model.__class__(*[getattr(model, k) for k in ("effects", "law", "num_cables", "blocks", "null", "scale",
                                                         "start")])
    f.compile_walkers(other)  # another model: compiled, by a new thread
    f.ahead.wait()
    assert lowered == ["fit", "walkers", "solutions", "walkers", "solutions"]


def _compiles(caplog, fn):
    with caplog.at_level(logging.WARNING), jax.log_compiles():
        caplog.clear()
        out = fn()
    return out, [r.getMessage() for r in caplog.records if "Compiling" in r.getMessage()]


def test_the_main_thread_reuses_what_was_compiled_ahead(caplog):
    """The background thread compiles the baseline model's fitting loop; then a fit and
    the held-out scorer (the same program without Jacobian columns: no residuals-only
    program) on the main thread compile no fitting loop again (JAX logs every
    compilation it starts); without a model to compile ahead no thread starts."""
    fitter = _fresh_fitter()
    fitter.compile_ahead(None)
    assert fitter.ahead.thread is None
    w = np.ones(fitter.n)
    w[3] = 0.0
    before = jax.config.jax_log_compiles
    jax.config.update("jax_log_compiles", True)  # global: jax.log_compiles() is thread-local
    try:
        _, ahead = _compiles(caplog, lambda: (fitter.compile_ahead([]), fitter.ahead.wait()))
    finally:
        jax.config.update("jax_log_compiles", before)
    assert [m for m in ahead if "_run_impl" in m], ahead
    model = fitter.models["base"]
    (fit, (r, ok)), logs = _compiles(caplog, lambda: (fitter.fit([], w)[1], fitter.scorer(model, 1 - w)(model.start)))
    assert fit.converged and bool(np.all(ok)) and np.all(np.isfinite(np.asarray(r)))
    assert np.count_nonzero(np.any(np.asarray(r) != 0, axis=1)) == 1  # only the held-out sample is scored
    assert not [m for m in logs if "_run_impl" in m or "residuals_only" in m], logs


class _Solutions:
    """Stands in for :func:`fitting.effects.model.solutions`: records the signature its
    ``lower`` would compile (``seen["ahead solutions"]``) and that of a call
    (``seen["solutions"]``), which returns zeros shaped as the real output (traced, nothing
    compiled) as a serialized program returns them: committed to the device by
    ``jit(exported.call)``, then re-wrapped by :func:`cstiffjax.runtime.programs._uncommitted`
    (``tests/test_programs.py`` checks that real programs' outputs go through it)."""

    def __init__(self, seen):
        self.seen = seen

    def lower(self, *args):
        self.seen["ahead solutions"] = "solutions", _signature(args)
        return SimpleNamespace(compile=lambda: None)

    def __call__(self, *args):
        from fitting.effects import model as M

        self.seen["solutions"] = "solutions", _signature(args)
        out = eqx.filter_eval_shape(M.solutions.impl, *args)
        self.seen["solved"] = [s.shape for s in jax.tree.leaves(out)]
        from cstiffjax.runtime.programs import _uncommitted

        return jax.tree.map(lambda s: _uncommitted(jax.device_put(np.zeros(s.shape, s.dtype), jax.devices()[0])),
                            out)


def test_the_posterior_calls_the_programs_compiled_ahead(monkeypatch):
    """The posterior check calls the two programs :meth:`Fitter.compile_walkers` compiled
    ahead (a call with another signature would be a second compilation of the vmapped
    model, seconds on the cold bundled diagnose): the equilibria's solve at the fitted θ
    (:func:`~fitting.effects.model.solutions`) and the ensemble, whose ``solved`` argument
    the background thread shapes without tracing (:func:`~fitting.effects.model.solved_like`)
    for the spring law (6 unknowns) and the catenary law (``6 + 2m``)."""
    from fitting.diagnosis import effect_posterior as ep
    from fitting.diagnosis import fitter as fx

    robot, rec = lab_robot("example02")
    seen = {}

    def same_program(ahead, call):
        return _same_program(seen.pop(ahead), seen.pop(call))

    def posterior(fitter, model):
        fit = SimpleNamespace(theta=np.asarray(model.start), free=np.ones(model.size, bool),
                              covariance=np.eye(model.size))
        with pytest.raises(_Stop):
            ep.posterior_check(fitter, model, fit, np.ones(fitter.n), [], steps=1, progress=False)

    monkeypatch.setattr(fx, "walker_residuals", _Recorder(seen, "walker_residuals", "posterior"))
    monkeypatch.setattr(ep, "walker_residuals", fx.walker_residuals)
    monkeypatch.setattr(fx, "solutions", _Solutions(seen))
    monkeypatch.setattr(ep, "solutions", fx.solutions)
    for law, k in ((CableLaw.spring, 6), (CableLaw.catenary, 18)):
        fitter = Fitter(robot, rec.select(np.arange(12)), law, ())
        model = fitter.models["base"]
        assert model.law is law and fitter.m == 6
        fitter.compile_walkers(model)
        assert fitter.ahead.thread is not None
        fitter.ahead.wait()
        posterior(fitter, model)
        assert seen.pop("solved") == [(12, k), (12, k, k), (12,), (12,)]
        assert same_program("ahead solutions", "solutions"), law
        assert same_program("ahead", "posterior"), law  # the ensemble
    # each program is waited for before its call (a call during its compile ahead would be a
    # second compilation): the order of the waits and the calls
    order, real = [], (fx.solutions, fx.walker_residuals)
    monkeypatch.setattr(ep, "solutions", lambda *a: (order.append("call solutions"), real[0](*a))[1])
    monkeypatch.setattr(ep, "walker_residuals", SimpleNamespace(
        bind=lambda *a, **k: (order.append("bind walkers"), real[1].bind(*a, **k))[1]))
    real_wait = fitter.ahead.wait
    monkeypatch.setattr(fitter.ahead, "wait", lambda kind=None, m=None: (order.append(f"wait {kind}"),
                                                                         real_wait(kind, m))[1])
    posterior(fitter, model)
    assert order == ["wait solutions", "call solutions", "wait walkers", "bind walkers"]


def _round_stub(screens: bool = True):
    """A diagnoser stand-in for the compile-ahead decisions of a round: the calls to
    ``compile_ahead`` are recorded."""
    calls = []
    f = SimpleNamespace(screens_mass=screens, num_data=lambda w: 100,
                        compile_ahead=lambda names, screen=False: calls.append((tuple(names), screen)))
    return SimpleNamespace(f=f, names=["anchor_offset", "nonlinear_elasticity", "cable_mass"]), calls


def _cand(effect, dbic, c2=1.0, accepted=False, law=CableLaw.spring):
    return SimpleNamespace(effect=effect, delta_bic=dbic, chi2_per_dof=c2, accepted=accepted, law=law,
                           fit=(None, SimpleNamespace(free=np.ones(3, bool))))


def test_the_catenary_compiles_ahead_only_when_the_screen_is_sure_to_need_it():
    """The catenary model of ``cable_mass`` is handed to the thread before the selection
    exactly when ``needs_catenary`` holds whichever candidate is selected: the screen's
    ΔBIC reaches SCREEN_FRACTION of the round's lowest (or of the BIC threshold)."""
    from fitting.diagnosis.rounds import SCREEN_FRACTION, Diagnoser, needs_catenary
    from fitting.diagnosis.selection import BIC_THRESHOLD

    lowest = -100.0
    for screen_dbic, expect in [(SCREEN_FRACTION * lowest - 1, True), (SCREEN_FRACTION * lowest + 1, False),
                                (np.inf, False)]:
        d, calls = _round_stub()
        out = [_cand("anchor_offset", lowest, accepted=True), _cand("nonlinear_elasticity", -30.0),
               _cand("cable_mass", screen_dbic, law=CableLaw.small_sag)]
        Diagnoser._catenary_ahead(d, out, ["x"])
        assert calls == ([(("cable_mass", "x"), False)] if expect else []), screen_dbic
        if expect:  # sure: needed whichever candidate passes
            for best in out[:2]:
                best.accepted = True
                assert needs_catenary(out[2], [best])
    d, calls = _round_stub()  # nothing below the threshold: the screen against the threshold itself
    Diagnoser._catenary_ahead(d, [_cand("cable_mass", SCREEN_FRACTION * BIC_THRESHOLD - 0.1,
                                         law=CableLaw.small_sag)], [])
    assert calls == [(("cable_mass",), False)]


def test_the_next_rounds_screen_compiles_ahead_when_the_selection_leaves_the_data_unexplained():
    """After the selection, the next round's small-sag screen (the same model whatever was
    selected) is handed to the thread when the selected candidate leaves χ²/dof above the
    explained threshold; not when it explains, when none is selected, when ``cable_mass``
    cannot follow the selected effect, or without a screen (a catenary baseline)."""
    from fitting.diagnosis.rounds import Diagnoser

    w = np.ones(10)
    for c2, effect, screens, expect in [(5.0, "anchor_offset", True, True), (1.0, "anchor_offset", True, False),
                                        (5.0, "nonlinear_elasticity", True, False),
                                        (5.0, "anchor_offset", False, False)]:
        d, calls = _round_stub(screens)
        Diagnoser._next_screen_ahead(d, [_cand(effect, -200.0, c2=c2, accepted=True)], [], w)
        assert calls == ([(("cable_mass", effect), True)] if expect else []), (c2, effect, screens)
    d, calls = _round_stub()
    Diagnoser._next_screen_ahead(d, [_cand("anchor_offset", -200.0, c2=5.0)], [], w)  # none selected
    assert calls == []


def test_only_the_small_sag_screens_are_compiled_for_compile_time():
    """The screen models of ``cable_mass`` (one fit per round) take the quick loop; the spring
    and catenary models, fitted over and over (held-out folds, later rounds), do not."""
    from fitting.effects import VOCABULARY
    from fitting.effects.model import fitted_once

    robot, rec = lab_robot("example02")
    f = Fitter(robot, rec.select(np.arange(12)), CableLaw.spring, VOCABULARY)
    assert {k: fitted_once(m) for k, m in f.models.items()} == {"base": False, "cat": False, "screen": True,
                                                                 "screen+": True}
