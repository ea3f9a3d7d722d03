import numpy as np
import pytest

from cstiffjax import RobotFileError, load_robot, save_robot
from cstiffjax.examples import example_path, list_examples
from cstiffjax.io.robot import CableRobot

BASE = (example_path("example01/robot.toml")).read_text()


def _write(tmp_path, text, name="robot.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_load_example_and_roundtrip(tmp_path):
    robot = load_robot(example_path("example01/robot.toml"))
    assert isinstance(robot, CableRobot) and robot.num_cables == 6
    np.testing.assert_allclose(robot.anchors[4], [-5.775, 0.01, 4.193])
    np.testing.assert_allclose(robot.EA, 1.01034e6)
    assert robot.name == "example01" and float(robot.noise.tension) == 0.3
    assert np.isinf(robot.tension_max) and float(robot.tension_min) == 0.0
    save_robot(robot, tmp_path / "copy.toml")
    again = load_robot(tmp_path / "copy.toml")
    for f in ("anchors", "attachments", "EA", "mass_per_length", "com", "gravity"):
        np.testing.assert_array_equal(getattr(again, f), getattr(robot, f))
    assert again.name == robot.name


def test_all_bundled_robots_load():
    tomls = [n for n in list_examples() if n.endswith(".toml")]
    assert len(tomls) >= 2
    for name in tomls:
        robot = load_robot(example_path(name))
        assert robot.num_cables >= 3


def test_optional_fields_roundtrip(tmp_path):
    inertia = "inertia = [[0.9, 0, 0], [0, 0.9, 0], [0, 0, 0.77]]"
    text = BASE.replace("com = [0.0, 0.0, 0.0]", "com = [0.0, 0.0, 0.1]\n" + inertia)
    text += "\n[limits]\ntension_min = 10.0\ntension_max = 400.0\n"
    robot = load_robot(_write(tmp_path, text))
    assert float(robot.tension_max) == 400.0
    np.testing.assert_allclose(np.diag(robot.inertia), [0.9, 0.9, 0.77])
    save_robot(robot, tmp_path / "b.toml")
    again = load_robot(tmp_path / "b.toml")
    assert float(again.tension_min) == 10.0 and float(again.com[2]) == 0.1


@pytest.mark.parametrize(
    ("old", "new", "match"),
    [
        ('kind = "cdpr"', 'kind = "delta"', r"key 'kind' \(line 1\).*'delta'.*allowed: 'cdpr', 'csjm'"),
        ("mass = 30.0", "mass = 30.0\ncolour = 1", r"key 'platform.colour' \(line 7\): unknown key"),
        ("EA = 1.01034e+06", "EA = 0.0", r"key 'cables\[1\].EA' \(line 17\): value 0.0 must be > 0"),
        ("EA = 1.01034e+06", "EA = nan", r"cables\[1\].EA.*NaN"),
        ("anchor = [5.327, -2.267, 4.193]", "anchor = [5.327, -2.267]", r"cables\[1\].anchor.*shape \(3,\)"),
        ("position = 2e-05", "position = -1.0", r"noise.position.*must be > 0"),
        ("mass = 30.0\n", "", r"missing required key 'platform.mass'"),
        ("mass_per_length = 0.0\n\n[[cables]]\nanchor = [5.327, -2.267, 3.822]",
         "mass_per_length = -0.1\n\n[[cables]]\nanchor = [5.327, -2.267, 3.822]", r"cables\[1\].mass_per_length.*>= 0"),
        ('name = "example01"', "name = 3", r"key 'name'.*non-empty string"),
        ("gravity = [0.0, 0.0, -9.81]", 'gravity = "down"', r"key 'gravity'.*expected numbers"),
    ],
)
def test_bad_input_errors_name_key_line_value(tmp_path, old, new, match):
    assert old in BASE
    p = _write(tmp_path, BASE.replace(old, new, 1))
    with pytest.raises(RobotFileError, match=match) as info:
        load_robot(p)
    assert str(p) in str(info.value)


def test_missing_file_and_bad_toml(tmp_path):
    with pytest.raises(RobotFileError, match="cannot read"):
        load_robot(tmp_path / "nope.toml")
    with pytest.raises(RobotFileError, match="not valid TOML"):
        load_robot(_write(tmp_path, "kind = = 3"))


def test_any_number_of_cables_but_none(tmp_path):
    head, *cables = BASE.split("[[cables]]")
    robot = load_robot(_write(tmp_path, head + "[[cables]]" + "[[cables]]".join(cables[:5])))
    assert robot.num_cables == 5  # under-constrained: gravity closes the equilibrium
    with pytest.raises(RobotFileError, match=r"key 'cables'.*expected one or more \[\[cables\]\] tables"):
        load_robot(_write(tmp_path, head.replace("[platform]", "cables = []\n[platform]")))


def test_limits_order(tmp_path):
    text = BASE + "\n[limits]\ntension_min = 50.0\ntension_max = 40.0\n"
    with pytest.raises(RobotFileError, match="limits.tension_max.*must exceed tension_min"):
        load_robot(_write(tmp_path, text))


def test_module_shape_check():
    robot = load_robot(example_path("example01/robot.toml"))
    with pytest.raises(ValueError, match=r"EA must have shape \(6,\)"):
        CableRobot(
            anchors=robot.anchors, attachments=robot.attachments, EA=np.ones(5), mass_per_length=np.zeros(6),
            platform_mass=1.0, com=np.zeros(3), inertia=np.eye(3), gravity=np.zeros(3), noise=robot.noise,
        )


@pytest.mark.parametrize(
    ("old", "new", "match"),
    [
        ("anchor = [5.327, -2.267, 4.193]", "anchor = [true, -2.267, 4.193]",
         r"key 'cables\[1\].anchor' \(line 15\): expected numbers of shape \(3,\); got the element True \(bool\)"),
        ("gravity = [0.0, 0.0, -9.81]", "gravity = [0.0, false, -9.81]", r"key 'gravity'.*element False \(bool\)"),
        ("com = [0.0, 0.0, 0.0]", 'com = [0.0, "0.5", 0.0]', r"key 'platform.com'.*element '0.5' \(str\)"),
        ("anchor = [5.327, -2.267, 4.193]", "anchor = [[5.327], -2.267, 4.193]",
         r"cables\[1\].anchor.*element \[5.327\]"),
        ("mass = 30.0", "mass = true", r"key 'platform.mass'.*expected a number, got True"),
        ("EA = 1.01034e+06", "EA = 1" + "0" * 400, r"key 'cables\[1\].EA'.*401 digits\) is too large for a float64"),
        ("anchor = [5.327, -2.267, 4.193]", "anchor = [1" + "0" * 320 + ", 0, 0]",
         r"cables\[1\].anchor.*321 digits\) is too large for a float64"),
        ("mass = 30.0", "mass = 1e400", r"platform.mass.*must be finite"),
        ("mass = 30.0", "mass = 3" + "0" * 5000, r"an integer has more than 4300 digits"),
    ],
)
def test_numbers_are_numbers(tmp_path, old, new, match):
    assert old in BASE
    p = _write(tmp_path, BASE.replace(old, new, 1))
    with pytest.raises(RobotFileError, match=match) as info:
        load_robot(p)
    assert str(p) in str(info.value)


@pytest.mark.parametrize("depth", [50, 5000])
def test_nesting_too_deep(tmp_path, depth):
    p = _write(tmp_path, BASE.replace("com = [0.0, 0.0, 0.0]", "com = " + "[" * depth + "0.0" + "]" * depth))
    with pytest.raises(RobotFileError, match="nested too deep|platform.com.*shape") as info:
        load_robot(p)
    assert str(p) in str(info.value)


def test_deep_inline_tables(tmp_path):
    p = _write(tmp_path, BASE + "\nextra = " + "{a = " * 3000 + "1" + "}" * 3000 + "\n")
    with pytest.raises(RobotFileError, match="nested too deep"):
        load_robot(p)


def test_non_utf8_is_an_error_naming_file_and_line(tmp_path):
    p = tmp_path / "robot.toml"
    p.write_bytes(BASE.replace("[noise]", "[noise]  # \u00b5m", 1).encode("latin-1"))
    with pytest.raises(RobotFileError, match=r"line 9: byte b5 .* is not UTF-8") as info:
        load_robot(p)
    assert str(p) in str(info.value)


def test_bom_is_stripped(tmp_path):
    p = tmp_path / "robot.toml"
    p.write_bytes(b"\xef\xbb\xbf" + BASE.encode())
    assert load_robot(p).name == "example01"


@pytest.mark.parametrize(
    "name", ['a "quoted" name', "back\\slash\\", "two\nlines\r\n", "tab\there", "nul\x00del\x7f\x1b",
             "Hallé ✓ 機械", "\\u0041 not an escape", "'single'"],
)
def test_save_robot_escapes_names(tmp_path, name):
    import dataclasses

    robot = dataclasses.replace(load_robot(example_path("example01/robot.toml")), name=name)
    save_robot(robot, tmp_path / "n.toml")
    (tmp_path / "n.toml").read_bytes().decode("utf-8")  # written as UTF-8 whatever the locale
    assert load_robot(tmp_path / "n.toml").name == name


def test_save_robot_refuses_lone_surrogate(tmp_path):
    import dataclasses

    robot = dataclasses.replace(load_robot(example_path("example01/robot.toml")), name="bad\ud800")
    with pytest.raises(ValueError, match="lone surrogate"):
        save_robot(robot, tmp_path / "s.toml")
    assert not (tmp_path / "s.toml").exists()


@pytest.mark.parametrize(("old", "new", "match"), [
    ("EA = 1.01034e+06", "EA = 1e308", r"key 'cables\[1\]\.EA' \(line 17\): value 1e\+308 N is outside the physical "
                                       r"range of this key: magnitudes 0\.001\.\.1e\+16 N"),
    ("EA = 1.01034e+06", "EA = 5e-324", r"cables\[1\]\.EA.*value 5e-324 N is outside .*0\.001\.\.1e\+16 N"),
    ("mass = 30.0", "mass = 1e308",
     r"key 'platform\.mass' \(line 6\): value 1e\+308 kg is outside .*1e-06\.\.1e\+09 kg \(formats"),
    ("anchor = [5.327, -2.267, 4.193]", "anchor = [5.327, -2.267, 4.193e200]",
     r"cables\[1\]\.anchor.*value 4\.193e\+200 m is outside .*0\.\.1e\+06 m"),
    ("gravity = [0.0, 0.0, -9.81]", "gravity = [0.0, 0.0, -9.81e300]", r"'gravity'.*-9\.81e\+300 m/s² is outside"),
    ("position = 2e-05", "position = 1e-300", r"noise\.position.*1e-300 m is outside .*1e-12\.\.1e\+06 m \(formats"),
    ("mass_per_length = 0.0", "mass_per_length = 1e-320", r"mass_per_length.*outside .*1e-12\.\.100000 kg/m \(or 0\)"),
])
def test_values_outside_the_physical_range(tmp_path, old, new, match):
    """Numbers a float64 statics cannot use (an all-NaN stiffness at EA = 1e308 N) are refused by key and value."""
    assert old in BASE
    with pytest.raises(RobotFileError, match=match):
        load_robot(_write(tmp_path, BASE.replace(old, new, 1)))


@pytest.mark.parametrize("value", [1e12, 1e16, 1e-3, 1e2])
def test_the_promised_ea_range_loads(tmp_path, value):
    """benchmarks/LIMITS.md runs EA from 1e2 to 1e12 N; the range leaves room on both sides."""
    robot = load_robot(_write(tmp_path, BASE.replace("EA = 1.01034e+06", f"EA = {value!r}")))
    assert float(robot.EA[0]) == value
