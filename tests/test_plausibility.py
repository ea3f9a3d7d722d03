"""The description checked against itself (:func:`cstiffjax.io.plausibility.proportion_checks`):
anchors or attachments written in mm, pulley radii, EA and ``tension_max`` against the
platform's weight. Edited copies of the bundled examples must fail ``check`` (exit 1) with
the quantities that disagree and their values (spreads recomputed here with scipy); every
bundled example and the benchmark robots from 1.25 cm to 1 km, EA from 1e2 N, still pass."""

import re

import equinox as eqx
import numpy as np
import pytest
from scipy.spatial.distance import pdist

from benchmarks.bench_limits import ring_robot
from cstiffjax.commands.cli import main
from cstiffjax.commands.common import EXIT_OK, EXIT_USAGE
from cstiffjax.examples import example_path, list_examples
from cstiffjax.io.plausibility import geometry_checks, proportion_checks
from cstiffjax.io.robot_io import load_robot, save_robot

EXAMPLES = ["example02/robot.toml", "onboard4/robot.toml", "pulleys8/robot.toml", "suspended3.toml"]


def _edited(tmp_path, example, **scale):
    """A copy of ``example`` with fields multiplied (``anchors=1e3``, ...), written as TOML."""
    robot = load_robot(example_path(example))
    for name, factor in scale.items():
        robot = eqx.tree_at(lambda r, n=name: getattr(r, n), robot, getattr(robot, name) * factor)
    path = tmp_path / "robot.toml"
    save_robot(robot, path)
    return path, robot


def _check(capsys, *argv):
    code = main(["check", *map(str, argv)])
    out = capsys.readouterr()
    return code, out.out, out.err


@pytest.mark.parametrize("example", EXAMPLES)
@pytest.mark.parametrize("field", ["anchors", "attachments"])
def test_check_refuses_all_anchors_or_all_attachments_in_mm(tmp_path, capsys, example, field):
    path, robot = _edited(tmp_path, example, **{field: 1e3})
    code, out, err = _check(capsys, path)
    assert code == EXIT_USAGE and "robot OK" not in out
    big, small = pdist(np.asarray(robot.anchors)).max(), pdist(np.asarray(robot.attachments)).max()
    assert f"the anchors lie within {big:.4g} m of each other and the attachments within {small:.4g} m" in err
    other = "frame" if field == "anchors" else "platform"
    assert re.search(f"a {other} [0-9.e+]+ times wider", err) and f"the {field} written in mm instead of m?" in err
    assert str(path) in err


@pytest.mark.parametrize("example", ["example02/robot.toml", "onboard4/robot.toml"])
def test_every_length_in_mm_is_only_a_warning_then_the_recordings_refuse_it(tmp_path, capsys, example):
    """A consistent robot 1000x large keeps its proportions (and its strain under the weight):
    only its absolute size is out of the ordinary; the recordings' l0 then disagree."""
    path, robot = _edited(tmp_path, example, anchors=1e3, attachments=1e3)
    code, out, _ = _check(capsys, path)
    big = pdist(np.asarray(robot.anchors)).max()
    assert code == EXIT_OK
    assert f"warning: {path}: the anchors lie within {big:.4g} m of each other, larger than any robot" in out
    code, _, err = _check(capsys, path, example_path(example.replace("robot.toml", "recordings.csv")))
    assert code == EXIT_USAGE and "column l0_1 (cable 1)" in err and "mm against m" in err


def test_check_refuses_a_pulley_radius_in_mm(tmp_path, capsys):
    path, _ = _edited(tmp_path, "pulleys8/robot.toml", pulley_radius=1e3)
    code, _, err = _check(capsys, path)
    assert code == EXIT_USAGE and "pulley_radius = 25 m against the anchors' spread of 2.57 m" in err
    assert "the radius written in mm instead of m?" in err


def test_check_refuses_a_tension_max_in_kn(tmp_path, capsys):
    path, robot = _edited(tmp_path, "suspended3.toml", tension_max=1e-3)
    weight = float(robot.platform_mass) * np.linalg.norm(np.asarray(robot.gravity))
    code, _, err = _check(capsys, path)
    assert code == EXIT_USAGE and f"the platform's weight {weight:.4g} N is more than the 3 cables hold" in err
    assert f"tension_max = {float(robot.tension_max):.4g} N" in err and "tension_max in kN instead of N?" in err


@pytest.mark.parametrize("factor, refused", [(1e-4, True), (1e-3, False)])
def test_ea_against_the_weight(tmp_path, capsys, factor, refused):
    """Some cable stretches by at least weight / sum(EA) (the tensions' vertical parts hold the
    weight): above 100 % an error, above 10 % a warning."""
    path, robot = _edited(tmp_path, "suspended3.toml", EA=factor)
    strain = float(robot.platform_mass) * np.linalg.norm(np.asarray(robot.gravity)) / np.sum(np.asarray(robot.EA))
    assert bool(strain > 1.0) is refused and strain > 0.1
    code, out, err = _check(capsys, path)
    text = f"some cable stretches by at least {100 * strain:.3g}% of its length (EA in kN"
    assert (code, text in (err if refused else out)) == ((EXIT_USAGE if refused else EXIT_OK), True)


def test_every_bundled_example_passes(capsys):
    for name in list_examples():
        if name.endswith(".toml"):
            errors, warnings = geometry_checks(load_robot(example_path(name)), name)
            assert errors == [] and warnings == [], name


@pytest.mark.parametrize("robot", [ring_robot(8, scale=0.005), ring_robot(8, scale=400.0), ring_robot(6, ea=1e2),
                                   ring_robot(12), ring_robot(6, mass=1e-3)],
                         ids=["1.25cm", "1km", "ea1e2", "12cables", "1g"])
def test_the_benchmark_robots_are_not_refused(robot):
    errors, _ = proportion_checks(robot, "ring")
    assert errors == []
