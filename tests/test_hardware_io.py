"""formats.md §1 version 2: per-cable pulley and gain fields in the robot TOML."""

import numpy as np
import pytest

from cstiffjax import RobotFileError, load_robot, save_robot
from cstiffjax.examples import example_path
from cstiffjax.io.robot import CableRobot

BASE = example_path("example01/robot.toml").read_text()
FIRST = "mass_per_length = 0.0\n"  # end of the first [[cables]] table


def _with(tmp_path, extra: str):
    assert FIRST in BASE
    p = tmp_path / "robot.toml"
    p.write_text(BASE.replace(FIRST, FIRST + extra, 1))
    return p


def test_v1_file_means_what_it_meant():
    robot = load_robot(example_path("example01/robot.toml"))
    np.testing.assert_array_equal(robot.pulley_radius, np.zeros(6))
    np.testing.assert_array_equal(robot.pulley_axis, np.zeros((6, 3)))
    np.testing.assert_array_equal(robot.length_gain, np.ones(6))
    np.testing.assert_array_equal(robot.tension_gain, np.ones(6))


def test_v1_file_written_without_v2_keys(tmp_path):
    robot = load_robot(example_path("example01/robot.toml"))
    save_robot(robot, tmp_path / "a.toml")
    text = (tmp_path / "a.toml").read_text()
    for key in ("pulley_radius", "pulley_axis", "length_gain", "tension_gain"):
        assert key not in text


def test_v2_fields_roundtrip(tmp_path):
    extra = ("pulley_radius = 0.025\npulley_axis = [0.0, 0.6, 0.8]\n"
             "length_gain = 1.013\ntension_gain = 0.985\n")
    robot = load_robot(_with(tmp_path, extra))
    assert float(robot.pulley_radius[0]) == 0.025 and float(robot.pulley_radius[1]) == 0.0
    np.testing.assert_array_equal(robot.pulley_axis[0], [0.0, 0.6, 0.8])
    np.testing.assert_array_equal(robot.pulley_axis[1], [0.0, 0.0, 0.0])
    assert float(robot.length_gain[0]) == 1.013 and float(robot.tension_gain[0]) == 0.985
    save_robot(robot, tmp_path / "b.toml")
    again = load_robot(tmp_path / "b.toml")
    for f in ("pulley_radius", "pulley_axis", "length_gain", "tension_gain", "anchors", "EA"):
        np.testing.assert_array_equal(getattr(again, f), getattr(robot, f))
    text = (tmp_path / "b.toml").read_text()
    assert text.count("pulley_radius") == 1 and text.count("length_gain") == 1


@pytest.mark.parametrize(
    ("extra", "match"),
    [
        ("pulley_radius = 0.02\n", r"missing required key 'cables\[1\].pulley_axis'.*pulley_radius = 0.02 > 0"),
        ("pulley_radius = 0.02\npulley_axis = [0.0, 0.0, 2.0]\n",
         r"key 'cables\[1\].pulley_axis' \(line \d+\): must be a unit vector.*\[0.0, 0.0, 2.0\].*length 2.0"),
        ("pulley_radius = -0.01\npulley_axis = [0.0, 0.0, 1.0]\n", r"cables\[1\].pulley_radius.*-0.01 must be >= 0"),
        ("pulley_axis = [0.0, 1.0]\n", r"cables\[1\].pulley_axis.*shape \(3,\)"),
        ("length_gain = 0.0\n", r"cables\[1\].length_gain.*0.0 must be > 0"),
        ("tension_gain = \"one\"\n", r"cables\[1\].tension_gain.*expected a number"),
        ("pulley_colour = 1\n", r"cables\[1\].pulley_colour.*unknown key.*pulley_axis"),
    ],
)
def test_bad_v2_fields_name_key_value(tmp_path, extra, match):
    p = _with(tmp_path, extra)
    with pytest.raises(RobotFileError, match=match) as info:
        load_robot(p)
    assert str(p) in str(info.value)


def test_robot_shape_checks_name_the_field():
    robot = load_robot(example_path("example01/robot.toml"))
    kw = {k: getattr(robot, k) for k in ("anchors", "attachments", "EA", "mass_per_length", "platform_mass",
                                          "com", "inertia", "gravity", "noise")}
    with pytest.raises(ValueError, match=r"pulley_axis must have shape \(6, 3\)"):
        CableRobot(**kw, pulley_axis=np.zeros((6, 2)))
    with pytest.raises(ValueError, match=r"length_gain must have shape \(6,\)"):
        CableRobot(**kw, length_gain=np.ones(5))


def test_summary_names_pulleys_and_gains(tmp_path):
    from cstiffjax.io.robot import robot_summary

    plain = load_robot(example_path("example01/robot.toml"))
    assert "pulley" not in robot_summary(plain) and "gain" not in robot_summary(plain)
    robot = load_robot(_with(tmp_path, "pulley_radius = 0.025\npulley_axis = [0.0, 0.0, 1.0]\ntension_gain = 1.02\n"))
    s = robot_summary(robot)
    assert "swivel pulleys on cables 1 (radius 0.025..0.025 m)" in s
    assert "load-cell gains 1..1.02" in s and "winch" not in s
