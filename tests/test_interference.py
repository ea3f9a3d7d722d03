"""Interference: segment distances against a brute-force minimization, the platform hull,
crossing cables, a cable through the platform, sagging profiles; and the two CLI commands."""

import json

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cstiffjax.commands.cli import main
from cstiffjax.core.status import Status
from cstiffjax.examples import example_path
from cstiffjax.io.robot_io import load_robot
from cstiffjax.workspace.interference import (
    cable_points,
    interference,
    interference_model,
    platform_hull,
    segment_distance,
)


def brute_segment_distance(p1, q1, p2, q2):
    """Minimum of |p1 + s d1 - p2 - t d2| over [0, 1]²: interior stationary point and the
    four edges (each a clamped 1-D minimization), all candidates compared."""
    d1, d2 = q1 - p1, q2 - p2

    def dist(s, t):
        return np.linalg.norm(p1 + s * d1 - p2 - t * d2)

    cands = []
    M = np.array([[d1 @ d1, -d1 @ d2], [-d1 @ d2, d2 @ d2]])
    rhs = np.array([-(p1 - p2) @ d1, (p1 - p2) @ d2])
    if abs(np.linalg.det(M)) > 1e-14:
        s, t = np.linalg.solve(M, rhs)
        if 0 <= s <= 1 and 0 <= t <= 1:
            cands.append(dist(s, t))
    for t in (0.0, 1.0):
        s = np.clip(-((p1 - p2 - t * d2) @ d1) / max(d1 @ d1, 1e-300), 0, 1)
        cands.append(dist(s, t))
    for s in (0.0, 1.0):
        t = np.clip(((p1 + s * d1 - p2) @ d2) / max(d2 @ d2, 1e-300), 0, 1)
        cands.append(dist(s, t))
    return min(cands)


def test_segment_distance_matches_brute_force():
    rng = np.random.default_rng(0)
    f = jax.jit(jax.vmap(segment_distance))
    X = rng.normal(size=(400, 4, 3))
    X[:50, 3] = X[:50, 2] + 1e-3 * (X[:50, 1] - X[:50, 0])  # nearly parallel
    X[50:80, 1] = X[50:80, 0]  # a point
    X[80:100, 2:] = X[80:100, :2] + np.array([0.0, 0.5, 0.0])  # exactly parallel
    d = np.asarray(f(*[jnp.asarray(X[:, k]) for k in range(4)]))
    ref = np.array([brute_segment_distance(*x) for x in X])
    np.testing.assert_allclose(d, ref, atol=1e-12, rtol=1e-10)


def test_platform_hull_box_and_flat():
    robot = load_robot(example_path("tcpr8.toml"))
    hull = platform_hull(robot.attachments)
    assert hull.normals.shape == (6, 3)  # the box's 6 faces
    assert np.all(np.asarray(hull.incidence).sum(0) == 3)  # 3 faces at each corner
    flat = load_robot(example_path("prototype_4mm.toml"))
    h2 = platform_hull(flat.attachments)
    assert np.all(np.asarray(h2.incidence).sum(0) == 4)  # both faces and two edges per vertex
    with pytest.raises(ValueError, match="collinear"):
        platform_hull(np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0.0]]))


@pytest.fixture(scope="module")
def tcpr8():
    robot = load_robot(example_path("tcpr8.toml"))
    return robot, interference_model(robot, diameter=0.004)


def test_crossing_cables_and_cable_through_platform(tcpr8):
    robot, model = tcpr8
    f = jax.jit(jax.vmap(lambda p: interference(robot, model, p)))
    # a half turn about z crosses the cables of each group in the middle of the workspace
    P = jnp.array([[0, 0, 0.89, 0, 0, 0], [0, 0, 0.89, 0, 0, np.pi * 0.999], [0, 1.2, 0.89, 0, np.pi, 0]])
    out = f(P)
    assert bool(out.free[0]) and np.all(np.asarray(out.platform_clearance[0]) > 0.5)
    assert float(out.margin[0]) == pytest.approx(0.085 - 0.004, abs=1e-9)  # cables 1 and 5 near the platform
    assert not bool(out.free[1]) and float(jnp.min(out.cable_distance[1])) < 0.004
    # turned over about y and moved beyond the +y anchors: cable 1 (top +x+y anchor) leaves its
    # corner into the box (+x, -y, +z all point inside there)
    assert not bool(out.free[2]) and float(out.platform_clearance[2, 0]) < 0


@pytest.mark.slow  # compiles the sagging inverse statics and the catenary (~1 min on 2 cores)
def test_sagging_profile_ends_at_the_attachment_and_sags_below_the_chord():
    robot = load_robot(example_path("prototype_4mm.toml"))
    pose = jnp.array([0.0, 0.0, 3.0, 0.0, 0.0, 0.0])
    points = eqx.filter_jit(cable_points)  # one compile for both robots
    pts, result = points(robot, pose, None, 9)
    assert result == Status.successful
    from cstiffjax.statics.geometry import attachment_points

    np.testing.assert_allclose(np.asarray(pts[:, -1]), np.asarray(attachment_points(robot, pose)), atol=1e-7)
    chord_mid = 0.5 * (np.asarray(pts[:, 0]) + np.asarray(pts[:, -1]))
    assert np.all(np.asarray(pts[:, 4, 2]) < chord_mid[:, 2])  # the middle sample hangs below
    light = eqx.tree_at(lambda r: r.mass_per_length, robot, jnp.full(6, 1e-9))
    pts0, _ = points(light, pose, None, 9)
    straight = np.linspace(np.asarray(pts0[:, 0]), np.asarray(pts0[:, -1]), 9, axis=1)
    np.testing.assert_allclose(np.asarray(pts0), straight, atol=1e-5)  # a nearly massless cable is straight


def test_cli_workspace_and_tensions(tmp_path, capsys):
    out = tmp_path / "ws"
    grid = ["--pose-grid", "-0.3", "0.3", "3", "-0.2", "0.2", "2", "0.6", "1.2", "2"]
    box = ["--wrench-box", *"-5 5 -5 5 -5 5 -0.5 0.5 -0.5 0.5 -0.5 0.5".split()]
    assert main(["workspace", "tcpr8.toml", "--kind", "wrench-feasible", *grid, *box, "--out", str(out),
                 "--no-progress"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    res = np.load(out / "results.npz")
    assert summary["poses"] == 12 and summary["members"] == int(res["member"].sum())
    w = np.einsum("i,j,k->ijk", [0.15, 0.3, 0.15], [0.2, 0.2], [0.3, 0.3])  # trapezoid cell per grid point
    assert summary["volume_m3"] == pytest.approx(float(np.sum(w[res["member"]])), rel=1e-12)
    assert (out / "workspace_3d.png").stat().st_size > 0 and (out / "workspace_sections.png").exists()
    # refuse to overwrite inputs and to mix options
    robot_copy = tmp_path / "results.npz"
    robot_copy.write_text(example_path("tcpr8.toml").read_text())
    assert main(["workspace", str(robot_copy), "--kind", "wrench-closure", *grid, "--out", str(tmp_path)]) == 1
    assert "would overwrite the input" in capsys.readouterr().err
    assert main(["workspace", "tcpr8.toml", "--kind", "wrench-closure", *grid, *box, "--out", str(out)]) == 1
    assert "only used with --kind wrench-feasible" in capsys.readouterr().err
    js = tmp_path / "t.json"
    code = main(["tensions", "tcpr8.toml", "--pose", "0", "0", "0.9", "0", "0", "0", "--method", "cfm",
                 "--json", str(js)])
    payload = json.loads(js.read_text())
    assert code == 0 and payload["status"] == "ok" and len(payload["tensions"]) == 8
