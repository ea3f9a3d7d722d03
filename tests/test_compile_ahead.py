"""The diagnosis's background compilation (fitting.diagnose._Ahead, fitting.lm.compile_ahead)."""

import logging
import threading
import time

import jax
import numpy as np
import pytest

from fitting.diagnose import _Ahead, _Fitter

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

    ahead = _Ahead()
    ahead.start([("fit", model_a, job("a", fail=True)), ("residuals", model_b, job("b"))])
    ahead.wait("fit", object())  # not one of the jobs: returns at once
    assert seen == []
    gate.set()
    ahead.wait("residuals", model_b)  # blocks until b is compiled, although a raised before it
    assert [s[0] for s in seen] == ["a", "b"]
    assert all(name == "cstiffjax-compile-ahead" for _, name in seen)
    ahead.wait()
    assert ahead.thread is None and ahead.jobs == []


def test_wait_blocks_until_that_job_is_done():
    ahead, done = _Ahead(), []
    model = object()
    ahead.start([("fit", model, lambda: (time.sleep(0.3), done.append(1)))])
    ahead.wait("residuals", model)  # another program of the same model: no wait
    assert done == []
    ahead.wait("fit", model)
    assert done == [1]


@pytest.fixture(scope="module")
def fitter():
    robot, rec = lab_robot("example02")
    return _Fitter(robot, rec.select(np.arange(12)), "spring", ())


def _compiles(caplog, fn):
    with caplog.at_level(logging.WARNING), jax.log_compiles():
        caplog.clear()
        out = fn()
    return out, [r.getMessage() for r in caplog.records if "Compiling" in r.getMessage()]


def test_the_main_thread_reuses_what_was_compiled_ahead(fitter, caplog):
    """After the background thread compiled the fitting loop and the scorer, the fit and
    the held-out scoring on the main thread compile neither again (JAX logs every
    compilation it starts: none of ``_run`` or ``residuals_only``)."""
    w = np.ones(fitter.n)
    fitter.compile_ahead([])  # the baseline model's fitting loop and its residuals
    assert fitter.ahead.thread is not None
    fitter.ahead.wait()
    (model, fit), logs = _compiles(caplog, lambda: fitter.fit([], w))
    assert fit.converged and not [m for m in logs if "_run" in m], logs
    (r, ok), logs = _compiles(caplog, lambda: fitter.scorer(model, w)(fit.theta))
    assert bool(np.all(ok)) and np.isclose(float(np.sum(np.asarray(r) ** 2)), fit.chi2, rtol=1e-9)
    assert not [m for m in logs if "residuals_only" in m], logs
