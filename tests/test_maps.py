"""The x-y maps of `sag --map` and `frf --sweep` cover a region around --pose, or --region."""

import json

import numpy as np
import pytest

from cstiffjax.commands.cli import main
from cstiffjax.commands.common import MAP_HALF_WIDTH, region_axes


def test_region_axes_centred_on_the_pose_or_as_given():
    x, y = region_axes(None, [0.3, -0.2, 0.5, 0, 0, 0], 5, "--grid")
    np.testing.assert_allclose(x, 0.3 + np.linspace(-MAP_HALF_WIDTH, MAP_HALF_WIDTH, 5), atol=1e-15)
    np.testing.assert_allclose(y, -0.2 + np.linspace(-MAP_HALF_WIDTH, MAP_HALF_WIDTH, 5), atol=1e-15)
    x, y = region_axes((-1.0, 0.0, 0.1, 0.3), [0.3, -0.2, 0.5, 0, 0, 0], 3, "--grid")
    np.testing.assert_allclose(x, [-1.0, -0.5, 0.0]) and np.testing.assert_allclose(y, [0.1, 0.2, 0.3])
    with pytest.raises(ValueError, match=r"--region 1 0 0 1: need XMIN < XMAX"):
        region_axes((1.0, 0.0, 0.0, 1.0), [0] * 6, 3, "--grid")
    with pytest.raises(ValueError, match="--sweep: 1 points per axis; a map needs at least 2"):
        region_axes(None, [0] * 6, 1, "--sweep")


@pytest.mark.slow  # the sagging statics of the map compile (~1-2 min)
def test_sag_map_is_centred_on_the_pose(tmp_path):
    pose = ["0.2", "-0.1", "0.5", "0", "0", "0"]
    assert main(["sag", "prototype_4mm.toml", "--pose", *pose, "--map", "--grid", "2", "--quiet",
                 "--out", str(tmp_path / "a")]) == 0
    m = json.loads((tmp_path / "a" / "sag.json").read_text())["map"]
    np.testing.assert_allclose(m["x"], [-0.3, 0.7], atol=1e-12)  # the pose's x and y +- 0.5 m
    np.testing.assert_allclose(m["y"], [-0.6, 0.4], atol=1e-12)
    assert np.asarray(m["z_catenary"]).shape == (2, 2)
    assert main(["sag", "prototype_4mm.toml", "--pose", *pose, "--map", "--grid", "2", "--quiet",
                 "--region", "-0.1", "0.1", "0.0", "0.2", "--out", str(tmp_path / "b")]) == 0
    m = json.loads((tmp_path / "b" / "sag.json").read_text())["map"]
    np.testing.assert_allclose(m["x"], [-0.1, 0.1]) and np.testing.assert_allclose(m["y"], [0.0, 0.2])
    assert np.asarray(m["z_catenary"]).shape == (2, 2)


@pytest.mark.slow  # the dynamic stiffness model compiles (~1-2 min)
def test_frf_sweep_is_centred_on_the_pose(tmp_path):
    assert main(["frf", "prototype_8mm.toml", "--pose", "0.3", "0.1", "0.5", "0", "0", "0", "--fmax", "5", "--n",
                 "20", "--sweep", "3", "--quiet", "--out", str(tmp_path)]) == 0
    s = json.loads((tmp_path / "frf.json").read_text())["sweep"]
    np.testing.assert_allclose(s["x"], [-0.2, 0.3, 0.8], atol=1e-12)
    np.testing.assert_allclose(s["y"], [-0.4, 0.1, 0.6], atol=1e-12)
    assert np.asarray(s["first_frequency_hz"]).shape == (3, 3)
