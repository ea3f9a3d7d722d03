"""The ``small_sag`` cable law (Irvine's small-sag theory, cstiffjax.statics.forward) and the
diagnosis's screen of ``cable_mass`` with it (fitting.diagnosis.diagnose, fitting.diagnosis.fitter).

References independent of the law's code: the elastic catenary (closed-form spans solved
jointly with the pose), the cubic itself, central differences, and the bilateral law."""

import types

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cstiffjax.cable.laws import CableLaw
from cstiffjax.examples import example_path
from cstiffjax.io.recordings import load_recordings
from cstiffjax.io.robot_io import load_robot
from cstiffjax.statics.forward import StaticsProblem, forward_statics
from cstiffjax.statics.residuals import sag_root
from fitting.diagnosis.fitter import Fitter
from fitting.diagnosis.rounds import needs_catenary
from fitting.diagnosis.selection import BIC_THRESHOLD, Candidate
from fitting.effects import VOCABULARY


def _fd(f, x, h):
    """Central differences of ``f`` at ``x`` with a step ``h[j]`` per input (columns = inputs)."""
    cols = []
    for j in range(x.size):
        e = np.zeros_like(x)
        e[j] = h[j]
        cols.append((np.asarray(f(jnp.asarray(x + e))) - np.asarray(f(jnp.asarray(x - e)))) / (2 * h[j]))
    return np.stack(cols, -1)


def _case(name):
    robot = load_robot(example_path(f"{name}/robot.toml"))
    return robot, load_recordings(example_path(f"{name}/recordings.csv"), robot)


def _with_mass(robot, mu):
    return eqx.tree_at(lambda r: r.mass_per_length, robot, jnp.full_like(robot.mass_per_length, mu))


@eqx.filter_jit
def _changes(robot, l0, wrench, pose0, mus, law):
    """(pose, exit tensions) change from the weightless bilateral equilibrium, per mass per
    length ``mus`` (k,) and sample: ``(k, n, 6 + m)``."""
    def one(mu, l0, w, p0):
        rb = _with_mass(robot, mu)
        ref = forward_statics(StaticsProblem(_with_mass(robot, 0.0), l0, w, CableLaw.bilateral), pose0=p0,
                              start="warm")
        fs = forward_statics(StaticsProblem(rb, l0, w, law), pose0=ref.pose, start="warm")
        return jnp.concatenate([fs.pose - ref.pose, fs.tensions - ref.tensions])
    return jax.vmap(lambda mu: jax.vmap(lambda a, b, c: one(mu, a, b, c))(l0, wrench, pose0))(mus)


@pytest.mark.parametrize("name", ["concealed", pytest.param("pulleys8", marks=pytest.mark.slow)])
def test_small_sag_follows_the_elastic_catenary(name):
    """Straight cables (concealed, 6 cables) and 2.5 cm swivel pulleys (pulleys8): the law's
    change of the pose and of the tensions against the catenary's, up to a heavy
    0.25 kg/m; the relative error falls with the mass (it is the sag's higher orders)."""
    robot, rec = _case(name)
    idx = np.array([0, 7, 19])
    args = (rec.l0[idx], rec.wrench[idx], rec.pose[idx], jnp.array([0.25, 0.1, 0.01]))
    cat = np.asarray(_changes(robot, *args, CableLaw.catenary))
    sag = np.asarray(_changes(robot, *args, CableLaw.small_sag))
    err = np.abs(sag - cat)
    rel_pose = err[..., :6].max(axis=(1, 2)) / np.abs(cat[..., :6]).max(axis=(1, 2))
    rel_ten = err[..., 6:].max(axis=(1, 2)) / np.abs(cat[..., 6:]).max(axis=(1, 2))
    assert np.all(np.abs(cat[0, :, 6:]).max(axis=1) > 1.0)  # the weight moves the tensions by newtons
    assert np.all(rel_pose < 3e-3) and np.all(rel_ten < 2e-2), (rel_pose, rel_ten)
    assert rel_ten[2] < 0.2 * rel_ten[0]


def test_small_sag_without_cable_weight_is_the_bilateral_law():
    """Warm: the bilateral law's Newton iterates (equal to rounding); cold: its equilibrium
    (the cold start's second LM stage starts from the bilateral solution)."""
    robot, rec = _case("concealed")
    rb = _with_mass(robot, 0.0)

    @eqx.filter_jit
    def run(l0, w, p):
        fs = [forward_statics(StaticsProblem(rb, l0, w, law), pose0=p, start=start)
              for law, start in ((CableLaw.small_sag, "warm"), (CableLaw.bilateral, "warm"),
                                 (CableLaw.small_sag, "cold"))]
        return [jnp.concatenate([f.pose, f.tensions, f.tensions_attachment, f.forces.ravel()]) for f in fs]

    sag_warm, bil_warm, sag_cold = (np.asarray(x) for x in jax.vmap(run)(rec.l0[:5], rec.wrench[:5], rec.pose[:5]))
    np.testing.assert_allclose(sag_warm, bil_warm, rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(sag_cold, bil_warm, rtol=1e-9, atol=1e-8)


def test_sag_root_solves_the_cubic_and_its_derivative_is_implicit():
    rng = np.random.default_rng(3)
    a = np.concatenate([rng.uniform(1.0, 500.0, 20), rng.uniform(-50.0, -0.1, 10), [0.0]])
    c = np.concatenate([10 ** rng.uniform(-3, 6, 30), [5.0]])
    T = np.asarray(sag_root(jnp.asarray(a), jnp.asarray(c)))
    assert np.all(T > 0) and np.all(T > a)
    # a root to rounding: the cubic's residual within a few ulps of its terms' size
    assert np.all(np.abs(T * T * (T - a) - c) <= 1e-14 * (T**3 + np.abs(a) * T * T + c))
    np.testing.assert_array_equal(np.asarray(sag_root(jnp.asarray(a), jnp.zeros_like(jnp.asarray(a)))), a)
    for i in (0, 25):  # a positive and a negative a
        x = np.array([a[i], c[i]])
        fd = _fd(lambda v: sag_root(v[0:1], v[1:2]), x, 1e-6 * np.abs(x))
        ad = jax.jacfwd(lambda v: sag_root(v[0:1], v[1:2]))(jnp.asarray(x))
        np.testing.assert_allclose(np.asarray(ad), fd, rtol=1e-6)


def test_small_sag_implicit_derivative_matches_fd():
    """d(pose, tensions)/d(mass per length, EA) through the warm solve, against central
    differences of fresh solves."""
    robot, rec = _case("pulleys8")
    l0, w, p0 = rec.l0[3], rec.wrench[3], rec.pose[3]

    def f(x):
        rb = eqx.tree_at(lambda r: (r.mass_per_length, r.EA), robot,
                         (jnp.full_like(robot.mass_per_length, x[0]), robot.EA * x[1]))
        fs = forward_statics(StaticsProblem(rb, l0, w, CableLaw.small_sag), pose0=p0, start="warm")
        return jnp.concatenate([fs.pose, fs.tensions])

    x = jnp.array([0.1, 1.0])
    ad = np.asarray(jax.jit(jax.jacfwd(f))(x))
    fd = _fd(jax.jit(f), np.asarray(x), np.array([1e-5, 1e-6]))
    scale = np.abs(fd).max(axis=0)
    np.testing.assert_allclose(ad / scale, fd / scale, atol=2e-6)


# ----------------------------------------------------------------- the diagnosis's screen
def _cand(effect, dbic, accepted=False, law=CableLaw.spring):
    return Candidate(effect, dbic, 1.0, {}, 1, 0.0, 0.0, True, 0.0, accepted=accepted, law=law)


def test_the_catenary_is_fitted_when_the_screen_could_win():
    winner = _cand("exit_friction", -23903.0, accepted=True)
    assert not needs_catenary(_cand("cable_mass", -60.0, law=CableLaw.small_sag), [winner])  # bundled example
    assert needs_catenary(_cand("cable_mass", -5000.0, law=CableLaw.small_sag), [winner])  # 20 % of the winner's
    assert needs_catenary(_cand("cable_mass", -30000.0, law=CableLaw.small_sag), [winner])  # better than the winner
    assert needs_catenary(_cand("cable_mass", np.inf, law=CableLaw.small_sag), [winner])  # the screen failed
    nothing = [_cand("length_offset", 5.0)]  # nothing selected: against the BIC threshold
    assert needs_catenary(_cand("cable_mass", 0.2 * BIC_THRESHOLD, law=CableLaw.small_sag), nothing)
    assert not needs_catenary(_cand("cable_mass", 1.0, law=CableLaw.small_sag), nothing)


def test_fitter_screens_cable_mass_on_a_spring_baseline_only():
    robot, rec = _case("concealed")
    f = Fitter(robot, rec, CableLaw.spring, VOCABULARY)
    assert f.screens_mass
    # round 1: the screen alone (the smallest program); later rounds: beside every spring effect
    assert f.model_for(["cable_mass"], screen=True) is f.models["screen"]
    assert [e.name for e in f.models["screen"].effects] == ["cable_mass"]
    assert f.models["screen"].law is CableLaw.small_sag
    assert f.model_for(["anchor_offset", "cable_mass"], screen=True) is f.models["screen+"]
    assert f.models["screen+"].law is CableLaw.small_sag
    assert f.model_for(["cable_mass"]) is f.models["cat"] and f.models["cat"].law is CableLaw.catenary
    assert f.model_for(["anchor_offset"], screen=True) is f.models["base"]
    assert {e.name for e in f.models["screen+"].effects} == {e.name for e in VOCABULARY}
    c = Fitter(robot, rec, CableLaw.catenary, VOCABULARY)
    assert not c.screens_mass and c.model_for(["cable_mass"], screen=True) is c.models["cat"]


def test_a_round_screens_only_the_cable_mass_candidate_and_refits_it_when_it_could_win(monkeypatch):
    """The round's orchestration (fits replaced by canned candidates): ``cable_mass`` is the
    only screened candidate; a screen that could win is refitted on the catenary and the
    selection made again (the catenary's fit wins here); with ``cable_mass`` already in the
    model every candidate is fitted without the screen."""
    from fitting.diagnosis.rounds import Diagnoser

    dbic = {("anchor_offset", False): -50.0, ("cable_mass", True): -40.0, ("cable_mass", False): -60.0,
            ("length_offset", False): -20.0}
    calls = []

    def candidate(self, name, current, cur_fit, weight, screen=False):
        calls.append((tuple(current), name, screen))
        law = CableLaw.small_sag if screen else CableLaw.catenary if name == "cable_mass" else CableLaw.spring
        c = Candidate(name, dbic[name, screen], 1.0, {}, 1, 100.0, 10.0, True, 1.0, law=law)
        c.fit = (None, types.SimpleNamespace(free=np.ones(2, bool)))
        return c

    ahead = []
    d = Diagnoser.__new__(Diagnoser)
    d.names, d.progress, d.discovery, d.min_explained = ["anchor_offset", "cable_mass"], False, None, 0.5
    d.f = types.SimpleNamespace(screens_mass=True, num_data=lambda weight: 100,
                                compile_ahead=lambda names, screen=False: ahead.append((tuple(names), screen)))
    monkeypatch.setattr(Diagnoser, "_candidate", candidate)
    monkeypatch.setattr(Diagnoser, "cv", lambda self, names, weight, fit: 1.0)
    out = d.round([], None, None, lambda: 2.0)
    assert calls == [((), "anchor_offset", False), ((), "cable_mass", True), ((), "cable_mass", False)]
    assert ahead == [(("cable_mass",), False)]  # the screen (-40) is sure to need the catenary: compiled ahead
    mass = next(c for c in out if c.effect == "cable_mass")
    assert mass.law is CableLaw.catenary and mass.screen_delta_bic == -40.0 and mass.accepted and out[0] is mass
    assert not next(c for c in out if c.effect == "anchor_offset").accepted
    calls.clear()
    d.names = ["length_offset", "cable_mass"]
    d.round(["cable_mass"], None, None, lambda: 2.0)
    assert calls == [(("cable_mass",), "length_offset", False)]


def _fitted(name, r):
    """A candidate's ``fit``, ``(model, fit)``, as far as deferring reads it: the model's one
    effect ``name`` with one parameter, identified (its whitened Jacobian column 10 per datum,
    :func:`fitting.diagnosis.discover.identified_count` 1), and the whitened residuals ``r``."""
    def effect_index(effect):
        assert effect == name, effect
        return 0

    model = types.SimpleNamespace(effect_index=effect_index, block_slice=lambda i: slice(0, 1))
    return model, types.SimpleNamespace(free=np.array([True]), J=np.full((len(r), 1), 10.0), r=np.asarray(r))


def test_the_terms_defer_to_the_catenary_fit_not_to_the_screen_it_replaced(monkeypatch):
    """A grammar term within ΔBIC 10 of the screen (-95 vs -100) yields to it; once the
    catenary's fit (-80) replaces the screen, the term is 15 better and is selected."""
    from fitting.diagnosis.discover import Discovery
    from fitting.diagnosis.rounds import Diagnoser

    dbic = {("cable_mass", True): -100.0, ("cable_mass", False): -80.0}

    def candidate(self, name, current, cur_fit, weight, screen=False):
        c = Candidate(name, dbic[name, screen], 1.0, {}, 1, 100.0, 10.0, True, 1.0,
                      law=CableLaw.small_sag if screen else CableLaw.catenary)
        c.fit = _fitted(name, np.ones(100))
        return c

    d = Diagnoser.__new__(Diagnoser)
    d.names, d.progress, d.min_explained = ["cable_mass"], False, 0.5
    d.f = types.SimpleNamespace(screens_mass=True, num_data=lambda weight: 100, compile_ahead=lambda *a, **k: None)
    d.discovery = Discovery.__new__(Discovery)
    d.discovery.d = d
    name = "term:l0|offset|-|shared"
    term = Candidate(name, -95.0, 1.0, {}, 1, 100.0, 10.0, True, 1.0)
    term.fit = _fitted(name, np.zeros(100))  # predicts other recordings than cable_mass (χ² 100 apart)
    # the search's fitter, as far as deferring reads it: its terms and the number of data
    d.discovery.f = types.SimpleNamespace(terms={name: types.SimpleNamespace(name=name)}, num_data=lambda weight: 100)
    monkeypatch.setattr(Discovery, "round_terms", lambda self, current, cur_fit, weight: [term])
    monkeypatch.setattr(Diagnoser, "_candidate", candidate)
    monkeypatch.setattr(Diagnoser, "cv", lambda self, names, weight, fit: 1.0)
    out = d.round([], None, None, lambda: 2.0)
    assert term.accepted and term.defer == "" and out[0] is term
    assert next(c for c in out if c.effect == "cable_mass").law is CableLaw.catenary


def test_later_rounds_compile_the_screen_beside_the_selection_ahead(monkeypatch):
    """Round 1 screens ``cable_mass`` alone (compiled ahead at the start); once an effect is
    selected, the next round queues the screen model that holds every spring effect
    (``screen+``) in the background, once, before its candidates (the screen is fitted last).
    Rounds replaced by canned ones; the baseline fit is real (12 samples)."""
    from fitting.diagnosis import diagnose as D
    from fitting.diagnosis.fitter import Fitter as F
    from fitting.diagnosis.rounds import Diagnoser

    robot, rec = _case("concealed")
    rec = rec.select(np.arange(12))
    queued, rounds = [], []

    def fit_job(self, model, names):  # what compile_ahead hands to the thread: recorded, never compiled
        queued.append((model, "cable_mass" in names))
        return ("fit", model, lambda: None)

    monkeypatch.setattr(F, "_fit_job", fit_job)
    monkeypatch.setattr(F, "compile_walkers", lambda self, model: None)
    picks = ["length_offset", "tension_sensor_bias"]  # each leaves excess χ²: three rounds

    def round_(self, current, cur_fit, weight, cur_cv):
        rounds.append(list(current))
        if len(current) == len(picks):
            return []
        name = picks[len(current)]
        c = Candidate(name, -100.0, 50.0, {}, 1, 100.0, 10.0, True, 1.0)
        c.accepted, c.fit = True, self.f.fit([*current, name], weight)
        return [c]

    monkeypatch.setattr(Diagnoser, "round", round_)
    effects = tuple(e for e in VOCABULARY if e.name in ("cable_mass", "exit_friction", *picks))
    d = D.diagnose(robot, rec, effects=effects, posterior_steps=0, discover=False, detect_outliers=False)
    f = F(robot, rec, CableLaw.spring, effects)
    assert rounds == [[], picks[:1], picks] and set(d.effects) <= set(picks)  # (the drop-one re-check may prune)
    assert [(m.law, [e.name for e in m.effects], s) for m, s in queued] == [
        (CableLaw.small_sag, ["cable_mass"], True),  # round 1, at the start
        (CableLaw.small_sag, [e.name for e in f.models["screen+"].effects], True)]  # round 2 (not again in round 3)
