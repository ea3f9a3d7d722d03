"""The recordings schema (cstiffjax.io.schema) against the contract text, the writer and the loader.

The contract's table (formats.md §2, the package copy) is parsed here independently and
compared with the schema's groups; files written from the schema's columns in any order,
with any covariate names, load back to the values written (rounded by ``%.12g``, a check
independent of the loader) with the contract's defaults for the columns left out.
"""

import dataclasses
import math
import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cstiffjax import RecordingsError, load_recordings, load_robot
from cstiffjax.examples import example_path
from cstiffjax.io import schema
from cstiffjax.io.column_names import meant
from cstiffjax.io.recordings import Recordings, write_recordings

FORMATS = Path(schema.__file__).with_name("formats.md")
ROBOTS = {name: load_robot(example_path(name)) for name in ("prototype_8mm.toml", "tcpr8.toml", "csjm.toml")}


# ------------------------------------------------------------------ the contract's table
def _contract_rows():
    """``[(names cell, required cell, meaning cell)]`` of the §2 column table."""
    text = FORMATS.read_text(encoding="utf-8")
    section = text[text.index("## 2. Recordings"):text.index("## 3. Diagnosis")]
    rows = [line for line in section.splitlines() if line.startswith("| ")][1:]  # the header row left out
    return [tuple(c.strip() for c in row.strip("|").split("|")) for row in rows]


def _names(cell: str) -> tuple[str, ...]:
    """``l0_1 … l0_m`` -> ``("l0_{i}",)``; ``fx fy fz`` -> the three names."""
    cell = cell.replace("`", "")
    if mt := re.fullmatch(r"(\w+)_1 … \1_m", cell):
        return (f"{mt.group(1)}_{{i}}",)
    return tuple(cell.split())


def _required(cell: str) -> tuple[tuple[str, ...], float | None]:
    """(kinds that must have the column, value when absent if the cell states one)."""
    if cell == "yes":
        return ("cdpr", "csjm"), None
    if mt := re.fullmatch(r"(cdpr|csjm): yes", cell):
        return (mt.group(1),), None
    if mt := re.fullmatch(r"no \(([0-9.]+)\)", cell):
        return (), float(mt.group(1))
    assert cell == "no", cell
    return (), None


def test_groups_are_the_contract_table_in_order():
    rows = _contract_rows()
    assert rows[-1][0] == "anything else"  # the covariates
    assert len(rows) - 1 == len(schema.GROUPS)
    for (names, required, meaning), g in zip(rows[:-1], schema.GROUPS, strict=True):
        assert _names(names) == g.names, g.key
        kinds, absent = _required(required)
        assert g.required == kinds, g.key
        if absent is not None:
            assert g.absent == absent, g.key
        parts = meaning.split(", ")
        if g.unit in parts:  # "..., base frame, m": the unit is one of the comma-separated parts
            parts.remove(g.unit)
            assert ", ".join(parts) == g.meaning, g.key
        elif not g.unit:  # a dimensionless id (session)
            assert meaning == g.meaning, g.key
        else:  # "s since the start of the session"
            assert meaning.startswith(g.unit + " ") and meaning == g.meaning, g.key


def test_contract_version_is_the_documents():
    first = FORMATS.read_text(encoding="utf-8").splitlines()[0]
    assert f"(version {schema.CONTRACT_VERSION})" in first


def test_per_cable_optional_and_used_rules():
    assert schema.column_names(2) == ("session", "time", "l0_1", "l0_2", "fx", "fy", "fz", "mx", "my", "mz", "x", "y",
                                      "z", "rx", "ry", "rz", "t_1", "t_2", "tx", "ty", "tz", "swivel_1", "swivel_2",
                                      "roll", "pitch", "yaw")
    # version 3: a CDPR's pose columns are optional (on-board sensors), a CSJM still measures its rotation
    assert schema.required_columns("cdpr", 2) == ("l0_1", "l0_2")
    assert schema.required_columns("csjm", 2) == ("rx", "ry", "rz", "tx", "ty", "tz")
    assert schema.field_columns("wrench", 3) == ("fx", "fy", "fz", "mx", "my", "mz")
    assert schema.field_columns("tensions", 3) == ("t_1", "t_2", "t_3")
    assert schema.cable_prefixes() == ("l0", "t", "swivel") and schema.cable_column("l0", "i") == "l0_i"
    assert schema.find("t_3", 6) is schema.group("tension")
    for name, m in (("t_7", 6), ("t_0", 6), ("t_03", 6), ("T_1", 6), ("temperature", 6), ("l0_", 6)):
        assert schema.find(name, m) is None, name
    assert [schema.unit(c) for c in ("l0_4", "fz", "mx", "rz", "t_2", "time", "tz", "humidity")] == \
        ["m", "N", "N·m", "rad", "N", "s", "N·m", ""]
    assert math.isnan(schema.group("tension").absent) and schema.group("tension").empty_ok
    assert [g.since for g in schema.GROUPS if g.since > 1] == [3, 3, 3]  # session, swivel, ahrs
    with pytest.raises(KeyError, match="no column group"):
        schema.group("swivels")
    with pytest.raises(KeyError, match="no per-cable column"):
        schema.cable_column("x", 1)


# ------------------------------------------------------------------ writer
def test_to_columns_is_the_schema_order_then_covariates():
    n, m = 4, 3
    cols = schema.to_columns(m, {"pose": np.zeros((n, 6)), "time": np.arange(n), "tensions": np.ones((n, m)),
                                 "l0": np.ones((n, m))}, {"humidity": np.zeros(n), "a b": np.zeros(n)})
    groups = [schema.group(k) for k in ("time", "l0", "position", "rotation", "tension")]
    assert list(cols) == [*schema.column_names(m, groups), "humidity", "a b"]
    with pytest.raises(ValueError, match="covariate 'fz' is a contract column"):
        schema.to_columns(m, {}, {"fz": np.zeros(n)})
    with pytest.raises(ValueError, match=r"pose: 5 columns, the schema has 6"):
        schema.to_columns(m, {"pose": np.zeros((n, 5))})
    with pytest.raises(KeyError, match="unknown recordings field"):
        schema.to_columns(m, {"poses": np.zeros((n, 6))})


@pytest.mark.parametrize("name", ["concealed/recordings.csv", "example01/recordings.csv",
                                  "example02/recordings.csv", "pulleys8/recordings.csv"])
def test_bundled_cdpr_files_have_the_writers_header(name):
    """The generated examples' headers are the schema's columns in table order, then covariates
    (they have the columns of contract version 2: a laser tracker, no on-board sensors)."""
    header = example_path(name).read_text().splitlines()[0].split(",")
    m = sum(h.startswith("l0_") for h in header)
    used = [g for g in schema.GROUPS if g.key != "joint_moment" and g.since <= 2]
    assert header == [*schema.column_names(m, used), "temperature"]


def test_written_header_is_the_columns(tmp_path):
    cols = schema.to_columns(2, {"time": [0.5, 1.0], "tensions": [[1.0, math.nan], [3.0, 4.0]]}, {"hum": [1, 2]})
    write_recordings(cols, tmp_path / "r.csv")
    assert (tmp_path / "r.csv").read_text() == "time,t_1,t_2,hum\n0.5,1,,1\n1,3,4,2\n"
    for bad in ("", " x", "a,b", 'q"', "a\nb"):
        with pytest.raises(ValueError, match="cannot be written"):
            write_recordings({bad: [1.0]}, tmp_path / "bad.csv")
    with pytest.raises(ValueError, match="column 'x' has shape .3,., column 'time' .2,."):
        write_recordings({"time": [1.0, 2.0], "x": [1.0, 2.0, 3.0]}, tmp_path / "bad.csv")


# ------------------------------------------------------------------ round trip
CONTRACT_LIKE = {re.sub(r"[^a-z0-9]", "", n) for n in schema.fixed_names()}


def _covariate_ok(name: str) -> bool:
    """Not a contract name nor a near-miss of one (the loader's rules: case and separators
    written out here; misspellings and long forms by :func:`cstiffjax.io.column_names.meant`)."""
    canon = re.sub(r"[^a-z0-9]", "", name.lower())
    return canon not in CONTRACT_LIKE and not re.fullmatch(r"(l0|t)[ _.\-]*[0-9]+", name, re.IGNORECASE) \
        and meant(name, 99) is None


COVARIATE = st.from_regex(r"[A-Za-z][A-Za-z0-9_ ]{0,10}[A-Za-z0-9]", fullmatch=True).filter(_covariate_ok)
VALUE = st.floats(-1e6, 1e6, allow_nan=False, allow_subnormal=False)


def _written(v: float) -> float:
    return float(f"{v:.12g}")


@settings(max_examples=60, deadline=None, database=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_any_column_order_and_covariates_round_trip(tmp_path, data):
    robot = ROBOTS[data.draw(st.sampled_from(sorted(ROBOTS)), label="robot")]
    m, kind, n = robot.num_cables, robot.kind, data.draw(st.integers(1, 5), label="n")
    # swivel and AHRS columns need a robot that states their zero and sigmas: tests/test_onboard_recordings.py
    optional = [g for g in schema.GROUPS if kind not in g.required and g.key not in ("swivel", "ahrs")]
    present = [g for g in schema.GROUPS if kind in g.required or g in data.draw(st.sets(st.sampled_from(optional)))]
    if kind == "cdpr" and not {g.key for g in present} & set(schema.POSE_CHANNELS):
        present.append(schema.group("tension"))  # a CDPR's file needs a channel that constrains the pose
    covs = data.draw(st.lists(COVARIATE, max_size=3, unique=True), label="covariates")
    values = {}
    for g in present:
        for c in g.columns(m):
            lo = 0.1 if g.positive else -1e6
            hi = 6.0 if g.key == "rotation" else 1e6  # a rotation-vector component beyond 2 pi means degrees
            number = st.integers(-1000, 1000).map(float) if g.integer else \
                st.floats(max(lo, -hi), hi, allow_nan=False, allow_subnormal=False)
            v = data.draw(st.lists(number, min_size=n, max_size=n), label=c)
            if g.empty_ok:  # a tension not recorded: an empty cell
                v = [x if keep else math.nan for x, keep in zip(v, data.draw(st.lists(st.booleans(), min_size=n,
                                                                                            max_size=n)), strict=True)]
            values[c] = np.array(v)
    for c in covs:
        values[c] = np.array(data.draw(st.lists(VALUE, min_size=n, max_size=n), label=c))
    order = data.draw(st.permutations(list(values)), label="order")
    path = tmp_path / "r.csv"
    write_recordings({c: values[c] for c in order}, path)
    rec = load_recordings(path, robot)

    def expect(names, absent):
        return np.stack([np.vectorize(_written)(values[c]) if c in values else np.full(n, absent) for c in names], 1)

    assert rec.covariate_names == tuple(c for c in order if c in covs)
    assert rec.rows == tuple(range(2, n + 2)) and rec.num_samples == n
    np.testing.assert_array_equal(rec.covariates, expect(rec.covariate_names, None) if covs else np.zeros((n, 0)))
    np.testing.assert_array_equal(rec.time, expect(["time"], math.nan)[:, 0])
    np.testing.assert_array_equal(rec.wrench, expect(["fx", "fy", "fz", "mx", "my", "mz"], 0.0))
    np.testing.assert_array_equal(rec.moment, expect(["tx", "ty", "tz"], 0.0))
    tens = expect([f"t_{i}" for i in range(1, m + 1)], math.nan)
    np.testing.assert_array_equal(rec.tension_mask, ~np.isnan(tens))
    np.testing.assert_array_equal(rec.tensions, np.nan_to_num(tens, nan=0.0))
    pose = expect(["x", "y", "z", "rx", "ry", "rz"], math.nan)  # version 3: not measured when absent
    if kind == "csjm":  # a CSJM's pose is a rotation only; it has no commanded lengths
        pose[:, :3] = 0.0
    np.testing.assert_array_equal(rec.pose_mask, ~np.isnan(pose))
    np.testing.assert_array_equal(rec.pose, np.nan_to_num(pose, nan=0.0))
    np.testing.assert_array_equal(rec.session, expect(["session"], 0.0)[:, 0])
    l0 = expect([f"l0_{i}" for i in range(1, m + 1)], 0.0) if kind == "cdpr" else np.zeros((n, m))
    np.testing.assert_array_equal(rec.l0, l0)


# ------------------------------------------------------------------ one place
def test_required_columns_come_from_the_schema_alone(tmp_path, monkeypatch):
    """Making a CSJM's ``rx ry rz`` optional in the schema is all the loader needs to accept a
    file without them (as version 3 did for a CDPR's ``x y z``)."""
    robot = ROBOTS["csjm.toml"]
    cols = schema.to_columns(robot.num_cables, {"pose": np.zeros((2, 6)), "moment": np.zeros((2, 3))})
    write_recordings({c: v for c, v in cols.items() if c not in ("rx", "ry", "rz")}, tmp_path / "r.csv")
    with pytest.raises(RecordingsError, match="required column.s. missing for a csjm with .* cables: rx, ry, rz"):
        load_recordings(tmp_path / "r.csv", robot)
    groups = tuple(dataclasses.replace(g, required=()) if g.key == "rotation" else g for g in schema.GROUPS)
    monkeypatch.setattr(schema, "GROUPS", groups)
    assert load_recordings(tmp_path / "r.csv", robot).num_samples == 2


def test_rows_must_match_the_samples():
    n, m = 2, 1
    kw = dict(l0=np.ones((n, m)), wrench=np.zeros((n, 6)), pose=np.zeros((n, 6)), tensions=np.zeros((n, m)),
              tension_mask=np.zeros((n, m), bool), moment=np.zeros((n, 3)), time=np.zeros(n),
              covariates=np.zeros((n, 0)))
    assert Recordings(**kw, rows=(2, 4)).select(np.array([False, True])).rows == (4,)
    assert Recordings(**kw).select(np.array([1])).rows == ()
    with pytest.raises(ValueError, match="rows has 3 line numbers for 2 samples"):
        Recordings(**kw, rows=(2, 3, 4))


def test_a_per_cable_index_must_be_ascii_digits():
    """'t_²' (a superscript two, which str.isdigit accepts) is a covariate name, not cable 2:
    the loader then refuses or keeps it as a covariate, never crashes."""
    from cstiffjax.io import schema

    assert schema.find("t_²") is None and schema.find("t_٣") is None and schema.find("t_2") is not None
