"""CLI safety: output paths checked before any work (never overwrite an input,
no folder where a file goes or the reverse, no missing parent), rows dropped or out of
time order reported by file line, no verdict without equilibrium, feasible default
tensions for `stiffness`, readable messages from errors raised inside jit."""

import functools
import hashlib
import json
import os
import shutil

import jax
import numpy as np
import pytest

import fitting.diagnosis.diagnose
from cstiffjax.commands.cli import main
from cstiffjax.commands.common import check_outputs
from cstiffjax.core.errors import OutputPathError
from cstiffjax.core.status import Status, raise_if_failed
from cstiffjax.examples import example_path
from cstiffjax.io.recordings import load_recordings
from cstiffjax.io.robot_io import load_robot
from cstiffjax.statics import geometry as statics

POSE = ["--pose", "0", "0", "0.5", "0", "0", "0"]


def _digest(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture
def lab(tmp_path):
    """Copies of the example02 robot and recordings (first 20 rows) in tmp_path."""
    robot = tmp_path / "robot.toml"
    shutil.copy(example_path("example02/robot.toml"), robot)
    lines = example_path("example02/recordings.csv").read_text().splitlines()
    rec = tmp_path / "rec.csv"
    rec.write_text("\n".join(lines[:21]) + "\n")
    return robot, rec


# ------------------------------------------------------------------- output paths
def _cases(robot, rec, tmp):
    csjm = tmp / "csjm.toml"
    shutil.copy(example_path("csjm.toml"), csjm)
    inside = tmp / "inside"
    inside.mkdir()
    for name in ("diagnosis.json", "summary.json", "sag.json", "frf.json", "residuals.png"):
        shutil.copy(robot if name != "diagnosis.json" else rec, inside / name)
    return [
        (["diagnose", str(robot), str(rec), "--json", str(rec)], rec),
        (["diagnose", str(robot), str(rec), "--json", str(robot)], robot),
        (["diagnose", str(robot), str(inside / "diagnosis.json"), "--report", str(inside)], inside / "diagnosis.json"),
        (["fit", str(robot), str(rec), "--json", str(rec)], rec),
        (["fit", str(robot), str(inside / "residuals.png"), "--plots", str(inside)], inside / "residuals.png"),
        (["check", str(robot), str(rec), "--json", str(rec)], rec),
        (["stiffness", str(robot), *POSE, "--json", str(robot)], robot),
        (["csjm", str(csjm), "--json", str(csjm)], csjm),
        (["css", str(inside / "summary.json"), "--pose-grid", *["0"] * 9, "--stiffness-at", *["0"] * 6,
          "--out", str(inside)], inside / "summary.json"),
        (["sag", str(inside / "sag.json"), *POSE, "--out", str(inside)], inside / "sag.json"),
        (["frf", str(inside / "frf.json"), *POSE, "--out", str(inside)], inside / "frf.json"),
    ]


def test_no_output_may_overwrite_an_input(lab, tmp_path, capsys):
    """Every command, every output option: refused at once (exit 1, a usage error), the input untouched."""
    for argv, victim in _cases(*lab, tmp_path):
        before = _digest(victim)
        assert main(argv) == 1, argv
        err = capsys.readouterr().err
        assert "is an input of this command" in err and str(victim.name) in err, (argv, err)
        assert _digest(victim) == before, argv


def test_symlink_and_hard_link_to_the_input_are_refused(lab, tmp_path, capsys):
    robot, rec = lab
    sym = tmp_path / "out_sym.json"
    sym.symlink_to(rec)
    hard = tmp_path / "out_hard.json"
    os.link(rec, hard)
    before = _digest(rec)
    for out in (sym, hard):
        assert main(["check", str(robot), str(rec), "--json", str(out)]) == 1
        assert "is an input of this command" in capsys.readouterr().err
    assert _digest(rec) == before


def test_folder_where_a_file_goes_and_the_reverse(lab, tmp_path, capsys):
    robot, rec = lab
    folder = tmp_path / "a_folder"
    folder.mkdir()
    assert main(["check", str(robot), "--json", str(folder)]) == 1
    assert "is a folder; give a file name" in capsys.readouterr().err
    assert main(["diagnose", str(robot), str(rec), "--report", str(rec)]) == 1
    assert "is a file, not a folder" in capsys.readouterr().err
    (folder / "report.md").mkdir()  # a folder where --report writes a file
    assert main(["diagnose", str(robot), str(rec), "--report", str(folder)]) == 1
    assert "report.md is a folder" in capsys.readouterr().err


def test_missing_parent_fails_at_once(lab, tmp_path, capsys):
    robot, rec = lab
    out = tmp_path / "no" / "such" / "d.json"
    assert main(["diagnose", str(robot), str(rec), "--json", str(out)]) == 1
    err = capsys.readouterr().err
    assert "does not exist; create it first" in err and not out.parent.exists()


def test_two_outputs_writing_one_file(lab, tmp_path, capsys):
    robot, rec = lab
    rep = tmp_path / "rep"
    assert main(["diagnose", str(robot), str(rec), "--report", str(rep), "--json", str(rep / "diagnosis.json")]) == 1
    assert "both write" in capsys.readouterr().err


def test_check_outputs_accepts_new_folders_and_refuses_a_file_on_the_way(tmp_path):
    check_outputs((), folders={"--out": (tmp_path / "new" / "deeper", ("a.json",))})  # created later: fine
    (tmp_path / "plain").write_text("x")
    with pytest.raises(OutputPathError, match="is a file, not a folder"):
        check_outputs((), folders={"--out": (tmp_path / "plain" / "sub", ("a.json",))})
    check_outputs((tmp_path / "plain",), files={"--json": tmp_path / "other.json", "--x": None})


# --------------------------------------------------------- rows, time order, dropped
def _write(path, header, rows):
    path.write_text("\n".join([header, *rows]) + "\n")


def test_recordings_rows_are_file_lines(lab, tmp_path):
    robot, rec = lab
    lines = rec.read_text().splitlines()
    header, data = lines[0], lines[1:]
    bad = data[3].split(",")
    bad[1] = "oops"
    # line 1 header, 2-3 data, 4 blank, 5 data, 6 invalid, 7.. data
    _write(tmp_path / "r.csv", header, [data[0], data[1], "", data[2], ",".join(bad), *data[4:]])
    loaded = load_recordings(tmp_path / "r.csv", load_robot(robot), drop_invalid=True)
    kept, dropped = list(loaded.rows), list(loaded.dropped_rows)
    assert dropped == [6] and kept == [2, 3, 5, *range(7, 7 + len(data) - 4)]
    assert len(kept) == loaded.num_samples
    file_lines = (tmp_path / "r.csv").read_text().splitlines()
    for k, line in enumerate(kept):  # each sample is the file line it names
        cells = file_lines[line - 1].split(",")
        assert float(cells[header.split(",").index("x")]) == float(loaded.pose[k, 0])
    order = np.arange(loaded.num_samples)[::-1]
    assert list(loaded.select(order).rows) == kept[::-1]  # the line numbers follow the samples
    assert load_recordings(rec, load_robot(robot)).rows == tuple(range(2, 2 + len(data)))


def _shuffled_with_blank(rec, path):
    lines = rec.read_text().splitlines()
    data = lines[1:]
    data[4], data[5] = data[5], data[4]
    _write(path, lines[0], [*data[:2], "", *data[2:]])  # the swap now sits on file lines 7 and 8
    return path


@pytest.mark.parametrize("cmd", ["fit", "diagnose"])
def test_time_going_backwards_names_the_file_line(lab, tmp_path, capsys, cmd):
    robot, rec = lab
    path = _shuffled_with_blank(rec, tmp_path / "shuffled.csv")
    assert main([cmd, str(robot), str(path)]) == 1
    err = capsys.readouterr().err
    assert "row 8: time" in err and "at row 7" in err and "--sort-by-time" in err


def _dropped_and_shuffled(rec, path):
    path = _shuffled_with_blank(rec, path)
    lines = path.read_text().splitlines()
    cells = lines[9].split(",")
    cells[2] = ""  # an empty required l0 cell on file line 10
    lines[9] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")
    return path


def test_fit_summary_names_dropped_rows_and_sorting(lab, tmp_path, capsys, monkeypatch):
    """What fit says about its input, up to the calibration (stopped there: it is the slow part)."""
    def stop(*args, **kwargs):
        raise ValueError("stopped before calibrating")

    monkeypatch.setattr("fitting.calibration.least_squares.calibrate", stop)
    robot, rec = lab
    path = _dropped_and_shuffled(rec, tmp_path / "shuffled.csv")
    assert main(["fit", str(robot), str(path), "--drop-invalid", "--sort-by-time"]) == 1
    out = capsys.readouterr()
    assert "19 samples; dropped 1 invalid rows: [10]; sorted by time (--sort-by-time)" in out.out
    assert "stopped before calibrating" in out.err


@pytest.mark.slow
def test_fit_reports_dropped_rows_and_sorts_by_time(lab, tmp_path, capsys):
    robot, rec = lab
    path = _dropped_and_shuffled(rec, tmp_path / "shuffled.csv")
    out = tmp_path / "fit.json"
    assert main(["fit", str(robot), str(path), "--drop-invalid", "--sort-by-time", "--json", str(out)]) == 0
    stdout = capsys.readouterr().out
    assert "19 samples; dropped 1 invalid rows: [10]; sorted by time" in stdout
    doc = json.loads(out.read_text())
    assert doc["dropped_rows"] == {"count": 1, "rows": [10]} and doc["sorted_by_time"] is True
    assert 0.3 < doc["chi2_per_dof"] < 2.0  # clean data: the sorted fit explains it


# ------------------------------------------------------------------------- diagnose
@pytest.fixture
def small_diagnose(monkeypatch):
    """The CLI's diagnosis restricted to the baseline (cheap); the command logic is unchanged."""
    monkeypatch.setattr(fitting.diagnosis.diagnose, "diagnose",
                        functools.partial(fitting.diagnosis.diagnose.diagnose, effects=(), posterior_steps=0))


def test_diagnose_no_verdict_without_equilibrium(lab, tmp_path, capsys, small_diagnose):
    robot, rec = lab
    lines = rec.read_text().splitlines()
    header = lines[0].split(",")
    cols = [j for j, h in enumerate(header) if h.startswith("l0_")]
    half = [",".join(repr(float(c) / 2) if j in cols else c for j, c in enumerate(r.split(","))) for r in lines[1:]]
    _write(tmp_path / "half.csv", lines[0], half)
    out = tmp_path / "d.json"
    assert main(["diagnose", str(robot), str(tmp_path / "half.csv"), "--json", str(out), "--quiet"]) == 1
    err = capsys.readouterr().err
    assert "no equilibrium for 20 of 20 samples (row 2, row 3" in err and "shorter than the anchor-attachment" in err
    assert not out.exists()


def test_diagnose_reports_failed_and_dropped_rows(lab, tmp_path, capsys, small_diagnose):
    robot, rec = lab
    lines = rec.read_text().splitlines()
    header = lines[0].split(",")
    j = header.index("l0_2")
    rows = []
    for k, r in enumerate(lines[1:]):
        cells = r.split(",")
        if k in (3, 10):  # half lengths: no equilibrium (file lines 5 and 13 once a row is inserted)
            cells = [repr(float(c) / 2) if h.startswith("l0_") else c for h, c in zip(header, cells, strict=True)]
        rows.append(",".join(cells))
    bad = rows[0].split(",")
    bad[j] = "n/a"
    rows.insert(6, ",".join(bad))  # file line 8 is invalid and dropped; 20 samples remain
    _write(tmp_path / "mixed.csv", lines[0], rows)
    out, rep = tmp_path / "d.json", tmp_path / "rep"
    assert main(["diagnose", str(robot), str(tmp_path / "mixed.csv"), "--drop-invalid", "--json", str(out),
                 "--report", str(rep), "--quiet"]) == 0
    verdict = capsys.readouterr().out
    assert "no equilibrium (left out): 2 samples, rows [5, 13]" in verdict
    assert "dropped: 1 rows [8]" in verdict
    doc = json.loads(out.read_text())
    assert doc["failed_samples"] == {"count": 2, "samples": [4, 11], "rows": [5, 13]}
    assert doc["dropped_rows"] == {"count": 1, "rows": [8]}
    md = (rep / "report.md").read_text()
    assert "for 2 of 20 samples (file rows [5, 13])" in md and "**Dropped** 1 invalid row(s)" in md


# ------------------------------------------------------------------------ stiffness
@pytest.fixture(scope="module")
def tcpr8():
    return load_robot(example_path("tcpr8.toml"))


def test_stiffness_uses_feasible_tensions_on_a_redundant_robot(tmp_path, capsys, tcpr8):
    out = tmp_path / "k.json"
    argv = ["stiffness", "tcpr8.toml", "--pose", "0", "0", "0.83", "0", "0", "0", "--wrench", *["0"] * 6]
    assert main([*argv, "--json", str(out)]) == 0
    assert "centroid of the CTFR (2 degrees of redundancy" in capsys.readouterr().out
    doc = json.loads(out.read_text())
    t = np.asarray(doc["tensions"])
    assert np.all(t >= 10.0 - 1e-9) and np.all(t <= 400.0 + 1e-9)
    np.testing.assert_allclose(np.sort(np.unique(np.round(t, 1))), [193.7, 210.3])  # Cui et al. 2019 Table 3
    S = np.asarray(statics.structure_matrix(tcpr8, np.array([0, 0, 0.83, 0, 0, 0.0])))
    w = np.asarray(statics.gravity_wrench(tcpr8, np.array([0, 0, 0.83, 0, 0, 0.0])))
    assert np.linalg.norm(S @ t + w) < 1e-6 * np.linalg.norm(w)  # the tensions hold the platform
    assert doc["tension_rule"].startswith("feasible tensions: centroid of the CTFR")


def test_stiffness_fails_when_no_feasible_tensions(capsys):
    argv = ["stiffness", "tcpr8.toml", "--pose", "0", "0", "0.83", "0", "0", "0", "--wrench", "0", "0", "-5000",
            "0", "0", "0"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "no feasible tensions" in err and "[10, 400] N" in err and "pass --tensions" in err


def test_stiffness_refuses_a_zero_length_cable(capsys, tcpr8):
    p = np.asarray(tcpr8.anchors[0] - tcpr8.attachments[0])
    argv = ["stiffness", "tcpr8.toml", "--pose", *[str(v) for v in p], "0", "0", "0", "--tensions", *["100"] * 8]
    assert main(argv) == 1
    assert "a cable has zero length" in capsys.readouterr().err


# -------------------------------------------------------------- errors inside jit
def test_cli_prints_the_message_of_an_error_raised_inside_jit(monkeypatch, capsys):
    failing = jax.jit(lambda x: raise_if_failed(Status.where(x > 0, Status.successful, Status.invalid_input), x, True))

    def run(args):
        failing(-1.0)
        return 0

    monkeypatch.setattr("cstiffjax.commands.check.run", run)
    assert main(["check", "example02/robot.toml"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("cstiffjax check: error: invalid input (non-positive length")
    assert "CpuCallback" not in err and "Traceback" not in err
