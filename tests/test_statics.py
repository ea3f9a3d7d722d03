import functools

import equinox as eqx
import hypothesis.extra.numpy as hnp
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cstiffjax import CableLaw, Status
from cstiffjax.core import lie
from cstiffjax.examples import example_path
from cstiffjax.io.robot_io import load_robot
from cstiffjax.statics import forward as fwd
from cstiffjax.statics import geometry as statics
from cstiffjax.statics.forward import NEWTON_STEPS, Solved, StaticsProblem, solve_unknowns

from .helpers import (
    central_difference,
    eight_cable_robot,
    lab_robot,
    np_cables,
    np_fd,
    np_frame,
    np_potential,
    np_spring_wrench,
)

ROBOT, REC = lab_robot("example02")
BOX = eight_cable_robot()

poses = st.tuples(
    hnp.arrays(np.float64, 3, elements=st.floats(-0.5, 0.5)),
    hnp.arrays(np.float64, 3, elements=st.floats(-0.4, 0.4)),
).map(lambda pr: np.concatenate([pr[0] + np.array([0.0, 0.0, 1.5]), pr[1]]))


@settings(max_examples=40, deadline=None)
@given(poses)
def test_structure_matrix_autodiff_matches_closed_form(pose):
    np.testing.assert_allclose(
        statics.structure_matrix(BOX, pose), statics.structure_matrix_closed_form(BOX, pose), atol=1e-12
    )


def test_structure_matrix_is_minus_length_jacobian_by_fd():
    pose = jnp.array([0.2, -0.1, 1.4, 0.1, -0.2, 0.3])
    fd = central_difference(lambda d: statics.cable_lengths(BOX, statics.apply_twist(pose, d)), np.zeros(6))
    np.testing.assert_allclose(-fd.T, statics.structure_matrix(BOX, pose), atol=1e-8)


def test_cable_geometry_invariant_under_rigid_motion():
    """Moving base anchors and platform pose by the same rigid motion keeps the lengths."""
    pose = jnp.array([0.3, 0.1, 1.2, 0.2, -0.1, 0.4])
    Q, c = lie.exp(jnp.array([0.5, -0.3, 0.8])), jnp.array([1.0, -2.0, 0.5])
    moved = BOX.__class__(**{**BOX.__dict__, "anchors": BOX.anchors @ Q.T + c})
    p, R = statics.frame(pose)
    pose2 = jnp.concatenate([Q @ p + c, lie.log(Q @ R)])
    np.testing.assert_allclose(statics.cable_lengths(moved, pose2), statics.cable_lengths(BOX, pose), atol=1e-12)


def test_inverse_statics_balances_the_wrench():
    pose = jnp.array([0.1, 0.2, 1.3, 0.05, 0.0, -0.1])
    ext = jnp.array([5.0, -3.0, 10.0, 0.5, 0.2, -0.3])
    sol = statics.inverse_statics(BOX, pose, ext, throw=False)
    np.testing.assert_allclose(statics.wrench(BOX, pose, sol.tensions, ext), 0.0, atol=1e-9)
    # min-norm: orthogonal to the null space of S
    S = statics.structure_matrix_closed_form(BOX, pose)
    null = np.linalg.svd(np.asarray(S))[2][6:]
    np.testing.assert_allclose(null @ np.asarray(sol.tensions), 0.0, atol=1e-9)


def test_inverse_statics_reports_infeasible_and_singular():
    pose = jnp.array([0.0, 0.0, 1.5, 0.0, 0.0, 0.0])
    push_up = jnp.array([0.0, 0.0, 5000.0, 0.0, 0.0, 0.0])  # would need pushing cables
    BOX6 = ROBOT
    sol = statics.inverse_statics(BOX6, jnp.array([0, 0, 0.5, 0, 0, 0.0]), push_up, throw=False)
    assert sol.result == Status.infeasible
    with pytest.raises(Exception, match="no cable tensions within"):
        statics.inverse_statics(BOX6, jnp.array([0, 0, 0.5, 0, 0, 0.0]), push_up)
    # all anchors at one point: rank-deficient structure matrix
    degenerate = BOX.__class__(**{**BOX.__dict__, "anchors": jnp.zeros((8, 3)).at[:, 2].set(5.0)})
    assert statics.inverse_statics(degenerate, pose, throw=False).result == Status.singular


# ------------------------------------------------------------------ forward statics
# One set of tests for cstiffjax.statics.forward.forward_statics (every law, both starts).
# Compiled functions are shared (module scope) to keep the suite cheap.
HEAVY = eqx.tree_at(lambda r: r.mass_per_length, ROBOT, jnp.full(6, 0.25))  # 8 mm steel rope


def _solve(robot, l0, w, p0, law, start, **kw):
    return fwd.forward_statics(StaticsProblem(robot, l0, w, law), pose0=p0, start=start, throw=False, **kw)


@functools.cache
def _batched(law, start):
    return jax.jit(jax.vmap(lambda rb, l0, w, p0: _solve(rb, l0, w, p0, law, start), in_axes=(None, 0, 0, 0)))


def _ok(fs):
    return bool(jnp.all(fs.result == Status.successful))


def test_forward_statics_reproduces_clean_lab_data_to_noise():
    sol = _batched(CableLaw.spring, "cold")(ROBOT, REC.l0, REC.wrench, jax.vmap(
        lambda l: fwd.forward_kinematics(ROBOT, l, throw=False).pose)(REC.l0))
    assert _ok(sol)
    z_pos = (sol.pose[:, :3] - REC.pose[:, :3]) / ROBOT.noise.position
    z_t = (sol.tensions - REC.tensions) / ROBOT.noise.tension
    # mean z² of k unit normals: 1 ± 3 √(2/k) (k = 270 positions, 540 tensions; the noise
    # sigmas of the file). Noise-free or mis-scaled (x 1.3) residuals fall outside.
    for z in (z_pos, z_t):
        k = z.size
        assert abs(float(jnp.mean(z**2)) - 1.0) < 3 * np.sqrt(2 / k), (k, float(jnp.mean(z**2)))


@pytest.mark.slow  # cold and warm compiles (~40 s)
def test_starts_agree_spring():
    """Cold from the ideal pose, cold and warm from the measured pose: one equilibrium,
    balanced (independent wrench: straight massless cables, inverse statics)."""
    l0, w = REC.l0, REC.wrench  # every sample: the same shapes (and compiled call) as the test above
    ideal = jax.vmap(lambda l: fwd.forward_kinematics(ROBOT, l, throw=False).pose)(l0)
    cold = _batched(CableLaw.spring, "cold")(ROBOT, l0, w, ideal)
    cold_meas = _batched(CableLaw.spring, "cold")(ROBOT, l0, w, REC.pose)
    warm = _batched(CableLaw.bilateral, "warm")(ROBOT, l0, w, REC.pose)
    assert _ok(cold) and _ok(cold_meas) and _ok(warm)
    for other in (cold_meas, warm):
        np.testing.assert_allclose(other.pose, cold.pose, atol=1e-11)
        np.testing.assert_allclose(other.tensions, cold.tensions, rtol=1e-9)
    assert float(jnp.max(jnp.abs(ideal - cold.pose))) > 1e-4  # the starts really differ
    # the warm Newton stops once converged (NEWTON_STOP), well before its step limit, and
    # still agrees with the cold LM above to 1e-11 m: stopping early loses nothing
    assert int(jnp.max(warm.num_steps)) < NEWTON_STEPS and int(jnp.min(warm.num_steps)) >= 2
    W = jax.vmap(lambda p, t, e: statics.wrench(ROBOT, p, t, e))(cold.pose, cold.tensions, w)
    np.testing.assert_allclose(W, 0.0, atol=1e-7)
    inv = jax.vmap(lambda p, e: statics.inverse_statics(ROBOT, p, e, throw=False).tensions)(cold.pose, w)
    np.testing.assert_allclose(inv, cold.tensions, rtol=1e-8)
    assert not bool(jnp.any(cold.slack))


def _notebook_seed1_truth():
    """The robot of notebooks/uncertainty_analysis.ipynb (rng seed 1)."""
    from fitting.calibration.parameters import apply_to_robot

    nominal = load_robot(example_path("example01/robot.toml"))
    rng = np.random.default_rng(1)
    ea = nominal.EA * (1 + 0.05 * rng.uniform(-1, 1, 6))
    mass = 0.25 * (1 + 0.05 * rng.uniform(-1, 1, 6))
    return apply_to_robot(nominal, {"EA": ea, "mass_per_length": jnp.asarray(mass)})


@pytest.fixture(scope="module")
def seed1():
    """The call the uncertainty notebook had to dodge: PRNGKey(1), 30 samples, catenary,
    cold start from the target poses inside ``synthetic_recordings`` (which raises
    ``ValueError`` if a sample fails)."""
    from fitting import synthetic_recordings

    truth = _notebook_seed1_truth()
    return truth, synthetic_recordings(truth, jax.random.PRNGKey(1), 30, law=CableLaw.catenary, noisy=False)


@pytest.mark.slow  # cold catenary compile (~40 s)
def test_cold_catenary_converges_on_the_notebook_seed1_data(seed1):
    """The former nested design (LM on the pose with a per-cable catenary root find in
    every residual) reported sample 12 of this data ``nonlinear_max_steps_reached`` after
    256 LM steps with a wrench residual of 6e-14 (relative): LM stalled at the rounding
    floor of the nested root finds, and the code meant to accept such a stall tested
    lineax's ``max_steps_reached`` instead. Now every sample converges (the fixture would
    raise) and the wrench re-evaluated with the independent per-cable root find
    (:func:`cstiffjax.cable.catenary.catenary_force`) vanishes at the solutions."""
    truth, rec = seed1
    W = jax.vmap(lambda p, l, e: statics.elastic_wrench(truth, p, l, e, law=CableLaw.catenary))(
        rec.pose, rec.l0, rec.wrench)
    scale = float(jnp.linalg.norm(truth.weight)) + 400.0
    assert float(jnp.max(jnp.abs(W))) < 1e-8 * scale


@pytest.mark.slow
def test_starts_agree_catenary(seed1):
    """Catenary: cold (LM, joint pose + end forces from the spring equilibrium; the same
    compiled call as the fixture's) from 2 cm away, warm (Newton) from there, and warm
    from a nearby robot's (pose, H, V_B) in 2 steps all give the fixture's equilibrium;
    ``T_A = hypot(H, V_B - w l0)``."""
    from fitting.calibration.models import predict_cdpr, predict_cdpr_state

    truth, rec = seed1
    start = rec.pose.at[:, :3].add(0.02)
    cold = predict_cdpr(truth, rec.l0, rec.wrench, law=CableLaw.catenary, pose0=start, method="statics")
    warm = predict_cdpr_state(truth, rec.l0, rec.wrench, start, law=CableLaw.catenary)
    near = eqx.tree_at(lambda r: [r.mass_per_length, r.EA], truth, [truth.mass_per_length * 0.99, truth.EA * 1.01])
    other = predict_cdpr_state(near, rec.l0, rec.wrench, rec.pose, law=CableLaw.catenary)
    again = predict_cdpr_state(truth, rec.l0, rec.wrench, other[0], law=CableLaw.catenary, steps=2,
                               forces0=other[3])
    for out in (cold, warm, other, again):
        assert bool(jnp.all(out[2] == Status.successful))
    assert float(jnp.max(jnp.abs(other[0] - rec.pose))) > 1e-6  # the nearby start really is elsewhere
    for out in (cold, warm, again):
        np.testing.assert_allclose(out[0], rec.pose, atol=1e-11)
        np.testing.assert_allclose(out[1], rec.tensions, rtol=1e-9)
    H, VB = warm[3][:, 0], warm[3][:, 1]
    np.testing.assert_allclose(jnp.hypot(H, VB - truth.mass_per_length * 9.81 * rec.l0), warm[1], rtol=1e-10)


def test_implicit_derivative_matches_fd_spring_both_starts():
    l0, w, p0 = REC.l0[0], REC.wrench[0], REC.pose[0]

    @functools.partial(jax.jit, static_argnums=2)
    def pose_of(l0_, ea, start):
        robot = eqx.tree_at(lambda r: r.EA, ROBOT, ea)
        law = CableLaw.spring if start == "cold" else CableLaw.bilateral
        return fwd.forward_statics(StaticsProblem(robot, l0_, w, law), pose0=p0, start=start).pose

    for start in ("cold", "warm"):
        J_l0, J_ea = jax.jacfwd(pose_of, argnums=(0, 1))(l0, ROBOT.EA, start)
        fd_l0 = central_difference(lambda x, s=start: pose_of(x, ROBOT.EA, s), np.asarray(l0), 1e-7)
        np.testing.assert_allclose(J_l0, fd_l0, rtol=1e-5, atol=1e-8)
        fd_ea = central_difference(lambda x, s=start: pose_of(l0, x, s), np.asarray(ROBOT.EA), 1.0)
        np.testing.assert_allclose(J_ea, fd_ea, rtol=1e-4, atol=1e-6 * np.abs(fd_ea).max())
        assert float(jnp.sum(J_ea[2])) > 0  # stiffer cables: the platform rises


@pytest.mark.slow
def test_implicit_derivative_matches_fd_through_the_catenary_solve():
    """d(pose, exit tensions)/d(l0, mass per length) through the joint catenary solve."""
    l0, w, p0 = REC.l0[1], REC.wrench[1], REC.pose[1]

    @jax.jit
    def out(l0_, rho):
        rb = eqx.tree_at(lambda r: r.mass_per_length, HEAVY, rho)
        fs = fwd.forward_statics(StaticsProblem(rb, l0_, w, CableLaw.catenary), pose0=p0, start="warm")
        return jnp.concatenate([fs.pose, fs.tensions])

    rho = HEAVY.mass_per_length
    J_l0, J_rho = jax.jacfwd(out, argnums=(0, 1))(l0, rho)
    fd_l0 = central_difference(lambda x: out(x, rho), np.asarray(l0), 1e-7)
    fd_rho = central_difference(lambda x: out(l0, x), np.asarray(rho), 1e-5)
    np.testing.assert_allclose(J_l0, fd_l0, rtol=1e-5, atol=1e-5 * np.abs(fd_l0).max())
    np.testing.assert_allclose(J_rho, fd_rho, rtol=1e-5, atol=1e-5 * np.abs(fd_rho).max())
    assert float(jnp.abs(J_rho[2]).max()) > 1e-3  # heavier cables move the platform


@pytest.mark.parametrize("law, start", [(CableLaw.bilateral, "warm"), (CableLaw.catenary, "warm")])
def test_a_given_solve_gives_the_same_statics_and_derivative(law, start):
    """``forward_statics(..., solved=solve_unknowns(...))`` skips the solve and takes only
    the implicit step: the same pose and tensions as the full call, bit for bit (the net
    wrench left, ~1e-11 N, to rounding), and the same derivative with respect to ``l0``
    and ``EA`` (the full call's is checked against finite differences above). A ``Solved``
    of the wrong size, or for the ideal law, is refused."""
    robot = HEAVY if law is CableLaw.catenary else ROBOT
    l0, w, p0 = REC.l0[1], REC.wrench[1], REC.pose[1]
    m = robot.num_cables

    def out(l0_, ea, given):
        rb = eqx.tree_at(lambda r: r.EA, robot, ea)
        problem = StaticsProblem(rb, l0_, w, law)
        sv = solve_unknowns(problem, pose0=p0, start=start) if given else None
        fs = fwd.forward_statics(problem, pose0=p0, start=start, solved=sv)
        return jnp.concatenate([fs.pose, fs.tensions, fs.residual, (fs.result == Status.successful)[None]])

    def with_derivative(given):  # one compiled program per variant: values and d/d(l0, EA)
        f = functools.partial(out, given=given)
        return jax.jit(lambda l0_, ea: (f(l0_, ea), jax.jacfwd(f, argnums=(0, 1))(l0_, ea)))(l0, robot.EA)

    (got, dgot), (want, dwant) = with_derivative(True), with_derivative(False)
    np.testing.assert_array_equal(got[:6 + m], want[:6 + m])  # pose and tensions
    np.testing.assert_allclose(got[6 + m:], want[6 + m:], rtol=0, atol=1e-12)  # net wrench ~0 N and the status
    assert float(want[-1]) == 1.0  # converged
    for dg, dw in zip(dgot, dwant):
        np.testing.assert_allclose(dg[:6 + m], dw[:6 + m], rtol=1e-12, atol=1e-12 * float(jnp.abs(dw).max()))
        assert float(jnp.abs(dw[:6 + m]).max()) > 0
    k = 6 if law is CableLaw.catenary else 6 + 2 * m  # the other law's number of unknowns
    wrong = Solved(jnp.zeros(k), jnp.eye(k), jnp.asarray(True), jnp.asarray(0))
    with pytest.raises(ValueError, match=f"unknowns for law '{law.name}' and {m} cables"):
        fwd.forward_statics(StaticsProblem(robot, l0, w, law), pose0=p0, start=start, solved=wrong)
    ideal = StaticsProblem(ROBOT, l0, w, CableLaw.ideal)
    elastic = "supported: 'spring', 'bilateral', 'small_sag', 'catenary'(?!,)"  # (jit appends a note)
    with pytest.raises(ValueError, match=f"solve_unknowns does not support the 'ideal' cable law; {elastic}"):
        solve_unknowns(ideal, pose0=p0)
    with pytest.raises(ValueError, match=f"solved= does not support the 'ideal' cable law; {elastic}"):
        fwd.forward_statics(ideal, pose0=p0, solved=wrong)


def test_tension_hook_parameters_get_the_implicit_derivative():
    """A stiffening law t (1 + k t / 100 N) through ``tension``: its parameter's
    derivative (a leaf of the Partial) matches finite differences."""
    l0, w, p0 = REC.l0[2], REC.wrench[2], REC.pose[2]

    @jax.jit
    def pose_of(k):
        hook = jax.tree_util.Partial(lambda k, t: t * (1.0 + k * t / 100.0), k)
        return fwd.forward_statics(StaticsProblem(ROBOT, l0, w, CableLaw.bilateral, hook), pose0=p0,
                                   start="warm").pose

    k = jnp.asarray(0.05)
    np.testing.assert_allclose(jax.jacfwd(pose_of)(k), central_difference(pose_of, np.array([0.05]), 1e-6)[:, 0],
                               rtol=1e-5, atol=1e-10)
    assert float(jnp.abs(pose_of(k) - pose_of(jnp.asarray(0.0))).max()) > 1e-6


def test_slack_cable_reported():
    l0 = REC.l0[0].at[2].add(0.3)  # pay out 30 cm of cable 3
    sol = fwd.forward_statics(StaticsProblem(ROBOT, l0, REC.wrench[0]), throw=False)
    assert sol.result == Status.successful
    assert bool(sol.slack[2]) and float(sol.tensions[2]) == 0.0
    assert int(jnp.sum(sol.slack)) >= 1


def test_failure_statuses_and_exceptions():
    sol = fwd.forward_statics(StaticsProblem(ROBOT, REC.l0[0], REC.wrench[0]), max_steps=1, throw=False)
    assert sol.result == Status.not_converged
    with pytest.raises(Exception, match="did not converge"):
        fwd.forward_statics(StaticsProblem(ROBOT, REC.l0[0], REC.wrench[0]), max_steps=1)
    # a warm start 1 m away cannot converge in 2 clipped steps: a status, finite numbers
    far = REC.pose[0].at[2].add(1.0)
    for law in (CableLaw.bilateral, CableLaw.catenary):
        rb = HEAVY if law is CableLaw.catenary else ROBOT
        sol = fwd.forward_statics(StaticsProblem(rb, REC.l0[0], REC.wrench[0], law), pose0=far, start="warm",
                                  steps=2, throw=False)
        assert sol.result == Status.not_converged
        assert bool(jnp.all(jnp.isfinite(sol.pose))) and bool(jnp.all(jnp.isfinite(sol.tensions)))


def test_ideal_forward_statics_recovers_pose():
    pose = jnp.array([0.5, 0.2, 0.6, 0.02, -0.03, 0.05])
    l = statics.cable_lengths(ROBOT, pose)
    sol = fwd.forward_statics(StaticsProblem(ROBOT, l, law=CableLaw.ideal))
    np.testing.assert_allclose(sol.pose, pose, atol=1e-9)
    np.testing.assert_allclose(statics.wrench(ROBOT, sol.pose, sol.tensions), 0.0, atol=1e-8)


def test_argument_errors_and_prototype_example_loads():
    with pytest.raises(ValueError, match="unknown cable law 'rope'; allowed: 'spring', 'bilateral', 'small_sag', "
                                         "'catenary', 'ideal'$"):
        CableLaw.parse("rope")
    with pytest.raises(TypeError, match=r"law must be a CableLaw member.*CableLaw.parse\('catenary'\)"):
        StaticsProblem(ROBOT, REC.l0[0], law="catenary")
    with pytest.raises(TypeError, match="takes a StaticsProblem"):
        fwd.forward_statics(ROBOT)
    with pytest.raises(ValueError, match="l0 has shape \\(5,\\); robot 'example02' has 6 cables"):
        StaticsProblem(ROBOT, REC.l0[0][:5])
    with pytest.raises(ValueError, match="external has shape \\(3,\\)"):
        StaticsProblem(ROBOT, REC.l0[0], jnp.zeros(3))
    with pytest.raises(ValueError, match="start must be 'cold' or 'warm', got 'hot'"):
        fwd.forward_statics(StaticsProblem(ROBOT, REC.l0[0]), start="hot")
    with pytest.raises(ValueError, match="tension hook .* does not support the 'catenary' cable law; supported: "
                                         "'spring', 'bilateral', 'small_sag'$"):
        StaticsProblem(ROBOT, REC.l0[0], law=CableLaw.catenary, tension=lambda t: t)
    with pytest.raises(ValueError, match="forces0 warm-starts the catenary law only"):
        fwd.forward_statics(StaticsProblem(ROBOT, REC.l0[0]), forces0=jnp.zeros((2, 6)))
    assert load_robot(example_path("example01/robot.toml")).num_cables == 6


def test_gravity_wrench_with_com_offset():
    robot = eight_cable_robot(com=(0.1, 0.0, 0.0))
    w = statics.gravity_wrench(robot, jnp.array([0, 0, 1.0, 0, 0, 0.0]))
    np.testing.assert_allclose(w[:3], [0, 0, -20 * 9.81])
    np.testing.assert_allclose(w[3:], np.cross([0.1, 0, 0], [0, 0, -20 * 9.81]))


PUBLIC = {
    "cable_lengths": lambda pose, t: statics.cable_lengths(BOX, pose),
    "cable_vectors": lambda pose, t: statics.cable_vectors(BOX, pose),
    "structure_matrix": lambda pose, t: statics.structure_matrix(BOX, pose),
    "gravity_wrench": lambda pose, t: statics.gravity_wrench(eight_cable_robot(com=(0.1, 0, 0)), pose),
    "wrench": lambda pose, t: statics.wrench(BOX, pose, t),
    "elastic_wrench": lambda pose, t: statics.elastic_wrench(BOX, pose, jnp.full(8, 2.0) + 1e-6 * t),
    "inverse_statics": lambda pose, t: statics.inverse_statics(BOX, pose, t[:6], throw=False).tensions,
}


@pytest.mark.parametrize("name", sorted(PUBLIC))
def test_public_functions_jit_vmap_grad(name):
    fn = PUBLIC[name]
    poses = jnp.array([[0.1, 0.0, 1.4, 0.0, 0.1, 0.0], [-0.2, 0.1, 1.6, 0.1, 0.0, -0.2]])
    ts = jnp.array([jnp.linspace(10.0, 80.0, 8), jnp.linspace(60.0, 5.0, 8)])
    batched = jax.jit(jax.vmap(fn))(poses, ts)
    for i in range(2):
        np.testing.assert_allclose(batched[i], fn(poses[i], ts[i]), rtol=1e-12, atol=1e-12)

    def scalar(x):
        out = fn(x[:6], x[6:])
        weights = jnp.cos(jnp.arange(out.size) * 1.3).reshape(out.shape)  # a fixed cotangent
        return jnp.sum(out * weights)

    x = jnp.concatenate([poses[0], ts[0]])
    fd = central_difference(lambda y: scalar(y)[None], np.asarray(x), 1e-6)[0]
    np.testing.assert_allclose(jax.grad(scalar)(x), fd, rtol=1e-6, atol=1e-6 * float(jnp.abs(fd).max()))


# ---------------- com offset, turned attachments, external moments: independent references
TCPR_COM = eqx.tree_at(lambda r: r.com, load_robot(example_path("tcpr8.toml")), jnp.array([0.03, -0.02, 0.04]))
POSE_M = np.array([0.05, -0.03, 0.85, 0.04, -0.03, 0.06])
EXT_M = np.array([4.0, -3.0, 6.0, 3.0, -2.0, 4.0])  # several N·m: K is asymmetric


def _designed_lengths(robot, pose, ext):
    """Unstrained lengths that hold ``pose`` under ``ext``: feasible (CTFR centroid) tensions,
    then l0 = l EA / (EA + t) (spring law inverted)."""
    from cstiffjax.stiffness.tensions import feasible_tensions

    t = np.asarray(feasible_tensions(robot, jnp.asarray(pose), jnp.asarray(ext)).tensions)
    _, _, l = np_cables(robot, *np_frame(pose))
    return l * np.asarray(robot.EA) / (np.asarray(robot.EA) + t), t


def test_forward_statics_with_com_offset_and_moments_against_numpy_balance_and_energy():
    """The solution balances a numpy wrench written from scratch (scipy rotations), is the
    designed pose, and is a stationary point and minimum of the numpy potential energy."""
    l0, t = _designed_lengths(TCPR_COM, POSE_M, EXT_M)
    assert np.all(t > 5.0)
    sol = fwd.forward_statics(StaticsProblem(TCPR_COM, jnp.asarray(l0), jnp.asarray(EXT_M)))
    pose = np.asarray(sol.pose)
    weight = float(TCPR_COM.platform_mass) * 9.81 + np.abs(EXT_M).sum()
    assert np.max(np.abs(np_spring_wrench(TCPR_COM, l0, EXT_M, pose))) < 1e-7 * weight
    np.testing.assert_allclose(pose, POSE_M, atol=1e-9)
    np.testing.assert_allclose(sol.tensions, t, rtol=1e-7, atol=1e-6)
    grad = np_fd(lambda d: np_potential(TCPR_COM, l0, EXT_M, pose, d), 6, 1e-6)
    assert np.max(np.abs(grad)) < 1e-5 * weight  # chart gradient = -wrench = 0
    # without the com lever arm (or with it unrotated) the same lengths give another pose
    centred = eqx.tree_at(lambda r: r.com, TCPR_COM, jnp.zeros(3))
    moved = fwd.forward_statics(StaticsProblem(centred, jnp.asarray(l0), jnp.asarray(EXT_M)))
    assert np.max(np.abs(np.asarray(moved.pose) - POSE_M)) > 1e-4


def test_spring_law_is_hooke_on_the_unstrained_length():
    """A straight spring cable: t = EA (l - l0) / l0 (engineering strain on the unstrained
    length; ∂t/∂l = EA/l0 as in Cui et al. 2019 eq. 17), written out here. At 5% strain a strain on the
    stretched length instead would be 5% off; the force points from the attachment to the
    anchor with that magnitude, and a slack cable carries nothing."""
    from cstiffjax.cable import laws as cables

    anchor, attachment = jnp.array([0.3, -0.4, 2.0]), jnp.array([0.0, 0.0, 0.8])
    l = float(np.linalg.norm(np.asarray(anchor - attachment)))  # 1.3 m
    l0, EA = l / 1.05, 2.0e4
    f = cables.spring_force(anchor, attachment, l0, EA)
    t = EA * (l - l0) / l0
    assert float(f.tension_anchor) == pytest.approx(t, rel=1e-13)
    np.testing.assert_allclose(f.on_platform, t * np.asarray(anchor - attachment) / l, rtol=1e-13)
    assert float(cables.spring_force(anchor, attachment, 1.01 * l, EA).tension_anchor) == 0.0


@pytest.mark.slow
def test_dense_cold_start_matches_optimistix():
    """Reference for the built-in dense Levenberg-Marquardt of the cold start: optimistix's
    ``LevenbergMarquardt`` (``solver=default_solver()``), the solver it replaced, reaches the
    same equilibrium from the same start, spring and catenary, on the example's samples."""
    from cstiffjax.statics.forward import default_solver

    for law, rb in ((CableLaw.spring, ROBOT), (CableLaw.catenary, HEAVY)):
        def solve(solver, rb=rb, law=law):
            f = jax.vmap(lambda l0, w: fwd.forward_statics(StaticsProblem(rb, l0, w, law), solver=solver, throw=False))
            return jax.jit(f)(REC.l0[:12], REC.wrench[:12])

        dense, optx_ = solve(None), solve(default_solver())
        assert bool(jnp.all(dense.result == Status.successful)) and bool(jnp.all(optx_.result == Status.successful))
        np.testing.assert_allclose(dense.pose, optx_.pose, atol=1e-9, err_msg=law.name)
        np.testing.assert_allclose(dense.tensions, optx_.tensions, rtol=1e-7, atol=1e-6, err_msg=law.name)


def test_dense_lm_rejects_steps_that_raise_the_cost():
    """The cold start's dense Levenberg-Marquardt on ``(atan(x), tanh(3y) + y/10) = 0`` from
    (300, -5): undamped Gauss-Newton steps overshoot without bound on both (atan is flat far
    out; tanh saturates), so accepting a step that raises the cost diverges (measured: it
    ends at (300, 1.77) after 256 steps). Damping plus rejection reach the root (0, 0),
    known in closed form."""
    from cstiffjax.statics.root_finding import dense_lm

    def f(z):
        return jnp.array([jnp.arctan(z[0]), jnp.tanh(3 * z[1]) + 0.1 * z[1]])

    z, J, ok, steps = jax.jit(lambda z0: dense_lm(f, z0, 256))(jnp.array([300.0, -5.0]))
    assert bool(ok) and int(steps) < 256
    np.testing.assert_allclose(z, [0.0, 0.0], atol=1e-10)
    np.testing.assert_allclose(J, np.diag([1.0, 3.1]), atol=1e-9)  # the Jacobian at the returned root


def test_newton_returns_the_jacobian_at_its_solution():
    """The warm Newton hands the implicit step ``J`` at the returned ``z`` (not at the
    previous iterate): on ``(z0² - 2, z0 z1 - 1) = 0`` from (1, 1) it converges to
    (√2, 1/√2), where ``J = [[2√2, 0], [1/√2, √2]]`` (closed form); with a step limit of 2
    it stops early and ``J`` is still the Jacobian at the (unconverged) point it returns."""
    from cstiffjax.statics.root_finding import newton

    def f(z):
        return jnp.array([z[0] ** 2 - 2.0, z[0] * z[1] - 1.0])

    def jac(z):
        return np.array([[2 * z[0], 0.0], [z[1], z[0]]])

    r2 = np.sqrt(2.0)
    z, J, taken = jax.jit(lambda z0: newton(f, z0, 12, 10.0))(jnp.array([1.0, 1.0]))
    np.testing.assert_allclose(z, [r2, 1 / r2], atol=1e-12)
    np.testing.assert_allclose(J, [[2 * r2, 0.0], [1 / r2, r2]], atol=1e-10)
    assert 3 <= int(taken) < 12
    z, J, taken = jax.jit(lambda z0: newton(f, z0, 2, 10.0))(jnp.array([1.0, 1.0]))
    assert int(taken) == 2 and abs(float(z[0]) - r2) > 1e-6
    np.testing.assert_allclose(J, jac(np.asarray(z)), atol=1e-12)


def test_values_only_statics_end_with_a_chord_check():
    """``forward_statics(..., derivatives=False)`` (the posterior walkers): from a start
    1e-8 away it linearizes once (the step after it, formed with the same Jacobian,
    confirms convergence), against twice with derivatives; from the measured pose it
    saves the last linearization too; the values are the same either way, and carry no
    derivative. The one-sided ``spring`` law (a softening kink at slack) never takes the
    chord exit: the same steps and values as with derivatives."""
    l0, w, pose_meas = REC.l0[3], REC.wrench[3], REC.pose[3]

    @functools.partial(jax.jit, static_argnums=(2, 3))
    def solve(l0_, p0, derivatives, law=CableLaw.bilateral):
        fs = fwd.forward_statics(StaticsProblem(ROBOT, l0_, w, law), pose0=p0, start="warm", derivatives=derivatives)
        return fs.pose, fs.tensions, fs.num_steps, fs.result == Status.successful

    exact = solve(l0, pose_meas, True)
    near = exact[0] + 1e-8 * jnp.array([1.0, -2.0, 1.5, 0.5, -1.0, 2.0])
    for law, fewer in ((CableLaw.bilateral, 1), (CableLaw.spring, 0)):
        for p0 in (near, pose_meas):
            full, values = solve(l0, p0, True, law), solve(l0, p0, False, law)
            assert bool(full[3]) and bool(values[3])
            np.testing.assert_allclose(values[0], exact[0], rtol=0, atol=1e-13)
            np.testing.assert_allclose(values[1], exact[1], rtol=1e-11)
            assert int(values[2]) == int(full[2]) - fewer, (law, int(values[2]), int(full[2]))
    assert int(solve(l0, near, True)[2]) == 2
    d = jax.jacfwd(lambda x: solve(x, near, False)[0])(l0)
    assert float(jnp.abs(d).max()) == 0.0
    assert float(jnp.abs(jax.jacfwd(lambda x: solve(x, near, True)[0])(l0)).max()) > 0


def test_the_chord_check_does_not_stop_across_a_kink():
    """A kink between the last step's start and end (a one-sided law's slope changes at
    ``z = 0``): the step with the old Jacobian is not small there, so the chord check does
    not end the iteration; it ends at the root after one more linearization (stopping at
    the small step, as a plain early stop would, leaves an error of 5e-8)."""
    from cstiffjax.statics.root_finding import newton

    def fn(z):  # slope 1 left of 0, 1.5 right of it; root at 1e-7
        return z - 1.5e-7 + 0.5 * jnp.maximum(z, 0.0)

    for chord, taken in ((True, 2), (False, 3)):
        z, J, n = jax.jit(lambda z0, c=chord: newton(fn, z0, 12, 1.0, c))(jnp.array([-1e-7]))
        np.testing.assert_allclose(z, [1e-7], rtol=0, atol=1e-15)
        assert int(n) == taken and float(J[0, 0]) == 1.5
