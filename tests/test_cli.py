import json

import numpy as np
import pytest

from cstiffjax.commands.cli import main
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
    assert main(["check", str(bad)]) == 1
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
    # values against an independent reference: tensions from numpy least squares of the
    # weight balance (6 cables: unique), K = -∂W/∂x by central differences of a numpy wrench
    from cstiffjax import load_robot
    from cstiffjax.examples import example_path

    from .helpers import np_cables, np_fd, np_frame, np_spring_wrench

    rb = load_robot(example_path("example02/robot.toml"))
    pose = np.array([0, 0, 0.5, 0, 0, 0.0])
    r, d, l = np_cables(rb, *np_frame(pose))
    u = d / l[:, None]
    S = np.vstack([u.T, np.cross(r, u).T])
    weight = float(rb.platform_mass) * np.asarray(rb.gravity)
    w = np.concatenate([weight, np.cross(np.asarray(rb.com), weight)])
    t = np.linalg.solve(S, -w)
    np.testing.assert_allclose(data["tensions"], t, rtol=1e-9)
    l0 = l * np.asarray(rb.EA) / (np.asarray(rb.EA) + t)
    fd = -np_fd(lambda tw: np_spring_wrench(rb, l0, np.zeros(6), pose, tw), 6, 1e-7)
    np.testing.assert_allclose(K, fd, rtol=1e-6, atol=1e-6 * np.abs(fd).max())
    assert np.allclose(sorted(data["translation_eigenvalues"]), np.linalg.eigvalsh(0.5 * (K[:3, :3] + K[:3, :3].T)),
                       rtol=1e-9)


def test_stiffness_rejects_wrong_tension_count(capsys):
    rc = main(["stiffness", "example02/robot.toml", "--pose", "0", "0", "0.5", "0", "0", "0", "--tensions", "1", "2"])
    assert rc == 1
    assert "got 2 values, the robot has 6 cables" in capsys.readouterr().err


def test_missing_file(capsys):
    assert main(["check", "nope.toml"]) == 1
    assert "no such file" in capsys.readouterr().err


@pytest.mark.parametrize("cmd", ["check", "stiffness"])
def test_subcommand_help(cmd, capsys):
    with pytest.raises(SystemExit) as e:
        main([cmd, "--help"])
    assert e.value.code == 0
    assert "usage" in capsys.readouterr().out
