import csv

import numpy as np
import pytest

from cstiffjax import RecordingsError, load_recordings, load_robot
from cstiffjax.examples import example_path
from cstiffjax.io.recordings import MAX_CELL_CHARS

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


def _write_bytes(tmp_path, data: bytes):
    p = tmp_path / "rec.csv"
    p.write_bytes(data)
    return p


def _lines():
    return CSV.read_text().splitlines()


def _raises(path, match, **kw):
    with pytest.raises(RecordingsError, match=match) as info:
        load_recordings(path, ROBOT, **kw)
    assert str(path) in str(info.value)
    return str(info.value)


def test_load_example():
    rec = load_recordings(CSV, ROBOT)
    assert rec.num_samples == 90 and rec.num_cables == 6
    assert rec.covariate_names == ("temperature",)
    assert rec.has_tensions and bool(np.all(rec.tension_mask))
    assert rec.dropped_rows == () and rec.drop_reasons == ()
    first = _rows()[1]
    np.testing.assert_allclose(rec.l0[0, 0], float(first[1]))
    np.testing.assert_allclose(rec.pose[0, 3], float(first[16]))


def test_csjm_example_loads():
    robot = load_robot(example_path("csjm.toml"))
    rec = load_recordings(example_path("csjm_recordings.csv"), robot)
    assert rec.kind == "csjm" and rec.num_samples > 0
    np.testing.assert_array_equal(rec.l0, 0.0)


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
    keep = [j for j, h in enumerate(rows[0]) if h not in ("fx", "fy", "fz", "mx", "my", "mz", "time", "t_6")]
    rows = [[r[j] for j in keep] for r in rows]
    rows[0].append("humidity")
    for r in rows[1:]:
        r.append("0.4")
    rec = load_recordings(_write(tmp_path, rows), ROBOT)
    np.testing.assert_array_equal(rec.wrench, 0.0)
    assert np.all(np.isnan(rec.time))
    assert rec.covariate_names == ("temperature", "humidity")
    np.testing.assert_allclose(rec.covariate("humidity"), 0.4)
    assert not bool(np.any(rec.tension_mask[:, 5])) and bool(np.all(rec.tension_mask[:, 0]))
    with pytest.raises(KeyError, match="available"):
        rec.covariate("pressure")


def test_empty_tension_cell_is_masked_not_dropped(tmp_path):
    rows = _rows()
    rows[6][rows[0].index("t_4")] = ""
    rec = load_recordings(_write(tmp_path, rows), ROBOT, drop_invalid=True)
    assert rec.num_samples == 90 and rec.dropped_rows == ()
    assert not bool(rec.tension_mask[5, 3]) and int(np.sum(~np.asarray(rec.tension_mask))) == 1


# data row r of _rows() is on file line r + 1 (the header is line 1)
@pytest.mark.parametrize(
    ("row", "col", "value", "match"),
    [
        (3, "l0_2", "", r"line 4, column 'l0_2': value is missing \(empty cell\) in a required column"),
        (5, "x", "abc", r"line 6, column 'x': value 'abc' is not a finite decimal number"),
        (7, "rz", "nan", r"line 8, column 'rz'.*'nan' is not a finite decimal"),
        (2, "t_1", "n/a", r"line 3, column 't_1'"),
        (4, "l0_3", "4_605", r"line 5, column 'l0_3': value '4_605' is not a finite decimal.*not '_'"),
        (4, "fz", "1_0.0", r"line 5, column 'fz': value '1_0.0'"),
        (9, "y", "inf", r"line 10, column 'y': value 'inf'"),
        (9, "y", "-Infinity", r"line 10, column 'y': value '-Infinity'"),
        (9, "temperature", "0x1p3", r"line 10, column 'temperature': value '0x1p3'"),
        (9, "z", "\uff11\uff12", r"line 10, column 'z'"),  # full-width digits: float() takes them
        (9, "z", "1e400", r"line 10, column 'z'.*overflows float64"),
        (11, "fx", "", r"line 12, column 'fx': value is missing \(empty cell\) in an optional column"),
        (11, "temperature", "  ", r"line 12, column 'temperature': value is missing"),
        (12, "l0_5", "-4.8", r"line 13, column 'l0_5': value '-4.8' must be > 0"),
        (12, "l0_1", "0", r"line 13, column 'l0_1': value '0' must be > 0"),
        (20, "rx", "1" * (MAX_CELL_CHARS + 1), r"line 21, column 'rx': cell is 201 characters long"),
        (6, "t_3", "1e308", r"line 7, column 't_3': value '1e308' is implausibly large \(tension: \|value\| "
                            r"<= 1e\+12 N\)"),
        (6, "fy", "-2e13", r"line 7, column 'fy': value '-2e13' is implausibly large \(external force"),
        (6, "l0_4", "3e7", r"line 7, column 'l0_4': value '3e7' is implausibly large .* <= 1e\+07 m"),
        (6, "x", "1e300", r"line 7, column 'x': value '1e300' is implausibly large \(position"),
    ],
)
def test_bad_cells_name_line_and_column(tmp_path, row, col, value, match):
    rows = _rows()
    rows[row][rows[0].index(col)] = value
    path = _write(tmp_path, rows)
    _raises(path, match)
    rec = load_recordings(path, ROBOT, drop_invalid=True)
    assert rec.num_samples == 89 and rec.dropped_rows == (row + 1,)
    assert rec.drop_reasons[0].startswith(f"column '{col}': ")
    keep = np.delete(np.asarray(load_recordings(CSV, ROBOT).l0), row - 1, axis=0)
    np.testing.assert_array_equal(rec.l0, keep)


def test_line_numbers_count_blank_lines(tmp_path):
    lines = _lines()
    lines[5] = lines[5].replace(lines[5].split(",")[14], "oops", 1)  # column y of file line 6
    text = "\n".join([*lines[:3], "", "   ", *lines[3:]]) + "\n"  # two blank lines after line 3
    path = _write_bytes(tmp_path, text.encode())
    assert text.splitlines()[7].split(",")[14] == "oops"  # now on file line 8
    _raises(path, r"line 8, column 'y': value 'oops'")
    assert load_recordings(path, ROBOT, drop_invalid=True).dropped_rows == (8,)


@pytest.mark.parametrize(
    ("old", "new", "match"),
    [
        ("t_1", "T_1", r"'T_1': did you mean 't_1'"),
        ("t_2", "t2", r"'t2': did you mean 't_2'"),
        ("fz", "Fz", r"'Fz': did you mean 'fz'"),
        ("fz", "f_z", r"'f_z': did you mean 'fz'"),
        ("l0_1", "L0_1", r"'L0_1': did you mean 'l0_1'"),
        ("l0_1", "l0_01", r"'l0_01': did you mean 'l0_1'"),
        ("l0_1", "l0-1", r"'l0-1': did you mean 'l0_1'"),
        ("time", "Time", r"'Time': did you mean 'time'"),
        ("rx", "RX", r"'RX': did you mean 'rx'"),
        ("temperature", "l0_0", r"'l0_0': cable indices start at 1 \(allowed: l0_1..l0_6\)"),
        ("temperature", "t_0", r"'t_0': cable indices start at 1 \(allowed: t_1..t_6\)"),
        ("temperature", "t_7", r"'t_7': refers to cable 7 but the robot 'example02' has 6 cables"),
        ("temperature", "l0_12", r"'l0_12': refers to cable 12"),
        ("temperature", "tx", None),  # a contract name (csjm moment) is not a covariate: ignored
    ],
)
def test_header_near_miss_is_an_error_suggesting_the_name(tmp_path, old, new, match):
    rows = _rows()
    rows[0][rows[0].index(old)] = new
    path = _write(tmp_path, rows)
    if match is None:
        assert load_recordings(path, ROBOT).covariate_names == ()
        return
    msg = _raises(path, match)
    assert "line 1 (header)" in msg and "near-miss" in msg
    _raises(path, match, drop_invalid=True)


def test_several_near_misses_are_listed_together(tmp_path):
    rows = _rows()
    rows[0][rows[0].index("fx")] = "FX"
    rows[0][rows[0].index("t_6")] = "T6"
    msg = _raises(_write(tmp_path, rows), r"'FX': did you mean 'fx'")
    assert "'T6': did you mean 't_6'" in msg


def test_utf8_bom_is_stripped(tmp_path):
    path = _write_bytes(tmp_path, b"\xef\xbb\xbf" + CSV.read_bytes())
    rec = load_recordings(path, ROBOT)
    np.testing.assert_array_equal(rec.time, load_recordings(CSV, ROBOT).time)


def test_invisible_character_in_a_header_name(tmp_path):
    text = CSV.read_text().replace(",fx,", ",\ufefffx,", 1)
    _raises(_write_bytes(tmp_path, text.encode()), r"line 1 \(header\): column 8 name .*invisible")


@pytest.mark.parametrize(("delim", "word"), [(";", "';'"), ("\t", "a tab"), ("|", "'|'"), (" ", "spaces")])
def test_other_delimiters_are_an_error_saying_so(tmp_path, delim, word):
    text = CSV.read_text().replace(",", delim)
    msg = _raises(_write_bytes(tmp_path, text.encode()), "line 1 \\(header\\): read as a single column")
    assert f"seems to use {word} as delimiter" in msg and "comma-separated" in msg


def test_mixed_delimiter_in_header(tmp_path):
    text = CSV.read_text().replace("x,y", "x;y", 1)
    _raises(_write_bytes(tmp_path, text.encode()), r"column name 'x;y' contains ';'")


@pytest.mark.parametrize("line", [1, 5])
def test_non_utf8_bytes_name_file_and_line(tmp_path, line):
    lines = CSV.read_bytes().split(b"\n")
    lines[line - 1] = lines[line - 1].replace(b"e" if line == 1 else b"0", b"\xe9", 1)  # latin-1 é
    _raises(_write_bytes(tmp_path, b"\n".join(lines)), rf"line {line}: byte e9 .* is not UTF-8")


def test_quoted_cell_spanning_lines_is_always_an_error(tmp_path):
    rows = _rows()
    rows[3][-1] = "20.89\n21.0"  # csv.writer quotes it: the cell spans file lines 4-5
    path = _write(tmp_path, rows)
    for drop in (False, True):
        _raises(path, r"lines 4-5: a quoted cell spans several lines", drop_invalid=drop)


def test_unclosed_quote_cannot_swallow_the_rest(tmp_path):
    lines = _lines()
    lines[9] = '"' + lines[9]  # never closed: would swallow lines 10..91 into one cell
    path = _write_bytes(tmp_path, ("\n".join(lines) + "\n").encode())
    for drop in (False, True):
        _raises(path, r"lines 10-91: a quoted cell spans several lines", drop_invalid=drop)


def test_bad_quoting_on_one_line_is_droppable(tmp_path):
    lines = _lines()
    cells = lines[9].split(",")
    cells[3] = f'"{cells[3]}"x'
    lines[9] = ",".join(cells)
    path = _write_bytes(tmp_path, ("\n".join(lines) + "\n").encode())
    _raises(path, r"line 10: not valid CSV")
    rec = load_recordings(path, ROBOT, drop_invalid=True)
    assert rec.dropped_rows == (10,) and rec.num_samples == 89


def test_field_over_the_csv_limit(tmp_path):
    lines = _lines()
    lines[2] = lines[2] + "9" * 200_000
    path = _write_bytes(tmp_path, ("\n".join(lines) + "\n").encode())
    _raises(path, r"line 3(: not valid CSV \(field larger|, column 'temperature': cell is)")
    assert load_recordings(path, ROBOT, drop_invalid=True).dropped_rows == (3,)


def test_header_that_is_data(tmp_path):
    _raises(_write(tmp_path, _rows()[1:]), r"line 1 \(header\): looks like data")


def test_missing_required_column(tmp_path):
    rows = _rows()
    j = rows[0].index("l0_4")
    rows = [r[:j] + r[j + 1:] for r in rows]
    _raises(_write(tmp_path, rows), "required column.*l0_4")


def test_ragged_row_and_duplicates(tmp_path):
    rows = _rows()
    rows[4] = rows[4][:-2]
    path = _write(tmp_path, rows)
    _raises(path, r"line 5: has 24 cells, the header \(line 1\) has 26")
    rec = load_recordings(path, ROBOT, drop_invalid=True)
    assert rec.dropped_rows == (5,) and "24 cells" in rec.drop_reasons[0]
    rows = _rows()
    rows[0][-1] = "x"
    _raises(_write(tmp_path, rows), "names column 'x' twice")


def test_all_rows_invalid(tmp_path):
    rows = _rows()[:4]
    for r in rows[1:]:
        r[1] = "-1"
    _raises(_write(tmp_path, rows), r"no valid data rows \(dropped 3: lines 2, 3, 4; line 2: column 'l0_1': "
            r"value '-1' must be > 0", drop_invalid=True)
    _raises(_write(tmp_path, rows[:1]), "no data rows after the header")


def test_empty_and_unreadable(tmp_path):
    _raises(_write_bytes(tmp_path, b"\xef\xbb\xbf\n\n"), "empty file")
    _raises(tmp_path, "cannot read recordings")


def test_select_subset():
    rec = load_recordings(CSV, ROBOT)
    sub = rec.select(np.arange(10))
    assert sub.num_samples == 10
    np.testing.assert_array_equal(sub.l0, rec.l0[:10])


def test_spaces_around_names_and_values_are_ignored(tmp_path):
    rows = _rows()
    rows = [[f" {c}  " for c in r] for r in rows]
    rec = load_recordings(_write(tmp_path, rows), ROBOT)
    np.testing.assert_array_equal(rec.l0, load_recordings(CSV, ROBOT).l0)
    assert rec.covariate_names == ("temperature",)


ONBOARD = load_robot(example_path("onboard4/robot.toml"))
ONBOARD_CSV = example_path("onboard4/recordings.csv")


@pytest.mark.parametrize(("col", "value", "limit"), [("pitch", "11.0", "1.5708"), ("roll", "-4", "3.14159"),
                                                     ("yaw", "179.5", "3.14159"), ("swivel_3", "45", "6.28319")])
def test_angles_in_degrees_are_an_error_even_when_dropping(tmp_path, col, value, limit):
    """An angle outside its range means the column is in degrees: an error naming line, column, value
    and range, which drop_invalid does not turn into a dropped row (the other rows would be degrees too)."""
    with ONBOARD_CSV.open() as fh:
        rows = list(csv.reader(fh))
    rows[3][rows[0].index(col)] = value
    path = _write(tmp_path, rows)
    for drop in (False, True):
        with pytest.raises(RecordingsError, match=rf"line 4, column '{col}': value '{value}' is outside "
                                                  rf"\[-{limit}, {limit}\] rad.*in degrees\?"):
            load_recordings(path, ONBOARD, drop_invalid=drop)
    rows[3][rows[0].index(col)] = str(float(limit) * 0.999)  # inside the range: read
    assert load_recordings(_write(tmp_path, rows), ONBOARD).num_samples == len(rows) - 1


# ------------------------------------------------------------------ misspelt columns, long forms, holes
def _onboard_rows():
    with ONBOARD_CSV.open() as fh:
        return list(csv.reader(fh))


@pytest.mark.parametrize(("old", "new", "meant"), [
    ("swivel_2", "swivle_2", "swivel_2"), ("t_2", "tension_2", "t_2"), ("t_3", "Tension 3", "t_3"),
    ("l0_1", "length_1", "l0_1"), ("l0_4", "lenght_4", "l0_4"), ("l0_2", "lo_2", "l0_2"),
    ("swivel_4", "swivel_angle_4", "swivel_4"), ("swivel_1", "swievl_1", "swivel_1"), ("time", "tiem", "time"),
    ("time", "timestamp", "time"), ("session", "sesion", "session"), ("pitch", "pitchh", "pitch"),
])
def test_a_misspelt_or_long_form_column_is_an_error_naming_both(tmp_path, old, new, meant):
    """The near-miss and the column it means are named (here the meant column is missing:
    without the check the file loaded, the near-miss a covariate)."""
    rows = _onboard_rows()
    rows[0][rows[0].index(old)] = new
    path = _write(tmp_path, rows)
    with pytest.raises(RecordingsError, match=rf"'{new}': did you mean '{meant}'\? \('{meant}' is missing\)") as e:
        load_recordings(path, ONBOARD)
    assert "prefix its name with 'cov_'" in str(e.value) and str(path) in str(e.value)
    rows[0][rows[0].index(new)] = "cov_" + new  # declared a covariate: no near-miss (a hole may remain)
    rows[0].append(meant)
    for r in rows[1:]:
        r.append(r[rows[0].index("cov_" + new)])
    assert load_recordings(_write(tmp_path, rows), ONBOARD).covariate_names == ("cov_" + new,)


@pytest.mark.parametrize("name", ["temperature", "temp", "humidity", "version", "t_set_2", "force_2", "run",
                                  "cov_tension_2"])
def test_extra_columns_that_are_no_near_miss_stay_covariates(tmp_path, name):
    rows = _onboard_rows()
    rows[0].append(name)
    for r in rows[1:]:
        r.append("1.5")
    assert load_recordings(_write(tmp_path, rows), ONBOARD).covariate_names == (name,)


@pytest.mark.parametrize(("drop", "have", "gap"), [("swivel_2", "swivel_1, swivel_3, swivel_4", "swivel_2"),
                                                   ("t_3", "t_1, t_2, t_4", "t_3")])
def test_a_group_with_a_hole_is_an_error(tmp_path, drop, have, gap):
    rows = _onboard_rows()
    j = rows[0].index(drop)
    rows = [r[:j] + r[j + 1:] for r in rows]
    with pytest.raises(RecordingsError, match=rf"has {have} but not {gap}: a misspelt or missing"):
        load_recordings(_write(tmp_path, rows), ONBOARD)
    rows = [[*r[:j], drop if k == 0 else "", *r[j:]] for k, r in enumerate(rows)]  # an empty column: not recorded
    rec = load_recordings(_write(tmp_path, rows), ONBOARD)
    mask = rec.swivel_mask if drop.startswith("swivel") else rec.tension_mask
    assert not np.asarray(mask)[:, int(drop[-1]) - 1].any() and np.asarray(mask)[:, 0].all()


def test_trailing_cables_without_a_sensor_are_no_hole(tmp_path):
    rows = _onboard_rows()
    j = rows[0].index("t_4")
    rows = [r[:j] + r[j + 1:] for r in rows]
    rec = load_recordings(_write(tmp_path, rows), ONBOARD)
    assert not np.asarray(rec.tension_mask)[:, 3].any()
