"""Mismatch diagnosis: calibrate the nominal model, locate what it misses, try every
candidate effect, select, iterate, report (``cstiffjax/io/formats.md`` §3).

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
from cstiffjax.io.screening import distinct, duplicate_groups, recordings_warnings
from cstiffjax.io.sigmas import fit_noise
from cstiffjax.runtime import programs
from fitting.calibration.arguments import check_arguments
from fitting.calibration.models import FIT_LAWS, with_start_poses
from fitting.diagnosis import localize as loc
from fitting.diagnosis import residual_checks, sensor_faults
from fitting.diagnosis.discover import prune
from fitting.diagnosis.effect_posterior import posterior_check
from fitting.diagnosis.rounds import Diagnoser, skipped
from fitting.diagnosis.sample_checks import (
    MAX_FAILED_FRACTION,
    elasticity_unknown,
    enough_distinct,
    no_equilibrium_cause,
    time_order,
)
from fitting.diagnosis.selection import (
    EA_LOG_STD_MAX,
    calibrated_ea,
    chi2_dof,
    effect_parameters,
    explained_threshold,
)
from fitting.effects import VOCABULARY
from fitting.effects.grammar import is_term

MAX_ROUNDS = 3


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
    covariate_names: tuple = ()  # the recordings' covariate columns (the grammar's drivers cov:k)

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
        robot with its largest misfit, the residual against each discovered term's driver)."""
        from fitting.diagnosis.report import open_figures

        return open_figures(self)


def _posterior_wanted(posterior_steps, current) -> bool:
    """Whether the diagnosis runs its posterior check on the selection ``current`` (not for
    an empty one, nor yet for discovered terms)."""
    return bool(posterior_steps and current and not any(map(is_term, current)))


def diagnose(robot, recordings, *, law: CableLaw = CableLaw.spring, effects=VOCABULARY, folds: int = 5,
             min_explained: float = 0.5, detect_outliers: bool = True, posterior_steps: int = 300,
             sort_by_time: bool = False, rows=None, dropped_rows=None,
             progress: bool | None = None, discover: bool = True, discovery_budget_s: float = 60.0,
             on_verdict=None) -> Diagnosis:
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
      the default leaves room for the slower-mixing chains of the blind benchmark,
      benchmarks/LATENCY.md). Its result goes to
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
    - ``on_verdict``: ``None``, or a function called (in this thread) with the
      :class:`Diagnosis` as soon as its verdict is final and before the posterior check
      (``final`` then has no ``"posterior"``; nothing else differs): the command line
      hands the report's figures, which do not show the posterior, to a process that draws
      them while the walkers sample (:mod:`fitting.diagnosis.figure_worker`). Not called when
      no posterior is sampled.

    **Returns:** a :class:`Diagnosis` (``to_json()`` is the formats.md §3 document);
    ``failed_samples`` ``{count, samples, rows}`` lists the samples without an equilibrium
    in the nominal model (left out), ``dropped_rows`` ``{count, rows}``.

    **Raises:** ``TypeError`` when ``robot`` is not a ``CableRobot`` or ``recordings`` not a
    ``Recordings`` (a file name: load it first), ``ValueError`` when their numbers of cables
    differ (:func:`fitting.calibration.arguments.check_arguments`, as :func:`fitting.calibrate`);
    :class:`~cstiffjax.core.errors.DiagnosisError` when more than half of the
    samples have no equilibrium in the nominal model (no verdict; the message names the
    likely cause), or when ``time`` goes backwards and ``sort_by_time`` is false;
    :class:`~cstiffjax.core.errors.RecordingsError` when a recorded channel has no ``[noise]``
    sigma (:func:`cstiffjax.io.sigmas.fit_noise`).
    """
    check_arguments(robot, recordings, "diagnose")
    check_law(law, FIT_LAWS, "diagnose")
    if isinstance(posterior_steps, bool) or not isinstance(posterior_steps, int) or not (
            posterior_steps == 0 or posterior_steps >= 40):
        raise ValueError(f"posterior_steps must be 0 (skip) or an integer >= 40, got {posterior_steps!r}")
    if rows is not None and len(rows) != recordings.num_samples:
        raise ValueError(f"rows: {len(rows)} line numbers for {recordings.num_samples} samples")
    robot = fit_noise(robot, recordings)  # a recorded channel needs its sigma; the others a placeholder
    recordings, rows, was_sorted = time_order(recordings, sort_by_time=sort_by_time, rows=rows)
    groups = duplicate_groups(recordings, robot.noise)
    enough_distinct(recordings, groups, folds)
    notes = recordings_warnings(recordings, robot, rows=() if rows is None else rows)
    recordings, rows = distinct(recordings, rows, groups)  # each measurement counted once (named in notes)
    recordings = with_start_poses(robot, recordings)  # no x y z (on-board sensors): the nominal equilibria
    dropped = list(recordings.dropped_rows if dropped_rows is None else dropped_rows)
    t0 = time.perf_counter()
    d = Diagnoser(robot, recordings, law, tuple(effects), folds, min_explained, progress, discover,
                   discovery_budget_s)
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
                             progress, t0, on_verdict)
        finally:
            f.ahead.wait()  # no compilation outlives the call (also on an error)


def _diagnose(d, robot, recordings, law, rows, dropped, was_sorted, detect_outliers, posterior_steps, progress,
              t0, on_verdict=None) -> Diagnosis:
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
        if rnd > 0 and f.screens_mass and "cable_mass" in d.names and not skipped("cable_mass", current):
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
    unexplained = {} if explained else {
        "residual_localization": loc.localize(recordings, f.data, fit_f.r, keep)["channels"]}
    r_base_all, _, _ = f.evaluator(model, np.ones(n), columns=[])(base.theta)
    r_fin_all, _, _ = f.evaluator(model_f, np.ones(n), columns=[])(fit_f.theta)
    arrays = {"r_base": np.asarray(r_base_all), "r_final": np.asarray(r_fin_all), "keep": keep,
              "covariates": loc.covariates(recordings, f.data), "robot": robot, "poses": np.asarray(recordings.pose),
              "sensors": f.data.sensors, "session": np.asarray(recordings.session)}
    discovered, discovery = [], {"drop_one": drop_one}
    if d.discovery is not None:
        discovered, discovery = d.discovery.report(current, cur_fit, weight, drop_one)

    def result(posterior):
        return Diagnosis(robot.name, n, law, baseline, localization, candidates,
                         [e for e in current if not is_term(e)], explained, {**final, **posterior, **unexplained},
                         [int(i) + 1 for i in outliers], iterations,
                         {"count": len(failed), "samples": [int(i) + 1 for i in failed],
                          "rows": [int(rows[i]) for i in failed] if rows is not None else None},
                         d.not_applicable, time.perf_counter() - t0, arrays,
                         {"count": len(dropped), "rows": [int(r) for r in dropped]}, was_sorted, discovered,
                         discovery, assumptions, d.warnings, faults,
                         {e: why for e, why in d.equivalents.items() if e in current},
                         tuple(recordings.covariate_names))

    if not _posterior_wanted(posterior_steps, current):
        return result({})
    if on_verdict is not None:  # the verdict is final: the posterior only checks it
        on_verdict(result({}))
    return result({"posterior": posterior_check(f, model_f, fit_f, weight, current, steps=posterior_steps,
                                                progress=progress)})
