"""Property tests: randomly damaged copies of the bundled examples either load into a valid
object or raise the project's own error naming the file, never another exception.

No JAX compilation happens here: the loaders only convert arrays.
"""

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from cstiffjax import RecordingsError, RobotFileError, load_recordings, load_robot, save_robot
from cstiffjax.examples import example_path
from cstiffjax.io.recordings import Recordings
from cstiffjax.io.robot import CableRobot, SphericalJointModule

SETTINGS = settings(max_examples=40, deadline=None, database=None,
                    suppress_health_check=[HealthCheck.too_slow])

ROBOTS = {name: example_path(name).read_text(encoding="utf-8")
          for name in ("example01/robot.toml", "tcpr8.toml", "csjm.toml")}
# recordings: the header and 8 data rows keep each example small
RECORDINGS = {
    name: (load_robot(example_path(robot)), "".join(example_path(name).read_text().splitlines(True)[:9]))
    for name, robot in (("example02/recordings.csv", "example02/robot.toml"),
                        ("csjm_recordings.csv", "csjm.toml"))
}
TOKENS = [",", ";", "\t", '"', "'", "\ufeff", "\n", "\r", "\r\n", "\x00", " ", "_", "e", "-", ".", "#",
          "=", "[", "]", "{", "}", "true", "nan", "inf", "1e999", "0x1p3", "1_0", "9" * 400, "9" * 5000]
CHARS = st.characters(exclude_categories=("Cs",))


@st.composite
def _mutation(draw, text: str) -> str:
    """One random damage to ``text``: a character flipped, deleted, duplicated or inserted,
    a token inserted, a line truncated or two cells/lines swapped."""
    n = len(text)
    i = draw(st.integers(0, max(n - 1, 0)))
    kind = draw(st.sampled_from(["flip", "delete", "duplicate", "insert", "token", "truncate", "swap_cells",
                                 "swap_lines", "bom"]))
    if kind == "flip" and n:
        return text[:i] + chr(ord(text[i]) ^ (1 << draw(st.integers(0, 7)))) + text[i + 1:]
    if kind == "delete":
        return text[:i] + text[i + 1:]
    if kind == "duplicate":
        return text[:i] + text[i:i + 1] * draw(st.integers(2, 5)) + text[i + 1:]
    if kind == "insert":
        return text[:i] + draw(st.text(CHARS, min_size=1, max_size=3)) + text[i:]
    if kind == "token":
        return text[:i] + draw(st.sampled_from(TOKENS)) + text[i:]
    if kind == "bom":
        return "\ufeff" + text
    lines = text.split("\n")
    k = draw(st.integers(0, len(lines) - 1))
    if kind == "truncate":
        lines[k] = lines[k][:draw(st.integers(0, len(lines[k])))]
    elif kind == "swap_cells":
        cells = lines[k].split(",")
        a, b = draw(st.integers(0, len(cells) - 1)), draw(st.integers(0, len(cells) - 1))
        cells[a], cells[b] = cells[b], cells[a]
        lines[k] = ",".join(cells)
    else:
        j = draw(st.integers(0, len(lines) - 1))
        lines[k], lines[j] = lines[j], lines[k]
    return "\n".join(lines)


@st.composite
def _damaged(draw, text: str) -> bytes:
    for _ in range(draw(st.integers(1, 3))):
        text = draw(_mutation(text))
    data = text.encode("utf-8")
    if draw(st.booleans()) and data:  # a raw byte flip may break the UTF-8 encoding
        i = draw(st.integers(0, len(data) - 1))
        data = data[:i] + bytes([data[i] ^ (1 << draw(st.integers(0, 7)))]) + data[i + 1:]
    return data


@pytest.fixture(scope="module")
def tmp(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("damaged")


def _write(tmp: Path, data: bytes, suffix: str) -> Path:
    p = tmp / f"damaged{suffix}"
    p.write_bytes(data)
    return p


def _assert_valid_robot(robot):
    assert isinstance(robot, CableRobot | SphericalJointModule)
    for f in ("anchors", "attachments", "EA", "mass_per_length", "com", "gravity"):
        assert np.all(np.isfinite(np.asarray(getattr(robot, f)))), f
    assert np.all(np.asarray(robot.EA) > 0) and float(robot.platform_mass) > 0
    assert isinstance(robot.name, str) and robot.name


@pytest.mark.parametrize("name", sorted(ROBOTS))
@SETTINGS
@given(data=st.data())
def test_damaged_robot_files(tmp, name, data):
    path = _write(tmp, data.draw(_damaged(ROBOTS[name])), ".toml")
    try:
        robot = load_robot(path)
    except RobotFileError as e:
        assert str(path) in str(e)
        event("RobotFileError")
        return
    event("loaded")
    _assert_valid_robot(robot)
    save_robot(robot, tmp / "again.toml")  # whatever loads must also save and load back equal
    again = load_robot(tmp / "again.toml")
    assert again.name == robot.name and type(again) is type(robot)
    np.testing.assert_array_equal(again.anchors, robot.anchors)


@pytest.mark.parametrize("name", sorted(RECORDINGS))
@SETTINGS
@given(data=st.data(), drop=st.booleans())
def test_damaged_recordings(tmp, name, data, drop):
    robot, text = RECORDINGS[name]
    path = _write(tmp, data.draw(_damaged(text)), ".csv")
    try:
        rec = load_recordings(path, robot, drop_invalid=drop)
    except RecordingsError as e:
        assert str(path) in str(e)
        event("RecordingsError")
        return
    event("loaded, some rows dropped" if rec.dropped_rows else "loaded")
    assert isinstance(rec, Recordings) and 1 <= rec.num_samples <= 8 + 3
    assert rec.num_cables == robot.num_cables
    for f in ("l0", "wrench", "pose", "tensions", "moment", "covariates"):
        assert np.all(np.isfinite(np.asarray(getattr(rec, f)))), f
    if robot.kind == "cdpr":
        assert np.all(np.asarray(rec.l0) > 0)
    assert len(rec.dropped_rows) == len(rec.drop_reasons) and (drop or not rec.dropped_rows)
    assert all(line >= 2 for line in rec.dropped_rows)


@settings(SETTINGS, max_examples=25)
@given(name=st.text(st.characters(exclude_categories=("Cs",)), min_size=1, max_size=30))
def test_any_robot_name_round_trips(tmp, name):
    robot = dataclasses.replace(load_robot(example_path("csjm.toml")), name=name)
    save_robot(robot, tmp / "named.toml")
    assert load_robot(tmp / "named.toml").name == name
