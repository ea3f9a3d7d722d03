"""Effects library and the extended model: identity at null, hooks, forward statics
against the independent solvers of cstiffjax.statics.geometry / cstiffjax.cable.catenary, autodiff
Jacobian against finite differences, bad inputs."""

from types import SimpleNamespace

import equinox as eqx
import jax
import jax.extend.core
import jax.numpy as jnp
import numpy as np
import pytest

from cstiffjax import CableLaw, StaticsProblem, load_recordings, load_robot
from cstiffjax.core import lie
from cstiffjax.examples import example_path
from cstiffjax.statics import forward as fwd
from cstiffjax.statics import geometry as statics
from fitting.effects import (
    EFFECTS,
    VOCABULARY,
    CableMass,
    ExitFriction,
    LengthOffset,
    NonlinearElasticity,
    PlatformMass,
    PoseFrameOffset,
    TensionSensorBias,
    build_data,
    get_effect,
    make_model,
)
from fitting.effects import model as M

N = 6
_predict = eqx.filter_jit(M.predict)


@pytest.fixture(scope="module")
def setup():
    rb = load_robot(example_path("example02/robot.toml"))
    rec = load_recordings(example_path("example02/recordings.csv"), rb).select(np.arange(N))
    data = build_data(rec)
    spring = [e for e in VOCABULARY if e.name != "cable_mass"]
    model = make_model(rb, data, spring)
    return rb, rec, data, model


def _width(model):
    return -(-model.size // M.CHUNK) * M.CHUNK


def _padded(cols, model):
    """``cols`` padded with -1 to the one length every call on ``model`` uses (one compile)."""
    cols = np.asarray(cols, dtype=int)
    return jnp.asarray(np.concatenate([cols, np.full(_width(model) - len(cols), -1)]))


def _evaluate(model, theta, rb, data):
    """Residuals and the full Jacobian (every column asked for explicitly, so that the
    column tests below share this call's compiled program)."""
    return [np.asarray(a) for a in M.residuals_and_jacobian(model, jnp.asarray(theta), rb, data,
                                                            _padded(np.arange(model.size), model))]


def test_the_chunks_share_one_solve_of_the_equilibria(setup):
    """``residuals_and_jacobian`` solves the equilibria once per call (``_solutions``, at
    the call's θ) and each chunk takes only the implicit steps from there: its residuals
    are those of :func:`residuals` solving on its own, to the rounding of two programs (a
    solve at another θ would differ by its Newton step squared, ~1e-4). Its Jacobian is
    checked against finite differences above."""
    rb, _rec, data, model = setup
    theta = jnp.asarray(np.random.default_rng(4).normal(0, 0.3, model.size))
    r, _J, ok = (np.asarray(a) for a in M.residuals_and_jacobian(model, theta, rb, data,
                                                                  _padded(np.arange(model.size), model)))
    r_own, ok_own = eqx.filter_jit(M.residuals)(model, theta, rb, data)
    np.testing.assert_allclose(r, np.asarray(r_own), rtol=1e-8, atol=1e-8)
    np.testing.assert_array_equal(ok, np.asarray(ok_own))
    assert ok.all()


def test_vocabulary_matches_formats_table():
    assert [e.name for e in VOCABULARY] == [
        "cable_mass", "anchor_offset", "length_offset", "length_drift", "tension_sensor_bias",
        "pose_frame_offset", "exit_friction", "nonlinear_elasticity", "platform_mass",
        "pulley_kinematics", "length_gain", "tension_sensor_gain", "attachment_offset"]
    for e in VOCABULARY:
        assert e.summary


def test_null_parameters_are_the_nominal_model(setup):
    rb, _rec, data, model = setup
    empty = make_model(rb, data, [])
    r_all, _, ok_all = _evaluate(model, np.zeros(model.size), rb, data)
    r_nom, _, ok_nom = _evaluate(empty, np.zeros(empty.size), rb, data)
    assert ok_all.all() and ok_nom.all()
    np.testing.assert_allclose(r_all, r_nom, atol=1e-9)


@pytest.mark.slow
def test_spring_prediction_matches_optimistix_forward_statics(setup):
    rb, rec, data, _ = setup
    empty = make_model(rb, data, [])
    pose, t, _ok = _predict(empty, jnp.zeros(empty.size), rb, data)
    for i in range(3):
        fs = fwd.forward_statics(StaticsProblem(rb, rec.l0[i], rec.wrench[i], CableLaw.spring), pose0=rec.pose[i])
        np.testing.assert_allclose(np.asarray(pose[i]), np.asarray(fs.pose), atol=1e-10)
        np.testing.assert_allclose(np.asarray(t[i]), np.asarray(fs.tensions), rtol=1e-8)


@pytest.mark.slow  # catenary model compile (~45 s)
def test_catenary_equilibrium_satisfies_per_cable_catenary_solver(setup):
    """The joint (pose, H, V) Newton solve vs the per-cable optimistix catenary of cstiffjax."""
    rb, rec, data, _ = setup
    model = make_model(rb, data, [CableMass()])
    theta = np.zeros(model.size)
    theta[6] = 0.251 / 0.05  # 8 mm steel rope
    pose, t, ok = _predict(model, jnp.asarray(theta), rb, data)
    assert np.asarray(ok).all()
    heavy = eqx.tree_at(lambda r: r.mass_per_length, rb, jnp.full(6, 0.251))

    @jax.jit
    def reference(pose, l0, ext):  # per-cable optimistix catenary solves of cstiffjax
        W = statics.elastic_wrench(heavy, pose, l0, ext, law=CableLaw.catenary)
        return W, statics.elastic_cable_forces(heavy, pose, l0, law=CableLaw.catenary).tension_anchor

    W, t_ref = jax.vmap(reference)(pose, rec.l0, rec.wrench)
    assert np.max(np.abs(np.asarray(W))) < 1e-7 * (30 * 9.81)
    np.testing.assert_allclose(np.asarray(t), np.asarray(t_ref), rtol=1e-9)
    # the sag moves the platform by millimetres: the effect is visible at 2e-5 m noise
    empty = make_model(rb, data, [])
    pose0, _, _ = _predict(empty, jnp.zeros(empty.size), rb, data)
    assert np.max(np.abs(np.asarray(pose - pose0)[:, :3])) > 1e-3


@pytest.mark.slow  # catenary model compile (~45 s)
def test_catenary_at_zero_mass_is_the_spring(setup):
    rb, _rec, data, _ = setup
    model = make_model(rb, data, [CableMass()])
    empty = make_model(rb, data, [])
    pc, tc, _ = _predict(model, jnp.zeros(model.size), rb, data)
    ps, ts, _ = _predict(empty, jnp.zeros(empty.size), rb, data)
    np.testing.assert_allclose(np.asarray(pc), np.asarray(ps), atol=1e-10)
    np.testing.assert_allclose(np.asarray(tc), np.asarray(ts), rtol=1e-8)


_solutions = eqx.filter_jit(M._solutions)
_chord_start = eqx.filter_jit(M.chord_start)


def _from_a_chord_start(model, rb, data, theta, step=0.01):
    """At ``theta + step`` (1 % of EA: a few posterior standard deviations): the chord
    start from ``theta`` (the posterior walkers' start),
    the predictions from it and from the measured poses, and the Newton linearizations of
    both solves (``num_steps``: applied steps plus the converged one)."""
    centre, near = jnp.asarray(theta), jnp.asarray(theta + step)
    start = _chord_start(model, near, rb, data, centre, _solutions(model, centre, rb, data))
    steps = [np.asarray(_solutions(model, near, rb, data, s).num_steps) for s in (start, None)]
    return start, _predict(model, near, rb, data, start), _predict(model, near, rb, data), steps


def _reaches_the_same_equilibrium(model, rb, data, theta):
    (pose_s, forces_s), (p1, t1, ok1), (p0, t0, ok0), (n1, n0) = _from_a_chord_start(model, rb, data, theta)
    assert np.asarray(ok1).all() and np.asarray(ok0).all()
    assert np.max(np.abs(np.asarray(p1 - pose_s))) > 1e-12  # the start is not the answer
    np.testing.assert_allclose(np.asarray(p1), np.asarray(p0), atol=1e-12)
    np.testing.assert_allclose(np.asarray(t1), np.asarray(t0), rtol=1e-10)
    return pose_s, forces_s, n1, n0


@pytest.mark.slow  # the fast set checks the catenary start below
def test_a_chord_start_reaches_the_same_equilibrium_in_one_newton_step(setup):
    """``predict(..., start=chord_start(θ + δ from θ))`` (the posterior walkers' start) is
    the prediction from the measured poses; Newton applies one step from it and stops at
    the next linearization (from the measured poses: two steps and the third), so a
    start that were ignored, or predicted with a wrong derivative, fails here."""
    rb, _rec, data, _ = setup
    model = make_model(rb, data, [ExitFriction()])
    theta = np.full(model.size, 0.1)
    pose_s, forces_s, n1, n0 = _reaches_the_same_equilibrium(model, rb, data, theta)
    assert pose_s.shape == (N, 6) and forces_s.shape == (N, 2, 6)
    assert np.all(n1 == 2) and np.all(n0 >= 3), (n1, n0)
    _, _, ok_bad = _predict(model, jnp.asarray(theta + 0.01), rb, data, (pose_s * np.nan, forces_s))
    assert not np.asarray(ok_bad).any()  # the start's pose is used


def test_catenary_chord_start_reaches_the_same_equilibrium(setup):
    """Catenary law: the chord start's end forces replace the spring stage; the same
    equilibrium, with one Newton step and the converged one instead of the spring stage's
    solve and the joint one (~9 s of compiles)."""
    rb, _rec, data, _ = setup
    model = make_model(rb, data, [CableMass()])
    theta = np.zeros(model.size)
    theta[6] = 0.251 / 0.05
    pose_s, forces_s, n1, n0 = _reaches_the_same_equilibrium(model, rb, data, theta)
    assert np.all(n1 == 2) and np.all(n0 >= 5), (n1, n0)
    # the start's end forces are used (not the spring stage): unusable ones fail every sample
    _, _, ok_bad = _predict(model, jnp.asarray(theta + 0.01), rb, data, (pose_s, forces_s * np.nan))
    assert not np.asarray(ok_bad).any()


def test_the_chord_start_is_the_equilibria_to_first_order(setup):
    """``chord_start(c + δ)`` predicts the equilibria at ``c + δ`` from those at ``c``: it
    is the equilibria at ``c``; its derivative there (central differences, step ``h δ``)
    is the implicit-function derivative of the solved equilibria (their central
    differences); its error is second order (halving ``δ`` quarters it). Spring law,
    every parameter moved, effects that enter the statics through each hook: the inputs
    (length offsets), the tensions (nonlinear elasticity) and the robot (platform mass)."""
    rb, _rec, data, _ = setup
    model = make_model(rb, data, [LengthOffset(), NonlinearElasticity(), PlatformMass()])
    c = jnp.asarray(np.full(model.size, 0.1))
    delta = jnp.asarray(np.random.default_rng(3).standard_normal(model.size))
    eq = eqx.filter_jit(M.equilibria)
    solved = _solutions(model, c, rb, data)

    def start(x):
        return _chord_start(model, c + x * delta, rb, data, c, solved)

    for a, b in zip(start(0.0), eq(model, c, rb, data)):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=0, atol=1e-12)
    h = 1e-4
    fd = [(a - b) / (2 * h) for a, b in zip(eq(model, c + h * delta, rb, data), eq(model, c - h * delta, rb, data))]
    slope = [(a - b) / (2 * h) for a, b in zip(start(h), start(-h))]
    # relative to the largest entry: the end forces are stiff in the pose, so the two
    # differences' O(h²) terms differ by ~1e-6 of them (here 1.7e-6 of 19.9 N, the pose's
    # 6.5e-9 of 0.048 m; with exit friction and a sensor bias 1.9e-5 of 4.8 N, 1.8e-3 at h = 1e-3)
    for got, d, tol in zip(slope, fd, (1e-7, 2e-5)):
        got, d = np.asarray(got), np.asarray(d)
        assert np.abs(got - d).max() <= tol * np.abs(d).max(), (np.abs(got - d).max(), np.abs(d).max())
    assert np.abs(np.asarray(fd[0])).max() > 1e-4  # the equilibria do move
    err = [np.abs(np.asarray(start(x)[0] - eq(model, c + x * delta, rb, data)[0])).max() for x in (0.02, 0.01)]
    assert err[1] > 1e-10 and 3.0 < err[0] / err[1] < 5.0, err  # second order, not exact


def test_catenary_chord_start_keeps_half_the_horizontal_force(monkeypatch):
    """A catenary chord start whose extrapolated ``H`` falls below half of its value at the
    centre is raised to that half (``V_B``, the pose and the other ``H`` untouched); a
    spring start is returned as evaluated. ``_statics`` stubbed: the clamp's own logic."""
    pose = jnp.zeros((2, 6))
    at_theta = jnp.asarray([[[10.0, -1.0, 40.0], [5.0, 6.0, 7.0]], [[30.0, 2.0, 3.0], [8.0, 9.0, 1.0]]])
    at_centre = jnp.asarray([[[12.0, 12.0, 12.0], [0.0, 0.0, 0.0]], [[40.0, 40.0, 40.0], [0.0, 0.0, 0.0]]])
    centre = jnp.zeros(3)
    monkeypatch.setattr(M, "_statics", lambda model, t, *a, **k: M.SampleStatics(
        None, None, None, pose, at_centre if t is centre else at_theta))
    got_pose, got = M.chord_start(SimpleNamespace(law=CableLaw.catenary), jnp.ones(3), None, None, centre, None)
    want = at_theta.at[0, 0].set(jnp.asarray([10.0, 6.0, 40.0])).at[1, 0].set(jnp.asarray([30.0, 20.0, 20.0]))
    np.testing.assert_array_equal(np.asarray(got), np.asarray(want))
    assert got_pose is pose
    _, spring = M.chord_start(SimpleNamespace(law=CableLaw.spring), jnp.ones(3), None, None, centre, None)
    assert spring is at_theta


def _nested_programs(jaxpr, out):
    """Names of the nested ``jit`` programs anywhere in ``jaxpr`` (loop bodies included)."""
    for eqn in jaxpr.eqns:
        if eqn.primitive.name in ("pjit", "jit"):
            out.append(eqn.params["name"])
        for sub in jax.extend.core.jaxprs_in_params(eqn.params):
            _nested_programs(sub, out)
    return out


def _measured(out):
    """The predicted measurements of a :class:`~fitting.effects.model.SampleStatics`."""
    return out.pose, out.tensions, out.ok


def test_values_only_statics_trace_forward_statics_inline(setup):
    """The posterior's values-only statics trace ``forward_statics`` inline (batching its
    nested program a second time cost the ensemble's trace ~0.55 s); the fitting loop's,
    with derivatives, keep it a nested program. The same numbers either way."""
    rb, _rec, data, _ = setup
    model = make_model(rb, data, [ExitFriction()])
    theta = jnp.asarray(np.full(model.size, 0.1))

    def names(derivatives):
        f = lambda t: _measured(M._statics(model, t, rb, data, derivatives=derivatives))  # noqa: E731
        return _nested_programs(jax.make_jaxpr(f)(theta).jaxpr, [])

    assert "forward_statics" in names(True)
    assert "forward_statics" not in names(False) and names(False)  # (other nested programs remain)
    run = eqx.filter_jit(lambda t, d: _measured(M._statics(model, t, rb, data, derivatives=d)))
    for a, b in zip(run(theta, True), run(theta, False)):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-12, atol=1e-12)


def test_jacobian_matches_finite_differences(setup):
    rb, _rec, data, model = setup
    rng = np.random.default_rng(1)
    theta = rng.normal(0, 0.3, model.size)  # every effect switched on
    _r, J, ok = _evaluate(model, theta, rb, data)
    assert ok.all()
    h = 1e-4  # θ is scaled to O(1); smaller steps drown in the 1e-12 m equilibrium rounding / 2e-5 m σ
    for i in range(model.size):
        tp, tm = theta.copy(), theta.copy()
        tp[i] += h
        tm[i] -= h
        fd = (_evaluate(model, tp, rb, data)[0] - _evaluate(model, tm, rb, data)[0]).ravel() / (2 * h)
        np.testing.assert_allclose(J[:, i], fd, atol=1e-5 * (1 + np.abs(fd).max()), err_msg=f"θ[{i}]")


def test_jacobian_columns_are_those_of_the_full_jacobian(setup):
    """The diagnosis computes only the Jacobian columns of a fit's free entries (``cols``,
    padded with -1; chunks of :func:`jacobian_width` for more): the same numbers as the
    columns of the full forward-mode Jacobian above (checked there against finite
    differences), zeros elsewhere, in one call or in chunks."""
    rb, _rec, data, model = setup
    theta = np.random.default_rng(2).normal(0, 0.3, model.size)
    r, J, ok = _evaluate(model, theta, rb, data)
    want = np.array([0, 3, 7, model.size - 1])
    rc, Jc, okc = (np.asarray(a) for a in M.residuals_and_jacobian(model, jnp.asarray(theta), rb, data,
                                                                    _padded(want, model)))
    np.testing.assert_array_equal(rc, r)
    np.testing.assert_array_equal(okc, ok)
    np.testing.assert_allclose(Jc[:, want], J[:, want], rtol=1e-12, atol=1e-12 * np.abs(J).max())
    assert not np.any(np.delete(Jc, want, axis=1))
    # several chunks of M.CHUNK tangents in the compiled loop, in any order, with padding
    # chunks before the wanted columns (the loop runs to the last chunk holding a column)
    want2 = np.arange(1, model.size, 2)
    assert len(want2) > 2 * M.CHUNK
    cols2 = _padded(np.concatenate([np.full(M.CHUNK, -1), want2[::-1], [-1] * 5]), model)
    _, Jc2, _ = (np.asarray(a) for a in M.residuals_and_jacobian(model, jnp.asarray(theta), rb, data, cols2))
    np.testing.assert_allclose(Jc2[:, want2], J[:, want2], rtol=1e-12, atol=1e-12 * np.abs(J).max())
    assert not np.any(np.delete(Jc2, want2, axis=1))
    assert [c.tolist() for c in M.column_chunks([5, 1, 3], 2)] == [[1, 3], [5, -1]]
    assert [c.tolist() for c in M.column_chunks([], 3)] == [[-1, -1, -1]]
    assert M.jacobian_width(model) == _width(model)  # no probe: every entry in one call


@pytest.mark.slow  # reverse-mode compile of the Newton solve: ~30 s on a loaded 2-core machine
def test_grad_and_vmap_of_chi2(setup):
    rb, _rec, data, _ = setup
    model = make_model(rb, data, [TensionSensorBias(), ExitFriction()])

    def chi2(th):
        r, _ = M.residuals(model, th, rb, data)
        return jnp.sum(r * r)

    th = jnp.full(model.size, 0.1)
    g = jax.jit(jax.grad(chi2))(th)
    r, J, _ = _evaluate(model, np.asarray(th), rb, data)
    np.testing.assert_allclose(np.asarray(g), 2 * J.T @ r.ravel(), rtol=1e-6, atol=1e-6)
    assert float(jax.jit(chi2)(th)) == pytest.approx(float(np.sum(r * r)))  # samples are vmapped inside


def test_measurement_hooks():
    pose = jnp.array([3.0, 0.1, 0.5, 0.01, -0.02, 0.03])
    t = jnp.array([100.0, 120.0])
    ctx = type("C", (), {"time": 0.0, "direction": jnp.array([1.0, -1.0])})()
    _, tb = TensionSensorBias().measure(pose, t, ctx, {"bias": jnp.array([1.5, -2.0])})
    np.testing.assert_allclose(tb, [101.5, 118.0])
    _, tf = ExitFriction().measure(pose, t, ctx, {"friction": 2.0})
    np.testing.assert_allclose(tf, [98.0, 122.0])  # paid out reads low, hauled in reads high
    rot, tr = np.array([1e-3, -2e-3, 5e-4]), np.array([1e-3, 2e-3, -1e-3])
    pm, _ = PoseFrameOffset().measure(pose, t, ctx, {"rotation": jnp.asarray(rot), "translation": jnp.asarray(tr)})
    Ro = np.asarray(lie.exp(rot))
    np.testing.assert_allclose(pm[:3], Ro @ np.asarray(pose[:3]) + tr, atol=1e-14)
    np.testing.assert_allclose(np.asarray(lie.exp(pm[3:])), Ro @ np.asarray(lie.exp(pose[3:])), atol=1e-14)
    tl = jnp.array([50.0, 200.0])
    np.testing.assert_allclose(NonlinearElasticity().tension(tl, {"stiffening": 0.2}), tl * (1 + 0.2 * tl / 100.0))


def test_bad_inputs(setup):
    rb, _rec, data, _ = setup
    with pytest.raises(ValueError, match="unknown effect 'sag'.*allowed: cable_mass"):
        get_effect("sag")
    with pytest.raises(ValueError, match="'nonlinear_elasticity' needs the spring cable law"):
        make_model(rb, data, [CableMass(), NonlinearElasticity()])
    assert set(EFFECTS) == {e.name for e in VOCABULARY}


def test_applicability():
    rb = load_robot(example_path("example02/robot.toml"))
    rec = load_recordings(example_path("example02/recordings.csv"), rb)
    assert all(e.applicable(rb, rec) is None for e in VOCABULARY)
    no_t = eqx.tree_at(lambda r: (r.tension_mask, r.time), rec,
                       (jnp.zeros_like(rec.tension_mask), jnp.full(rec.num_samples, jnp.nan)))
    assert get_effect("tension_sensor_bias").applicable(rb, no_t) == "no tensions recorded"
    assert get_effect("length_drift").applicable(rb, no_t) == "no time column"
