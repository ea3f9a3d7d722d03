"""Search the grammar of corrections (:mod:`fitting.effects.grammar`) beside the vocabulary
(steps 3-4 of :mod:`fitting.diagnosis.diagnose`).

In every round of the diagnosis whose current model leaves χ²/dof above the explained
threshold or structure in the residual (:mod:`fitting.diagnosis.residual_checks`), also when a
vocabulary candidate of that round would explain the recordings (a term must be able to
beat a look-alike: 24 anchor z-offsets mimic a tracker z-scale on the TCPR-8's frame):

1. **Score** every grammar term at the current fit with one evaluation of the compiled
   model (:class:`~fitting.effects.terms_model.TermModel` holding every term): the
   Gauss-Newton χ² decrease of the term alone with the current free parameters projected
   out (the score/Lagrange-multiplier test), ``ΔBIC ≈ -score + k ln N``.
2. **Propose**: the ``shortlist`` best-scoring terms, plus the best terms whose driver is
   the one the localization named (:func:`fitting.diagnosis.localize.localize`), are fitted exactly
   (masked Levenberg-Marquardt with EA and the current effects free) and become ordinary
   :class:`~fitting.diagnosis.selection.Candidate`\\ s: the same ΔBIC, Wald, identifiability,
   explained-fraction and held-out checks decide, in competition with the vocabulary.
3. After the rounds, :func:`prune` re-checks every selected effect or term against the
   final model (drop-one ΔBIC) so a vocabulary effect that only absorbed part of a
   discovered term's signal is not reported.

A compute budget (``budget_s``) caps the time spent here; when it runs out the search
stops proposing terms and says so in ``Discovery.log``.
"""

import dataclasses
import time

import numpy as np

from cstiffjax.io import schema
from fitting.diagnosis.discover_report import describe
from fitting.diagnosis.effect_posterior import with_weight
from fitting.diagnosis.fitter import Fitter, transfer
from fitting.diagnosis.residual_checks import residual_structure
from fitting.diagnosis.selection import (
    BIC_THRESHOLD,
    Candidate,
    chi2_dof,
    effect_parameters,
    explained_threshold,
    physical_problem,
    verdict,
    wald_critical,
)
from fitting.effects import make_model
from fitting.effects.fit import fit_masked
from fitting.effects.grammar import WRENCH_NAMES, basis, family_terms, generate_grammar, is_term, plausibility
from fitting.effects.terms_model import Probe, TermModel, chain_basis, probe_sensitivities

# a term model's host-driven fit pads θ to a multiple of this many entries: its kernels
# (fitting.calibration.lm._propose, _update, _result) then compile once for the bundled example's
# 146- and 151-entry term models instead of twice (~0.3 s of a cold diagnosis's main thread)
HOST_WIDTH = 32

# grammar terms a vocabulary effect already covers (the term equals it or is nested in it)
VOCABULARY_EQUIVALENT = {
    "l0|offset|-|per_cable": "length_offset", "l0|offset|-|shared": "length_offset",
    "l0|linear|time|per_cable": "length_drift", "l0|linear|time|shared": "length_drift",
    "tension|offset|-|per_cable": "tension_sensor_bias", "tension|offset|-|shared": "tension_sensor_bias",
    "tension|step|dir|shared": "exit_friction",
    "l0|gain|-|per_cable": "length_gain", "l0|gain|-|shared": "length_gain",
    "tension|gain|-|per_cable": "tension_sensor_gain", "tension|gain|-|shared": "tension_sensor_gain",
}


def _generalizes(term, effect: str) -> bool:
    """Whether ``term`` is the vocabulary ``effect`` with other sharing (its physics, per cable
    instead of shared or the reverse): no look-alike to name beside it."""
    where, form, driver, _sharing = term.name[len("term:"):].split("|")
    return any(k.startswith(f"{where}|{form}|{driver}|") and v == effect for k, v in VOCABULARY_EQUIVALENT.items())


def _equivalent(term, vocabulary_names) -> bool:
    key = term.name[len("term:"):]
    if term.family.where == "pose" and term.family.form == "offset":
        return "pose_frame_offset" in vocabulary_names
    return VOCABULARY_EQUIVALENT.get(key) in vocabulary_names


class DiscoveryFitter(Fitter):
    """:class:`~fitting.diagnosis.fitter.Fitter` that also fits model lists holding grammar terms
    (names ``term:...``) on a :class:`TermModel` over one compiled vocabulary + probe model."""

    def __init__(self, robot, recordings, law, effects):
        super().__init__(robot, recordings, law, effects)
        self.families = generate_grammar(self.robot, self.data, has_tensions=recordings.has_tensions)
        self.terms = {t.name: t for t in family_terms(self.families)}
        self.by_family = {fam: [t for t in self.terms.values() if t.family == fam] for fam in self.families}
        base = self.models["base"]  # the vocabulary model gains a (never freed) probe: one compile for both
        self.models["base"] = make_model(self.robot, self.data, [*base.effects, Probe()], base.law)
        self._tms = {}

    @property
    def core(self):
        return self.models["base"]

    def term_model(self, term_names) -> TermModel:
        key = tuple(term_names)
        if key not in self._tms:
            self._tms[key] = TermModel(self.core, [self.terms[k] for k in key], self.robot, self.data)
        return self._tms[key]

    def model_for(self, names, screen: bool = False):
        terms = [n for n in names if is_term(n)]
        if not terms:
            return super().model_for(names, screen)
        if "cable_mass" in names:
            raise ValueError("grammar terms cannot be combined with cable_mass (no catenary term model)")
        return self.term_model(terms)

    def evaluator(self, model, weight, columns=None):
        if not isinstance(model, TermModel):
            return super().evaluator(model, weight, columns)
        data = with_weight(self.data, weight)
        core = None if columns is None else [c for c in columns if c < model.core.size]
        return lambda th: model.evaluate(th, self.robot, data, core_columns=core)

    def fit_free(self, model, weight, theta0, free):
        """:meth:`Fitter.fit_free`; a term model's fit runs on the host
        (:func:`fitting.calibration.lm.drive_on_host`) with ``θ`` padded by fixed zeros to a multiple of
        :data:`HOST_WIDTH` entries, so that its kernels compile for a few widths, not once
        per term size (the padded entries are never free: their step is exactly 0; the
        result is trimmed back)."""
        if not isinstance(model, TermModel):
            return super().fit_free(model, weight, theta0, free)
        P = model.size
        pad = -P % HOST_WIDTH
        ev = self.evaluator(model, weight, np.flatnonzero(free))

        def padded(theta):
            r, J, ok = ev(theta[:P])
            return r, np.pad(J, ((0, 0), (0, pad))), ok

        fit = fit_masked(padded, np.pad(theta0, (0, pad)), None, np.pad(free, (0, pad)),
                         must_succeed=np.asarray(weight) > 0, on_host=True)
        return dataclasses.replace(fit, theta=fit.theta[:P], free=fit.free[:P], J=fit.J[:, :P])


class Discovery:
    """The search state of one diagnosis (see module doc)."""

    def __init__(self, diagnoser, vocabulary_names, *, budget_s: float = 60.0, shortlist: int = 4,
                 localized: int = 2):
        self.d = diagnoser
        self.f: DiscoveryFitter = diagnoser.f
        self.vocab = set(vocabulary_names)
        self.budget_s, self.shortlist, self.localized = budget_s, shortlist, localized
        self.spent = 0.0
        self.log: list[dict] = []
        self.localization = None  # channels of the current localization (set by the caller)

    @property
    def exhausted(self) -> bool:
        return self.spent >= self.budget_s

    def structured(self, cur_fit, weight) -> bool:
        """Whether the residual of ``cur_fit`` still fails :mod:`fitting.diagnosis.residual_checks`."""
        keep = np.asarray(weight) > 0
        return residual_structure(self.f.rec, self.f.data, cur_fit[1].r, keep)["structured"]

    def round_terms(self, current, cur_fit, weight) -> list:
        """Grammar candidates for this round, or ``[]`` when the current model leaves
        neither excess χ² nor residual structure."""
        ndata = self.f.num_data(weight)
        thr = explained_threshold(ndata - cur_fit[1].free.sum())
        if chi2_dof(cur_fit[1], ndata) <= thr and not self.structured(cur_fit, weight):
            return []
        return self.candidates(current, cur_fit, weight)

    def defer(self, out, vocabulary_candidates, weight) -> list:
        """The grammar candidates ``out`` compete with the vocabulary by ΔBIC, but a term is
        only selected over a passing vocabulary candidate with strong evidence: its ΔBIC must
        be lower by ``-BIC_THRESHOLD`` than the vocabulary candidate's counted with the
        parameters the data identify (:func:`identified_count`: an effect is not charged for
        directions the recordings leave undetermined), and it must predict recordings the
        vocabulary candidate does not (:func:`same_predictions`). Otherwise the vocabulary
        name wins (``defer`` set); a look-alike sets the vocabulary candidate's
        ``equivalent`` reading."""
        for c in vocabulary_candidates:
            c.equivalent = ""
        passing = [c for c in vocabulary_candidates
                   if np.isfinite(c.delta_bic) and verdict(c, self.d.min_explained, check_cv=False)[0]]
        if not passing:
            return out
        lnN = np.log(self.f.num_data(weight))
        effective = {c.effect: c.delta_bic - (c.k - identified_count(c)) * lnN for c in passing}
        best = min(passing, key=lambda c: effective[c.effect])
        for c in sorted(out, key=lambda c: c.delta_bic):
            fitted = np.isfinite(c.delta_bic)
            term = self.f.terms[c.effect]
            twin = next((v for v in sorted(passing, key=lambda v: v.delta_bic) if fitted
                         and not _generalizes(term, v.effect) and same_predictions(v, c)), None)
            if twin is not None and not twin.equivalent:
                twin.equivalent = f"indistinguishable here from {self.reading(c)}"
            if c.delta_bic > effective[best.effect] + BIC_THRESHOLD:
                counted = "" if effective[best.effect] == best.delta_bic else \
                    " counting the parameters the data identify"
                c.defer = (f"within ΔBIC {-BIC_THRESHOLD:.0f} of the vocabulary's {best.effect} "
                           f"({effective[best.effect]:.1f}{counted}): the vocabulary is preferred")
                if twin is None and fitted and not best.equivalent and not _generalizes(term, best.effect) and \
                        c.delta_bic - best.delta_bic <= LOOK_ALIKE * abs(best.delta_bic):
                    best.equivalent = (f"close to {self.reading(c)}, which fits these recordings worse "
                                       f"(ΔBIC higher by {c.delta_bic - best.delta_bic:.0f})")
                continue
            if twin is not None:
                c.defer, c.defer_physical = (f"predicts the same recordings as the vocabulary's {twin.effect} "
                                             f"(within the noise on these samples): the named effect is "
                                             f"reported, with this reading beside it"), True
        return out

    def reading(self, cand) -> str:
        """The plain-language reading of a fitted grammar candidate (its interpretation)."""
        return describe(self.f.terms[cand.effect], cand.parameters["a"], self.f.data, delta_bic=cand.delta_bic,
                        chi2_per_dof=cand.chi2_per_dof)["interpretation"]

    def report(self, current, cur_fit, weight, drop_one) -> tuple[list, dict]:
        """``(discovered, discovery)``: formats.md §3 entries of the terms in the final
        model, and the search log."""
        out = []
        model, fit = cur_fit
        ndata = self.f.num_data(weight)
        c2 = chi2_dof(fit, ndata)
        for name in (n for n in current if is_term(n)):
            rest = [n for n in current if n != name]
            _, f2 = self.f.fit(rest, weight, (model, fit.theta))
            k = int(fit.free.sum() - f2.free.sum())
            params, _, _ = effect_parameters(model, fit, name, np.sqrt(max(1.0, c2)))
            out.append(describe(self.f.terms[name], params["a"], self.f.data,
                                delta_bic=float(fit.chi2 - f2.chi2 + k * np.log(ndata)), chi2_per_dof=float(c2)))
        log = {"budget_s": self.budget_s, "elapsed_s": self.spent, "budget_exhausted": self.exhausted,
               "grammar_terms": len(self.f.terms), "rounds": self.log, "drop_one": drop_one}
        return out, log

    def candidates(self, current, cur_fit, weight) -> list:
        """Fitted grammar candidates on top of ``current`` (a list of Candidates)."""
        if "cable_mass" in current or self.exhausted:
            if self.exhausted:
                self.log.append({"model": list(current), "skipped": "compute budget spent"})
            return []
        t0 = time.perf_counter()
        ranked = self.score(current, cur_fit, weight)
        picks = [t for t, _ in ranked[: self.shortlist]]
        loc = [t for t, _ in ranked if self._matches_localization(t) and t not in picks][: self.localized]
        out = []
        for i, t in enumerate(loc + picks):
            if i > 0 and time.perf_counter() - t0 + self.spent > self.budget_s:
                break  # the best-placed proposal is always fitted
            out.append(self._candidate(t, current, cur_fit, weight))
        self.spent += time.perf_counter() - t0
        self.log.append({"model": list(current), "scored": len(ranked), "fitted": [c.effect for c in out],
                         "top_scores": [{"term": t.name, "approx_delta_bic": float(s)} for t, s in ranked[:8]],
                         "elapsed_s": time.perf_counter() - t0})
        return out

    def score(self, current, cur_fit, weight):
        """``[(term, approximate ΔBIC)]`` of every admissible term, best first: one
        evaluation of the current model, the probe's sensitivities chained with each
        family's closed-form basis (:func:`~fitting.effects.grammar.basis`), and the score
        test of each term with the current free parameters projected out."""
        f = self.f
        cur_terms = [n for n in current if is_term(n)]
        model = f.model_for(current)
        free = f.free_mask(model, current)
        theta = transfer(cur_fit[0], cur_fit[1].theta, model, np.asarray(model.start) * 0.0, free)
        r, J, _ok = f.evaluator(model, weight)(theta)
        n, c = r.shape
        S = probe_sensitivities(f.core, J)
        r = r.ravel()
        Q, _ = np.linalg.qr(J[:, free])
        lnN = np.log(f.num_data(weight))
        out = []
        for fam in f.families:
            qty, B = basis(fam, f.data, f.robot)
            Jf = chain_basis(S, qty, B, n, c)
            shape = next(s.shape for s in fam.specs(f.robot, f.data) if s.name == "a")
            for t in f.by_family[fam]:
                if t.name in cur_terms or _equivalent(t, self.vocab):
                    continue
                Jt = Jf[:, t.entries(shape)]  # rows of left-out samples are zero (weighted residuals)
                Jt = Jt - Q @ (Q.T @ Jt)
                if not np.any(np.abs(Jt) > 0):
                    continue
                g = Jt.T @ r
                s = float(g @ np.linalg.lstsq(Jt.T @ Jt, g, rcond=1e-10)[0])
                out.append((t, -s + Jt.shape[1] * lnN))
        names = f.data.covariate_names  # ranked with the evidence an implausible correction needs
        out.sort(key=lambda x: x[1] + plausibility(x[0], names)[0])
        return out

    def _matches_localization(self, term) -> bool:
        ch = (self.localization or [{}])[0]
        cov = ch.get("correlates_with")
        if not cov:
            return False
        name = driver_name(term, self.f.data.covariate_names)
        return name is not None and (name == cov or (name.endswith("_i") and cov.startswith(name[:-1])))

    def _candidate(self, t, current, cur_fit, weight):
        f = self.f
        ndata = f.num_data(weight)
        cur_model, cur = cur_fit
        model, fit = f.fit([*current, t.name], weight, (cur_model, cur.theta))
        if fit.steps == 0 and not fit.converged:
            return Candidate(t.name, np.inf, np.inf, {}, 0, 0.0, 0.0, False, 0.0, reason=fit.message)
        k = int(fit.free.sum() - cur.free.sum())
        c2 = chi2_dof(fit, ndata)
        params, wald, ident = effect_parameters(model, fit, t.name, np.sqrt(max(1.0, c2)))
        excess = cur.chi2 - (ndata - cur.free.sum())
        cand = Candidate(t.name, float(fit.chi2 - cur.chi2 + k * np.log(ndata)), float(c2), params, k, wald,
                         wald_critical(k), ident, float((cur.chi2 - fit.chi2) / max(excess, 1e-9)))
        cand.physical = physical_problem(t, params, f.robot, f.data)
        cand.penalty, cand.plausibility = plausibility(t, f.data.covariate_names)
        cand.fit = (model, fit)
        return cand


def identified_count(cand) -> int:
    """How many directions of a fitted candidate's parameters the recordings identify: the
    singular values above 1 of its Jacobian columns (θ, each in units of its parameter's
    typical scale) with the model's other free parameters projected out, i.e. the directions
    whose standard deviation is below the parameter's typical magnitude. At most ``cand.k``."""
    model, fit = cand.fit
    block = np.zeros(fit.free.shape, bool)
    block[model.block_slice(model.effect_index(cand.effect))] = True
    own, rest = fit.free & block, fit.free & ~block
    J = np.asarray(fit.J)
    Jb = J[:, own]
    if rest.any():
        Q, _ = np.linalg.qr(J[:, rest])
        Jb = Jb - Q @ (Q.T @ Jb)
    sv = np.linalg.svd(Jb, compute_uv=False) if Jb.size else np.zeros(0)
    return int(min(cand.k, np.sum(sv > 1.0)))


LOOK_ALIKE = 0.01  # a term whose ΔBIC is within this share of a vocabulary effect's is named beside it
EQUIVALENCE_P = 1e-3  # two fits predict the same recordings when their difference is this likely as noise


def same_predictions(a, b) -> bool:
    """Whether two fitted candidates predict the same recordings within the noise on these
    samples: the squared difference of their whitened residuals (both fits, every sample in
    the fit) stays below the χ² quantile ``1 - EQUIVALENCE_P`` with as many degrees of freedom
    as the two fits' new parameters together (what fitting the noise alone can make them
    differ by)."""
    from scipy import special

    ra, rb = np.asarray(a.fit[1].r), np.asarray(b.fit[1].r)
    if ra.shape != rb.shape:
        return False
    diff = float(np.sum((ra - rb) ** 2))
    return diff <= float(special.chdtri(max(a.k + b.k, 1), EQUIVALENCE_P))


def prune(d, current, cur_fit, weight):
    """Drop-one re-check of every selected effect and term against the final model.

    Repeatedly removes the entry whose removal raises the BIC least, while that rise is
    below ``-BIC_THRESHOLD`` (the evidence an entry needs to be selected at all).

    **Returns:** ``(current, cur_fit, log)``; ``log`` lists ``{entry, delta_bic_drop, dropped}``.
    """
    f = d.f
    log = []
    lnN = np.log(f.num_data(weight))
    while len(current) > 1:
        model, fit = cur_fit
        rows = []
        for name in current:
            rest = [c for c in current if c != name]
            m2, f2 = f.fit(rest, weight, (model, fit.theta))
            k = int(fit.free.sum() - f2.free.sum())
            rows.append((f2.chi2 - fit.chi2 - k * lnN, name, (m2, f2)))
        rows.sort(key=lambda x: x[0])
        worst = rows[0]
        log += [{"entry": nm, "delta_bic_drop": float(db), "dropped": nm == worst[1] and db < -BIC_THRESHOLD}
                for db, nm, _ in rows]
        if worst[0] >= -BIC_THRESHOLD:
            break
        current = [c for c in current if c != worst[1]]
        cur_fit = worst[2]
    return current, cur_fit, log


def driver_name(term, covariate_names) -> str | None:
    """Recording-column name of a term's driver (``temperature``, ``time``, ``fz``, ``l0_i``,
    ``t_3``, ``dir_i``), ``index`` for the sample index, None for undriven forms."""
    k = term.driver
    if k is None:
        return None
    if k.startswith("cov:"):
        return covariate_names[int(k[4:])]
    if k.startswith("w:"):
        return WRENCH_NAMES[int(k[2:])]
    if k.startswith("t:"):
        return schema.cable_column("t", int(k[2:]) + 1)
    return {"own_l0": schema.cable_column("l0", "i"), "dir": "dir_i"}.get(k, k)
