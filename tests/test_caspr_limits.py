"""Size limits of the CASPR reader (:data:`cstiffjax.io.caspr.MAX_FILE_BYTES`,
:data:`cstiffjax.io.caspr.MAX_CABLES`), checked at its entry on small hand-made files with
the limits monkeypatched down (the real limits are tens of MiB and tens of thousands of
cables, measured in ``benchmarks/LIMITS.md``), and the robot writer that a large converted
model goes through (:func:`cstiffjax.io.robot_io.robot_to_toml`, one numpy conversion per
field), compared with a TOML text typed by hand."""

import tomllib
import xml.parsers.expat

import numpy as np
import pytest

from benchmarks.limits_scale import caspr_files
from cstiffjax.commands.cli import main
from cstiffjax.io import caspr
from cstiffjax.io.caspr import CasprModelError, read_caspr
from cstiffjax.io.robot import CableRobot, Noise
from cstiffjax.io.robot_io import robot_to_toml
from tests.test_caspr import COGIRO_CABLES, body, cable, cables_file, cogiro_cables, write


def test_a_file_over_the_size_limit_is_refused_before_it_is_parsed(tmp_path, monkeypatch):
    b, c = write(tmp_path, body(), cogiro_cables())
    size = c.stat().st_size
    assert b.stat().st_size < size
    monkeypatch.setattr(caspr, "MAX_FILE_BYTES", size - 1)
    parsers = []
    create = xml.parsers.expat.ParserCreate

    def counted(*args, **kw):
        parsers.append(1)
        return create(*args, **kw)

    monkeypatch.setattr(xml.parsers.expat, "ParserCreate", counted)
    with pytest.raises(CasprModelError) as e:
        read_caspr(b, c, ea=2e5)
    assert parsers == [1]  # the bodies file only
    msg = str(e.value)
    assert msg.startswith(f"{c}: CASPR cables file of {size} bytes")
    assert f"limit of {size - 1} bytes" in msg and "MAX_FILE_BYTES" in msg


def test_a_file_at_the_size_limit_is_read(tmp_path, monkeypatch):
    b, c = write(tmp_path, body(), cogiro_cables())
    monkeypatch.setattr(caspr, "MAX_FILE_BYTES", max(b.stat().st_size, c.stat().st_size))
    assert read_caspr(b, c, ea=2e5).robot.num_cables == 8


def test_the_bodies_file_has_the_size_limit_too(tmp_path, monkeypatch):
    b, c = write(tmp_path, body() + "<!-- " + "x" * 5000 + " -->\n", cogiro_cables())
    assert c.stat().st_size < b.stat().st_size
    monkeypatch.setattr(caspr, "MAX_FILE_BYTES", b.stat().st_size - 1)
    with pytest.raises(CasprModelError, match=rf"^{b}: CASPR bodies file of {b.stat().st_size} bytes"):
        read_caspr(b, c, ea=2e5)


def _sets(sizes):
    """Cable sets ``s0, s1, ...`` of the given sizes (CoGiRo's cables, repeated)."""
    return [(f"s{k}", [cable(f"c{i}", *COGIRO_CABLES[i % 8]) for i in range(n)]) for k, n in enumerate(sizes)]


def test_cables_beyond_the_count_limit_are_refused_at_the_first_one(tmp_path, monkeypatch):
    monkeypatch.setattr(caspr, "MAX_CABLES", 10)
    b, c = write(tmp_path, body(), cables_file(_sets([6, 6])))  # 12 cables in all: the limit counts every set
    lines = c.read_text().splitlines()
    eleventh = [i for i, s in enumerate(lines, 1) if s.strip().startswith("<cable_ideal")][10]
    with pytest.raises(CasprModelError) as e:
        read_caspr(b, c, ea=2e5, cable_set="s0")
    assert str(e.value).startswith(f"{c}: line {eleventh}: <cable_ideal>: more than 10 cables in the file")
    assert "MAX_CABLES" in str(e.value)


def test_cables_at_the_count_limit_are_read(tmp_path, monkeypatch):
    monkeypatch.setattr(caspr, "MAX_CABLES", 12)
    b, c = write(tmp_path, body(), cables_file(_sets([6, 6])))
    model = read_caspr(b, c, ea=2e5, cable_set="s1")
    assert model.robot.num_cables == 6 and model.cable_sets == ("s0", "s1")


def test_convert_says_the_limit_and_exits_1(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(caspr, "MAX_CABLES", 7)
    b, c = write(tmp_path, body(), cogiro_cables())
    out = tmp_path / "robot.toml"
    assert main(["convert", str(b), str(c), "--ea", "2e5", "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert "error:" in err and "more than 7 cables" in err and c.name in err
    assert not out.exists()


def test_robot_to_toml_writes_each_cable_from_its_arrays():
    robot = CableRobot(anchors=np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.5]]),
                       attachments=np.array([[0.1, 0.0, 0.0], [0.0, -0.2, 0.0]]), EA=np.array([1e5, 2e5]),
                       mass_per_length=np.array([0.0, 0.01]), platform_mass=2.0, com=np.zeros(3),
                       inertia=np.eye(3), gravity=np.array([0.0, 0.0, -9.81]), noise=Noise(1e-4, 1e-3, 1.0),
                       pulley_radius=np.array([0.0, 0.03]), pulley_axis=np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 1.0]]),
                       length_gain=np.array([1.0, 1.01]), tension_gain=np.array([0.98, 1.0]),
                       swivel_zero=np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]), name="two")
    cables = tomllib.loads(robot_to_toml(robot))["cables"]
    assert cables == [
        {"anchor": [1.0, 2.0, 3.0], "attachment": [0.1, 0.0, 0.0], "EA": 1e5, "mass_per_length": 0.0,
         "tension_gain": 0.98},
        {"anchor": [4.0, 5.0, 6.5], "attachment": [0.0, -0.2, 0.0], "EA": 2e5, "mass_per_length": 0.01,
         "pulley_radius": 0.03, "pulley_axis": [0.0, 0.0, 1.0], "length_gain": 1.01, "swivel_zero": [1.0, 0.0, 0.0]}]


def test_the_benchmarks_generated_cables_file_reads_back(tmp_path):
    model = read_caspr(*caspr_files(8, tmp_path), ea=1e6)
    th = 2 * np.pi * np.arange(8) / 8
    np.testing.assert_allclose(np.asarray(model.robot.anchors),
                               np.stack([7 * np.cos(th), 5 * np.sin(th), np.full(8, 5.4)], 1), atol=1e-6)
    assert model.cable_set == "big" and model.robot.num_cables == 8
