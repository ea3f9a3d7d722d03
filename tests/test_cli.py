import json

import numpy as np
import pytest

from cstiffjax.cli import main
from cstiffjax.examples import example_path


def test_help_lists_commands(capsys):
    assert main([]) == 0
    out = capsys.readouterr().out
    assert "check" in out and "stiffness" in out and "examples:" in out


def test_check_summarizes(tmp_path, capsys):
    out_json = tmp_path / "s.json"
    rc = main(["check", str(example_path("example02/robot.toml")), str(example_path("example02/recordings.csv")),
               "--json", str(out_json)])
    assert rc == 0
    out = capsys.readouterr().out
    assert "recordings OK: 90 samples" in out and "covariates: temperature" in out
    assert json.loads(out_json.read_text())["samples"] == 90


def test_check_reports_bad_file_clearly(tmp_path, capsys):
    bad = tmp_path / "r.toml"
    bad.write_text(example_path("example02/robot.toml").read_text().replace("EA = 1.01034e+06", "EA = -5", 1))
    assert main(["check", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "cables[1].EA" in err and "-5" in err and "must be > 0" in err


def test_stiffness_command_json(tmp_path, capsys):
    out_json = tmp_path / "k.json"
    rc = main(["stiffness", "example02/robot.toml", "--pose", "0", "0", "0.5", "0", "0", "0", "--json", str(out_json)])
    assert rc == 0
    data = json.loads(out_json.read_text())
    K = np.array(data["K"])
    assert K.shape == (6, 6) and np.allclose(K, K.T, atol=1e-6 * np.abs(K).max())
    assert min(data["translation_eigenvalues"]) > 0
    assert "translation eigen-stiffnesses" in capsys.readouterr().out


def test_stiffness_rejects_wrong_tension_count(capsys):
    rc = main(["stiffness", "example02/robot.toml", "--pose", "0", "0", "0.5", "0", "0", "0", "--tensions", "1", "2"])
    assert rc == 2
    assert "got 2 values, the robot has 6 cables" in capsys.readouterr().err


def test_missing_file(capsys):
    assert main(["check", "nope.toml"]) == 2
    assert "no such file" in capsys.readouterr().err


@pytest.mark.parametrize("cmd", ["check", "stiffness"])
def test_subcommand_help(cmd, capsys):
    with pytest.raises(SystemExit) as e:
        main([cmd, "--help"])
    assert e.value.code == 0
    assert "usage" in capsys.readouterr().out
