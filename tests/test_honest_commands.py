"""Honest commands: one exit-code convention for every command (0 an answer, 1 bad arguments or
input files, 2 no valid answer, 3 results written with a problem, 4 an output not written, 130
interrupted), ``check`` running the per-cable checks of the diagnosis, ``sag`` refusing a pose
outside the frame and saying when cables have no mass, ``tensions`` giving one answer whatever
the method (or saying what it needs), progress bars silenced by ``--quiet`` or a non-terminal,
and ``--version``."""

import io
import json
import re
import shutil
from importlib.metadata import version

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

from cstiffjax.commands import cli
from cstiffjax.commands.cli import main
from cstiffjax.commands.common import EXIT_CHECK, EXIT_INTERRUPTED, EXIT_NO_ANSWER, EXIT_OK, EXIT_USAGE, EXIT_WRITE
from cstiffjax.examples import example_path

POSE = ["--pose", "0", "0", "0.83", "0", "0", "0"]  # tcpr8: the reference pose, feasible
HEAVY = ["--wrench", "0", "0", "-5000", "0", "0", "0"]  # tcpr8: no tensions within [10, 400] N hold it


# ------------------------------------------------------------------ 1. one exit-code convention
def test_the_exit_codes_are_the_documented_ones():
    assert (EXIT_OK, EXIT_USAGE, EXIT_NO_ANSWER, EXIT_CHECK, EXIT_WRITE, EXIT_INTERRUPTED) == (0, 1, 2, 3, 4, 130)
    text = cli.build_parser().format_help()
    for line in ("0    an answer", "1    usage: bad arguments or input files", "2    no valid answer",
                 "3    results written", "4    an output could not be written", "130  interrupted"):
        assert line in text, line
    sub = cli.build_parser()._subparsers._group_actions[0].choices
    for name in ("check", "tensions", "sag", "stiffness", "workspace", "fit", "diagnose", "generate"):
        assert "1 bad arguments or input files; 2 no valid answer" in sub[name].format_help(), name


@pytest.mark.parametrize("argv", [
    ["tensions", "tcpr8.toml", "--pose", "0", "0"],  # too few numbers
    ["tensions", "tcpr8.toml", *POSE, "--method", "simplex"],  # not a choice
    ["sag", "tcpr8.toml", "--pose", "nan", "0", "0.8", "0", "0", "0"],  # not finite
    ["stiffness", "tcpr8.toml"],  # --pose missing
    ["no-such-command"],
    ["check", "--no-such-option"],
])
def test_argument_errors_exit_1_not_argparse_2(argv, capsys):
    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == EXIT_USAGE
    assert "error:" in capsys.readouterr().err


@pytest.mark.parametrize("argv, words", [
    (["check", "no_such_robot.toml"], "no such file"),
    (["tensions", "no_such_robot.toml", *POSE, "--method", "cfm"], "no such file"),
    (["stiffness", "tcpr8.toml", *POSE, "--tensions", "1", "2"], "got 2 values, the robot has 8 cables"),
    (["tensions", "tcpr8.toml", *POSE, "--method", "cfm", "--objective", "max"], "only with --method qp"),
    (["generate", "--cases", "proto_clean"], "--out DIR is required"),
    (["diagnose", "tcpr8.toml"], "give both ROBOT.toml and RECORDINGS.csv"),
    (["fit", "example02/robot.toml", "no_such.csv"], "no such file"),
])
def test_bad_input_files_and_values_exit_1(argv, words, capsys):
    assert main(argv) == EXIT_USAGE
    assert words in capsys.readouterr().err


@pytest.mark.parametrize("argv, words", [
    (["tensions", "tcpr8.toml", *POSE, *HEAVY, "--method", "cfm"], "no cable tensions within"),
    (["stiffness", "tcpr8.toml", *POSE, *HEAVY], "no feasible tensions"),
])
def test_no_valid_answer_exits_2(argv, words, capsys):
    assert main(argv) == EXIT_NO_ANSWER
    out = capsys.readouterr()
    assert words in out.out + out.err


def test_a_fit_that_did_not_converge_exits_2(capsys):
    assert main(["fit", "example02/robot.toml", "example02/recordings.csv", "--max-steps", "1"]) == EXIT_NO_ANSWER
    assert "did not converge" in capsys.readouterr().err


# ------------------------------------------------------------------ 5. --version, progress bars
def test_version_prints_the_package_version(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0
    assert capsys.readouterr().out.strip() == f"cstiffjax {version('cstiffjax')}"


class _Terminal(io.StringIO):
    def isatty(self):
        return True


@pytest.mark.parametrize("quiet", [True, False])
def test_workspace_bar_follows_quiet_and_the_terminal(tmp_path, monkeypatch, quiet):
    """On a terminal the bar shows unless --quiet; on a non-terminal (a pipe, a log) never."""
    grid = ["--pose-grid", "-0.1", "0.1", "2", "-0.1", "0.1", "2", "0.8", "0.9", "2"]
    argv = ["workspace", "tcpr8.toml", "--kind", "wrench-closure", *grid, "--out", str(tmp_path / "ws")]
    err = _Terminal()
    monkeypatch.setattr("sys.stderr", err)
    assert main(argv + (["--quiet"] if quiet else [])) == EXIT_OK
    assert ("wrench-closure:" in err.getvalue()) is not quiet  # the bar's label
    pipe = io.StringIO()
    monkeypatch.setattr("sys.stderr", pipe)
    shutil.rmtree(tmp_path / "ws")
    assert main(argv) == EXIT_OK
    assert "wrench-closure:" not in pipe.getvalue() and "pose/s" not in pipe.getvalue()


# ------------------------------------------------------------------ 2. check: the diagnosis's per-cable checks
def _copy(tmp_path, robot_edit=None, l0_scale=None):
    """Copies of the bundled example02 robot and recordings; ``robot_edit(text) -> text``,
    ``l0_scale``: ``{cable (1-based): factor}`` applied to that cable's l0 column."""
    robot = tmp_path / "robot.toml"
    text = example_path("example02/robot.toml").read_text()
    robot.write_text(robot_edit(text) if robot_edit else text)
    rec = tmp_path / "recordings.csv"
    lines = example_path("example02/recordings.csv").read_text().splitlines()
    header = lines[0].split(",")
    for cable, factor in (l0_scale or {}).items():
        j = header.index(f"l0_{cable}")
        rows = [r.split(",") for r in lines[1:]]
        for r in rows:
            r[j] = repr(float(r[j]) * factor)
        lines = [lines[0], *(",".join(r) for r in rows)]
    rec.write_text("\n".join(lines) + "\n")
    return robot, rec


def _run_check(capsys, *argv):
    code = main(["check", *map(str, argv)])
    out = capsys.readouterr()
    return code, out.out, out.err


def test_check_refuses_l0_in_mm_naming_the_column(tmp_path, capsys):
    robot, rec = _copy(tmp_path, l0_scale={c: 1e3 for c in range(1, 7)})
    code, out, err = _run_check(capsys, robot, rec)
    assert code == EXIT_USAGE and "recordings OK" not in out
    assert "column l0_1 (cable 1)" in err and "mm against m" in err and str(rec) in err


def test_check_refuses_one_cable_in_mm_and_names_only_it(tmp_path, capsys):
    robot, rec = _copy(tmp_path, l0_scale={3: 1e3})
    code, _, err = _run_check(capsys, robot, rec)
    assert code == EXIT_USAGE and "column l0_3 (cable 3)" in err and "mm against m" in err
    assert "l0_1" not in err and "l0_2" not in err and "l0_4" not in err
    # the value named: the median l0 of cable 3 (m, as written) against its distance
    ref = np.median(np.loadtxt(rec, delimiter=",", skiprows=1, usecols=3))
    assert f"median {ref:.6g} m" in err


def test_check_refuses_one_anchor_in_mm(tmp_path, capsys):
    robot, _ = _copy(tmp_path, lambda t: t.replace("anchor = [5.327, -2.267, 3.822]",
                                                   "anchor = [5327.0, -2267.0, 3822.0]", 1))
    code, out, err = _run_check(capsys, robot)
    assert code == EXIT_USAGE and out == ""
    assert "cable 2: anchor = [5327.0, -2267.0, 3822.0]" in err and "mm instead of m" in err


def test_check_warns_on_gravity_up_and_implausible_noise(tmp_path, capsys):
    robot, _ = _copy(tmp_path, lambda t: t.replace("gravity = [0.0, 0.0, -9.81]", "gravity = [0.0, 0.0, 9.81]")
                       .replace("position = 2e-05", "position = 20.0"))
    code, out, _ = _run_check(capsys, robot)
    assert code == EXIT_OK and "robot OK" in out
    warnings = [line.strip() for line in out.splitlines() if line.strip().startswith("warning:")]
    assert any("gravity = [0.0, 0.0, 9.81] points up" in w for w in warnings), out
    assert any("noise.position = 20 m: implausibly large" in w for w in warnings), out


def test_the_bundled_examples_check_without_warnings(capsys):
    for argv in (["example02/robot.toml", "example02/recordings.csv"], ["concealed/robot.toml",
                 "concealed/recordings.csv"], ["pulleys8/robot.toml", "pulleys8/recordings.csv"], ["tcpr8.toml"],
                 ["prototype_8mm.toml"], ["csjm.toml", "csjm_recordings.csv"]):
        code, out, _ = _run_check(capsys, *[example_path(a) for a in argv])
        assert code == EXIT_OK and "warning" not in out, (argv, out)


def test_diagnosis_cause_and_check_share_the_per_cable_rule():
    """The diagnosis's no-equilibrium cause names the cable that check refuses (one implementation)."""
    from cstiffjax.io.plausibility import cable_length_checks
    from cstiffjax.io.recordings import load_recordings
    from cstiffjax.io.robot_io import load_robot
    from fitting.diagnosis.sample_checks import no_equilibrium_cause

    robot = load_robot(example_path("example02/robot.toml"))
    rec = load_recordings(example_path("example02/recordings.csv"), robot)
    l0 = np.asarray(rec.l0).copy()
    l0[:, 4] *= 1e3
    errors, _ = cable_length_checks(robot, l0, rec.pose)
    assert len(errors) == 1 and "l0_5 (cable 5)" in errors[0]
    bad = eqx.tree_at(lambda r: r.l0, rec, jnp.asarray(l0))
    assert re.match(r"l0_5 is 99\d\.\d times the anchor-attachment distance .*: wrong units",
                    no_equilibrium_cause(robot, bad, list(range(5))))


# ------------------------------------------------------------------ 3. sag
def test_sag_refuses_a_pose_outside_the_frame(tmp_path, capsys):
    code = main(["sag", "prototype_8mm.toml", "--pose", "30", "0", "0.5", "0", "0", "0", "--out", str(tmp_path / "o")])
    out = capsys.readouterr()
    assert code == EXIT_NO_ANSWER
    assert "outside the anchors' frame" in out.err and "no positive cable tensions" in out.err
    assert "nan" not in out.out and "pose errors" not in out.out and not (tmp_path / "o").exists()


def test_sag_refuses_a_pose_whose_unique_tensions_are_not_positive(capsys):
    """prototype_8mm (6 cables): inside the anchors' box but above the upper anchors' height the
    cables would have to push; the numpy solve of S t = -W says so independently."""
    from cstiffjax.io.robot_io import load_robot

    robot = load_robot(example_path("prototype_8mm.toml"))
    pose = np.array([0.0, 0.0, 6.0, 0, 0, 0])
    u = np.asarray(robot.anchors) - (pose[:3] + np.asarray(robot.attachments))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    S = np.vstack([u.T, np.cross(np.asarray(robot.attachments), u).T])
    w = float(robot.platform_mass) * np.asarray(robot.gravity)
    t = np.linalg.solve(S, -np.concatenate([w, np.cross(np.asarray(robot.com), w)]))
    assert np.any(t <= 0)  # the reference: this pose cannot be held
    assert main(["sag", "prototype_8mm.toml", "--pose", *map(str, pose)]) == EXIT_NO_ANSWER
    assert "no positive cable tensions hold this pose" in capsys.readouterr().err


def test_sag_with_massless_cables_says_there_is_no_sag(tmp_path, capsys):
    code = main(["sag", "tcpr8.toml", "--pose", "0", "0", "0.83", "0", "0", "0", "--out", str(tmp_path)])
    out = capsys.readouterr().out
    assert code == EXIT_OK and "the cables have no mass" in out
    line = next(x for x in out.splitlines() if x.strip().startswith("sag-introduced"))
    assert [float(v) for v in line.split()[1:]] == [0.0] * 6
    doc = json.loads((tmp_path / "sag.json").read_text())
    assert doc["massless"] and doc["error_sag"] == [0.0] * 6 and doc["error_catenary"] == doc["error_spring"]
    assert main(["sag", "tcpr8.toml", "--pose", "0", "0", "0.83", "0", "0", "0", "--map"]) == EXIT_USAGE
    assert "have no mass" in capsys.readouterr().err


# ------------------------------------------------------------------ 4. tensions: one answer whatever the method
METHODS = [["cfm"], ["icfm"], ["dykstra"], ["qp"], ["qp", "--objective", "max"]]


def _tensions(capsys, robot, pose, *extra):
    code = main(["tensions", str(robot), "--pose", *map(str, pose), *extra])
    out = capsys.readouterr()
    line = next((x for x in out.out.splitlines() if x.startswith("tensions [N]:")), "")
    return code, np.array([float(v) for v in line.split(":")[1].split()]) if line else None, out.out + out.err


def _numpy_structure(robot, pose):
    p = np.asarray(pose, dtype=float)
    assert np.all(p[3:] == 0)  # unrotated: attachments in the base frame as given
    b = np.asarray(robot.attachments)
    u = np.asarray(robot.anchors) - (p[:3] + b)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    w = float(robot.platform_mass) * np.asarray(robot.gravity)
    return np.vstack([u.T, np.cross(b, u).T]), np.concatenate([w, np.cross(np.asarray(robot.com), w)])


def test_every_method_gives_the_unique_tensions_of_a_six_cable_robot(capsys):
    """prototype_8mm, tension_max = inf: cfm, dykstra and stiffness found 103.9 53.9 ... N while
    icfm gave nan and qp zeros. Reference: numpy's solve of S t = -W."""
    from cstiffjax.io.robot_io import load_robot

    pose = [3, 0, 0.5, 0, 0, 0]
    robot = load_robot(example_path("prototype_8mm.toml"))
    S, W = _numpy_structure(robot, pose)
    ref = np.linalg.solve(S, -W)
    assert np.all(ref > 0) and ref[0] == pytest.approx(103.93, abs=0.01)
    for method in METHODS:
        code, t, text = _tensions(capsys, "prototype_8mm.toml", pose, "--method", *method)
        assert code == EXIT_OK and "status: ok" in text, (method, text)
        np.testing.assert_allclose(t, ref, atol=1e-4, err_msg=str(method))  # printed to 1e-4 N


def test_every_method_gives_the_tensions_closest_to_the_mid_tension(capsys):
    """tcpr8 (8 cables, [10, 400] N): cfm, icfm, dykstra and qp (2-norm) all return the
    tensions closest to t_m = 205 N, here within the limits. Reference: numpy's t_m - S⁺(W + S t_m)."""
    from cstiffjax.io.robot_io import load_robot

    pose = [0.05, -0.03, 0.83, 0, 0, 0]
    robot = load_robot(example_path("tcpr8.toml"))
    S, W = _numpy_structure(robot, pose)
    tm = np.full(8, 0.5 * (float(robot.tension_min) + float(robot.tension_max)))
    ref = tm - np.linalg.pinv(S) @ (W + S @ tm)
    assert np.all((ref > 10) & (ref < 400))
    for method in METHODS[:4]:
        code, t, text = _tensions(capsys, "tcpr8.toml", pose, "--method", *method)
        assert code == EXIT_OK, (method, text)
        np.testing.assert_allclose(t, ref, atol=2e-4, err_msg=str(method))


def test_every_method_says_infeasible_and_exits_2(capsys):
    pose = [0, 0, 0.83, 0, 0, 0]
    for method in METHODS:
        code, _, text = _tensions(capsys, "tcpr8.toml", pose, *HEAVY, "--method", *method, "--max-steps", "2000")
        assert code == EXIT_NO_ANSWER, (method, text)
        assert "status: no cable tensions within [tension_min, tension_max] hold this pose" in text, (method, text)
        assert "did not converge" not in text


def test_a_method_that_needs_tension_max_says_so(tmp_path, capsys):
    robot = tmp_path / "robot.toml"
    text = example_path("tcpr8.toml").read_text()
    robot.write_text(re.sub(r"(?m)^tension_max = .*$", "", text))
    for method in METHODS[:4]:
        code, _, out = _tensions(capsys, robot, [0, 0, 0.83, 0, 0, 0], "--method", *method)
        assert code == EXIT_NO_ANSWER and "needs a finite [limits] tension_max" in out, (method, out)
    code, t, _ = _tensions(capsys, robot, [0, 0, 0.83, 0, 0, 0], "--method", "qp", "--objective", "max")
    assert code == EXIT_OK and np.all(t >= 10 - 1e-6)
