import csv

import numpy as np
import pytest

from cstiffjax import RecordingsError, load_recordings, load_robot
from cstiffjax.examples import example_path

ROBOT = load_robot(example_path("example02/robot.toml"))
CSV = example_path("example02/recordings.csv")


def _rows():
    with CSV.open() as fh:
        return list(csv.reader(fh))


def _write(tmp_path, rows):
    p = tmp_path / "rec.csv"
    with p.open("w", newline="") as fh:
        csv.writer(fh).writerows(rows)
    return p


def test_load_example():
    rec = load_recordings(CSV, ROBOT)
    assert rec.num_samples == 90 and rec.num_cables == 6
    assert rec.covariate_names == ("temperature",)
    assert rec.has_tensions and bool(np.all(rec.tension_mask))
    first = _rows()[1]
    np.testing.assert_allclose(rec.l0[0, 0], float(first[1]))
    np.testing.assert_allclose(rec.pose[0, 3], float(first[16]))


def test_column_order_is_free(tmp_path):
    rows = _rows()
    perm = np.random.default_rng(0).permutation(len(rows[0]))
    shuffled = [[r[j] for j in perm] for r in rows]
    a = load_recordings(CSV, ROBOT)
    b = load_recordings(_write(tmp_path, shuffled), ROBOT)
    for f in ("l0", "wrench", "pose", "tensions", "time", "covariates"):
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f))


def test_optional_columns_default_and_covariates_kept(tmp_path):
    rows = _rows()
    keep = [j for j, h in enumerate(rows[0]) if h not in ("fx", "fy", "fz", "mx", "my", "mz", "time", "t_3")]
    rows = [[r[j] for j in keep] for r in rows]
    rows[0].append("humidity")
    for r in rows[1:]:
        r.append("0.4")
    rec = load_recordings(_write(tmp_path, rows), ROBOT)
    np.testing.assert_array_equal(rec.wrench, 0.0)
    assert np.all(np.isnan(rec.time))
    assert rec.covariate_names == ("temperature", "humidity")
    np.testing.assert_allclose(rec.covariate("humidity"), 0.4)
    assert not bool(np.any(rec.tension_mask[:, 2])) and bool(np.all(rec.tension_mask[:, 0]))
    with pytest.raises(KeyError, match="available"):
        rec.covariate("pressure")


@pytest.mark.parametrize(
    ("row", "col", "value", "match"),
    [
        (3, "l0_2", "", r"row 3, column 'l0_2': value is missing"),
        (5, "x", "abc", r"row 5, column 'x': value 'abc' is not a finite number"),
        (7, "rz", "nan", r"row 7, column 'rz'.*not a finite number"),
        (2, "t_1", "n/a", r"row 2, column 't_1'"),
    ],
)
def test_bad_cells_name_row_and_column(tmp_path, row, col, value, match):
    rows = _rows()
    rows[row][rows[0].index(col)] = value
    path = _write(tmp_path, rows)
    with pytest.raises(RecordingsError, match=match) as info:
        load_recordings(path, ROBOT)
    assert str(path) in str(info.value)
    rec = load_recordings(path, ROBOT, drop_invalid=True)
    assert rec.num_samples == 89 and rec.dropped_rows == (row,)


def test_missing_required_column(tmp_path):
    rows = _rows()
    j = rows[0].index("l0_4")
    rows = [r[:j] + r[j + 1:] for r in rows]
    with pytest.raises(RecordingsError, match="required column.*l0_4"):
        load_recordings(_write(tmp_path, rows), ROBOT)


def test_cable_count_mismatch(tmp_path):
    rows = _rows()
    rows[0].append("t_7")
    for r in rows[1:]:
        r.append("1.0")
    with pytest.raises(RecordingsError, match=r"'t_7' refers to cable 7.*has 6 cables"):
        load_recordings(_write(tmp_path, rows), ROBOT)


def test_ragged_row_and_duplicates(tmp_path):
    rows = _rows()
    rows[4] = rows[4][:-2]
    with pytest.raises(RecordingsError, match="row 4: has 24 cells, the header has 26"):
        load_recordings(_write(tmp_path, rows), ROBOT)
    rows = _rows()
    rows[0][-1] = "x"
    with pytest.raises(RecordingsError, match="names column 'x' twice"):
        load_recordings(_write(tmp_path, rows), ROBOT)


def test_select_subset():
    rec = load_recordings(CSV, ROBOT)
    sub = rec.select(np.arange(10))
    assert sub.num_samples == 10
    np.testing.assert_array_equal(sub.l0, rec.l0[:10])
