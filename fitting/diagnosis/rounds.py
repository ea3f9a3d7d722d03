"""The rounds of a diagnosis (:func:`fitting.diagnosis.diagnose.diagnose`): every candidate
fitted on top of the current selection, ranked by ΔBIC, the best that passes every check
selected; the ``cable_mass`` candidate screened by the small-sag law and fitted on the
elastic catenary only when the screen could matter; the models a later step needs
compiled ahead in the background (:class:`~fitting.diagnosis.fitter.Ahead`)."""

import numpy as np

from cstiffjax.cable.laws import CableLaw
from cstiffjax.core.progress import bar
from fitting.diagnosis.fitter import Fitter
from fitting.diagnosis.sample_checks import held_out_folds
from fitting.diagnosis.selection import (
    BIC_THRESHOLD,
    Candidate,
    chi2_dof,
    effect_parameters,
    explained_threshold,
    physical_problem,
    physical_verdict,
    verdict,
    wald_critical,
)
from fitting.effects.grammar import is_term

FAIL_CHI2 = 1e6  # held-out χ² charged for a sample whose forward statics fails


class Diagnoser:
    """The state of one diagnosis between its rounds: the fitter (:class:`~fitting.diagnosis.fitter.Fitter`,
    its compiled models), the candidate names, the held-out folds, the discovery search; a
    round fits every candidate on top of the current selection and selects at most one."""

    def __init__(self, robot, recordings, law, effects, folds, min_explained, progress=None, discover=False,
                 budget_s=60.0):
        if discover:  # grammar terms (fitting.diagnosis.discover) on top of the vocabulary
            from fitting.diagnosis.discover import DiscoveryFitter
        self.f = (DiscoveryFitter if discover else Fitter)(robot, recordings, law, effects)
        self.progress = progress
        self.robot, self.rec, self.law = robot, recordings, law
        self.folds, self.min_explained = folds, min_explained
        self.fold_of = held_out_folds(np.arange(recordings.num_samples), folds)  # copies: counted once already
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
        (:func:`needs_catenary`): then the catenary fit replaces it and the selection is
        made again."""
        out = []  # one fit at a time: calls of compiled programs from two threads at once can hang
        # in XLA's CPU runtime (fitting.diagnosis.effect_posterior, benchmarks/LATENCY.md)
        for name in bar(self.names, desc=f"round {len(current) + 1} candidates", progress=self.progress):
            if skipped(name, current):
                continue
            # only the cable_mass candidate (last: its model may still compile) is screened (with
            # cable_mass in `current`, every candidate is fitted on the catenary model)
            out.append(self._candidate(name, current, cur_fit, weight, screen=name == "cable_mass"))
        self._catenary_ahead(out, current)  # compiles beside the grammar search
        terms = [] if self.discovery is None else self.discovery.round_terms(current, cur_fit, weight)
        out += self._defer(terms, out, weight)
        self._select(out, current, weight, cur_cv)
        screened = next((c for c in out if c.law is CableLaw.small_sag), None)
        self._next_screen_ahead(out, current, weight)
        if screened is not None and needs_catenary(screened, out):
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
        against whichever of the candidates ``out`` is selected (:func:`needs_catenary`:
        its ΔBIC reaches :data:`SCREEN_FRACTION` of their lowest ΔBIC), the catenary model
        starts compiling in the background, beside the grammar search and the selection's
        held-out checks, not after them on the main thread. ``out`` is the vocabulary's
        candidates: a grammar term far ahead of them all can still make the catenary fit
        unneeded (then it was compiled for nothing, in the background)."""
        screened = next((c for c in out if c.law is CableLaw.small_sag), None)
        if screened is None or not np.isfinite(screened.delta_bic):
            return
        lowest = min([c.delta_bic for c in out if np.isfinite(c.delta_bic)], default=BIC_THRESHOLD)
        if screen_reaches(screened.delta_bic, lowest):
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
        if skipped("cable_mass", names):
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


def skipped(name, current) -> bool:
    """Whether candidate ``name`` is not tried on top of ``current`` (in it already, or a
    combination the models cannot hold: cable_mass with nonlinear_elasticity or a grammar term)."""
    return name in current or (name == "nonlinear_elasticity" and "cable_mass" in current) or (
        name == "cable_mass" and ("nonlinear_elasticity" in current or any(map(is_term, current))))


SCREEN_FRACTION = 0.2  # the catenary is fitted when the small-sag screen reaches this share of the winner's ΔBIC
SCREEN_NOTE = (" (screened with the small-sag law, Irvine's approximation of the elastic catenary; not fitted on "
               f"the catenary: the screen's ΔBIC is under {SCREEN_FRACTION:.0%} of the selected candidate's, or of the "
               "BIC threshold)")


def needs_catenary(screened, out) -> bool:
    """Whether the small-sag screen of ``cable_mass`` could change the round's outcome,
    so the elastic catenary must be fitted: the screen failed, or its ΔBIC reaches
    :data:`SCREEN_FRACTION` of the selected candidate's (of ``BIC_THRESHOLD`` when none is
    selected). The screen follows the catenary closely (its change of the tensions within
    1.3 % at a heavy 0.25 kg/m, ``tests/test_small_sag.py``; on the blind benchmark's
    ``proto_cable_mass`` its ΔBIC is the catenary's to 5e-6); the 5x margin is for the
    sag beyond small-sag theory."""
    if not np.isfinite(screened.delta_bic):
        return True
    return screen_reaches(screened.delta_bic, next((c.delta_bic for c in out if c.accepted), BIC_THRESHOLD))


def screen_reaches(screen_delta_bic: float, best: float) -> bool:
    """The margin of :func:`needs_catenary`: the screen's ΔBIC reaches :data:`SCREEN_FRACTION`
    of ``best`` (a candidate's ΔBIC), or of ``BIC_THRESHOLD`` when that is lower."""
    return screen_delta_bic <= SCREEN_FRACTION * min(best, BIC_THRESHOLD)
