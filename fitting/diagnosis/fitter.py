"""The diagnosis's fitting machinery: the compiled extended models of one data set and the
masked fits of effect sets on them (:class:`Fitter`), and their compilation ahead of need
in a background thread (:class:`Ahead`).

One spring model holds every vocabulary effect (on a spring baseline, two small-sag models
screen ``cable_mass``, :class:`~fitting.effects.CableMassScreen`: one with the screen alone
for the first round, one with every spring effect beside it for the later rounds; one
catenary model every effect that the catenary law allows, for ``cable_mass``); a fit of an
effect set frees that set's
entries of the model's parameter vector ``θ`` (a mask), and held-out folds or left-out
samples are sample weights: masks and weights are data, so every candidate and fold of a
diagnosis runs on the same compiled program (:mod:`fitting.effects.fit`).
"""

import threading

import numpy as np

from cstiffjax.cable.laws import CableLaw
from cstiffjax.runtime import programs
from fitting.calibration.models import measured_mask
from fitting.diagnosis.effect_posterior import POSTERIOR_WALKERS, with_weight
from fitting.effects import CableMassScreen, build_data, make_model
from fitting.effects.fit import fit_masked, lower_masked
from fitting.effects.model import (
    column_chunks,
    evaluate_columns,
    fitted_once,
    jacobian_width,
    model_rJ,
    solutions,
    solved_like,
    walker_residuals,
)

EA_RUNAWAY = 3.0  # a fit that moved some EA beyond this factor of nominal is also restarted at nominal


class Fitter:
    """Holds the compiled models and the data; fits effect sets by masking θ."""

    def __init__(self, robot, recordings, law, effects):
        import dataclasses

        self.robot = dataclasses.replace(robot, name="robot")  # static name: share compiled code
        self.rec = recordings
        self.data = build_data(recordings)
        self.n = recordings.num_samples
        self.m = robot.num_cables
        base = [e for e in effects if e.name != "cable_mass" and not (e.spring_only and law is not CableLaw.spring)]
        self.models = {"base": make_model(self.robot, self.data, base, law)}
        self.ahead = Ahead()
        if any(e.name == "cable_mass" for e in effects):
            cat = [e for e in effects if not e.spring_only]
            cat = [next(e for e in effects if e.name == "cable_mass")] + [e for e in cat if e.name != "cable_mass"]
            self.models["cat"] = make_model(self.robot, self.data, cat, law)
            if law is CableLaw.spring:  # cable_mass screened by the small-sag law: alone, beside every spring effect
                self.models["screen"] = make_model(self.robot, self.data, [CableMassScreen()], law)
                self.models["screen+"] = make_model(self.robot, self.data, [*base, CableMassScreen()], law)

    @property
    def screens_mass(self) -> bool:
        """Whether ``cable_mass`` candidates are screened by the small-sag law (a spring baseline)."""
        return "screen" in self.models

    def model_for(self, names, screen: bool = False):
        """The model that fits ``names``: the spring model, or the catenary model when
        ``names`` holds ``cable_mass`` (with ``screen`` and a spring baseline: a small-sag
        screen model instead, :class:`~fitting.effects.CableMassScreen`; for ``cable_mass``
        alone, a round-1 candidate, the one without the other effects: ~1.4 s less to
        compile on the bundled example, 1.6 + 3.8 s of CPU against 1.8 + 5.1 s)."""
        if "cable_mass" not in names:
            return self.models["base"]
        if not (screen and self.screens_mass):
            return self.models["cat"]
        return self.models["screen" if set(names) == {"cable_mass"} else "screen+"]

    def free_mask(self, model, names):
        free = np.zeros(model.size, dtype=bool)
        free[: model.base_size] = True  # EA and the recordings' zeros: every fit
        for i, e in enumerate(model.effects):
            if e.name in names:
                free[model.block_slice(i)] = True
        return free

    def evaluator(self, model, weight, columns=None):
        """``θ -> (r, J, ok)`` through the masked fits' compiled loop (no second compilation);
        ``columns``: the columns of ``J`` wanted (default all; the others are 0)."""
        data = with_weight(self.data, weight)
        want = np.arange(model.size) if columns is None else columns
        self.ahead.wait("fit", model)  # the fitting loop's program
        return lambda th: evaluate_columns(model, th, self.robot, data, want)

    def _masked_args(self, model, weight, free) -> tuple:
        (cols,) = column_chunks(np.flatnonzero(free), jacobian_width(model))  # free never holds a probe entry
        return (model, self.robot, with_weight(self.data, weight), np.asarray(cols))

    def fit_free(self, model, weight, theta0, free):
        """One masked fit (:func:`fitting.effects.fit.fit_masked`) of ``model`` on ``weight``;
        the Jacobian is computed for the free entries only (:func:`jacobian_width` columns)."""
        self.ahead.wait("fit", model)
        args = self._masked_args(model, weight, free)
        return fit_masked(model_rJ, theta0, args, free, must_succeed=np.asarray(weight) > 0, quick=fitted_once(model))

    def compile_ahead(self, names=None, screen: bool = False) -> None:
        """Compile, in a background thread (:class:`Ahead`), the fitting loop of the model
        of ``names`` (None: nothing; ``screen``: :meth:`model_for`), unless it was handed to
        the thread already (as :meth:`compile_walkers`). The held-out scorer needs no
        program of its own (:meth:`scorer`)."""
        if names is not None and not self.ahead.has("fit", model := self.model_for(names, screen)):
            self.ahead.start([self._fit_job(model, names)])

    def _fit_job(self, model, names):
        return ("fit", model, lambda: self.lower_fit(names, model).compile())

    def lower_fit(self, names, model=None):
        """The fitting loop of ``model`` (default :meth:`model_for` ``names``) traced and
        lowered for a fit of ``names`` on every sample: ``.compile()`` then compiles it for
        :meth:`fit` (in the diagnosis, the main thread lowers its baseline's loop before the
        background thread starts tracing: the two traces would share the interpreter lock)."""
        model, w = self.model_for(names) if model is None else model, np.ones(self.n)
        free = self.free_mask(model, names)
        return lower_masked(model_rJ, model.start, self._masked_args(model, w, free), free, must_succeed=w > 0,
                            quick=fitted_once(model))

    def compile_walkers(self, model) -> None:
        """Compile the posterior check's programs for ``model`` in the background thread,
        behind any compilation under way (the call does not wait), unless they were handed
        to the thread already: the ensemble (:func:`~fitting.effects.model.walker_residuals`,
        all walkers in one call, :func:`fitting.diagnosis.effect_posterior.posterior_check`), then the
        equilibria's solve at the fitted θ that its walkers start from
        (:func:`~fitting.effects.model.solutions`; the shorter job last, so that a main
        thread that reaches the check first takes it, :meth:`Ahead.wait`)."""
        if not self.ahead.has("walkers", model):
            self.ahead.start(self._walkers_jobs(model))  # queued behind any compilation under way

    def _walkers_jobs(self, model):
        data = with_weight(self.data, np.ones(self.n))
        theta, thetas = np.zeros(model.size), np.zeros((POSTERIOR_WALKERS, model.size))
        solved = solved_like(model, self.n)  # (not traced: tracing here would hold the interpreter lock)
        return [("walkers", model, lambda: walker_residuals.lower(model, thetas, self.robot, data, theta,
                                                                  solved).compile()),
                ("solutions", model, lambda: solutions.lower(model, theta, self.robot, data).compile())]

    def scorer(self, model, weight):
        """``θ -> (r, ok)`` (held-out scoring, one call per fold) through the fitting loop's
        compiled program (:meth:`evaluator` without Jacobian columns). A residuals-only
        program is a few ms cheaper per call, but compiling it cost a cold diagnosis of the
        bundled example ~1-2 s (benchmarks/LATENCY.md)."""
        ev = self.evaluator(model, weight, columns=[])

        def score(theta):
            r, _, ok = ev(theta)
            return r, ok

        return score

    def fit(self, names, weight, start: tuple | None = None, screen: bool = False) -> tuple:
        """Fit EA + the effects ``names`` on the samples of ``weight``; returns ``(model, MaskedFit)``
        (``screen``: ``cable_mass`` by its small-sag screen, :meth:`model_for`).

        ``start`` ``(model, θ)`` of a previous fit. When that fit pushed some ``EA`` beyond
        a factor ``EA_RUNAWAY`` of its nominal value (a misspecified model compensating
        with near-rigid or near-slack cables), the fit is also started from the nominal
        ``EA`` and the better of the two is kept."""
        model = self.model_for(names, screen)
        free = self.free_mask(model, names)
        theta0 = np.where(free, np.asarray(model.start), 0.0)
        starts = [theta0]
        if start is not None:
            starts = [transfer(*start, model, theta0, free)]
            if np.any(np.abs(start[1][: self.m]) > np.log(EA_RUNAWAY)):
                starts.append(theta0)
        best = None
        for th in starts:
            fit = self.fit_free(model, weight, th, free)
            if best is None or (fit.steps > 0 and fit.chi2 < best.chi2) or (best.steps == 0 and not best.converged):
                best = fit
        return model, best

    def use_recordings(self, recordings) -> None:
        """Fit ``recordings`` from now on: the same samples with other readings (e.g. a sensor
        fault corrected, :mod:`fitting.diagnosis.sensor_faults`); the compiled models stay valid
        (the data are arguments of their programs, not part of them)."""
        if recordings.l0.shape != self.rec.l0.shape:
            raise ValueError(f"use_recordings: {recordings.num_samples} samples of {recordings.num_cables} cables, "
                             f"the fitter holds {self.n} of {self.m}")
        self.rec, self.data = recordings, build_data(recordings)

    def num_data(self, weight):
        keep = np.asarray(weight) > 0
        return int(measured_mask(self.rec, self.data.sensors)[keep].sum())


class Ahead:
    """Compilation in a background thread, for the cold start of a diagnosis.

    The model of the ``cable_mass`` candidate (its small-sag screen on a spring baseline,
    the catenary model otherwise) is tried last in each round, so its compilation can
    overlap the spring model's compilation and fits; the spring model's posterior
    ensemble is queued behind it once the baseline leaves excess χ²
    (:func:`fitting.diagnosis.diagnose.diagnose`). Only
    *compilation* runs in the thread (``lower().compile()``: JAX keeps the result in its
    in-memory cache, and the main thread's later call reuses it); every execution stays
    on the main thread (concurrent executions deadlocked XLA's CPU runtime,
    :mod:`fitting.diagnosis.effect_posterior`). :meth:`wait` blocks the main thread before it runs
    a program that is still being compiled, so nothing is compiled twice. An error in the
    thread is dropped: the main thread's own call then compiles (and raises) as it would
    have without this.
    """

    def __init__(self):
        self.thread, self.jobs = None, []
        self.done = []  # (kind, model) of every job ever handed to the thread
        self._queue, self._lock = [], threading.Lock()

    def start(self, jobs) -> None:
        """Queue ``jobs`` ``[(kind, model, compile)]``: compiled in this order, after the jobs
        already queued, by one background thread (started when none is running; the call
        never waits)."""
        with self._lock:
            for kind, model, compile_ in jobs:
                done = threading.Event()
                self.jobs.append((kind, model, done))
                self.done.append((kind, model))
                self._queue.append((compile_, done))
            if self.thread is None and self._queue:
                self.thread = threading.Thread(target=self._work, name="cstiffjax-compile-ahead", daemon=True)
                self.thread.start()

    def _work(self) -> None:
        while True:
            with self._lock:
                if not self._queue:
                    self.thread = None  # a later start() runs a new thread
                    return
                compile_, done = self._queue.pop(0)
            self._run(compile_, done)

    @staticmethod
    def _run(compile_, done) -> None:
        """Compile one job (in the thread, or in the caller of :meth:`wait` that took it)."""
        try:
            with programs.concurrent_compiles():  # one-thread code generation (see there)
                compile_()
        except Exception:  # the main thread's own call compiles again and reports it
            pass
        finally:
            done.set()

    def has(self, kind, model) -> bool:
        """Whether the program ``kind`` of ``model`` was handed to the thread (compiled or
        being compiled; a failed compilation too: the main thread's call then compiles)."""
        return any(k == kind and m is model for k, m in self.done)

    def wait(self, kind=None, model=None) -> None:
        """Block until the program ``kind`` (``"fit"``, ``"solutions"``, ``"walkers"``) of
        ``model`` is compiled, if it is one of the jobs; ``wait()``: until the thread has
        finished. A job the thread has not started yet is taken from the queue and compiled
        here, in the caller (the same options: :func:`cstiffjax.runtime.programs.concurrent_compiles`),
        while the thread goes on with its own: a caller never waits idle behind other jobs
        (a cold diagnosis of the bundled example: the main thread compiles the walkers'
        :func:`~fitting.effects.model.solutions` while the thread compiles the ensemble,
        ~1 s sooner). While the thread compiles the job waited for, the caller compiles the
        jobs queued behind it (on IRMA4U's recordings: the next round's ``cable_mass`` screen
        beside this round's catenary model, where the thread would compile them one after
        the other)."""
        if kind is None:
            while True:
                with self._lock:
                    thread = self.thread
                if thread is None:
                    break
                thread.join()
            self.jobs = []
            return
        for k, m, done in self.jobs:
            if k == kind and m is model:
                with self._lock:
                    job = next((j for j in self._queue if j[1] is done), None)
                    if job is not None:
                        self._queue.remove(job)
                if job is not None:
                    self._run(*job)
                while not done.is_set():  # being compiled by the thread: compile what is queued behind it
                    with self._lock:
                        job = self._queue.pop(0) if self._queue else None
                    if job is None:
                        break
                    self._run(*job)
                done.wait()


def transfer(src_model, src_theta, dst_model, theta, free):
    """Copy EA and shared effect blocks of a previous fit into ``theta`` (free entries only)."""
    theta = theta.copy()
    m = src_model.base_size  # EA and the recordings' zeros (the same layout in every model of one data set)
    theta[:m] = src_theta[:m]
    src = {(src_model.effects[i].name, nm): (off, shape) for i, nm, off, shape, _ in src_model.blocks}
    for i, nm, off, shape, _ in dst_model.blocks:
        key = (dst_model.effects[i].name, nm)
        size = int(np.prod(shape, dtype=int))
        if key in src:  # entrywise: a grammar term frees only part of its family's block
            so = src[key][0]
            sl = slice(off, off + size)
            theta[sl] = np.where(free[sl], src_theta[so:so + size], theta[sl])
    return theta
