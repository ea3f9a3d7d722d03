"""Honest commands: one exit-code convention for every command (0 an answer, 1 bad arguments or
input files, 2 no valid answer, 3 results written with a problem, 4 an output not written, 130
interrupted), ``check`` running the per-cable checks of the diagnosis, ``sag`` refusing a pose
outside the frame and saying when cables have no mass, ``tensions`` giving one answer whatever
the method (or saying what it needs), progress bars silenced by ``--quiet`` or a non-terminal,
and ``--version``."""

import io
import shutil
from importlib.metadata import version

import pytest

from cstiffjax.commands import cli
from cstiffjax.commands.cli import main
from cstiffjax.commands.common import EXIT_CHECK, EXIT_INTERRUPTED, EXIT_NO_ANSWER, EXIT_OK, EXIT_USAGE, EXIT_WRITE

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

