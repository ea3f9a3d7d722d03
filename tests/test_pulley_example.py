"""The bundled swivel-pulley robot ``pulleys8`` and every CLI command that takes
a robot, on it: the pulleys and gains of formats.md §1 v2 must be honoured.

The numbers are compared with references independent of :mod:`cstiffjax.cable.path`,
:mod:`cstiffjax.statics.geometry` and :mod:`fitting`: the swivel-pulley path written here from
formats.md §1 with polar angles (:func:`np_paths`; cstiffjax writes it with ``atan2`` sums),
numpy/scipy wrench balances, central differences and linear programs. Each test also
checks that the same reference *without* the pulleys (or gains) disagrees by far more than
the tolerance, so a command that silently dropped them would fail.
"""

import json

import numpy as np
import pytest
from scipy.optimize import linprog

from cstiffjax.commands.cli import main
from cstiffjax.examples import example_path
from cstiffjax.io.recordings import load_recordings
from cstiffjax.io.robot_io import load_robot

from .helpers import np_fd, np_frame

ROBOT = "pulleys8/robot.toml"
RECORDINGS = "pulleys8/recordings.csv"
POSE = [0.0, 0.0, 0.83, 0.0, 0.0, 0.0]  # the workspace centre of the generator's TCPR-8 box


@pytest.fixture(scope="module")
def robot():
    return load_robot(example_path(ROBOT))


def stripped(tmp_path, keys=("pulley_radius", "pulley_axis"), name="stripped.toml"):
    """A copy of the example's TOML without the lines of ``keys`` (the version-1 meaning)."""
    text = example_path(ROBOT).read_text().splitlines()
    path = tmp_path / name
    path.write_text("\n".join(s for s in text if s.split("=")[0].strip() not in keys) + "\n")
    return path


# ------------------------------------------------------------------ independent references
def np_paths(robot, p, R, pulleys=True):
    """Lever arms ``R b`` (m, 3), path lengths (m,), unit directions P -> T (m, 3) and the
    tangent points T (m, 3) by formats.md §1: in the pulley plane (``u`` across, ``e`` along
    the axis, origin at the centre C) the entry point A is at polar angle pi, the cable runs
    clockwise and leaves at the tangent point of polar angle ``psi + acos(r / rho)`` (``psi``
    and ``rho`` the polar coordinates of P); the wrap is pi minus that angle.
    ``pulleys=False``: straight cables from the anchors (the version-1 reading)."""
    b, A = np.asarray(robot.attachments), np.asarray(robot.anchors)
    rad, axes = np.asarray(robot.pulley_radius), np.asarray(robot.pulley_axis)
    r = b @ R.T
    P = p + r
    L, T = np.empty(len(A)), np.empty_like(A)
    for i in range(len(A)):
        if not pulleys or rad[i] == 0:
            T[i], L[i] = A[i], np.linalg.norm(A[i] - P[i])
            continue
        e = axes[i] / np.linalg.norm(axes[i])
        d = P[i] - A[i]
        u = d - (d @ e) * e
        u /= np.linalg.norm(u)
        C = A[i] + rad[i] * u
        x, z = (P[i] - C) @ u, (P[i] - C) @ e
        rho, psi = np.hypot(x, z), np.arctan2(z, x)
        phi = psi + np.arccos(rad[i] / rho)
        beta = (np.pi - phi) % (2 * np.pi)
        T[i] = C + rad[i] * (np.cos(phi) * u + np.sin(phi) * e)
        L[i] = rad[i] * beta + np.sqrt(rho**2 - rad[i] ** 2)
    D = T - P
    return r, L, D / np.linalg.norm(D, axis=1)[:, None], T


def np_structure(robot, pose, pulleys=True):
    p, R = np_frame(pose)
    r, _, u, _ = np_paths(robot, p, R, pulleys)
    return np.vstack([u.T, np.cross(r, u).T])


def np_weight(robot, pose, external=None):
    """Weight (plus ``external``) as a wrench about the reference point, N and N·m."""
    _, R = np_frame(pose)
    w = float(robot.platform_mass) * np.asarray(robot.gravity)
    out = np.concatenate([w, np.cross(R @ np.asarray(robot.com), w)])
    return out if external is None else out + np.asarray(external)


def np_spring_wrench(robot, l0, pose, twist=None, pulleys=True):
    """Net wrench of spring cables ``max(EA (L - l0) / l0, 0)`` (slack ones carry nothing)
    along the pulley paths plus the weight, N and N·m."""
    p, R = np_frame(pose, twist)
    r, L, u, _ = np_paths(robot, p, R, pulleys)
    f = np.maximum(np.asarray(robot.EA) * (L - l0) / l0, 0.0)[:, None] * u
    w = float(robot.platform_mass) * np.asarray(robot.gravity)
    return np.concatenate([f.sum(0) + w, np.cross(r, f).sum(0) + np.cross(R @ np.asarray(robot.com), w)])


def np_stiffness(robot, pose, tensions, pulleys=True):
    """K = -dW/dx (base-frame twist) by central differences, the spring lengths of ``tensions`` held."""
    p, R = np_frame(pose)
    _, L, _, _ = np_paths(robot, p, R, pulleys)
    EA = np.asarray(robot.EA)
    l0 = L * EA / (EA + np.asarray(tensions))
    return -np_fd(lambda tw: np_spring_wrench(robot, l0, pose, tw, pulleys), 6, 1e-7)


# ------------------------------------------------------------------ the example itself
def test_example_states_pulleys_axes_and_gains(robot):
    assert robot.name == "pulleys8" and robot.num_cables == 8
    np.testing.assert_array_equal(robot.pulley_radius, np.full(8, 0.025))
    # formats.md §1: the cable comes up to the top pulleys (above the workspace) and down to the bottom ones
    up = np.asarray(robot.anchors)[:, 2] > POSE[2]
    np.testing.assert_array_equal(np.asarray(robot.pulley_axis), np.c_[np.zeros((8, 2)), np.where(up, 1.0, -1.0)])
    np.testing.assert_array_equal(robot.length_gain, [1, 1, 1.004, 1, 1, 0.997, 1, 1])
    np.testing.assert_array_equal(robot.tension_gain, [1, 1.012, 1, 1, 1, 1, 0.988, 1])
    tcpr8 = load_robot(example_path("tcpr8.toml"))  # everything else is the TCPR-8's
    for f in ("anchors", "attachments", "EA", "mass_per_length", "platform_mass", "com", "tension_min",
              "tension_max"):
        np.testing.assert_array_equal(getattr(robot, f), getattr(tcpr8, f), err_msg=f)
    text = example_path(ROBOT).read_text() + example_path(RECORDINGS).read_text()
    assert "/work" not in text and "/home" not in text  # no absolute paths


def test_recordings_follow_formats_and_the_stated_hardware(robot):
    """Every recorded tension is the load-cell reading ``tension_gain x EA (L - l0_true) / l0_true``
    over the pulley path at the recorded pose, ``l0_true = l0_ref + length_gain (l0 - l0_ref)``
    (formats.md §1), to the tension noise; dropping a pulley or a gain breaks it on its cables."""
    header = example_path(RECORDINGS).read_text().splitlines()[0].split(",")
    m = 8
    assert header == (["time"] + [f"l0_{i}" for i in range(1, m + 1)] + ["fx", "fy", "fz", "mx", "my", "mz", "x", "y",
                      "z", "rx", "ry", "rz"] + [f"t_{i}" for i in range(1, m + 1)] + ["temperature"])
    rec = load_recordings(example_path(RECORDINGS), robot)
    assert rec.num_samples == 80 and rec.has_tensions and np.all(np.diff(np.asarray(rec.time)) > 0)
    l0, pose, meas = np.asarray(rec.l0), np.asarray(rec.pose), np.asarray(rec.tensions)
    EA, sigma = np.asarray(robot.EA), float(robot.noise.tension)

    def rms(pulleys=True, length_gain=True, tension_gain=True):
        g = np.asarray(robot.length_gain) if length_gain else 1.0
        k = np.asarray(robot.tension_gain) if tension_gain else 1.0
        l0_true = l0[0] + g * (l0 - l0[0])
        L = np.array([np_paths(robot, *np_frame(q), pulleys)[1] for q in pose])
        return np.sqrt(np.mean((meas - k * EA * (L - l0_true) / l0_true) ** 2, axis=0))

    full = rms()
    assert np.all(full < 1.4 * sigma), full  # the noise: sigma 0.5 N, 80 samples
    assert np.all(rms(pulleys=False) > 100 * sigma)
    no_lg, no_tg = rms(length_gain=False), rms(tension_gain=False)
    assert no_lg[2] > 2 * sigma and no_lg[5] > 2 * sigma, no_lg  # cables 3 and 6
    assert no_tg[1] > 2.5 * sigma and no_tg[6] > 2.5 * sigma, no_tg  # cables 2 and 7


def np_segment_distance(p1, q1, p2, q2):
    """Minimum distance between two segments: the convex quadratic ``|p1 + s d1 - p2 - t d2|²``
    on ``[0, 1]²`` at its interior stationary point (when inside) or on the box's edges
    (each a clamped 1-D minimum)."""
    d1, d2, w = q1 - p1, q2 - p2, p1 - p2
    cand = []
    M = np.array([[d1 @ d1, -d1 @ d2], [-d1 @ d2, d2 @ d2]])
    if abs(np.linalg.det(M)) > 1e-14 * (d1 @ d1) * (d2 @ d2):
        s, t = np.linalg.solve(M, [-(d1 @ w), d2 @ w])
        if 0 <= s <= 1 and 0 <= t <= 1:
            cand.append((s, t))
    for s in (0.0, 1.0):
        cand.append((s, np.clip((w + s * d1) @ d2 / (d2 @ d2), 0, 1)))
    for t in (0.0, 1.0):
        cand.append((np.clip(-(w - t * d2) @ d1 / (d1 @ d1), 0, 1), t))
    return min(np.linalg.norm(w + s * d1 - t * d2) for s, t in cand)


def np_free_span_margin(robot, pose, diameter, pulleys=True):
    """Smallest distance between two free spans (tangent point -> attachment) minus ``diameter``, m."""
    p, R = np_frame(pose)
    r, _, _, T = np_paths(robot, p, R, pulleys)
    P = p + r
    m = len(P)
    return min(np_segment_distance(T[i], P[i], T[j], P[j]) for i in range(m) for j in range(i + 1, m)) - diameter


# ------------------------------------------------------------------ the commands
def test_check_summarizes_pulleys_and_gains(tmp_path, capsys):
    out = tmp_path / "c.json"
    assert main(["check", ROBOT, RECORDINGS, "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert ("  pulleys: all 8 cables run over swivel pulleys; radius 0.025 m; axis [0, 0, 1] on cables 1-4, "
            "[0, 0, -1] on cables 5-8\n") in text
    assert ("  gains: length_gain 1.004 (cable 3), 0.997 (cable 6); tension_gain 1.012 (cable 2), "
            "0.988 (cable 7); the others 1\n") in text
    assert "recordings OK: 80 samples, 8 cables" in text
    hw = json.loads(out.read_text())["hardware"]
    assert hw["pulleys"]["count"] == 8 and hw["pulleys"]["cables"] == list(range(1, 9))
    assert hw["pulleys"]["radius_min_m"] == hw["pulleys"]["radius_max_m"] == 0.025
    assert hw["pulleys"]["axis"] == [[0.0, 0.0, 1.0]] * 4 + [[0.0, 0.0, -1.0]] * 4
    assert hw["non_unit_gains"] == {"length_gain": {"3": 1.004, "6": 0.997}, "tension_gain": {"2": 1.012, "7": 0.988}}
    assert hw["length_gain"] == [1, 1, 1.004, 1, 1, 0.997, 1, 1]
    # a robot without them: one line, and the same JSON keys, empty
    assert main(["check", "tcpr8.toml", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "  hardware: no pulleys (every cable leaves straight from its anchor); gains all 1\n" in text
    assert "pulleys:" not in text and "gains:" not in text.replace("gains all 1", "")
    hw = json.loads(out.read_text())["hardware"]
    assert hw["pulleys"] == {"count": 0, "cables": [], "radius_m": [], "axis": [], "radius_min_m": None,
                             "radius_max_m": None} and hw["non_unit_gains"] == {}
    # some cables only, two radii, one gain
    text = example_path(ROBOT).read_text().split("[[cables]]")
    text = [text[0]] + [c if i < 3 else "\n".join(s for s in c.splitlines() if not s.startswith("pulley_"))
                        for i, c in enumerate(text[1:])]
    text[2] = text[2].replace("pulley_radius = 0.025", "pulley_radius = 0.04").replace("tension_gain = 1.012",
                                                                                      "tension_gain = 1.0")
    mixed = tmp_path / "mixed.toml"
    mixed.write_text("[[cables]]".join(text))
    assert main(["check", str(mixed)]) == 0
    text = capsys.readouterr().out
    assert ("  pulleys: 3 of 8 cables (cables 1-3) run over swivel pulleys; radius 0.025 m on cables 1, 3, "
            "0.04 m on cable 2; axis [0, 0, 1]\n") in text
    assert "  gains: length_gain 1.004 (cable 3), 0.997 (cable 6); tension_gain 0.988 (cable 7); the others 1" in text


def test_csjm_with_pulley_or_gain_is_refused(tmp_path):
    from cstiffjax.core.errors import RobotFileError

    base = example_path("csjm.toml").read_text()
    head, first, rest = base.partition("[[cables]]")
    for extra, key in (("pulley_radius = 0.02\npulley_axis = [0.0, 0.0, 1.0]\n", "cables[1].pulley_radius"),
                       ("tension_gain = 1.01\n", "cables[1].tension_gain")):
        path = tmp_path / "c.toml"
        lines = rest.split("\n", 1)
        path.write_text(head + first + lines[0] + "\n" + extra + lines[1])
        with pytest.raises(RobotFileError, match=rf"{key.replace('[', '.').replace(']', '.')}.*csjm"):
            load_robot(path)
    path.write_text(head + first + lines[0] + "\nlength_gain = 1.0\npulley_radius = 0.0\n" + lines[1])
    assert load_robot(path).kind == "csjm"  # the defaults written out are fine


def test_tensions_command_balances_over_the_pulleys(robot, tmp_path):
    out = tmp_path / "t.json"
    assert main(["tensions", ROBOT, "--pose", *map(str, POSE), "--method", "cfm", "--json", str(out)]) == 0
    t = np.array(json.loads(out.read_text())["tensions"])
    W = np_weight(robot, POSE)
    assert np.abs(np_structure(robot, POSE) @ t + W).max() < 1e-9
    assert np.abs(np_structure(robot, POSE, pulleys=False) @ t + W).max() > 1.0  # N: the straight reading is off

def _assert_balanced_pulley_stiffness(robot, t, K):
    """``t`` balances the weight at POSE (numpy statics), ``K`` is the numpy pulley-path
    stiffness at ``t`` and the straight-cable one differs from it by far more than that."""
    assert np.abs(np_structure(robot, POSE) @ t + np_weight(robot, POSE)).max() < 1e-8
    ref, straight = np_stiffness(robot, POSE, t), np_stiffness(robot, POSE, t, pulleys=False)
    scale = np.abs(ref).max()
    np.testing.assert_allclose(K, ref, rtol=0, atol=1e-6 * scale)
    assert np.abs(straight - ref).max() > 1e-3 * scale



@pytest.mark.slow  # compiles the CTFR centroid and the pulley-path stiffness: 6.9 s on 2 busy cores
def test_stiffness_command_over_the_pulleys(robot, tmp_path):
    """Default tensions (CTFR centroid) balance the weight over the pulley paths, and K is
    the central-difference stiffness of spring cables along those paths; the straight
    cables' K differs from it by far more than the tolerance."""
    out = tmp_path / "k.json"
    assert main(["stiffness", ROBOT, "--pose", *map(str, POSE), "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    _assert_balanced_pulley_stiffness(robot, np.array(data["tensions"]), np.array(data["K"]))


def test_workspace_interference_over_the_pulleys(robot, tmp_path):
    """Half a turn less 0.2 pi about z at z = 0.6 m brings two free spans within 5 cm of each
    other; their distance is measured from the tangent points (2.6 mm more than from the anchors)."""
    rz = 0.8 * np.pi
    out = tmp_path / "ws"
    assert main(["workspace", ROBOT, "--kind", "interference", "--pose-grid", "0", "0", "1", "0", "0", "1", "0.6",
                 "0.6", "1", "--rotation", "0", "0", repr(rz), "--cable-diameter", "0.004", "--out", str(out),
                 "--no-progress"]) == 0
    margin = json.loads((out / "summary.json").read_text())["margin_all"]["min"]
    pose = [0.0, 0.0, 0.6, 0.0, 0.0, rz]
    ref, straight = np_free_span_margin(robot, pose, 0.004), np_free_span_margin(robot, pose, 0.004, pulleys=False)
    assert margin == pytest.approx(ref, abs=1e-9)
    assert abs(straight - ref) > 2e-3


@pytest.mark.slow  # compiles the wrench-feasible kernel on the pulley path: 9.8 s on 2 busy cores
def test_workspace_wrench_feasible_over_the_pulleys(robot, tmp_path):
    """Membership on a line of poses against linear programs on the pulley structure matrix
    (every vertex of the force box held with tensions inside the limits). The box is sized
    so that the answer at z = 0.4 m depends on the pulleys (capacity margin +1.0 N with
    them, -1.3 N for straight cables)."""
    out = tmp_path / "ws"
    box = [-140, 140, -140, 140, -140, 140, 0, 0, 0, 0, 0, 0]
    assert main(["workspace", ROBOT, "--kind", "wrench-feasible", "--pose-grid", "0.3", "0.3", "1", "0", "0", "1",
                 "0.2", "0.6", "5", "--wrench-box", *map(str, box), "--out", str(out), "--no-progress"]) == 0
    res = np.load(out / "results.npz")
    vertices = np.unique(np.array(np.meshgrid(*np.reshape(box, (6, 2)), indexing="ij")).reshape(6, -1).T, axis=0)
    bounds = [(float(robot.tension_min), float(robot.tension_max))] * 8

    def feasible(pose, pulleys):
        S = np_structure(robot, pose, pulleys)
        return all(linprog(np.zeros(8), A_eq=S, b_eq=-np_weight(robot, pose, w), bounds=bounds).status == 0
                   for w in vertices)

    poses = [[0.3, 0.0, z, 0.0, 0.0, 0.0] for z in res["z"]]
    got = [bool(v) for v in res["member"].ravel()]
    assert got == [feasible(q, True) for q in poses] == [False, False, True, True, True]
    assert [feasible(q, False) for q in poses] == [False, False, False, True, True]


@pytest.mark.slow  # compiles spring and catenary forward statics and the sagging inverse statics: 22.6 s
def test_sag_command_over_the_pulleys(robot, tmp_path):
    """The ideal lengths are the pulley path lengths, and the spring-settled pose balances the
    weight over the pulleys (independent numpy wrench), not over straight cables. (The
    TCPR-8's cables are massless: at the minimum-norm tensions the lower four go slack, the
    catenary solve reports so, and only the spring part is checked.)"""
    assert main(["sag", ROBOT, "--pose", *map(str, POSE), "--out", str(tmp_path)]) == 0
    data = json.loads((tmp_path / "sag.json").read_text())
    p, R = np_frame(POSE)
    L, straight = np_paths(robot, p, R)[1], np_paths(robot, p, R, pulleys=False)[1]
    np.testing.assert_allclose(data["l0_ideal"], L, rtol=1e-13)
    assert np.abs(straight - L).min() > 0.03  # m: the wrap r beta and the shorter free span
    e = np.asarray(data["error_spring"])
    settled = np.concatenate([np.asarray(POSE[:3]) + e[:3], e[3:]])  # the reference pose is unrotated
    l0 = np.asarray(data["l0_ideal"])
    assert np.abs(np_spring_wrench(robot, l0, settled)).max() < 1e-6
    assert np.abs(np_spring_wrench(robot, l0, settled, pulleys=False)).max() > 1.0


@pytest.mark.slow  # compiles the CTFR centroid and the CSS membership on the pulley path: 18.3 s
def test_css_command_over_the_pulleys(robot, tmp_path):
    """The target stiffness k_c is the central-difference stiffness of spring cables along the
    pulley paths at the CTFR-centroid tensions (which balance the weight over the pulleys);
    the target pose itself is a member of its CSS."""
    out = tmp_path / "css"
    assert main(["css", ROBOT, "--pose-grid", "0", "0", "1", "0", "0", "1", "0.83", "0.83", "1",
                 "--stiffness-at", *map(str, POSE), "--out", str(out), "--no-progress"]) == 0
    data = json.loads((out / "summary.json").read_text())
    _assert_balanced_pulley_stiffness(robot, np.asarray(data["target_tensions"]), np.asarray(data["kc"]))
    assert data["members"] == 1


@pytest.mark.slow  # three calibrations (one compile of the forward statics, three fits): 19.7 s
def test_fit_command_honours_pulleys_and_gains(tmp_path):
    """EA calibrated on the example explains it to the noise (chi2/dof ~ 1); the same
    description without its pulleys, or without its gains, does not."""
    def chi2(path):
        out = tmp_path / "fit.json"
        assert main(["fit", str(path), RECORDINGS, "--free", "EA", "--json", str(out)]) == 0
        return json.loads(out.read_text())["chi2_per_dof"]

    assert chi2(example_path(ROBOT)) < 1.2
    assert chi2(stripped(tmp_path, ("length_gain", "tension_gain"), "no_gains.toml")) > 1.5
    assert chi2(stripped(tmp_path)) > 100.0


@pytest.mark.slow  # the whole diagnosis on 80 samples of an 8-cable robot: 126 s on 2 busy cores
def test_diagnose_finds_nothing_on_the_clean_pulley_example(tmp_path, capsys):
    """Nothing is concealed in the example (benchmarks/pulleys8_key.json): a description that
    states its pulleys and gains must get no false effect."""
    out = tmp_path / "d.json"
    assert main(["diagnose", ROBOT, RECORDINGS, "--json", str(out), "--quiet"]) == 0
    d = json.loads(out.read_text())
    assert d["effects"] == [] and d["explained"] is True and d["samples"] == 80
    assert d["final"]["chi2_per_dof"] < 1.2


def test_interference_polyline_wraps_the_pulley(robot):
    """The cable polyline of a pulley robot: the anchor, points on the pulley circle (centre
    C, radius r, in the plane of the axis and P) ending at the tangent point T, then P."""
    from cstiffjax.workspace.interference import ARC_POINTS, cable_points

    pose = [0.1, -0.05, 0.7, 0.02, 0.0, 0.3]
    pts = np.asarray(cable_points(robot, np.asarray(pose), None, 2)[0])
    p, R = np_frame(pose)
    r, _, _, T = np_paths(robot, p, R)
    assert pts.shape == (8, ARC_POINTS + 2, 3)
    np.testing.assert_allclose(pts[:, 0], robot.anchors, atol=1e-15)
    np.testing.assert_allclose(pts[:, ARC_POINTS - 1], T, atol=1e-12)
    np.testing.assert_allclose(pts[:, ARC_POINTS], T, atol=1e-12)
    np.testing.assert_allclose(pts[:, -1], p + r, atol=1e-12)
    A, e = np.asarray(robot.anchors), np.asarray(robot.pulley_axis)
    for i in range(8):
        d = p + r[i] - A[i]
        u = d - (d @ e[i]) * e[i]
        C = A[i] + 0.025 * u / np.linalg.norm(u)
        arc = pts[i, :ARC_POINTS]
        np.testing.assert_allclose(np.linalg.norm(arc - C, axis=1), 0.025, rtol=1e-12)
        np.testing.assert_allclose((arc - C) @ np.cross(e[i], u), 0.0, atol=1e-12)  # in the pulley plane
