"""The IRMA4U reader (cstiffjax.io.irma4u, ``cstiffjax convert irma4u``) on small synthetic
MATLAB files written here in the layout of the repository fzoffoli/UACDPR_SelfCalibration:
the robot model ``libs/config/IRMA4U_Mar25.mat`` (struct ``s``), and per run a processed log
``<run>_parsed.mat`` (struct ``st``) and a workspace file holding ``meas_idx`` (1-based).

Every signal row is a distinct pattern, so a swapped cable, a transposed array or an
off-by-one sample index changes the expected columns, which are computed here again from the
synthetic arrays. With ``CSTIFFJAX_IRMA4U`` set to a checkout of the repository, one more
test reads the real files.
"""

import math
import os
import re
import tomllib

import numpy as np
import pytest
from scipy.io import loadmat, savemat

from cstiffjax.commands.cli import main
from cstiffjax.io.irma4u import RUNS, Irma4uError, read_irma4u, robot_toml

ANCHORS = np.array([[1.065, -1.155, 1.839], [1.066, 1.155, 1.839], [-1.066, 1.155, 1.839], [-1.065, -1.155, 1.839]])
POINTS = np.array([[0.075, -0.075, 0.266], [0.075, 0.075, 0.266], [-0.075, 0.075, 0.266], [-0.075, -0.075, 0.266]])
# FixedFrame {x_i, y_i, z_i} of the source: swivel axis z_i = +x for cables 1, 2 and -x for 3, 4
FRAMES = [([0, 0, -1], [0, 1, 0], [1, 0, 0])] * 2 + [([0, 0, -1], [0, -1, 0], [-1, 0, 0])] * 2


def _cell(items, shape):
    out = np.empty(shape, dtype=object)
    for k, v in enumerate(items):
        out.flat[k] = v
    return out


def _config(frames=FRAMES, mass=12.992):
    pulleys = [{"Id": i + 1, "r": 0.03, "CableEnterPosition": ANCHORS[i].reshape(3, 1),
                "FixedFrame": _cell([np.array(v, float).reshape(3, 1) for v in frames[i]], (1, 3))} for i in range(4)]
    platform = {"m": mass, "PtoG": np.array([[0.0], [0.0], [0.173]]), "InertialMatrix": np.diag([0.18, 0.12, 0.19]),
                "points": _cell([POINTS[i].reshape(1, 3) for i in range(4)], (1, 4))}
    return {"s": {"DependencyVect": np.array([[1, 1, 1, 0, 0, 1]]), "EndEffector": {"Platform": platform},
                  "Trasmission": {"Cable": np.array([[1, 2, 3, 4]]), "Pulley": _cell(pulleys, (1, 4))}}}


def _st(session: int, n: int = 60):
    """A processed log of ``n`` samples at 10 Hz; each row its own pattern."""
    k = np.arange(n, dtype=float)
    t = 100.0 + 7 * session + 0.1 * k
    lengths = np.array([2.0 + 0.01 * i + 0.001 * session + 1e-4 * k for i in range(4)])
    lengths[2, 30:] += 0.02 * (k[30:] - 29)  # cable 3 pays out at 0.2 m/s from sample 30 on
    return {"t": t.reshape(1, n),
            "epsilon": np.array([0.01 + 1e-4 * k, -0.02 - 2e-4 * k, 0.003 * session + 3e-5 * k]),
            "cable_length": lengths,
            "swivel": np.array([(0.5 + 0.1 * i) * (-1) ** i + 1e-3 * k for i in range(4)]),
            "tensions": np.array([40.0 + 5 * i + 0.1 * k + session for i in range(4)]),
            "target_tensions": np.array([41.0 + 5 * i + 0.1 * k for i in range(4)])}


IDX = {0: [3, 10, 35], 1: [5, 6], 2: [1, 20, 40, 60]}  # 1-based, as MATLAB's meas_idx


@pytest.fixture
def repo(tmp_path):
    (tmp_path / "libs" / "config").mkdir(parents=True)
    savemat(tmp_path / "libs" / "config" / "IRMA4U_Mar25.mat", _config())
    for s, run in enumerate(RUNS):
        savemat(tmp_path / run.log, {"st": _st(s)})
        savemat(tmp_path / run.workspace, {"meas_idx": np.array([IDX[s]], dtype=np.uint16), "st": _st(s),
                                           "n": np.array([[4]], dtype=np.uint8)})
    return tmp_path


def _expected(column: str) -> np.ndarray:
    parts = []
    for s in range(len(RUNS)):
        st, i = _st(s), np.array(IDX[s]) - 1
        t = st["t"][0]
        table = {"session": np.full(i.size, s), "time": t[i] - t[0], "roll": st["epsilon"][0, i],
                 "pitch": st["epsilon"][1, i], "yaw": st["epsilon"][2, i]}
        for c in range(4):
            table |= {f"l0_{c + 1}": st["cable_length"][c, i], f"t_{c + 1}": st["tensions"][c, i],
                      f"swivel_{c + 1}": st["swivel"][c, i], f"t_set_{c + 1}": st["target_tensions"][c, i]}
        parts.append(table[column])
    return np.concatenate(parts).astype(float)


def test_columns_map_the_picked_samples(repo):
    data = read_irma4u(repo)
    assert list(data.columns) == ["session", "time", "l0_1", "l0_2", "l0_3", "l0_4", "t_1", "t_2", "t_3", "t_4",
                                  "swivel_1", "swivel_2", "swivel_3", "swivel_4", "roll", "pitch", "yaw",
                                  "t_set_1", "t_set_2", "t_set_3", "t_set_4", "winch_speed"]
    assert data.runs == ("sc_27_medium_a", "sc_8_final", "sc_27_final")
    for c in list(data.columns)[:-1]:
        np.testing.assert_allclose(data.columns[c], _expected(c), rtol=0, atol=1e-12, err_msg=c)
    # winch speed: the lengths move 1e-4 m per 0.1 s (1e-3 m/s) everywhere; cable 3 also pays out 0.02 m per
    # step from sample 30 (0-based) on. Windows of +-5 samples, clipped to the log: session 0's third sample
    # (34: 29..39) and session 2's third and fourth (39: 34..44; 59: 54..59) see cable 3 move, the others not
    speed = data.columns["winch_speed"]
    np.testing.assert_allclose(speed[[0, 1, 3, 4, 5, 6]], 1e-3, rtol=1e-9)
    np.testing.assert_allclose(speed[[2, 7, 8]], 0.201, rtol=1e-9)


def test_robot_tables_and_toml(repo):
    data = read_irma4u(repo, ea=2.5e5, name="irma-test")
    doc = tomllib.loads(robot_toml(data))
    assert doc["kind"] == "cdpr" and doc["name"] == "irma-test" and doc["gravity"] == [0.0, 0.0, -9.81]
    assert doc["platform"]["mass"] == 12.992 and doc["platform"]["com"] == [0.0, 0.0, 0.173]
    assert doc["platform"]["inertia"] == [[0.18, 0.0, 0.0], [0.0, 0.12, 0.0], [0.0, 0.0, 0.19]]
    assert doc["sensors"] == {"lengths": "relative", "ahrs_mounting": [0.0, 0.0, 0.0]}
    assert doc["noise"]["swivel"] > 0 and len(doc["noise"]["ahrs"]) == 3
    for i, c in enumerate(doc["cables"]):
        assert c["anchor"] == ANCHORS[i].tolist() and c["attachment"] == POINTS[i].tolist()
        assert c["pulley_radius"] == 0.03 and c["EA"] == 2.5e5 and c["mass_per_length"] == 0.0
        assert c["pulley_axis"] == list(map(float, FRAMES[i][2])) and c["swivel_zero"] == list(map(float, FRAMES[i][0]))
    assert "# Recordings sessions: 0 = sc_27_medium_a, 1 = sc_8_final, 2 = sc_27_final." in robot_toml(data)


def test_source_swivel_angle_is_the_contract_swivel():
    """The source's angle atan2(y_i·DA, x_i·DA) equals formats.md's swivel: the right-hand angle about
    pulley_axis = z_i from swivel_zero = x_i to u (the unit part of DA normal to the axis), for the
    frames of the real robot (checked right-handed by the reader)."""
    rng = np.random.default_rng(4)
    for x, y, z in FRAMES:
        x, y, z = (np.array(v, float) for v in (x, y, z))
        for da in rng.normal(size=(20, 3)):
            u = da - (da @ z) * z
            u /= np.linalg.norm(u)
            contract = math.atan2(np.cross(x, u) @ z, x @ u)
            assert math.isclose(math.atan2(y @ da, x @ da), contract, abs_tol=1e-12)


def test_left_handed_pulley_frame_is_refused(repo):
    frames = list(FRAMES)
    frames[2] = ([0, 0, -1], [0, 1, 0], [-1, 0, 0])  # x × y = +x, not z
    savemat(repo / "libs" / "config" / "IRMA4U_Mar25.mat", _config(frames))
    with pytest.raises(Irma4uError, match=r"IRMA4U_Mar25\.mat: s\.Trasmission\.Pulley\{3\}\.FixedFrame: .* not a "
                                          r"right-handed orthonormal frame"):
        read_irma4u(repo)


def test_config_next_to_the_runs_and_missing_config(repo, tmp_path):
    (repo / "libs" / "config" / "IRMA4U_Mar25.mat").rename(repo / "IRMA4U_Mar25.mat")
    assert read_irma4u(repo).columns["l0_1"].size == 9
    (repo / "IRMA4U_Mar25.mat").unlink()
    with pytest.raises(FileNotFoundError, match=r"no robot model libs/config/IRMA4U_Mar25\.mat or IRMA4U_Mar25\.mat"):
        read_irma4u(repo)
    with pytest.raises(FileNotFoundError, match="not a folder"):
        read_irma4u(tmp_path / "nowhere")


def test_errors_name_file_variable_and_value(repo):
    ws = repo / RUNS[1].workspace
    savemat(ws, {"meas_idx_typo": np.array([[1, 2]]), "k": 3})
    with pytest.raises(Irma4uError, match=r"ws_selfcalibration_8_final\.mat: no variable 'meas_idx' .*variables in the "
                                          r"file: k, meas_idx_typo"):
        read_irma4u(repo)
    savemat(ws, {"meas_idx": np.array([[5, 61]])})
    with pytest.raises(Irma4uError, match=r"meas_idx: values \[5\.0, 61\.0\].*expected whole numbers in 1\.\.60"):
        read_irma4u(repo)
    savemat(ws, {"meas_idx": np.array([[7, 5]])})
    with pytest.raises(Irma4uError, match=r"meas_idx: not increasing at position 2"):
        read_irma4u(repo)
    savemat(ws, {"meas_idx": np.array([[5, 7]])})
    st = _st(1)
    del st["swivel"]
    savemat(repo / RUNS[1].log, {"st": st})
    with pytest.raises(Irma4uError, match=r"sc_8_final_parsed\.mat: st: no field 'swivel'; fields: t, epsilon"):
        read_irma4u(repo)
    st = _st(1)
    st["tensions"] = st["tensions"][:3]
    savemat(repo / RUNS[1].log, {"st": st})
    with pytest.raises(Irma4uError, match=r"st\.tensions has shape \(3, 60\); expected \(4, 60\)"):
        read_irma4u(repo)
    st = _st(1)
    st["cable_length"][1, 4] = np.nan
    savemat(repo / RUNS[1].log, {"st": st})
    with pytest.raises(Irma4uError, match=r"st\.cable_length\(2, 5\) = nan at picked sample 1 of run sc_8_final"):
        read_irma4u(repo)
    with pytest.raises(ValueError, match="EA = -1.0 must be a finite number > 0"):
        read_irma4u(repo, ea=-1.0)


def test_log_absent_uses_the_workspace_copy(repo):
    (repo / RUNS[2].log).unlink()
    data = read_irma4u(repo)
    np.testing.assert_allclose(data.columns["swivel_4"], _expected("swivel_4"), atol=1e-12)
    assert any("sc_27_final: signals from the copy of st in ws_selfcalibration_27_final.mat" in a
               for a in data.assumptions)
    savemat(repo / RUNS[2].workspace, {"meas_idx": np.array([IDX[2]])})
    with pytest.raises(FileNotFoundError, match=r"sc_27_final_parsed\.mat: no such file .* holds no copy of st"):
        read_irma4u(repo)


def test_cli_writes_both_files(repo, tmp_path, capsys):
    out = tmp_path / "converted"
    assert main(["convert", "irma4u", str(repo), "--out", str(out), "--ea", "3e5"]) == 0
    text = capsys.readouterr().out
    assert "9 samples, session 0 = sc_27_medium_a (3), session 1 = sc_8_final (2), session 2 = sc_27_final (4)" in text
    assert "assumed: EA = 300000 N for every cable (given)" in text
    lines = (out / "recordings.csv").read_text().splitlines()
    assert lines[0].startswith("session,time,l0_1,") and len(lines) == 10
    row = dict(zip(lines[0].split(","), map(float, lines[3].split(",")), strict=True))  # session 0, 3rd sample
    assert row["session"] == 0 and math.isclose(row["l0_3"], _expected("l0_3")[2], rel_tol=1e-11)
    assert tomllib.loads((out / "robot.toml").read_text())["cables"][0]["EA"] == 3e5


def test_cli_names_the_conversion_it_replaces(repo, tmp_path, capsys):
    """A conversion into a new folder says nothing about replacing; into the folder of an
    earlier one it names that folder and both files on stderr before writing."""
    out = tmp_path / "converted"
    argv = ["convert", "irma4u", str(repo), "--out", str(out)]
    assert main(argv) == 0
    assert "replacing" not in capsys.readouterr().err
    assert main(argv) == 0
    err = capsys.readouterr().err
    assert f"note: replacing 2 file(s) of an earlier run in {out}/: recordings.csv, robot.toml" in err.splitlines(), err


@pytest.mark.parametrize(("extra", "message"), [
    (["--cable-set", "x"], r"--cable-set: option\(s\) of CASPR models only"),
    (["--noise", "1", "1", "1"], r"--noise: option\(s\) of CASPR models only"),
    (["--ea", "-2"], r"--ea -2: must be > 0"),
    (["--mass-per-length", "-1"], r"--mass-per-length -1: must be >= 0"),
])
def test_cli_refuses(repo, tmp_path, capsys, extra, message):
    assert main(["convert", "irma4u", str(repo), "--out", str(tmp_path / "o"), *extra]) == 1
    assert re.search(message, capsys.readouterr().err)
    assert not (tmp_path / "o").exists()


def test_cli_missing_folder(tmp_path, capsys):
    assert main(["convert", "irma4u", str(tmp_path / "absent"), "--out", str(tmp_path / "o")]) == 1
    assert "not a folder" in capsys.readouterr().err


@pytest.mark.skipif(not os.environ.get("CSTIFFJAX_IRMA4U"), reason="set CSTIFFJAX_IRMA4U to a checkout of "
                    "fzoffoli/UACDPR_SelfCalibration")
def test_real_repository():
    root = os.environ["CSTIFFJAX_IRMA4U"]
    data = read_irma4u(root)
    assert [int(np.sum(data.columns["session"] == s)) for s in range(3)] == [27, 8, 27]
    for s, run in enumerate(RUNS):  # the picked samples, read again with scipy alone
        st = loadmat(os.path.join(root, run.log))["st"][0, 0]
        idx = loadmat(os.path.join(root, run.workspace), variable_names=["meas_idx"])["meas_idx"].ravel() - 1
        mine = data.columns["session"] == s
        np.testing.assert_array_equal(data.columns["l0_2"][mine], st["cable_length"][1, idx])
        np.testing.assert_array_equal(data.columns["swivel_3"][mine], st["swivel"][2, idx])
        np.testing.assert_array_equal(data.columns["pitch"][mine], st["epsilon"][1, idx])


def test_a_log_of_another_run_is_refused(repo):
    """The workspace file's copy of st identifies the run: a log copied from another run (or
    another recording of the same name) is refused naming both files; removing it reads the copy."""
    (repo / RUNS[1].log).write_bytes((repo / RUNS[2].log).read_bytes())
    with pytest.raises(Irma4uError, match=r"sc_8_final_parsed\.mat: not the log of run sc_8_final: "
                                          r"ws_selfcalibration_8_final\.mat.*differs from it \(60 samples from "
                                          r"t = 114 s, the workspace's copy 60 from t = 107 s\).*remove it"):
        read_irma4u(repo)
    st = _st(1)
    st["tensions"][2, 17] += 0.5  # the same clock, one reading changed
    savemat(repo / RUNS[1].log, {"st": st})
    with pytest.raises(Irma4uError, match=r"not the log of run sc_8_final: .*st\.tensions differs \(first at "
                                          r"sample 18\)"):
        read_irma4u(repo)
    (repo / RUNS[1].log).unlink()
    np.testing.assert_allclose(read_irma4u(repo).columns["t_3"], _expected("t_3"), atol=1e-12)


def test_one_log_under_two_run_names_is_refused(repo):
    """Without the workspace copies to compare with, two runs whose logs hold the same clock are refused."""
    for s in (1, 2):
        savemat(repo / RUNS[s].workspace, {"meas_idx": np.array([IDX[s]])})
    (repo / RUNS[2].log).write_bytes((repo / RUNS[1].log).read_bytes())
    with pytest.raises(Irma4uError, match=r"sc_27_final_parsed\.mat: the log of run sc_27_final has the same 60 "
                                          r"sample times as .*sc_8_final_parsed\.mat"):
        read_irma4u(repo)
    savemat(repo / RUNS[2].log, {"st": _st(2)})
    assert any("holds no copy of st to confirm" in a for a in read_irma4u(repo).assumptions)


def _damage(data: bytes, kind: str) -> bytes:
    b = bytearray(data)
    if kind == "truncated":
        return bytes(b[: len(b) // 2])
    if kind == "empty":
        return b""
    if kind == "crash":  # a size byte that makes scipy's reader crash the interpreter (segmentation fault)
        b[289] = 227
        return bytes(b)
    rng = np.random.default_rng(int(kind[-1]))  # "flipped<seed>": five random bytes changed
    for k in rng.integers(128, len(b), 5):
        b[k] = rng.integers(0, 256)
    return bytes(b)


@pytest.mark.parametrize(("which", "kind"), [(w, k) for w in ("config", "log", "workspace")
                                             for k in ("truncated", "empty", "flipped1", "flipped2")]
                         + [("config", "crash")])
def test_damaged_files_give_a_clear_error(repo, which, kind):
    """Damaged copies of every file: read or a clear Irma4uError naming the file, never a traceback or a
    crash (scipy's reader runs in a child process; the "crash" copy of the model kills it)."""
    path = {"config": repo / "libs" / "config" / "IRMA4U_Mar25.mat", "log": repo / RUNS[1].log,
            "workspace": repo / RUNS[1].workspace}[which]
    path.write_bytes(_damage(path.read_bytes(), kind))
    if kind in ("truncated", "empty", "crash"):  # nothing readable is left: always the error
        with pytest.raises(Irma4uError, match=re.escape(path.name)) as info:
            read_irma4u(repo)
        if kind == "crash":
            assert "crashed on it (signal" in str(info.value) and "damaged or truncated" in str(info.value)
        return
    try:  # five bytes changed may fall where they change nothing the reader keeps
        read_irma4u(repo)
    except Irma4uError as e:
        assert path.name in str(e), e  # the damaged file, or (a changed copy of st) it and the log


@pytest.mark.parametrize(("edit", "message"), [
    (lambda st: st.update(t="ten"), r"st\.t: expected a numeric array, got text of shape \(1,\)"),
    (lambda st: st.update(swivel=_cell([1.0] * 4, (1, 4))),
     r"st\.swivel: expected a numeric array, got cells or structs of shape \(1, 4\)"),
    (lambda st: st["t"].__setitem__((0, 7), st["t"][0, 6]), r"st\.t\(1, 8\) = 107\.6: the log's clock must hold "
                                                            r"finite, increasing times"),
    (lambda st: st.update(epsilon=np.zeros((3, 0))), r"st\.epsilon has shape \(3, 0\); expected \(3, 60\)"),
])
def test_wrong_layout_of_the_log(repo, edit, message):
    st = _st(1)
    edit(st)
    savemat(repo / RUNS[1].log, {"st": st})
    savemat(repo / RUNS[1].workspace, {"meas_idx": np.array([IDX[1]])})
    with pytest.raises(Irma4uError, match=r"sc_8_final_parsed\.mat: " + message):
        read_irma4u(repo)


def test_wrong_layout_of_meas_idx_and_model(repo):
    savemat(repo / RUNS[0].workspace, {"meas_idx": "first"})
    with pytest.raises(Irma4uError, match=r"sc_27_medium_a_workspace\.mat: meas_idx: expected numbers, got"):
        read_irma4u(repo)
    cfg = _config()
    cfg["s"]["Trasmission"]["Pulley"] = np.array([[1.0, 2.0, 3.0, 4.0]])
    savemat(repo / "libs" / "config" / "IRMA4U_Mar25.mat", cfg)
    with pytest.raises(Irma4uError, match=r"s\.Trasmission\.Pulley\{1\}: expected a 1x1 struct, got"):
        read_irma4u(repo)
