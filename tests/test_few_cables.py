"""Robots with fewer than 6 cables (suspended: gravity closes the equilibrium), against
references that share no code with the package: a symmetric 3-cable closed form, a 3-cable
equilibrium built by hand (cables whose lines meet at one platform point), the minimum of
the potential energy by scipy, finite differences, and the CLI's answers and refusals."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.optimize import brentq, minimize

from cstiffjax.cable.laws import CableLaw
from cstiffjax.commands.cli import main
from cstiffjax.commands.common import EXIT_OK, EXIT_USAGE
from cstiffjax.core.errors import RobotFileError
from cstiffjax.core.status import Status, describe
from cstiffjax.examples import example_path
from cstiffjax.io.robot import CableRobot, Noise
from cstiffjax.io.robot_io import load_robot, robot_from_dict, save_robot
from cstiffjax.statics.forward import StaticsProblem, forward_statics
from cstiffjax.statics.geometry import inverse_statics
from cstiffjax.stiffness.matrix import stiffness
from cstiffjax.stiffness.tensions import feasible_tensions, tension_space

G = 9.81
ROBOT4 = load_robot(example_path("suspended4.toml"))
L0_4 = jnp.array([2.6, 2.75, 2.8, 2.65])  # unequal: the platform hangs off-centre and tilted


def _robot(anchors, attachments, mass, com, EA, mpl=0.0):
    m = len(anchors)
    return CableRobot(anchors=np.asarray(anchors, float), attachments=np.asarray(attachments, float),
                      EA=np.full(m, EA), mass_per_length=np.full(m, mpl), platform_mass=mass,
                      com=np.asarray(com, float), inertia=np.eye(3), gravity=[0.0, 0.0, -G],
                      noise=Noise(position=1e-3, rotation=1e-3, tension=0.5), name=f"few{m}")


def _rot(v):
    """Rodrigues' rotation matrix of a rotation vector; numpy, complex-step safe."""
    th = np.sqrt(np.sum(v * v))
    if abs(th) < 1e-300:
        return np.eye(3) + np.zeros((3, 3), dtype=v.dtype)
    k = v / th
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]], dtype=v.dtype)
    return np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * K @ K


# --------------------------------------------------------------------------- loading
def test_any_number_of_cables_loads_and_none_is_refused():
    text = (example_path("suspended4.toml")).read_text()
    import tomllib

    data = tomllib.loads(text)
    for m in (1, 2, 3, 5):
        d = dict(data, cables=(data["cables"] * 2)[:m])
        assert robot_from_dict(d).num_cables == m
    with pytest.raises(RobotFileError, match=r"cables.*expected one or more \[\[cables\]\] tables"):
        robot_from_dict(dict(data, cables=[]))
    assert load_robot(example_path("suspended3.toml")).num_cables == 3


# --------------------------------------------------------------------------- (a) closed forms
def test_symmetric_three_cable_closed_form():
    """Three cables from a triangle of radius A = 2.5 m (3 m high) to a triangle of radius
    b = 0.1 m on the platform: by symmetry it hangs level on the axis, each cable spanning
    A - b horizontally; one scalar equation 3 t v / l = m g with t = EA (l - l0)/l0."""
    A, b, H, up, EA, mass = 2.5, 0.1, 3.0, 0.05, 5e4, 5.0
    ang = np.radians([90.0, 210.0, 330.0])
    ring = np.stack([np.cos(ang), np.sin(ang), np.zeros(3)], 1)
    robot = _robot(A * ring + [0, 0, H], b * ring + [0, 0, up], mass, [0, 0, -0.1], EA)
    l0 = 2.7

    def balance(v):
        l = np.hypot(A - b, v)
        return 3 * EA * (l - l0) / l0 * v / l - mass * G

    v = brentq(balance, 0.5, 2.69, xtol=1e-15)
    t_ref = EA * (np.hypot(A - b, v) - l0) / l0
    for law in (CableLaw.spring, CableLaw.bilateral):
        fs = forward_statics(StaticsProblem(robot, jnp.full(3, l0), None, law), throw=False)
        assert fs.result == Status.successful, describe(fs.result)
        np.testing.assert_allclose(fs.pose, [0, 0, H - up - v, 0, 0, 0], atol=1e-9)
        np.testing.assert_allclose(fs.tensions, t_ref, rtol=1e-9)


def _concurrent(h, r=0.3, EA=1e5, mass=8.0):
    """A 3-cable robot built around a known equilibrium: the platform frame sits at P (no
    rotation), each attachment on the line from P to its anchor (r from P), the com h below P
    (h < 0: above). Every cable force and the weight pass through P: the moments vanish, and
    the forces balance for the tensions of the 3x3 system Σ t_i u_i = -m g."""
    a = np.array([[2.0, 0.3, 3.2], [-1.4, 1.9, 2.8], [-0.6, -2.2, 3.0]])
    P = np.array([0.2, -0.1, 1.4])
    u = (a - P) / np.linalg.norm(a - P, axis=1)[:, None]
    t = np.linalg.solve(u.T, [0.0, 0.0, mass * G])
    assert np.all(t > 0)
    length = np.linalg.norm(a - P, axis=1) - r
    robot = _robot(a, r * u, mass, [0, 0, -h], EA)
    return robot, jnp.asarray(length * EA / (EA + t)), np.r_[P, 0, 0, 0], t


def test_three_cables_meeting_at_one_point_hang_there():
    robot, l0, pose, t = _concurrent(h=0.2)
    fs = forward_statics(StaticsProblem(robot, l0, None, CableLaw.spring), throw=False)
    assert fs.result == Status.successful, describe(fs.result)
    np.testing.assert_allclose(fs.pose, pose, atol=1e-9)
    np.testing.assert_allclose(fs.tensions, t, rtol=1e-8)


# --------------------------------------------------------------------------- (b) energy
def _energy(x, robot, l0):
    """Straight spring cables (one-sided) plus the weight's potential, numpy (complex-step safe)."""
    a, b = np.asarray(robot.anchors), np.asarray(robot.attachments)
    EA, com, mass = np.asarray(robot.EA), np.asarray(robot.com), float(robot.platform_mass)
    R = _rot(x[3:])
    d = a - (x[:3] + b @ R.T)
    length = np.sqrt(np.sum(d * d, axis=1))
    s = np.where((length - l0).real > 0, length - l0, 0.0)
    return np.sum(EA * s * s / (2 * l0)) + mass * G * (x[2] + (R @ com)[2])


def _grad(x, robot, l0):
    h = 1e-30
    return np.array([_energy(x + 1j * h * e, robot, l0).imag / h for e in np.eye(6)])


def test_four_cables_hang_at_the_energy_minimum():
    l0 = np.asarray(L0_4)
    ref = minimize(_energy, np.array([0.0, 0.0, 1.5, 0.01, 0.01, 0.01]), args=(ROBOT4, l0), jac=_grad,
                   method="BFGS", options={"gtol": 1e-10, "maxiter": 2000})
    x = ref.x  # BFGS stops at its line search's rounding floor (|grad| ~ 1e-6 N): Newton polishes it
    for _ in range(4):
        H = np.stack([(_grad(x + 1e-6 * e, ROBOT4, l0) - _grad(x - 1e-6 * e, ROBOT4, l0)) / 2e-6 for e in np.eye(6)])
        x = x - np.linalg.solve(0.5 * (H + H.T), _grad(x, ROBOT4, l0))
    assert np.max(np.abs(_grad(x, ROBOT4, l0))) < 1e-9 and np.linalg.eigvalsh(0.5 * (H + H.T)).min() > 0
    fs = forward_statics(StaticsProblem(ROBOT4, L0_4, None, CableLaw.spring), throw=False)
    assert fs.result == Status.successful, describe(fs.result)
    assert np.max(np.abs(x[:2])) > 0.01 and np.max(np.abs(x[3:])) > 1e-3  # a non-trivial pose
    np.testing.assert_allclose(fs.pose, x, atol=1e-6)
    # the cold catenary (cables of 5 g/m) ends beside the spring's equilibrium, stable too
    cat = forward_statics(StaticsProblem(ROBOT4, L0_4, None, CableLaw.catenary), throw=False)
    assert cat.result == Status.successful, describe(cat.result)
    np.testing.assert_allclose(cat.pose, x, atol=2e-4)
    assert float(jnp.max(jnp.abs(cat.pose - fs.pose))) > 1e-7  # the cables' weight shows


# --------------------------------------------------------------------------- (c) derivative
def test_pose_derivative_wrt_lengths_matches_finite_differences():
    def pose(l0):
        return forward_statics(StaticsProblem(ROBOT4, l0, None, CableLaw.spring)).pose

    J = np.asarray(jax.jacfwd(pose)(L0_4))
    h = 1e-5
    fd = np.stack([(np.asarray(pose(L0_4 + h * e)) - np.asarray(pose(L0_4 - h * e))) / (2 * h)
                   for e in np.eye(4)], axis=1)
    assert np.max(np.abs(J)) > 0.5
    np.testing.assert_allclose(J, fd, atol=1e-5 * np.max(np.abs(J)))


# --------------------------------------------------------------------------- (d) stability
def test_a_balanced_platform_is_unstable_and_the_hanging_one_is_not():
    """The same cables with the com 0.2 m above their meeting point: still an equilibrium
    (every force through P), but a saddle: tipping by δθ about P lowers the weight's energy by
    m g h δθ²/2 and stretches cable i (attached r from P, free length L_i) by about
    r (r + L_i) δθ²/(2 L_i), storing t_i r (1 + r/L_i) δθ²/2: with r = 5 cm the cables' share
    is below the weight's."""
    r, h = 0.05, 0.2
    robot, l0, pose, t = _concurrent(h=-h, r=r)
    L = np.linalg.norm(np.asarray(robot.anchors) - pose[:3], axis=1) - r
    assert np.sum(t * r * (1 + r / L)) < 0.5 * float(robot.platform_mass) * G * h
    problem = StaticsProblem(robot, l0, None, CableLaw.spring)
    top = forward_statics(problem, pose0=jnp.asarray(pose), start="warm", throw=False)
    assert top.result == Status.unstable, describe(top.result)
    np.testing.assert_allclose(top.pose, pose, atol=1e-9)  # it is the equilibrium; only its verdict fails
    with pytest.raises(Exception, match="unstable"):
        forward_statics(problem, pose0=jnp.asarray(pose), start="warm")
    hanging = forward_statics(StaticsProblem(*_concurrent(h=h, r=r)[:2], None, CableLaw.spring),
                              pose0=jnp.asarray(pose), start="warm", throw=False)
    assert hanging.result == Status.successful, describe(hanging.result)


def test_stiffness_of_the_equilibrium_includes_the_weight():
    """``stiffness`` at the 4-cable equilibrium is -dW/dx of the net wrench, the weight's term
    included (central differences of a numpy wrench), and positive definite there."""
    fs = forward_statics(StaticsProblem(ROBOT4, L0_4, None, CableLaw.spring))
    K = np.asarray(stiffness(ROBOT4, fs.pose, fs.tensions).K)
    a, b = np.asarray(ROBOT4.anchors), np.asarray(ROBOT4.attachments)
    EA, l0, com = np.asarray(ROBOT4.EA), np.asarray(L0_4), np.asarray(ROBOT4.com)
    p0, R0 = np.asarray(fs.pose[:3]), _rot(np.asarray(fs.pose[3:]))
    weight = np.array([0, 0, -float(ROBOT4.platform_mass) * G])

    def wrench(tw, g=1.0):  # base-frame twist [dp, dtheta] from the equilibrium; g = 0: without the weight
        p, R = p0 + tw[:3], _rot(tw[3:]) @ R0
        r = b @ R.T
        d = a - p - r
        length = np.linalg.norm(d, axis=1)
        f = (EA * (length - l0) / l0 / length)[:, None] * d
        return np.r_[f.sum(0) + g * weight, np.cross(r, f).sum(0) + g * np.cross(R @ com, weight)]

    def fd(g):
        h = 1e-6
        return -np.stack([(wrench(h * e, g) - wrench(-h * e, g)) / (2 * h) for e in np.eye(6)], axis=1)

    np.testing.assert_allclose(K, fd(1.0), atol=1e-5 * np.abs(K).max())
    # the weight's term, m g |com| ~ 12.7 N·m/rad on the tilts, is in K
    assert np.abs(K[3:5, 3:5] - fd(0.0)[3:5, 3:5]).max() > 10.0
    assert np.linalg.eigvalsh(0.5 * (K + K.T)).min() > 0


def test_inverse_statics_and_tensions_need_an_equilibrium():
    fs = forward_statics(StaticsProblem(ROBOT4, L0_4, None, CableLaw.spring))
    inv = inverse_statics(ROBOT4, fs.pose, throw=False)
    assert inv.result == Status.successful
    np.testing.assert_allclose(inv.tensions, fs.tensions, rtol=1e-7)
    assert tension_space(ROBOT4, fs.pose).null_basis.shape == (4, 0)
    np.testing.assert_allclose(feasible_tensions(ROBOT4, fs.pose).tensions, fs.tensions, rtol=1e-7)
    off = fs.pose.at[0].add(0.2)  # moved sideways: no tensions hold it there
    bad = inverse_statics(ROBOT4, off, throw=False)
    assert bad.result == Status.infeasible and float(jnp.linalg.norm(bad.residual)) > 1.0
    assert feasible_tensions(ROBOT4, off, throw=False).result == Status.infeasible


def test_the_ideal_law_refuses_fewer_than_six_cables():
    with pytest.raises(ValueError, match="law ideal needs at least 6 cables.*free along 2 directions"):
        forward_statics(StaticsProblem(ROBOT4, L0_4, None, CableLaw.ideal))


# --------------------------------------------------------------------------- (e) the commands
def test_commands_answer_or_refuse_with_the_reason(tmp_path, capsys):
    name = "suspended4.toml"
    assert main(["check", name]) == EXIT_OK
    assert "rank 4" in capsys.readouterr().out
    pose = ["0", "0", "1.5656", "0", "0", "0"]  # on the axis of symmetry: an equilibrium at any height
    assert main(["stiffness", name, "--pose", *pose]) == EXIT_OK
    assert "62.17 62.17 62.17 62.17" in capsys.readouterr().out
    assert main(["tensions", name, "--pose", *pose, "--method", "icfm"]) == EXIT_OK
    assert "status: ok" in capsys.readouterr().out
    assert main(["stiffness", name, "--pose", "0.3", *pose[1:]]) == 2
    assert "is not an equilibrium of this 4-cable robot" in capsys.readouterr().err
    grid = ["--pose-grid", "-1", "1", "2", "-1", "1", "2", "1", "2", "2"]
    assert main(["css", name, *grid, "--stiffness-at", *pose, "--out", str(tmp_path / "css")]) == EXIT_USAGE
    assert "constant stiffness space needs at least 6 cables; robot 'suspended4' has 4" in capsys.readouterr().err
    assert main(["workspace", name, "--kind", "wrench-closure", *grid, "--out", str(tmp_path / "w")]) == EXIT_USAGE
    assert "wrench closure needs at least 7 cables; robot 'suspended4' has 4 (4 cables span" in \
        capsys.readouterr().err
    assert not (tmp_path / "css").exists() and not (tmp_path / "w").exists()



def _fd_stiffness(robot, l0, pose):
    """``-dW/dx`` (6x6, base-frame twist) of spring cables plus the weight at ``pose``,
    by central differences of a numpy wrench."""
    a, b, com = np.asarray(robot.anchors), np.asarray(robot.attachments), np.asarray(robot.com)
    EA, l0 = np.asarray(robot.EA), np.asarray(l0)
    weight = np.array([0, 0, -float(robot.platform_mass) * G])

    def wrench(tw):
        p, R = pose[:3] + tw[:3], _rot(tw[3:])
        r = b @ R.T
        d = a - p - r
        length = np.linalg.norm(d, axis=1)
        f = (EA * (length - l0) / l0 / length)[:, None] * d
        return np.r_[f.sum(0) + weight, np.cross(r, f).sum(0) + np.cross(R @ com, weight)]

    return -np.stack([(wrench(1e-6 * e) - wrench(-1e-6 * e)) / 2e-6 for e in np.eye(6)], axis=1)


@pytest.mark.parametrize("h", [-0.2, 0.2])
def test_stiffness_command_names_an_unstable_equilibrium(h, tmp_path, capsys):
    """``inverted3`` (h < 0): the 3-cable platform balanced with its com 0.2 m above the cables'
    meeting point. Its stiffness by central differences of a numpy wrench has a negative
    rotational eigen-stiffness (m g h ~ 16 N·m/rad against the cables' ~5); the command prints
    K, writes the JSON with the unstable status and exits 2. The com below (h > 0): a stable
    equilibrium, status ok, exit 0."""
    robot, l0, pose, _ = _concurrent(h=h, r=0.05)
    K = _fd_stiffness(robot, l0, pose)
    least = np.linalg.eigvalsh(0.5 * (K[3:, 3:] + K[3:, 3:].T))[0]
    assert least < -5.0 if h < 0 else least > 0.0
    path, out = tmp_path / "inverted3.toml", tmp_path / "k.json"
    save_robot(robot, path)
    expected = 2 if h < 0 else EXIT_OK
    assert main(["stiffness", str(path), "--pose", *map(str, pose), "--json", str(out)]) == expected
    captured = capsys.readouterr()
    doc = json.loads(out.read_text())
    assert doc["status"] == (describe(Status.unstable) if h < 0 else "ok")
    np.testing.assert_allclose(doc["rotation_eigenvalues"][0], least, rtol=1e-4)
    assert ("is an unstable equilibrium" in captured.err) == (h < 0)
    # given tensions that do not balance the load: an answer, stability not judged
    assert main(["stiffness", str(path), "--pose", *map(str, pose), "--tensions", "10", "10", "10"]) == EXIT_OK
    assert "status: not an equilibrium under the given tensions" in capsys.readouterr().out
