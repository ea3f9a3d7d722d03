"""Mismatch diagnosis: calibrate the nominal model, locate what it misses, try every
candidate effect, select, iterate, report (``shared/spec/formats.md`` §3).

Steps of :func:`diagnose`:

1. **Baseline**: the robot as described with every cable's ``EA`` free, fitted to the
   whitened residuals (:mod:`fitting.effects.model`). Gross outliers (a few samples whose
   χ² stands far above the rest, :func:`fitting.diagnosis.localize.detect_outliers`) are left out
   and the baseline refitted. Before that, faults of the load cells (saturated, stuck,
   exchanged, delayed or quantized channels, :mod:`fitting.diagnosis.sensor_faults`) are
   looked for on the baseline's predictions; each one found is corrected in the
   recordings (or its readings left out) and the baseline refitted: every later step
   describes the corrected readings.
2. **Locate**: χ² shares per channel, correlation with inputs and covariates, workspace
   regions, whiteness (:func:`fitting.diagnosis.localize.localize`).
3. **Candidates**: each applicable effect of the vocabulary is added to the current model
   and fitted (EA stays free). On a spring baseline ``cable_mass`` is first screened with
   the small-sag law (:class:`~fitting.effects.CableMassScreen`, a spring model: the
   catenary model is compiled and fitted only when the screen's ΔBIC reaches a fifth of
   the round's selected candidate's, :func:`_needs_catenary`; then the catenary fit
   replaces the screen and the round's selection is made again). Score:
   ``ΔBIC = Δχ² + Δk ln N`` (``N`` recorded scalars), held-out χ² per datum in
   ``folds``-fold cross-validation, and a Wald test of its new parameters against their
   null values with the Gauss-Newton covariance (plus a conditioning check: the
   parameters must be identified).
4. **Select**: the most negative ΔBIC among candidates that pass all checks *and* remove
   at least ``min_explained`` of the excess χ² (χ² − dof) left at that step. A candidate
   must also be physical evidence (:func:`fitting.diagnosis.selection.physical_verdict`):
   no estimate at or beyond a bound of its parameters' domains, nor too small for hardware
   to produce, and a correction without a physical reading needs far more evidence; a
   discovered correction that predicts the same recordings as a vocabulary effect yields
   to it and is named beside it (``equivalent``). Repeat with
   the selected effects in the model (a second effect, ...) until χ²/dof is consistent with
   1 or nothing passes. ``explained`` is false when χ²/dof stays above
   ``1 + max(0.25, 5 √(2/dof))``: structured residual remains, and the localization says
   where; no label is forced.
5. **Posterior check** (selected effects only): one emcee posterior of the final
   fit (:func:`fitting.diagnosis.effect_posterior.posterior_check`) must place each selected
   effect's null value outside its joint 99.9% credible region. A disagreement with the Gauss-Newton
   identification is reported (``posterior["agrees"]`` false, a line in the report); it
   does not change the verdict and the effect is not dropped.

Everything is compiled once per effect list (one spring model holding every effect, two
small-sag models for the ``cable_mass`` screen: alone in the first round, beside every
spring effect in the later ones; one catenary model for ``cable_mass``): candidates and
folds only change masks and weights.
"""

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from cstiffjax.cable.laws import CableLaw, check_law
from cstiffjax.core.errors import DiagnosisError
from cstiffjax.core.progress import bar
from cstiffjax.io.screening import duplicate_groups, recordings_warnings
from cstiffjax.runtime import programs
from fitting.calibration.models import FIT_LAWS, with_start_poses
from fitting.diagnosis import localize as loc
from fitting.diagnosis import residual_checks, sensor_faults
from fitting.diagnosis.discover import prune
from fitting.diagnosis.effect_posterior import posterior_check
from fitting.diagnosis.fitter import Fitter
from fitting.diagnosis.sample_checks import (
    MAX_FAILED_FRACTION,
    elasticity_unknown,
    enough_distinct,
    held_out_folds,
    no_equilibrium_cause,
    time_order,
)
from fitting.diagnosis.selection import (
    BIC_THRESHOLD,
    EA_LOG_STD_MAX,
    Candidate,
    calibrated_ea,
    chi2_dof,
    effect_parameters,
    explained_threshold,
    physical_problem,
    physical_verdict,
    verdict,
    wald_critical,
)
from fitting.effects import VOCABULARY
from fitting.effects.grammar import is_term

MAX_ROUNDS = 3
FAIL_CHI2 = 1e6  # held-out χ² charged for a sample whose forward statics fails


@dataclass
class Diagnosis:
    """Result of :func:`diagnose`; :meth:`to_json` gives the formats.md §3 document."""

    robot: str
    samples: int
    law: CableLaw
    baseline: dict
    localization: dict
    candidates: list
    effects: list
    explained: bool
    final: dict
    outliers: list
    iterations: list
    failed_samples: dict  # {count, samples (1-based), rows (file lines or None)}
    not_applicable: dict
    elapsed_s: float
    arrays: dict = field(default_factory=dict, repr=False)
    dropped_rows: dict = field(default_factory=lambda: {"count": 0, "rows": []})  # rows drop_invalid left out
    sorted_by_time: bool = False  # samples were sorted by time (sample numbers count in time order)
    discovered: list = field(default_factory=list)  # formats.md §3 `discovered`
    discovery: dict = field(default_factory=dict)  # search log (terms scored, fitted, drop-one)
    assumptions: dict = field(default_factory=dict)  # {effect: what it assumed}, e.g. the pulley axes
    warnings: list = field(default_factory=list)  # formats.md §3 `warnings` about the recordings
    sensor_faults: list = field(default_factory=list)  # SensorFault found and corrected before the physics
    equivalent: dict = field(default_factory=dict)  # {selected effect: the look-alike reading beside it}

    def to_json(self) -> dict:
        return {
            "robot": self.robot, "samples": self.samples, "baseline": self.baseline,
            "localization": self.localization["channels"],
            "candidates": [c.to_json() for c in self.candidates if not is_term(c.effect)],
            "discovered": self.discovered, "discovery": self.discovery,
            "effects": self.effects, "explained": self.explained, "final": self.final,
            "outliers": self.outliers, "iterations": self.iterations,
            "regions": self.localization["regions"], "whiteness": self.localization["whiteness"],
            "failed_samples": self.failed_samples, "not_applicable": self.not_applicable,
            "elapsed_s": self.elapsed_s, "dropped_rows": self.dropped_rows,
        } | ({"sorted_by_time": True} if self.sorted_by_time else {}) | (
            {"assumptions": self.assumptions} if self.assumptions else {}) | (
            {"warnings": list(self.warnings)} if self.warnings else {}) | (
            {"sensor_faults": [s.to_json() for s in self.sensor_faults]} if self.sensor_faults else {}) | (
            {"equivalent": dict(self.equivalent)} if self.equivalent else {})

    def summary(self) -> str:
        """The verdict in a few lines: baseline χ²/dof, the effects with their parameters,
        discovered corrections, explained or not, what was left out."""
        from fitting.diagnosis.report import summary_lines

        return "\n".join(summary_lines(self))

    def write_report(self, out_dir) -> Path:
        """Write ``report.md``, ``diagnosis.json`` and the figures into the folder ``out_dir``
        (replaced whole; :func:`fitting.diagnosis.report.write_report`). **Returns:** the path of
        ``report.md``."""
        from fitting.diagnosis.report import write_report

        return write_report(self, out_dir)

    def plot(self) -> dict:
        """The report's figures as open matplotlib figures, ``{file name: Figure}``: in a
        notebook they show inline (residuals of the localizing channel, χ² per channel, the
        robot with its largest misfit)."""
        from fitting.diagnosis.report import open_figures

        return open_figures(self)


def _posterior_wanted(posterior_steps, current) -> bool:
    """Whether the diagnosis runs its posterior check on the selection ``current`` (not for
    an empty one, nor yet for discovered terms)."""
    return bool(posterior_steps and current and not any(map(is_term, current)))


class _Diagnoser:
    def __init__(self, robot, recordings, law, effects, folds, min_explained, progress=None, discover=False,
                 budget_s=60.0, groups=None):
        if discover:  # grammar terms (fitting.diagnosis.discover) on top of the vocabulary
            from fitting.diagnosis.discover import DiscoveryFitter
        self.f = (DiscoveryFitter if discover else Fitter)(robot, recordings, law, effects)
        self.progress = progress
        self.robot, self.rec, self.law = robot, recordings, law
        self.folds, self.min_explained = folds, min_explained
        self.fold_of = held_out_folds(np.arange(recordings.num_samples) if groups is None else groups, folds)
        self.effects = effects
        self.not_applicable = {e.name: why for e in effects if (why := e.applicable(robot, recordings))}
        self.names = [e.name for e in effects if e.name not in self.not_applicable]
        if law is not CableLaw.spring:
            self.names = [n for n in self.names if not next(e for e in effects if e.name == n).spring_only]
        # the catenary candidate last: its model compiles in the background meanwhile (Ahead);
        # candidates are ranked by ΔBIC, so the order they are fitted in changes no verdict
        self.names.sort(key=lambda n: n == "cable_mass")
        self.discovery = None
        self.equivalents = {}  # {selected effect: its look-alike reading} (Discovery.defer)
        if discover:
            from fitting.diagnosis.discover import Discovery
            self.discovery = Discovery(self, self.names, budget_s=budget_s)

    def cv(self, names, weight, start):
        """Held-out χ² per held-out datum over ``folds`` folds (samples whose forward
        statics fails under a fold's parameters count as ``FAIL_CHI2`` each)."""
        start = (start[0], start[1].theta)  # (model, MaskedFit) -> (model, theta)
        held = 0.0
        for k in bar(range(self.folds), desc=f"held-out folds, +{names[-1] if names else 'baseline'}",
                     progress=self.progress):
            train = weight * (self.fold_of != k)
            test = weight * (self.fold_of == k)
            model, fit = self.f.fit(names, train, start)
            if not fit.converged and fit.steps == 0:
                return np.inf
            r, ok = self.f.scorer(model, test)(fit.theta)
            failed = np.sum(~np.asarray(ok)[test > 0])
            held += float(np.sum(np.asarray(r) ** 2)) + FAIL_CHI2 * failed
        return held / self.f.num_data(weight)

    def round(self, current, cur_fit, weight, cur_cv):
        """Every candidate on top of ``current``, ranked by ΔBIC, the best that passes
        every check selected. ``cable_mass`` is screened by its small-sag law in a spring-sized
        model (:class:`~fitting.effects.CableMassScreen`, no catenary compilation) and
        fitted on the elastic catenary only when the screen could matter
        (:func:`_needs_catenary`): then the catenary fit replaces it and the selection is
        made again."""
        out, terms = [], None
        for name in bar(self.names, desc=f"round {len(current) + 1} candidates", progress=self.progress):
            if _skipped(name, current):
                continue
            if name == "cable_mass" and self.discovery is not None:  # (last) its model may still compile
                terms = self.discovery.round_terms(current, cur_fit, weight)
            # only the cable_mass candidate is screened (with cable_mass in `current`, every
            # candidate is fitted on the catenary model)
            out.append(self._candidate(name, current, cur_fit, weight, screen=name == "cable_mass"))
        terms = [] if self.discovery is None else (
            self.discovery.round_terms(current, cur_fit, weight) if terms is None else terms)
        self._catenary_ahead([*out, *terms], current)
        out += self._defer(terms, out, weight)
        self._select(out, current, weight, cur_cv)
        screened = next((c for c in out if c.law is CableLaw.small_sag), None)
        self._next_screen_ahead(out, current, weight)
        if screened is not None and _needs_catenary(screened, out):
            exact = self._candidate("cable_mass", current, cur_fit, weight)
            exact.screen_delta_bic = screened.delta_bic
            out[out.index(screened)] = exact
            for c in out:
                c.accepted, c.reason = False, ""
            self._defer(terms, [c for c in out if c not in terms], weight)  # against the catenary's fit now
            self._select(out, current, weight, cur_cv)
        elif screened is not None:
            screened.reason += SCREEN_NOTE
        return out

    def _catenary_ahead(self, out, current) -> None:
        """When the small-sag screen of ``cable_mass`` is sure to need the catenary fit
        (:func:`_needs_catenary` against whichever candidate is selected: its ΔBIC reaches
        :data:`SCREEN_FRACTION` of the lowest ΔBIC of the round), the catenary model starts
        compiling in the background before the selection's held-out checks, not after them
        on the main thread."""
        screened = next((c for c in out if c.law is CableLaw.small_sag), None)
        if screened is None or not np.isfinite(screened.delta_bic):
            return
        lowest = min([c.delta_bic for c in out if np.isfinite(c.delta_bic)] + [BIC_THRESHOLD])
        if screened.delta_bic <= SCREEN_FRACTION * lowest:
            self.f.compile_ahead(["cable_mass", *current])

    def _next_screen_ahead(self, out, current, weight) -> None:
        """When the selected candidate leaves the recordings unexplained, the next round
        will screen ``cable_mass`` on top of it: its model starts compiling in the background
        now, beside the rest of this round (a catenary fit, the held-out checks), instead of
        at the next round's start, where the main thread would wait for it (the same model
        whatever was selected: :meth:`Fitter.model_for`)."""
        best = next((c for c in out if c.accepted and c.law is not CableLaw.small_sag), None)
        if best is None or not self.f.screens_mass or "cable_mass" not in self.names:
            return
        names = [*current, best.effect]
        if _skipped("cable_mass", names):
            return
        ndata = self.f.num_data(weight)
        if best.chi2_per_dof > explained_threshold(ndata - best.fit[1].free.sum()):
            self.f.compile_ahead(["cable_mass", *names], screen=True)

    def _defer(self, terms, vocabulary, weight) -> list:
        """The grammar ``terms`` with their ``defer`` marks set afresh against the vocabulary
        candidates (a term yields to a passing vocabulary name on a near tie)."""
        for t in terms:
            t.defer, t.defer_physical = "", False
        return self.discovery.defer(terms, vocabulary, weight) if terms else terms

    def _candidate(self, name, current, cur_fit, weight, screen=False) -> "Candidate":
        """``name`` fitted on top of ``current`` (``screen``: :meth:`Fitter.model_for`)."""
        ndata = self.f.num_data(weight)
        cur_model, cur = cur_fit
        names = [*current, name]
        model, fit = self.f.fit(names, weight, (cur_model, cur.theta), screen=screen)
        if fit.steps == 0 and not fit.converged:
            return Candidate(name, np.inf, np.inf, {}, 0, 0.0, 0.0, False, 0.0, reason=fit.message, law=model.law)
        gauge = model.effects[model.effect_index(name)].gauge(self.f.m)  # directions no reading sees
        k = int(fit.free.sum() - cur.free.sum()) - (0 if gauge is None else len(gauge))
        dbic = fit.chi2 - cur.chi2 + k * np.log(ndata)
        c2 = chi2_dof(fit, ndata)
        params, wald, ident = effect_parameters(model, fit, name, np.sqrt(max(1.0, c2)))
        excess = cur.chi2 - (ndata - cur.free.sum())
        frac = (cur.chi2 - fit.chi2) / max(excess, 1e-9)
        cand = Candidate(name, float(dbic), float(c2), params, k, wald, wald_critical(k),
                         ident, float(frac), law=model.law)
        cand.physical = physical_problem(model.effects[model.effect_index(name)], params, self.f.robot, self.f.data)
        cand.fit = (model, fit)
        return cand

    def _select(self, out, current, weight, cur_cv) -> None:
        """Sort ``out`` by ΔBIC and give every candidate its verdict: the held-out check
        lazily, best ΔBIC first, until one is selected (a candidate's held-out χ² is kept)."""
        out.sort(key=lambda c: c.delta_bic)
        selected = False
        for c in out:
            c.accepted, c.reason = verdict(c, self.min_explained, check_cv=False)
            c.rejected_because = c.reason if c.reason == physical_verdict(c) else ""  # physics, not statistics
            if c.accepted and getattr(c, "defer", ""):  # a grammar term yields to the vocabulary
                c.accepted, c.reason = False, c.defer
                c.rejected_because = c.defer if getattr(c, "defer_physical", False) else ""
            if not c.accepted:
                continue
            if selected:
                c.accepted, c.reason = False, "passes; a candidate with a lower ΔBIC was selected"
                continue
            if c.law is CableLaw.small_sag:  # a screen that passes is fitted on the catenary (no held-out check here)
                c.reason, selected = "the small-sag screen passes", True
                continue
            if c.cv is None:
                c.cv = self.cv([*current, c.effect], weight, c.fit)
            c.cv_reference = cur_cv()
            c.accepted, c.reason = verdict(c, self.min_explained)
            selected = c.accepted


def _skipped(name, current) -> bool:
    """Whether candidate ``name`` is not tried on top of ``current`` (in it already, or a
    combination the models cannot hold: cable_mass with nonlinear_elasticity or a grammar term)."""
    return name in current or (name == "nonlinear_elasticity" and "cable_mass" in current) or (
        name == "cable_mass" and ("nonlinear_elasticity" in current or any(map(is_term, current))))


SCREEN_FRACTION = 0.2  # the catenary is fitted when the small-sag screen reaches this share of the winner's ΔBIC
SCREEN_NOTE = (" (screened with the small-sag law, Irvine's approximation of the elastic catenary; not fitted on "
               f"the catenary: the screen's ΔBIC is under {SCREEN_FRACTION:.0%} of the selected candidate's, or of the "
               "BIC threshold)")


def _needs_catenary(screened, out) -> bool:
    """Whether the small-sag screen of ``cable_mass`` could change the round's outcome,
    so the elastic catenary must be fitted: the screen failed, or its ΔBIC reaches
    :data:`SCREEN_FRACTION` of the selected candidate's (of ``BIC_THRESHOLD`` when none is
    selected). The screen follows the catenary closely (its change of the tensions within
    1.3 % at a heavy 0.25 kg/m, ``tests/test_small_sag.py``; on the blind benchmark's
    ``proto_cable_mass`` its ΔBIC is the catenary's to 5e-6); the 5x margin is for the
    sag beyond small-sag theory."""
    if not np.isfinite(screened.delta_bic):
        return True
    best = next((c.delta_bic for c in out if c.accepted), BIC_THRESHOLD)
    return screened.delta_bic <= SCREEN_FRACTION * min(best, BIC_THRESHOLD)


def diagnose(robot, recordings, *, law: CableLaw = CableLaw.spring, effects=VOCABULARY, folds: int = 5,
             min_explained: float = 0.5, detect_outliers: bool = True, posterior_steps: int = 300,
             sort_by_time: bool = False, rows=None, dropped_rows=None,
             progress: bool | None = None, discover: bool = True, discovery_budget_s: float = 60.0) -> Diagnosis:
    """Diagnose what the nominal model of ``robot`` leaves out of ``recordings``.

    **Arguments:**

    - ``robot``: a :class:`~cstiffjax.io.robot.CableRobot` (the nominal description).
    - ``recordings``: a :class:`~cstiffjax.io.recordings.Recordings` made on it.
    - ``law``: baseline cable law, one of :data:`~fitting.calibration.models.FIT_LAWS`
      (``CableLaw.spring`` or ``CableLaw.catenary``).
    - ``effects``: candidate effects (default the whole formats.md §3 vocabulary).
    - ``folds``: cross-validation folds. ``min_explained``: smallest share of the excess
      χ² an effect must remove to be named. ``detect_outliers``: leave gross outliers out.
    - ``posterior_steps``: the most emcee steps of the posterior check of the selected
      effects (:func:`posterior_check`, one chain on the final fit: 100 steps, extended
      until the kept steps reach 50 autocorrelation times, at most this many; 0 skips it;
      300 lets τ reach 5.6 steps: at 200 three chains of the blind benchmark's 8-cable
      robot, τ 3.8-3.9, stopped short of it). Its result goes to
      ``final["posterior"]`` (one entry per selected effect); a
      posterior that contradicts the Gauss-Newton identification (``agrees`` false) is
      reported, never used to drop the effect silently or to change the verdict.
    - ``sort_by_time``: sort the samples by ``time`` when it goes backwards (else that is
      an error naming the first such row; :func:`fitting.diagnosis.sample_checks.time_order`).
    - ``rows``: file line number of each sample, for messages and ``failed_samples``
      (default: none; samples are named by their 1-based position).
    - ``dropped_rows``: the rows ``drop_invalid`` left out, reported under ``dropped_rows``
      (default ``recordings.dropped_rows``, the loader's numbering).
    - ``progress``: progress bars for candidates, folds and the posterior check (None:
      only on a terminal, :mod:`cstiffjax.core.progress`).
    - ``discover``: search the grammar of corrections (:mod:`fitting.diagnosis.discover`) when the
      vocabulary does not explain; found terms go to ``discovered`` (never ``effects``).
      ``discovery_budget_s``: the most seconds the search may add.

    **Returns:** a :class:`Diagnosis` (``to_json()`` is the formats.md §3 document);
    ``failed_samples`` ``{count, samples, rows}`` lists the samples without an equilibrium
    in the nominal model (left out), ``dropped_rows`` ``{count, rows}``.

    **Raises:** :class:`~cstiffjax.core.errors.DiagnosisError` when more than half of the
    samples have no equilibrium in the nominal model (no verdict; the message names the
    likely cause), or when ``time`` goes backwards and ``sort_by_time`` is false.
    """
    if robot.kind != "cdpr":
        raise ValueError(f"diagnose needs a CDPR robot (kind 'cdpr'), got kind {robot.kind!r}")
    check_law(law, FIT_LAWS, "diagnose")
    if isinstance(posterior_steps, bool) or not isinstance(posterior_steps, int) or not (
            posterior_steps == 0 or posterior_steps >= 40):
        raise ValueError(f"posterior_steps must be 0 (skip) or an integer >= 40, got {posterior_steps!r}")
    if rows is not None and len(rows) != recordings.num_samples:
        raise ValueError(f"rows: {len(rows)} line numbers for {recordings.num_samples} samples")
    recordings, rows, was_sorted = time_order(recordings, sort_by_time=sort_by_time, rows=rows)
    recordings = with_start_poses(robot, recordings)  # no x y z (on-board sensors): the nominal equilibria
    groups = duplicate_groups(recordings)
    enough_distinct(recordings, groups, folds)
    notes = recordings_warnings(recordings, robot, rows=() if rows is None else rows)
    dropped = list(recordings.dropped_rows if dropped_rows is None else dropped_rows)
    t0 = time.perf_counter()
    d = _Diagnoser(robot, recordings, law, tuple(effects), folds, min_explained, progress, discover,
                   discovery_budget_s, groups)
    d.warnings = notes
    f = d.f
    with programs.concurrent_compiles():  # two threads compile: one-thread code generation (see there)
        # cold start: the model of the cable_mass candidate (on a spring baseline its small-sag
        # screen, else the catenary model) compiles in a background thread while the baseline is
        # compiled and fitted (nothing is executed there; Ahead)
        baseline = f.lower_fit([])  # traced here first: the background thread's tracing would share the GIL
        f.compile_ahead(["cable_mass"] if "cat" in f.models and "cable_mass" in d.names else None, screen=True)
        baseline.compile()  # while the background thread traces
        try:
            return _diagnose(d, robot, recordings, law, rows, dropped, was_sorted, detect_outliers, posterior_steps,
                             progress, t0)
        finally:
            f.ahead.wait()  # no compilation outlives the call (also on an error)


def _diagnose(d, robot, recordings, law, rows, dropped, was_sorted, detect_outliers, posterior_steps, progress,
              t0) -> Diagnosis:
    """The steps of :func:`diagnose` after its checks (see there and the module doc)."""
    f, n = d.f, d.f.n
    assumptions = {e.name: note for mdl in f.models.values() for e in mdl.effects
                   if e.name in d.names and (note := e.note(f.robot, f.data))}
    weight = np.ones(n)
    model, base = f.fit([], weight)
    failed = [] if base.converged or base.steps else [int(i) for i in np.flatnonzero(~base.ok)]
    if len(failed) > MAX_FAILED_FRACTION * n:
        named = [f"row {rows[i]}" if rows is not None else f"sample {i + 1}" for i in failed[:5]]
        raise DiagnosisError(f"{recordings.source}: the nominal model has no equilibrium for {len(failed)} of {n} "
                             f"samples ({', '.join(named)}{', ...' if len(failed) > 5 else ''}); no verdict is "
                             f"possible. {no_equilibrium_cause(robot, recordings, failed)}")
    if failed:  # forward statics failed for some samples: leave them out, say so
        weight[failed] = 0.0
        model, base = f.fit([], weight)
    faults, recordings, (model, base) = sensor_faults.check(f, model, base, weight, recordings)  # corrected, refitted
    outliers = []
    if detect_outliers:
        for _ in range(2):
            new = loc.detect_outliers(base.r, weight > 0)
            if not new:
                break
            outliers += new
            weight[new] = 0.0
            model, base = f.fit([], weight, (model, base.theta))
    keep = weight > 0
    ndata = f.num_data(weight)
    base_c2 = chi2_dof(base, ndata)
    if posterior_steps and base_c2 > explained_threshold(ndata - base.free.sum()):
        f.compile_walkers(model)  # queued: an effect without cable_mass will likely need its posterior
    no_elasticity = elasticity_unknown(f, model, weight, EA_LOG_STD_MAX)
    if no_elasticity:  # tensions and stretch below the noise: no effect may be claimed on the cables' strain
        d.warnings.append(no_elasticity)
        for e in d.effects:
            if e.acts_through_elasticity and e.name in d.names:
                d.names.remove(e.name)
                d.not_applicable[e.name] = "the recordings carry no information about the cables' elasticity"
    localization = loc.localize(recordings, f.data, base.r, keep)
    if d.discovery is not None:
        d.discovery.localization = localization["channels"]
    baseline = {"model": law.name, "chi2_per_dof": base_c2, "chi2": base.chi2, "dof": ndata - int(base.free.sum()),
                "rms": loc.rms(base.r, keep, robot.noise, recordings, f.data.sensors),
                "calibrated": calibrated_ea(robot.EA, base, np.sqrt(max(1.0, base_c2))),
                "converged": base.converged}

    current, cur_fit = [], (model, base)
    cv_cache = {}

    def cur_cv():
        key = tuple(current)
        if key not in cv_cache:
            cv_cache[key] = d.cv(current, weight, cur_fit)
        return cv_cache[key]

    candidates, iterations = [], []
    for rnd in range(MAX_ROUNDS):
        c2 = chi2_dof(cur_fit[1], ndata)
        if rnd > 0 and c2 <= explained_threshold(ndata - cur_fit[1].free.sum()) and not (
                d.discovery is not None and d.discovery.structured(cur_fit, weight)):
            break  # every candidate is always tried once; further rounds only while unexplained
        if rnd > 0 and f.screens_mass and "cable_mass" in d.names and not _skipped("cable_mass", current):
            f.compile_ahead(["cable_mass", *current], screen=True)  # its screen beside the selection (fitted last)
        cands = d.round(current, cur_fit, weight, cur_cv)
        if rnd == 0:
            candidates = cands
        best = next((c for c in cands if c.accepted), None)
        iterations.append({"round": rnd + 1, "model": list(current), "chi2_per_dof": c2,
                           "tried": [{"effect": c.effect, "delta_bic": c.delta_bic, "chi2_per_dof": c.chi2_per_dof,
                                      "accepted": c.accepted, "reason": c.reason}
                                     | ({"rejected_because": c.rejected_because} if c.rejected_because else {})
                                     for c in cands],
                           "added": best.effect if best else None})
        if best is None:
            break
        if best.equivalent:  # a look-alike correction predicts the same recordings
            d.equivalents[best.effect] = best.equivalent
        current = [*current, best.effect]
        cur_fit = best.fit
    if _posterior_wanted(posterior_steps, current):  # the posterior's ensemble program, in the
        f.compile_walkers(f.model_for(current))  # background during the checks below
    drop_one = []
    if len(current) > 1:  # every selected entry must still earn its place in the final model
        current, cur_fit, drop_one = prune(d, current, cur_fit, weight)
    if detect_outliers:  # re-check the outliers against the final model, refit if they change
        model_f, fit_f = cur_fit
        r_all, _, ok_all = f.evaluator(model_f, np.ones(n), columns=[])(fit_f.theta)
        usable = np.asarray(ok_all) & ~np.isin(np.arange(n), failed)
        final_out = loc.detect_outliers(np.asarray(r_all), usable)
        if sorted(final_out) != sorted(outliers):
            outliers = final_out
            weight = usable.astype(float)
            weight[outliers] = 0.0
            cur_fit = f.fit(current, weight, (model_f, fit_f.theta))
            ndata = f.num_data(weight)
            keep = weight > 0
    model_f, fit_f = cur_fit
    c2f = chi2_dof(fit_f, ndata)
    dof_f = ndata - int(fit_f.free.sum())
    checks = residual_checks.residual_structure(recordings, f.data, fit_f.r, keep)
    explained = bool(c2f <= explained_threshold(dof_f)) and not checks["structured"]
    final_params = {e: effect_parameters(model_f, fit_f, e, np.sqrt(max(1.0, c2f)))[0]
                    for e in current if not is_term(e)}
    final = {"chi2_per_dof": c2f, "chi2": fit_f.chi2, "dof": dof_f,
             "rms": loc.rms(fit_f.r, keep, robot.noise, recordings, f.data.sensors),
             "calibrated": calibrated_ea(robot.EA, fit_f, np.sqrt(max(1.0, c2f))),
             "parameters": final_params, "converged": fit_f.converged, "residual_checks": checks}
    if _posterior_wanted(posterior_steps, current):
        final["posterior"] = posterior_check(f, model_f, fit_f, weight, current, steps=posterior_steps,
                                             progress=progress)
    if not explained:
        final["residual_localization"] = loc.localize(recordings, f.data, fit_f.r, keep)["channels"]
    r_base_all, _, _ = f.evaluator(model, np.ones(n), columns=[])(base.theta)
    r_fin_all, _, _ = f.evaluator(model_f, np.ones(n), columns=[])(fit_f.theta)
    arrays = {"r_base": np.asarray(r_base_all), "r_final": np.asarray(r_fin_all), "keep": keep,
              "covariates": loc.covariates(recordings, f.data), "robot": robot, "poses": np.asarray(recordings.pose),
              "sensors": f.data.sensors}
    discovered, discovery = [], {"drop_one": drop_one}
    if d.discovery is not None:
        discovered, discovery = d.discovery.report(current, cur_fit, weight, drop_one)
    return Diagnosis(robot.name, n, law, baseline, localization, candidates,
                     [e for e in current if not is_term(e)], explained, final,
                     [int(i) + 1 for i in outliers], iterations,
                     {"count": len(failed), "samples": [int(i) + 1 for i in failed],
                      "rows": [int(rows[i]) for i in failed] if rows is not None else None},
                     d.not_applicable, time.perf_counter() - t0, arrays,
                     {"count": len(dropped), "rows": [int(r) for r in dropped]}, was_sorted, discovered, discovery,
                     assumptions, d.warnings, faults,
                     {e: why for e, why in d.equivalents.items() if e in current})
