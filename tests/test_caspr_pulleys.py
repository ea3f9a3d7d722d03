"""CASPR models with rotating pulleys, fewer than 6 cables, and ``convert --out`` kept out of
cstiffjax's own files (cstiffjax.io.caspr, ``cstiffjax convert``).

The pulley model is CASPR's CUHK CUCableRobot (``indev_models/CUHK/CUCableRobot/``, cable set
``calibration_frame``), re-typed by hand from CASPR's repository (github.com/darwinlau/CASPR):
10 kg, ``q_initial = 1.14 1.14 1.0 0 0 0``, 8 ``cable_ideal`` cables over
``<base_rotating_pulley>``s of radius 0.045 m, four at the top of the frame (z = 1.905 m, the
cable entering upwards, ``cable_entry_vector = 0 0 1``) and four at the bottom (z = 0.095 m,
entering downwards, ``0 0 -1``). The reference lengths are CASPR's definition of that pulley
(``BaseRotatingPulleyAttachment``: centre, tangent point and arc), restated in numpy below.
"""

import re
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from cstiffjax.commands import convert
from cstiffjax.commands.cli import main
from cstiffjax.io.caspr import CasprModelError, pose_from_q, read_caspr
from cstiffjax.io.robot_io import load_robot
from cstiffjax.statics.geometry import cable_geometry, frame
from tests.test_caspr import COGIRO_CABLES, body, cable, cables_file, write

CUHK_BODY = body(name="CUHK", q="1.14 1.14 1.0 0.0 0.0 0.0", mass="10.0", com="0.0 0.0 0.0",
                 inertia=("1.0", "1.0", "1.0", "0.0", "0.0", "0.0"))
# CUHK_CUCableRobot_cables.xml, cable set calibration_frame: (name, fixed_location, entry, link 1 location)
CUHK_CABLES = [
    ("X", "0.083 2.197 1.905", "0 0 1", "-0.1825 0.1475 0.140"),
    ("Y", "2.197 2.197 0.095", "0 0 -1", "0.1825 0.1475 -0.140"),
    ("Z", "2.197 2.197 1.905", "0 0 1", "0.1825 0.1475 0.140"),
    ("A", "2.197 0.083 0.095", "0 0 -1", "0.1825 -0.1475 -0.140"),
    ("B", "2.197 0.083 1.905", "0 0 1", "0.1825 -0.1475 0.140"),
    ("C", "0.083 0.083 0.095", "0 0 -1", "-0.1825 -0.1475 -0.140"),
    ("U", "0.083 0.083 1.905", "0 0 1", "-0.1825 -0.1475 0.140"),
    ("V", "0.083 2.197 0.095", "0 0 -1", "-0.1825 0.1475 -0.140"),
]
RADIUS = 0.045


def pulley_cable(name, fixed, entry, platform, radius=RADIUS, first=None, kind="cable_ideal"):
    pulley = (f"<base_rotating_pulley><fixed_location>{fixed}</fixed_location><pulley_radius>{radius}"
              f"</pulley_radius><cable_entry_vector>{entry}</cable_entry_vector></base_rotating_pulley>")
    end = f"<attachment><link>1</link><location>{platform}</location></attachment>"
    first = pulley + end if first is None else first
    return (f'    <{kind} name="{name}" attachment_reference="joint">\n'
            f"      <properties><force_min>10</force_min><force_max>300</force_max></properties>\n"
            f"      <attachments>{first}</attachments>\n    </{kind}>\n")


def cuhk_files(tmp_path, cables=None):
    cables = CUHK_CABLES if cables is None else cables
    text = cables_file([("calibration_frame", [pulley_cable(*c) for c in cables])], default="calibration_frame")
    return write(tmp_path, CUHK_BODY, text, stem="CUHK_CUCableRobot")


def caspr_pulley(F, v, B, R):
    """CASPR's rotating pulley at one platform point, from its definition: the pulley plane
    holds the entry direction ``v`` and ``B - F``; the centre ``C`` lies ``R`` from the entry
    point ``F`` towards ``B``, normal to ``v``; the cable leaves at the tangent point
    ``A = C + rho² (B - C) - rho sqrt(1 - rho²) n × (B - C)`` (``rho = R / |B - C|``, ``n`` the
    plane's unit normal ``v × (B - F)``); the wrapped arc is ``R`` times the angle between
    ``F - C`` and ``A - C`` (an arccos, in [0, pi]); the cable length is the arc plus ``|B - A|``.

    **Returns:** ``(length, A, arc)``, m."""
    n = np.cross(v, B - F)
    c = np.cross(n, v)
    C = F + R * c / np.linalg.norm(c)
    d = B - C
    rho = R / np.linalg.norm(d)
    A = C + rho**2 * d - rho * np.sqrt(1 - rho**2) * np.cross(n / np.linalg.norm(n), d)
    arc = R * np.arccos(np.clip((F - C) @ (A - C) / R**2, -1.0, 1.0))
    return arc + np.linalg.norm(B - A), A, arc


def platform_points(q, platform):
    """CASPR's platform points of joint coordinate ``q`` (SPATIAL_EULER_XYZ, parent at 0)."""
    return np.asarray(q[:3]) + np.asarray(platform) @ Rotation.from_euler("XYZ", q[3:]).as_matrix().T


def test_rotating_pulleys_map_onto_swivel_pulleys(tmp_path):
    model = read_caspr(*cuhk_files(tmp_path), ea=1e5)
    r = model.robot
    fixed = np.array([np.fromstring(c[1], sep=" ") for c in CUHK_CABLES])
    entry = np.array([np.fromstring(c[2], sep=" ") for c in CUHK_CABLES])
    np.testing.assert_array_equal(np.asarray(r.anchors), fixed)  # the cable enters at the fixed location
    np.testing.assert_array_equal(np.asarray(r.pulley_radius), np.full(8, RADIUS))
    np.testing.assert_array_equal(np.asarray(r.pulley_axis), entry)  # +z at the top, -z at the bottom
    # swivel_zero: the pulley's horizontal direction towards the platform point at q_initial
    B = platform_points([1.14, 1.14, 1.0, 0, 0, 0], [np.fromstring(c[3], sep=" ") for c in CUHK_CABLES])
    horizontal = (B - fixed) * [1, 1, 0]
    np.testing.assert_allclose(np.asarray(r.swivel_zero), horizontal / np.linalg.norm(horizontal, axis=1)[:, None],
                               rtol=0, atol=1e-15)
    assert any("swivel_zero" in a and "q_initial" in a for a in model.assumptions)


@pytest.mark.parametrize("q", [[1.14, 1.14, 1.0, 0, 0, 0], [0.9, 1.4, 0.7, 0.15, -0.2, 0.3],
                               [1.5, 0.8, 1.3, -0.25, 0.1, -0.4]])
def test_converted_lengths_are_caspr_lengths(tmp_path, q):
    r = read_caspr(*cuhk_files(tmp_path), ea=1e5).robot
    g = cable_geometry(r, *frame(pose_from_q(q, [0, 0, 0])))
    B = platform_points(q, [np.fromstring(c[3], sep=" ") for c in CUHK_CABLES])
    for i, (_, fixed, entry, _) in enumerate(CUHK_CABLES):
        length, A, arc = caspr_pulley(np.fromstring(fixed, sep=" "), np.fromstring(entry, sep=" "), B[i], RADIUS)
        assert 0.3 < arc / RADIUS < 3.0  # a real wrap, below pi: where CASPR's arc is the wrap
        np.testing.assert_allclose(float(g.length[i]), length, rtol=0, atol=1e-12)
        np.testing.assert_allclose(np.asarray(g.exit[i]), A, rtol=0, atol=1e-12)  # the same tangent point
        np.testing.assert_allclose(float(g.wrap[i]), arc, rtol=0, atol=1e-12)


def test_wrap_beyond_pi_is_the_true_wrap(tmp_path):
    """With the platform point under the pulley, closer to the swivel axis than the pulley's
    far side, the cable leaves back towards the axis: the wrap exceeds pi, CASPR's arccos gives
    2 pi - wrap, and the converted length is the true path (caspr.md says so)."""
    cables = [("W", "0 0 2", "0 0 1", "0.06 0.0 0.0")]
    r = read_caspr(*cuhk_files(tmp_path, cables), ea=1e5).robot
    q = [0.0, 0.01, 1.0, 0, 0, 0]
    g = cable_geometry(r, *frame(pose_from_q(q, [0, 0, 0])))
    B = platform_points(q, [[0.06, 0, 0]])[0]
    length, A, arc = caspr_pulley(np.array([0, 0, 2.0]), np.array([0, 0, 1.0]), B, RADIUS)
    np.testing.assert_allclose(np.asarray(g.exit[0]), A, rtol=0, atol=1e-12)
    assert float(g.wrap[0]) > np.pi * RADIUS
    np.testing.assert_allclose(float(g.wrap[0]), 2 * np.pi * RADIUS - arc, rtol=0, atol=1e-12)
    np.testing.assert_allclose(float(g.length[0]), length - arc + (2 * np.pi * RADIUS - arc), rtol=0, atol=1e-12)


def test_convert_command_writes_pulleys_that_load(tmp_path, capsys):
    b, c = cuhk_files(tmp_path)
    out = tmp_path / "cuhk.toml"
    assert main(["convert", str(b), str(c), "--out", str(out), "--ea", "2e5"]) == 0
    text = capsys.readouterr().out
    assert "swivel pulleys on cables 1, 2, 3, 4, 5, 6, 7, 8 (radius 0.045..0.045 m)" in text
    assert "rank 6 of 6" in text
    robot, expected = load_robot(out), read_caspr(b, c, ea=2e5).robot
    for field in ("anchors", "attachments", "pulley_radius", "pulley_axis"):
        np.testing.assert_array_equal(np.asarray(getattr(robot, field)), np.asarray(getattr(expected, field)))
    # the loader scales swivel_zero to unit length again: the last bit may move
    np.testing.assert_allclose(np.asarray(robot.swivel_zero), np.asarray(expected.swivel_zero), rtol=0, atol=1e-15)


PULLEY_ARGS = ("X", "0.083 2.197 1.905", "0 0 1", "-0.1825 0.1475 0.140")
END = "<attachment><link>1</link><location>-0.1825 0.1475 0.140</location></attachment>"
BASE = "<attachment><link>0</link><location>0.083 2.197 1.905</location></attachment>"
PULLEY = ("<base_rotating_pulley><fixed_location>0.083 2.197 1.905</fixed_location><pulley_radius>0.045"
          "</pulley_radius><cable_entry_vector>0 0 1</cable_entry_vector></base_rotating_pulley>")
SCREW = ("<screw_base_rotating_pulley><constant_winch_point>0 0 0</constant_winch_point>"
         "</screw_base_rotating_pulley>")


@pytest.mark.parametrize("changed, pattern", [
    (pulley_cable(*PULLEY_ARGS, radius="0"), r"element 1 <pulley_radius>: value 0.0 must be > 0 \(m\)"),
    (pulley_cable(*PULLEY_ARGS[:2], "0 0 0", PULLEY_ARGS[3]),
     r"<cable_entry_vector>: value \[0.0, 0.0, 0.0\]: the direction in which the cable enters the pulley"),
    (pulley_cable(*PULLEY_ARGS).replace("<cable_entry_vector>0 0 1</cable_entry_vector>", ""),
     r"<attachments> element 1: missing element <cable_entry_vector>"),
    (pulley_cable(*PULLEY_ARGS, first=BASE + PULLEY + END),
     r"element 2: <base_rotating_pulley> cannot be mapped \(only as element 1, on the base\)"),
    (pulley_cable(*PULLEY_ARGS, first=SCREW + END), r"element 1: <screw_base_rotating_pulley> cannot be mapped: "
                                                    r"supported are straight cables .*\(no screw-drive pulleys"),
    (pulley_cable(*PULLEY_ARGS).replace(END, BASE + END),
     r"element 2 <link>: value '0': a cable must join link 0 \(the base, or a <base_rotating_pulley>\)"),
], ids=["radius 0", "zero entry", "no entry", "pulley second", "screw drive", "pulley and base point"])
def test_bad_pulleys_are_refused(tmp_path, changed, pattern):
    text = cables_file([("calibration_frame", [changed] + [pulley_cable(*c) for c in CUHK_CABLES[1:]])])
    with pytest.raises(CasprModelError, match=r"_cables\.xml: line \d+: <cable_set id='calibration_frame'> "
                                              r"<cable_ideal name='X'> <attachments>"):
        read_caspr(*write(tmp_path, CUHK_BODY, text), ea=1e5)
    with pytest.raises(CasprModelError, match=pattern):
        read_caspr(*write(tmp_path, CUHK_BODY, text), ea=1e5)


SUSPENDED = [COGIRO_CABLES[i] for i in (0, 2, 4, 6)]  # CoGiRo's lower attachment at each corner


def test_four_cable_suspended_model(tmp_path, capsys):
    cables = cables_file([("four", [cable(f"c{i}", b, p) for i, (b, p) in enumerate(SUSPENDED, 1)])])
    b, c = write(tmp_path, body(), cables)
    model = read_caspr(b, c, ea=2e5)
    r = model.robot
    assert r.num_cables == 4 and model.cable_set == "four"
    np.testing.assert_array_equal(np.asarray(r.anchors), [np.fromstring(a, sep=" ") for a, _ in SUSPENDED])
    np.testing.assert_array_equal(np.asarray(r.attachments), [np.fromstring(p, sep=" ") for _, p in SUSPENDED])
    out = tmp_path / "four.toml"
    assert main(["convert", str(b), str(c), "--out", str(out), "--ea", "2e5"]) == 0
    text = capsys.readouterr().out
    assert "4 cables: under-constrained, the platform's weight closes the equilibrium" in text
    assert "structure matrix rank 4 of 4" in text and "cannot be held" not in text
    assert load_robot(out).num_cables == 4


def test_empty_cable_set_is_refused(tmp_path):
    files = write(tmp_path, body(), cables_file([("none", [])]))
    with pytest.raises(CasprModelError, match=r"_cables\.xml: cable set 'none' has no cable; a robot needs one"):
        read_caspr(*files, ea=2e5)


def test_ea_is_required_for_ideal_cables_and_its_help_says_what_it_is(tmp_path, capsys):
    b, c = cuhk_files(tmp_path)
    with pytest.raises(CasprModelError, match=r"8 cable\(s\) are <cable_ideal> \(X, Y, .*\): CASPR's ideal cables "
                                              r"are rigid .*--ea N.*Young's modulus x cross-section area"):
        read_caspr(b, c)
    with pytest.raises(SystemExit):
        main(["convert", "--help"])
    help_text = " ".join(capsys.readouterr().out.split())
    assert re.search(r"--ea N\s+axial stiffness E\*A written for every cable, N: Young's modulus x cross-section "
                     r"area, e.g. from the cable's datasheet \(required when the model has cable_ideal", help_text)


SOURCE = Path(convert.__file__).resolve().parents[1]  # the cstiffjax package these tests run


@pytest.mark.parametrize("where", ["package", "checkout", "link"])
def test_out_inside_cstiffjax_is_refused(tmp_path, capsys, where):
    b, c = cuhk_files(tmp_path)
    if where == "package":
        out = SOURCE / "examples" / "cuhk_converted.toml"
    elif where == "checkout":
        assert (SOURCE.parent / "pyproject.toml").is_file()  # these tests run from a source checkout
        out = SOURCE.parent / "cuhk_converted.toml"
    else:
        (tmp_path / "link").symlink_to(SOURCE / "examples")
        out = tmp_path / "link" / "cuhk_converted.toml"
    assert main(["convert", str(b), str(c), "--out", str(out), "--ea", "1e5"]) == 1
    err = capsys.readouterr().err
    what = "cstiffjax's source checkout" if where == "checkout" else "the installed cstiffjax package"
    assert f"--out {out}: lies inside {what}" in err and "outside it" in err
    assert not out.exists()
    assert main(["convert", "irma4u", str(tmp_path), "--out", str(out.parent / "irma4u")]) == 1
    assert "lies inside" in capsys.readouterr().err
