"""`cstiffjax statics`: forward statics on the command line, against an independent reference.

The reference is numpy + scipy written here: straight one-sided spring cables
``t = EA (l - l0)/l0``, the weight at the centre of mass, the net wrench about the reference
point solved for the pose with ``scipy.optimize.root`` (rotation vector coordinates), and the
stability verdict from a numpy eigen-decomposition of a central finite-difference stiffness
``-dW/dx`` (base-frame twist), rotations scaled by the platform size."""

import json

import numpy as np
import pytest
from scipy.optimize import root
from scipy.spatial.transform import Rotation

from cstiffjax.commands.cli import main
from cstiffjax.examples import example_path
from cstiffjax.io.robot_io import load_robot


def _net_wrench(robot, l0, pose, R=None):
    """The net wrench (6,) on the platform at ``pose`` (``R`` overrides its rotation) and the tensions."""
    a, b = np.asarray(robot.anchors), np.asarray(robot.attachments)
    ea, com = np.asarray(robot.EA), np.asarray(robot.com)
    weight = float(robot.platform_mass) * np.asarray(robot.gravity)
    R = Rotation.from_rotvec(pose[3:]).as_matrix() if R is None else R
    arm = b @ R.T
    v = a - (pose[:3] + arm)
    length = np.linalg.norm(v, axis=1)
    t = np.maximum(ea * (length - l0) / l0, 0.0)
    f = t[:, None] * v / length[:, None]
    return np.concatenate([f.sum(0) + weight, np.cross(arm, f).sum(0) + np.cross(R @ com, weight)]), t


def _reference(robot, l0, start):
    sol = root(lambda q: _net_wrench(robot, l0, q)[0], start, method="hybr", tol=1e-13)
    assert np.max(np.abs(sol.fun)) < 1e-8, sol.message
    return sol.x, _net_wrench(robot, l0, sol.x)[1]


def _scaled_fd_eigenvalues(robot, l0, pose, h=1e-6):
    """Eigenvalues of the symmetric part of ``D K D`` (numpy), ``K = -dW/dx`` by central differences
    along a base-frame twist (``p + dp``, ``exp(dθ) R``), ``D = diag(1, 1, 1, 1/size x 3)``."""
    R0 = Rotation.from_rotvec(pose[3:]).as_matrix()
    K = np.zeros((6, 6))
    for j in range(6):
        w = []
        for s in (h, -h):
            d = np.zeros(6)
            d[j] = s
            R = Rotation.from_rotvec(d[3:]).as_matrix() @ R0
            w.append(_net_wrench(robot, l0, np.concatenate([pose[:3] + d[:3], pose[3:]]), R)[0])
        K[:, j] = -(w[0] - w[1]) / (2 * h)
    size = max(np.linalg.norm(np.asarray(robot.attachments), axis=1).max(), np.linalg.norm(np.asarray(robot.com)))
    D = np.diag([1, 1, 1] + [1 / size] * 3)
    Ks = D @ K @ D
    return np.linalg.eigvalsh(0.5 * (Ks + Ks.T))


def _run(tmp_path, robot, lengths, *extra):
    out = tmp_path / "statics.json"
    code = main(["statics", str(robot), "--lengths", *map(str, lengths), *extra, "--json", str(out)])
    return code, (json.loads(out.read_text()) if out.exists() else None)


CASES = [  # (robot, lengths, where the reference's root search starts)
    ("suspended3.toml", [2.6, 2.75, 2.7], [0.0, 0.0, 1.7, 0.0, 0.0, 0.0]),
    ("suspended4.toml", [2.6, 2.75, 2.7, 2.8], [0.0, 0.0, 1.55, 0.0, 0.0, 0.0]),  # hangs on cables 1 and 3
    ("example02/robot.toml", None, [0.1, -0.1, 2.0, 0.0, 0.0, 0.0]),
]


@pytest.mark.parametrize("name, lengths, start", CASES, ids=["3 cables", "4 cables", "6 cables"])
def test_the_equilibrium_is_the_wrench_balance_and_its_verdict_the_eigen_decomposition(tmp_path, capsys, name,
                                                                                        lengths, start):
    robot = load_robot(example_path(name))
    start = np.asarray(start)
    if lengths is None:  # 6 cables: 1 mm shorter than the straight distances at the start pose
        p = start[:3] + np.asarray(robot.attachments)
        lengths = np.linalg.norm(np.asarray(robot.anchors) - p, axis=1) - 1e-3
    l0 = np.asarray(lengths, float)
    code, doc = _run(tmp_path, example_path(name), l0)
    assert code == 0, capsys.readouterr().err
    pose, t = _reference(robot, l0, start)
    np.testing.assert_allclose(doc["pose"][:3], pose[:3], rtol=0, atol=1e-8)
    np.testing.assert_allclose(Rotation.from_rotvec(doc["pose"][3:]).as_matrix(),
                               Rotation.from_rotvec(pose[3:]).as_matrix(), rtol=0, atol=1e-8)
    np.testing.assert_allclose(doc["tensions"], t, rtol=1e-7, atol=1e-7)
    assert doc["slack_cables"] == [i + 1 for i in np.flatnonzero(t <= 0)]
    eig = _scaled_fd_eigenvalues(robot, l0, pose)
    assert doc["stable"] is True and eig[0] > 0
    np.testing.assert_allclose(doc["scaled_eigenvalues"], eig, rtol=1e-4, atol=1e-3 * abs(eig).max())
    assert "stable: the scaled stiffness's eigenvalues are all positive" in capsys.readouterr().out


def test_a_platform_balanced_above_its_cables_is_unstable_exit_2(tmp_path, capsys):
    """suspended4 with its centre of mass 0.3 m above the reference point (0.25 m above the
    attachments), started upright: the upright balance is a saddle (numpy: a negative
    eigenvalue there, the one the message gives); nothing is written."""
    text = example_path("suspended4.toml").read_text().replace("com = [0.0, 0.0, -0.1]", "com = [0.0, 0.0, 0.3]")
    path = tmp_path / "top_heavy.toml"
    path.write_text(text)
    robot = load_robot(path)
    l0 = np.full(4, 2.7)
    code, doc = _run(tmp_path, path, l0, "--start", "0", "0", "1.56", "0", "0", "0")
    err = capsys.readouterr().err
    assert code == 2 and doc is None and "is unstable" in err and "least eigenvalue" in err
    upright, _ = _reference(robot, l0, np.array([0.0, 0.0, 1.56, 0.0, 0.0, 0.0]))
    eig = _scaled_fd_eigenvalues(robot, l0, upright)
    assert eig[0] < 0
    assert f"least eigenvalue {eig[0]:.4g} N/m" in err.replace("\n", "")


@pytest.mark.parametrize("argv, message", [
    (["--lengths", "2.7", "2.7", "2.7"], "--lengths: got 3 value(s), robot 'suspended4' has 4 cables"),
    (["--lengths", "2.7", "2.7", "-2.7", "2.7"], "--lengths: cable 3: -2.7 m; every unstrained length must be > 0"),
    (["--lengths", "2.7", "2.7", "2.7", "2.7", "--law", "elastic"], "unknown cable law 'elastic'; allowed:"),
    (["--lengths", "2.7", "2.7", "2.7", "2.7", "--law", "ideal"], "law ideal needs at least 6 cables"),
    (["--lengths", "2.7", "2.7", "nan", "2.7"], "'nan' is not a finite number"),
])
def test_bad_input_exits_1_naming_the_value(tmp_path, capsys, argv, message):
    out = tmp_path / "s.json"
    try:
        code = main(["statics", "suspended4.toml", *argv, "--json", str(out)])
    except SystemExit as e:  # argparse's own errors
        code = e.code
    assert code == 1
    assert message in capsys.readouterr().err and not out.exists()


def test_lengths_that_leave_every_cable_slack_exit_2(tmp_path, capsys):
    """Without gravity, cables 5 m long from anchors 2.5 m from the platform's axis hold nothing."""
    text = example_path("suspended4.toml").read_text().replace("gravity = [0.0, 0.0, -9.81]",
                                                               "gravity = [0.0, 0.0, 0.0]")
    path = tmp_path / "weightless.toml"
    path.write_text(text)
    code, doc = _run(tmp_path, path, [5.0] * 4)
    assert code == 2 and doc is None
    assert "every cable is slack" in capsys.readouterr().err
