"""Robots drawn where they hang (`check --plot`): the pose drawn, the floor and frame box,
the axes' scales, and the description's optional ``[platform] reference_pose``. Checked on
the drawn data (matplotlib artists), not pixels; the equilibrium against scipy."""


import numpy as np
import pytest
from matplotlib.figure import Figure
from mpl_toolkits.mplot3d.art3d import Poly3DCollection
from scipy.optimize import root
from scipy.spatial.transform import Rotation

from cstiffjax.commands.check import plot_pose
from cstiffjax.commands.cli import main
from cstiffjax.core.errors import RobotFileError
from cstiffjax.examples import example_path
from cstiffjax.io.robot_io import load_description, load_robot, robot_to_toml
from cstiffjax.plots.robot import draw_robot


def _hanging_pose(robot):
    """numpy + scipy: straight spring cables of the lengths at the anchors' centroid, half way
    up from z = 0 to the highest anchor; the pose where the net wrench vanishes."""
    a, b, ea = (np.asarray(v) for v in (robot.anchors, robot.attachments, robot.EA))
    guess = np.r_[a[:, :2].mean(0), 0.5 * a[:, 2].max(), 0, 0, 0]
    l0 = np.linalg.norm(a - guess[:3] - b, axis=1)
    weight = float(robot.platform_mass) * np.asarray(robot.gravity)

    def wrench(q):
        R = Rotation.from_rotvec(q[3:]).as_matrix()
        arm = b @ R.T
        v = a - q[:3] - arm
        n = np.linalg.norm(v, axis=1)
        f = (np.maximum(ea * (n - l0) / l0, 0) / n)[:, None] * v
        return np.r_[f.sum(0) + weight, np.cross(arm, f).sum(0) + np.cross(R @ np.asarray(robot.com), weight)]

    sol = root(wrench, guess - [0, 0, 0.01, 0, 0, 0], tol=1e-13)  # below the guess: every cable taut
    assert np.max(np.abs(sol.fun)) < 1e-8
    return sol.x


def _drawn(robot, pose):
    ax = Figure().add_subplot(projection="3d")
    draw_robot(ax, robot, pose)
    return ax


def _platform_z(ax) -> np.ndarray:
    (line,) = [ln for ln in ax.get_lines() if ln.get_label() == "platform"]
    return np.asarray(line.get_data_3d()[2])


@pytest.mark.parametrize("name", ["suspended3.toml", "suspended4.toml"])
def test_a_suspended_robot_is_drawn_at_its_nominal_equilibrium(name):
    robot = load_robot(example_path(name))
    pose, what = plot_pose(robot)
    assert what == "where it hangs: the nominal gravity equilibrium"
    ref = _hanging_pose(robot)
    np.testing.assert_allclose(pose[:3], ref[:3], rtol=0, atol=1e-8)
    assert pose[2] < 0.55 * float(np.max(np.asarray(robot.anchors)[:, 2]))  # below the anchors, not at their height
    ax = _drawn(robot, pose)
    z_att = np.asarray(robot.attachments)[:, 2] + pose[2]  # hangs level: every attachment at this height
    np.testing.assert_allclose(np.sort(_platform_z(ax))[[0, -1]], [z_att.min(), z_att.max()], atol=1e-8)


def _floor(ax):
    return [c for c in ax.collections if isinstance(c, Poly3DCollection) and c.get_label().startswith("floor")]


@pytest.mark.parametrize("name, pose", [("suspended4.toml", [0, 0, 1.5, 0, 0, 0]),
                                        ("onboard4/robot.toml", [0, 0, 1.5, 0, 0, 0]),
                                        ("tcpr8.toml", [0, 0, 0.83, 0, 0, 0])])
def test_the_floor_is_drawn_and_no_axis_is_stretched(name, pose):
    """The shaded floor at z = 0 under the anchors (all at z = 3 m on the suspended robots),
    the frame box from it to the highest anchor, and the three axes at one scale."""
    robot = load_robot(example_path(name))
    ax = _drawn(robot, np.asarray(pose, float))
    (floor,) = _floor(ax)
    assert floor.get_label() == "floor (z = 0 m)"
    assert ax.get_zlim()[0] <= 0.0 and ax.get_zlim()[1] >= float(np.max(np.asarray(robot.anchors)[:, 2]))
    spans = np.array([np.ptp(ax.get_xlim()), np.ptp(ax.get_ylim()), np.ptp(ax.get_zlim())])
    box = np.asarray(ax.get_box_aspect(), float)
    np.testing.assert_allclose(box / box[0], spans / spans[0], rtol=1e-9)
    assert all("scale" not in label for label in (ax.get_xlabel(), ax.get_ylabel(), ax.get_zlabel()))


def test_a_flat_drawing_is_opened_only_to_a_twentieth():
    """Points in a plane (no floor to give the view height): the flat axis is opened to 5 % of
    the longest, and says so in its label; an axis of 30 % of the longest is left alone."""
    from cstiffjax.plots.scene import equal_aspect

    ax = Figure().add_subplot(projection="3d")
    pts = np.array([[0, 0, 0], [4, 0, 0], [4, 3, 0.01], [0, 3, 0]], float)
    ax.set(xlim=(0, 4), ylim=(0, 3), zlim=(0, 0.01))  # nothing else drawn
    stretched = equal_aspect(ax, pts)
    box = np.asarray(ax.get_box_aspect(), float)
    np.testing.assert_allclose(box / box[0], [1, 0.75, 0.05], rtol=1e-9)
    assert set(stretched) == {"z"} and stretched["z"] > 1
    ax = Figure().add_subplot(projection="3d")
    ax.set(xlim=(0, 4), ylim=(0, 3), zlim=(0, 1.2))
    assert equal_aspect(ax, pts * [1, 1, 120]) == {}


def test_reference_pose_round_trips_and_is_drawn(tmp_path):
    robot = load_robot(example_path("suspended4.toml"))
    stated = np.array([0.1, -0.2, 1.2, 0.0, 0.05, 0.3])
    path = tmp_path / "r.toml"
    path.write_text(robot_to_toml(robot, stated))
    again, pose = load_description(path)
    np.testing.assert_array_equal(pose, stated)
    assert robot_to_toml(again) == robot_to_toml(robot)  # the pose is beside the robot, not in it
    assert load_description(example_path("suspended4.toml"))[1] is None
    np.testing.assert_array_equal(plot_pose(again, stated=pose)[0], stated)
    np.testing.assert_array_equal(plot_pose(again, stated=pose, given=[0, 0, 1, 0, 0, 0])[0], [0, 0, 1, 0, 0, 0])


@pytest.mark.parametrize("value, message", [
    ("[0.0, 0.0, 1.5]", "expected shape (6,)"),
    ("[0.0, 0.0, 1.5, 0.0, 90.0, 0.0]", "rotation vector [rx, ry, rz] is 90 rad long"),
    ('[0.0, 0.0, 1.5, 0.0, "a", 0.0]', "expected numbers of shape (6,)"),
])
def test_a_bad_reference_pose_names_the_key_line_and_value(tmp_path, value, message):
    text = example_path("suspended4.toml").read_text()
    text = text.replace("mass = 12.99", f"mass = 12.99\nreference_pose = {value}")
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(RobotFileError, match=r"platform\.reference_pose' \(line 18\)") as e:
        load_robot(path)
    assert message in str(e.value)


def test_csjm_refuses_a_reference_pose(tmp_path):
    text = example_path("csjm.toml").read_text()
    text = text.replace("[platform]\n", "[platform]\nreference_pose = [0, 0, 0, 0, 0, 0]\n", 1)
    path = tmp_path / "c.toml"
    path.write_text(text)
    with pytest.raises(RobotFileError, match="kind = 'cdpr' only"):
        load_robot(path)


def test_convert_writes_caspr_q_initial_as_the_reference_pose(tmp_path, capsys):
    from tests.test_caspr import body, cogiro_cables, write

    b, c = write(tmp_path, body(), cogiro_cables())
    out = tmp_path / "cogiro.toml"
    assert main(["convert", str(b), str(c), "--ea", "2e5", "--out", str(out)]) == 0
    robot, pose = load_description(out)
    np.testing.assert_array_equal(pose, [0, 0, 2, 0, 0, 0])
    drawn, what = plot_pose(robot, stated=pose)
    assert what == "the description's reference_pose"
    ax = _drawn(robot, drawn)
    z = _platform_z(ax)  # CoGiRo's attachments at 0 and ~1 m above its reference point at z = 2
    assert z.min() == pytest.approx(2.0 - 0.0007) and z.max() == pytest.approx(2.9996)
    assert _floor(ax) and ax.get_zlim()[0] <= 0.0


def test_check_pose_needs_plot(capsys):
    assert main(["check", "suspended4.toml", "--pose", "0", "0", "1.5", "0", "0", "0"]) == 1
    assert "--pose: the pose --plot draws; give --plot PNG too" in capsys.readouterr().err
