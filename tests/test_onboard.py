"""Recordings from on-board sensors only (formats.md §2 version 3): no x y z, swivel encoders,
an AHRS, sessions and relative lengths; the sensor models against independent numpy/scipy
references, the loader's rules, and a calibration from these recordings alone."""

import math
import re
import warnings
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from cstiffjax import RecordingsError, RobotFileError, load_recordings
from cstiffjax.io import schema
from cstiffjax.io.recordings import write_recordings
from cstiffjax.io.robot_io import load_robot, robot_from_dict, robot_to_toml
from cstiffjax.statics.sensors import ahrs_angles, euler_zyx, rotation_zyx, swivel_angles
from fitting.calibration.least_squares import IdentifiabilityWarning, calibrate
from fitting.diagnosis.sample_checks import time_order
from fitting.synth.onboard import hanging_lengths, onboard_recordings

ROBOT = """
kind = "cdpr"
name = "onboard4"
gravity = [0.0, 0.0, -9.81]

[platform]
mass = 12.99
com = [0.0, 0.0, -0.1]

[noise]
position = 0.001
rotation = 0.001
tension = 0.5
swivel = 0.002
ahrs = [0.003, 0.003, 0.006]

[sensors]
lengths = "relative"
"""
CABLE = """
[[cables]]
anchor = [{ax}, {ay}, 3.0]
attachment = [{px}, {py}, 0.05]
EA = 1e5
mass_per_length = 0.0
pulley_radius = 0.03
pulley_axis = [0.0, 0.0, 1.0]
swivel_zero = [1.0, 0.0, 0.0]
"""
CORNERS = ((2.0, 1.5, 0.15, 0.1), (-2.0, 1.5, -0.15, 0.1), (-2.0, -1.5, -0.15, -0.1), (2.0, -1.5, 0.15, -0.1))


def _robot_text(extra: str = "") -> str:
    return ROBOT + extra + "".join(CABLE.format(ax=a, ay=b, px=c, py=d) for a, b, c, d in CORNERS)


@pytest.fixture(scope="module")
def robot(tmp_path_factory):
    path = tmp_path_factory.mktemp("onboard") / "robot.toml"
    path.write_text(_robot_text())
    return load_robot(path)


# ---------------------------------------------------------------- sensor models vs references
def _swivel_numpy(anchor, axis, zero, P):
    """The swivel angle written out: the pulley plane's direction u (the part of P - anchor
    normal to the axis) measured from ``zero`` about ``axis``, right-handed."""
    w = P - anchor
    u = w - (w @ axis) * axis
    u /= np.linalg.norm(u)
    x = zero / np.linalg.norm(zero)
    y = np.cross(axis, x)
    return math.atan2(u @ y, u @ x)


def test_swivel_angles_match_an_independent_numpy_implementation(robot):
    rng = np.random.default_rng(1)
    for _ in range(5):
        pose = np.concatenate([rng.uniform([-0.8, -0.6, 0.8], [0.8, 0.6, 2.0]), rng.normal(0, 0.1, 3)])
        R = Rotation.from_rotvec(pose[3:]).as_matrix()
        got = np.asarray(swivel_angles(robot, pose))
        for i in range(4):
            P = pose[:3] + R @ np.asarray(robot.attachments[i])
            want = _swivel_numpy(np.asarray(robot.anchors[i]), np.asarray(robot.pulley_axis[i]),
                                 np.asarray(robot.swivel_zero[i]), P)
            assert got[i] == pytest.approx(want, abs=1e-12)


def test_ahrs_reading_matches_scipy_euler_angles(robot):
    rng = np.random.default_rng(2)
    mounting = np.array([0.02, -0.01, 0.3])
    rb = robot_from_dict(__import__("tomllib").loads(_robot_text().replace(
        'lengths = "relative"', f'lengths = "relative"\nahrs_mounting = {mounting.tolist()}')))
    for _ in range(5):
        pose = np.concatenate([rng.normal(size=3), rng.normal(0, 0.4, 3)])
        yaw0 = rng.uniform(-3, 3)
        R = Rotation.from_rotvec([0, 0, yaw0]) * Rotation.from_rotvec(pose[3:]) * Rotation.from_rotvec(mounting)
        yaw, pitch, roll = R.as_euler("ZYX")
        np.testing.assert_allclose(ahrs_angles(rb, pose, yaw0), [roll, pitch, yaw], atol=1e-12)
    a = np.array([0.3, -0.2, 2.9])
    np.testing.assert_allclose(euler_zyx(rotation_zyx(a)), a, atol=1e-14)


def test_swivel_derivative_matches_finite_differences(robot):
    pose = np.array([0.2, -0.1, 1.4, 0.05, -0.03, 0.1])
    J = np.asarray(jax.jacfwd(lambda p: swivel_angles(robot, p))(pose))
    h = 1e-6
    fd = np.stack([(np.asarray(swivel_angles(robot, pose + h * e)) - np.asarray(swivel_angles(robot, pose - h * e)))
                   / (2 * h) for e in np.eye(6)], 1)
    np.testing.assert_allclose(J, fd, atol=1e-7)


# ---------------------------------------------------------------- robot description
def test_version3_robot_fields_round_trip(robot):
    again = robot_from_dict(__import__("tomllib").loads(robot_to_toml(robot)))
    assert again.relative_lengths and float(again.noise.swivel) == 0.002
    np.testing.assert_array_equal(again.noise.ahrs, robot.noise.ahrs)
    np.testing.assert_array_equal(again.swivel_zero, robot.swivel_zero)


@pytest.mark.parametrize("edit, match", [
    (('swivel_zero = [1.0, 0.0, 0.0]', 'swivel_zero = [1.0, 0.0, 0.5]'),
     r"cables\[1\].swivel_zero.*normal to pulley_axis"),
    (('lengths = "relative"', 'lengths = "relativ"'), r"sensors.lengths.*'absolute', 'relative'"),
    (('ahrs = [0.003, 0.003, 0.006]', 'ahrs = [0.003, 0.0, 0.006]'), r"noise.ahrs.*must be > 0"),
    (('[sensors]', '[sensors]\nwinch = 1'), r"sensors.winch"),
])
def test_bad_version3_robot_fields_name_the_key(tmp_path, edit, match):
    path = tmp_path / "r.toml"
    path.write_text(_robot_text().replace(*edit, 1))
    with pytest.raises(RobotFileError, match=match):
        load_robot(path)


@pytest.mark.parametrize("zero", [[1e-300, 0.0, 0.0], [1e200, 1e200, 0.0], [3e-320, -3e-320, 0.0], [7.0, 0.0, 0.0]])
def test_swivel_zero_of_any_length_is_normalized(tmp_path, zero):
    """swivel_zero is a direction: scaled before its norm, so neither 1e-300 nor 1e200 under- or overflows."""
    path = tmp_path / "r.toml"
    path.write_text(_robot_text().replace("swivel_zero = [1.0, 0.0, 0.0]", f"swivel_zero = {zero!r}", 1))
    expected = np.asarray(zero) / np.abs(zero).max()
    np.testing.assert_allclose(load_robot(path).swivel_zero[0], expected / np.linalg.norm(expected), rtol=1e-15)


@pytest.mark.parametrize(("zero", "match"), [
    ([0.0, 0.0, 0.0], r"cables\[1\]\.swivel_zero.*is the zero vector"),
    ([1e200, 0.0, 1e200], r"cables\[1\]\.swivel_zero.*normal to pulley_axis.*cosine of their angle is 0\.7071"),
])
def test_swivel_zero_refused_with_the_right_reason(tmp_path, zero, match):
    path = tmp_path / "r.toml"
    path.write_text(_robot_text().replace("swivel_zero = [1.0, 0.0, 0.0]", f"swivel_zero = {zero!r}", 1))
    with pytest.raises(RobotFileError, match=match):
        load_robot(path)


# ---------------------------------------------------------------- loader
def _write(tmp_path, rec, m, drop=(), extra=None):
    cols = schema.to_columns(m, {"session": rec.session, "time": rec.time, "l0": rec.l0, "tensions": rec.tensions,
                                 "swivel": rec.swivel, "ahrs": rec.ahrs}, extra)
    path = tmp_path / "rec.csv"
    write_recordings({c: v for c, v in cols.items() if c not in drop}, path)
    return path


@pytest.fixture(scope="module")
def clean(robot):
    rng = np.random.default_rng(3)
    l0 = hanging_lengths(robot, rng.uniform([-0.8, -0.6, 1.0], [0.8, 0.6, 2.0], (24, 3)))
    session = np.repeat([0, 1], 12)
    zeros = np.array([[0.004, -0.003, 0.002, 0.0], [-0.002, 0.001, 0.003, -0.004]])
    return onboard_recordings(robot, l0, session=session, length_zero=zeros, yaw_zero=np.array([0.2, -0.5]),
                              seed=4), zeros


def test_onboard_file_loads_without_a_pose(tmp_path, robot, clean):
    rec, _ = clean
    loaded = load_recordings(_write(tmp_path, rec, 4, extra={"t_set_2": np.full(24, 60.0)}), robot)
    assert not loaded.has_position and loaded.has_swivel and loaded.has_ahrs and loaded.sessions == (0, 1)
    assert not np.asarray(loaded.pose_mask).any() and loaded.covariate_names == ("t_set_2",)
    np.testing.assert_allclose(loaded.swivel, rec.swivel, rtol=1e-11)


@pytest.mark.parametrize("drop, extra, match", [
    (("yaw",), None, r"has roll, pitch but not yaw: the AHRS angle columns roll pitch yaw come all together"),
    ((*(f"{p}_{i}" for p in ("t", "swivel") for i in range(1, 5)), "roll", "pitch", "yaw"), None,
     r"no measured channel constrains the platform's pose"),
    ((), {"t_set_5": np.zeros(24)}, r"'t_set_5'.*has cables 1..4"),
    ((), {"T_set_1": np.zeros(24)}, r"did you mean 't_set_1'"),
])
def test_version3_header_rules(tmp_path, robot, clean, drop, extra, match):
    with pytest.raises(RecordingsError, match=match):
        load_recordings(_write(tmp_path, clean[0], 4, drop, extra), robot)


def test_sensor_columns_need_their_description(tmp_path, robot, clean):
    path = _write(tmp_path, clean[0], 4)
    no_zero = tmp_path / "nozero.toml"
    no_zero.write_text(_robot_text().replace("swivel_zero = [1.0, 0.0, 0.0]\n", "", 1))
    with pytest.raises(RecordingsError, match=r"'swivel_1' needs cables\[1\].swivel_zero"):
        load_recordings(path, load_robot(no_zero))
    no_sigma = tmp_path / "nosigma.toml"
    no_sigma.write_text(_robot_text().replace("ahrs = [0.003, 0.003, 0.006]\n", ""))
    with pytest.raises(RecordingsError, match=r"roll pitch yaw need noise.ahrs"):
        load_recordings(path, load_robot(no_sigma))


def test_session_ids_are_whole_numbers_and_time_restarts_per_session(tmp_path, robot, clean):
    rec = clean[0]
    path = _write(tmp_path, rec, 4)
    text = path.read_text().splitlines()
    text[3] = "0.5" + text[3][1:]
    path.write_text("\n".join(text) + "\n")
    with pytest.raises(RecordingsError, match=r"line 4, column 'session': value '0.5' must be a whole number"):
        load_recordings(path, robot)
    t = np.concatenate([np.arange(12.0), np.arange(12.0)])  # the second session's clock restarts
    assert time_order(eqx.tree_at(lambda r: r.time, rec, t))[2] is False
    with pytest.raises(Exception, match="earlier than"):
        time_order(eqx.tree_at(lambda r: (r.time, r.session), rec, (t, np.zeros(24, int))))


# ---------------------------------------------------------------- calibration from on-board sensors alone
def test_calibration_recovers_the_length_zeros_and_yaw_zeros(robot, clean):
    rec, zeros = clean
    fit = calibrate(robot, rec, ("EA",))
    assert set(fit.spec.free) == {"EA", "length_zero", "yaw_zero"}
    assert fit.chi2_per_dof < 1.6
    std = dict(zip(fit.names, np.sqrt(np.diag(fit.covariance)), strict=True))
    got = np.asarray(fit.values["length_zero"])
    sd = np.array([[std[f"length_zero[session {s}][{i + 1}]"] for i in range(4)] for s in range(2)])
    assert np.all(np.abs(got - zeros) < 4 * sd + 1e-9), (got, zeros, sd)
    np.testing.assert_allclose(fit.values["yaw_zero"], [0.2, -0.5], atol=4 * max(std["yaw_zero[session 0]"], 1e-4))


def test_fit_names_the_sessions_by_the_files_own_ids(tmp_path, robot, clean, capsys):
    """The file's session 0 is called 9 and its session 1 is called -7: every name (text and
    JSON) uses those ids, and each value sits under the id of the session it belongs to."""
    import json

    from cstiffjax.commands.cli import main

    rec, zeros = clean
    renamed = eqx.tree_at(lambda r: r.session, rec, np.where(np.asarray(rec.session) == 0, 9, -7))
    robot_path = tmp_path / "robot.toml"
    robot_path.write_text(_robot_text())
    out = tmp_path / "fit.json"
    assert main(["fit", str(robot_path), str(_write(tmp_path, renamed, 4)), "--json", str(out)]) == 0
    text = capsys.readouterr().out
    doc = json.loads(out.read_text())
    assert doc["sessions"] == [-7, 9]  # ascending: the rows of the per-session values
    names = [n for n in doc["names"] if "session" in n]
    assert names == [f"length_zero[session {s}][{i}]" for s in (-7, 9) for i in range(1, 5)] + [
        "yaw_zero[session -7]", "yaw_zero[session 9]"]
    assert "yaw_zero[session -7]" in text and "[session 1]" not in text and "[session 2]" not in text
    truth = {9: (0.2, zeros[0]), -7: (-0.5, zeros[1])}
    for row, sid in enumerate(doc["sessions"]):
        assert abs(doc["values"]["yaw_zero"][row] - truth[sid][0]) < 4 * max(doc["std"]["yaw_zero"][row], 1e-4)
        assert np.all(np.abs(np.subtract(doc["values"]["length_zero"][row], truth[sid][1]))
                      < 4 * np.asarray(doc["std"]["length_zero"][row]) + 1e-9)


# ---------------------------------------------------------------- diagnosis from on-board sensors alone
@pytest.fixture(scope="module")
def positions():
    return np.random.default_rng(3).uniform([-0.8, -0.6, 1.0], [0.8, 0.6, 2.0], (45, 3))


def _diagnose(robot, truth, positions):
    from fitting.diagnosis.diagnose import diagnose

    rec = onboard_recordings(truth, hanging_lengths(truth, positions), session=np.repeat([0, 1, 2], 15),
                             length_zero=np.random.default_rng(6).normal(0, 0.003, (3, 4)),
                             yaw_zero=np.array([0.1, -0.3, 0.5]), seed=5)
    return diagnose(robot, rec, progress=False, posterior_steps=0)


def test_clean_onboard_recordings_give_no_effect(robot, positions):
    d = _diagnose(robot, robot, positions)
    assert d.effects == [] and d.explained
    assert "length_offset" in d.not_applicable  # relative lengths: their zeros are calibrated, not an effect
    assert set(d.baseline["rms"]) >= {"swivel", "ahrs"} and d.baseline["rms"]["position"] is None


def test_a_concealed_load_cell_gain_is_named_without_a_tracker(robot, positions):
    truth = eqx.tree_at(lambda r: r.tension_gain, robot, np.array([1.04, 1.0, 0.97, 1.0]))
    d = _diagnose(robot, truth, positions)
    assert d.effects == ["tension_sensor_gain"] and d.explained
    gain = d.to_json()["candidates"][0]["parameters"]["gain"]
    np.testing.assert_allclose(gain["value"], [1.04, 1.0, 0.97, 1.0], atol=4 * max(gain["std"]))


@pytest.mark.slow
def test_moved_anchor_is_named_up_to_the_unseen_common_shift(robot, positions):
    """Without x y z a common shift of all anchors is invisible: the diagnosis names the
    effect and reports the offsets with zero mean (the truth's, minus their mean)."""
    moved = np.zeros((4, 3))
    moved[0] = [0.02, -0.015, 0.01]
    truth = eqx.tree_at(lambda r: r.anchors, robot, np.asarray(robot.anchors) + moved)
    d = _diagnose(robot, truth, positions)
    assert d.effects == ["anchor_offset"] and d.explained
    p = next(c for c in d.to_json()["candidates"] if c["effect"] == "anchor_offset")["parameters"]["offset"]
    np.testing.assert_allclose(p["value"], moved - moved.mean(0), atol=4 * np.max(p["std"]) + 1e-4)


def test_start_poses_are_the_nominal_cold_start_equilibria():
    """Without x y z every fit starts at ``start_poses``: the compiled cold-start program
    (its own XLA options) gives the equilibria of ``predict_cdpr(method="statics")``, a
    separately compiled path, on the bundled on-board example; a measured pose is kept."""
    from cstiffjax.core.status import Status
    from cstiffjax.examples import example_path
    from fitting.calibration.models import predict_cdpr, start_poses

    rec_path = example_path("onboard4/recordings.csv")
    robot = load_robot(example_path("onboard4/robot.toml"))
    rec = load_recordings(rec_path, robot)
    assert not np.asarray(rec.pose_mask).any()
    ref, _, res = predict_cdpr(robot, rec.l0, rec.wrench, method="statics")
    assert bool(np.all(np.asarray(res == Status.successful)))
    np.testing.assert_allclose(start_poses(robot, rec), np.asarray(ref), rtol=0, atol=1e-9)
    measured = eqx.tree_at(lambda r: r.pose_mask, rec, np.ones_like(np.asarray(rec.pose_mask)))
    np.testing.assert_array_equal(start_poses(robot, measured), np.asarray(rec.pose))


def test_check_and_fit_commands_on_the_bundled_onboard_example(tmp_path, capsys):
    from cstiffjax.commands.cli import main
    from cstiffjax.examples import example_path

    robot, rec = str(example_path("onboard4/robot.toml")), str(example_path("onboard4/recordings.csv"))
    assert main(["check", robot, rec, "--json", str(tmp_path / "c.json")]) == 0
    out = capsys.readouterr().out
    import json

    def no_nan(token):
        raise AssertionError(f"{token} is not JSON")

    doc = json.loads((tmp_path / "c.json").read_text(), parse_constant=no_nan)
    assert doc["pose_min"] == [None] * 6 and doc["sessions"] == [0, 1, 2] and "yaw" in doc["onboard_ranges"]
    assert " x: not recorded" in out and "swivel_1:" in out and "roll:" in out and "sessions: 0, 1, 2" in out
    assert "stretch" not in out  # no x y z: the lengths are judged for their units only
    mm = tmp_path / "mm.csv"
    lines = Path(rec).read_text().splitlines()
    head = lines[0].split(",")
    j = head.index("l0_2")
    mm.write_text("\n".join([lines[0]] + [",".join(f"{float(c) * 1000:g}" if k == j else c
                                                  for k, c in enumerate(row.split(","))) for row in lines[1:]]) + "\n")
    assert main(["check", robot, str(mm)]) == 1
    assert "column l0_2 (cable 2)" in capsys.readouterr().err
    assert main(["fit", robot, rec, "--free", "EA,anchors", "--quiet"]) == 0
    assert "without x y z a common shift of all anchors" in capsys.readouterr().out


# ---------------------------------------------------------------- [noise] sigmas of recorded channels only
def _without(text: str, *keys: str) -> str:
    """The robot description ``text`` without the ``[noise]`` lines of ``keys``."""
    out = text
    for k in keys:
        out, n = re.subn(rf"^{k} = .*\n", "", out, flags=re.M)
        assert n == 1, k
    return out


@pytest.fixture(scope="module")
def bundled_fits(tmp_path_factory):
    """The bundled on-board example (no x y z, rx ry rz) fitted with and without ``[noise]
    position/rotation`` (the free set of the fit command's test: the same compiled programs)."""
    from cstiffjax.examples import example_path

    path = tmp_path_factory.mktemp("sigmas") / "robot.toml"
    path.write_text(_without(example_path("onboard4/robot.toml").read_text(), "position", "rotation"))
    fits = []
    for robot in (load_robot(example_path("onboard4/robot.toml")), load_robot(path)):
        rec = load_recordings(example_path("onboard4/recordings.csv"), robot)
        # without x y z a common shift of the anchors changes no reading: both fits say so, and only that
        with warnings.catch_warnings(record=True) as heard:
            warnings.simplefilter("always")
            fits.append((robot, calibrate(robot, rec, ("EA", "anchors"))))
        assert heard and all(issubclass(w.category, IdentifiabilityWarning) for w in heard), heard
        assert any("common shift of all anchors" in str(w.message) for w in heard)
    return fits


def test_pose_sigmas_are_not_needed_without_a_pose(bundled_fits):
    """Without x y z and rx ry rz the pose sigmas change nothing: estimates, covariance and
    chi2 agree to 1e-10 with the description that states them, and the gradient of the fit's
    objective is finite (the placeholder sigma; a nan sigma behind the mask would make it nan)."""
    (_, full), (bare, part) = bundled_fits
    assert np.isnan(float(bare.noise.position)) and np.isnan(float(bare.noise.rotation))
    for k, v in full.values.items():
        np.testing.assert_allclose(part.values[k], v, rtol=1e-10, atol=1e-12, err_msg=k)
    scale = np.max(np.abs(np.asarray(full.covariance)))
    np.testing.assert_allclose(part.covariance, full.covariance, rtol=0, atol=1e-10 * scale)
    np.testing.assert_allclose(float(part.chi2), float(full.chi2), rtol=1e-10)

    @eqx.filter_jit  # one program for both sigma sets (they differ in leaves only)
    def objective(args):
        return jax.grad(lambda th: 0.5 * jnp.sum(part.residual_fn(th, args) ** 2))(part.ls.theta)

    grad = np.asarray(objective(part.args))
    assert np.all(np.isfinite(grad)) and np.max(np.abs(grad)) > 0
    assert np.all(np.isfinite(np.asarray(part.args[0].noise.position)))  # the fit's robot: the placeholder
    nan_sigmas = (eqx.tree_at(lambda r: r.noise, part.args[0], bare.noise), *part.args[1:])
    assert np.isnan(np.asarray(objective(nan_sigmas))).any()  # why: a masked nan sigma poisons the gradient


def test_a_recorded_channel_needs_its_sigma(tmp_path, capsys):
    """A recorded channel without its ``[noise]`` sigma: an error naming the recordings, the
    columns and the key, on loading, in calibrate (recordings made in memory) and on the
    command line (exit 1); a channel not recorded needs none (``check`` passes)."""
    from cstiffjax.commands.cli import main
    from cstiffjax.examples import example_path
    from cstiffjax.io.sigmas import fit_noise

    rec_path = example_path("onboard4/recordings.csv")
    text = example_path("onboard4/robot.toml").read_text()
    (tmp_path / "nopose.toml").write_text(_without(text, "position", "rotation"))
    assert main(["check", str(tmp_path / "nopose.toml"), str(rec_path)]) == 0
    (tmp_path / "notension.toml").write_text(_without(text, "tension"))
    bare = load_robot(tmp_path / "notension.toml")
    (tmp_path / "again.toml").write_text(robot_to_toml(bare))  # the writer states only the sigmas given
    assert "tension" not in robot_to_toml(bare).split("[noise]")[1].split("[")[0]
    assert np.isnan(float(load_robot(tmp_path / "again.toml").noise.tension))
    want = r"columns t_1 t_2 t_3 t_4 need noise.tension = sigma \(N\) in the \[noise\] table"
    with pytest.raises(RecordingsError, match=rf"recordings.csv: {want}"):
        load_recordings(rec_path, bare)
    rec = load_recordings(rec_path, load_robot(example_path("onboard4/robot.toml")))
    with pytest.raises(RecordingsError, match=want):
        calibrate(bare, rec, ("EA",))
    masked = eqx.tree_at(lambda r: r.tension_mask, rec, np.asarray(rec.tension_mask) & (np.arange(4) == 2))
    with pytest.raises(RecordingsError, match=r"columns t_3 need noise.tension"):  # only the column with values
        fit_noise(bare, masked)
    unrecorded = eqx.tree_at(lambda r: r.tension_mask, rec, np.zeros_like(np.asarray(rec.tension_mask)))
    assert float(fit_noise(bare, unrecorded).noise.tension) == 1.0
    for cmd in ("check", "fit"):
        assert main([cmd, str(tmp_path / "notension.toml"), str(rec_path)]) == 1
        err = capsys.readouterr().err
        assert "recordings.csv: columns t_1 t_2 t_3 t_4 need noise.tension" in err, (cmd, err)


def test_the_contracts_version3_examples_load(tmp_path):
    """The examples of formats.md §2 "Version 3" are valid: its CSV loads on the bundled 4-cable
    on-board robot, its TOML keys are accepted in that robot's description."""
    import tomllib

    from cstiffjax.examples import example_path

    text = (Path(schema.__file__).with_name("formats.md")).read_text(encoding="utf-8")
    section = text[text.index("### Version 3"):text.index("## 3. Diagnosis")]
    toml_block = section.split("```toml")[1].split("```")[0]
    csv_block = section.split("```csv")[1].split("```")[0]
    base = tomllib.loads(example_path("onboard4/robot.toml").read_text())
    extra = tomllib.loads(toml_block)
    base["noise"].update(extra["noise"])
    base["sensors"] = extra["sensors"]
    base["cables"][0].update(extra["cables"][0])
    robot = robot_from_dict(base)
    (tmp_path / "v3.csv").write_text(csv_block.lstrip("\n"))
    rec = load_recordings(tmp_path / "v3.csv", robot)
    assert rec.sessions == (0, 1) and rec.has_swivel and rec.has_ahrs and not rec.has_position
    assert rec.covariate_names == ("t_set_1",)


@pytest.mark.slow
@pytest.mark.parametrize("m", [3, 5])
def test_three_and_five_cable_onboard_robots_are_diagnosed_clean(m):
    """A 3-cable (a cable camera) and a 5-cable suspended robot with pulleys, recorded by their
    own sensors only: clean recordings give no effect."""
    import tomllib

    from fitting.diagnosis.diagnose import diagnose

    ang = 2 * np.pi * np.arange(m) / m + 0.3
    text = ROBOT + "".join(CABLE.format(ax=2.0 * np.cos(a), ay=1.6 * np.sin(a), px=0.15 * np.cos(a),
                                        py=0.12 * np.sin(a)) for a in ang)
    robot = robot_from_dict(tomllib.loads(text))
    pos = np.random.default_rng(1).uniform([-0.5, -0.4, 1.0], [0.5, 0.4, 2.0], (45, 3))
    rec = onboard_recordings(robot, hanging_lengths(robot, pos), session=np.repeat([0, 1, 2], 15),
                             length_zero=np.full((3, m), 0.002), seed=2)
    d = diagnose(robot, rec, progress=False, posterior_steps=0)
    assert d.effects == [] and d.explained and d.final["chi2_per_dof"] < 1.3
