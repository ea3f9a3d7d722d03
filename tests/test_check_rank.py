"""`cstiffjax check` refuses a robot whose structure matrix is rank deficient."""

import csv
import json
import re

import numpy as np
import pytest

from cstiffjax.commands.cli import main
from cstiffjax.examples import example_path, list_examples
from cstiffjax.io.robot_io import load_robot

BASE = example_path("example01/robot.toml").read_text()
HEAD, *CABLES = BASE.split("[[cables]]")
TCPR8 = example_path("tcpr8.toml").read_text()
HEAD8, *CABLES8 = TCPR8.split("[[cables]]")


def _robot(tmp_path, cables, head=HEAD):
    p = tmp_path / "robot.toml"
    p.write_text(head + "".join("[[cables]]" + c for c in cables))
    return p


def _set(cable, key, value):
    out = re.sub(rf"^{key} = \[.*\]$", f"{key} = {value}", cable, count=1, flags=re.M)
    assert out != cable
    return out


def _check(capsys, *argv):
    rc = main(["check", *map(str, argv)])
    out = capsys.readouterr()
    return rc, out.out, out.err


@pytest.mark.parametrize("name", [n for n in list_examples() if n.endswith(".toml")])
def test_bundled_robots_pass(capsys, name):
    rc, out, _ = _check(capsys, example_path(name))
    m = load_robot(example_path(name)).num_cables
    full = 3 if "csjm" in name else min(6, m)  # fewer than 6 cables (suspended): every cable independent
    assert rc == 0 and f"structure matrix rank {full} at the reference pose" in out
    assert ("under-constrained" in out) == (m < 6 and "csjm" not in name)


def test_duplicate_cable_fails_naming_it(tmp_path, capsys):
    rc, out, err = _check(capsys, _robot(tmp_path, [CABLES[0], CABLES[0], *CABLES[2:]]))
    assert rc == 1 and out == ""
    assert "cannot hold any pose" in err and "rank 5 < 6" in err
    assert "cables 1 and 2 are duplicates (same anchor and attachment)" in err
    assert "Rule:" in err and str(tmp_path / "robot.toml") in err


def test_all_anchors_at_one_point(tmp_path, capsys):
    rc, _, err = _check(capsys, _robot(tmp_path, [_set(c, "anchor", "[1.0, 2.0, 3.0]") for c in CABLES]))
    assert rc == 1 and "all anchors are at one point [1.0, 2.0, 3.0]" in err


def test_all_attachments_at_one_point(tmp_path, capsys):
    cables = [_set(c, "attachment", "[0.0, 0.1, 0.0]") for c in CABLES]
    rc, _, err = _check(capsys, _robot(tmp_path, cables))
    # cables through one platform point cannot apply a moment about it: rank 3
    assert rc == 1 and "rank 3 < 6" in err and "all attachments are at one point [0.0, 0.1, 0.0]" in err


def test_collinear_attachments_name_the_missing_wrench(tmp_path, capsys):
    # every cable meets the platform x axis, so none has a moment about it: the
    # unreachable wrench is the pure moment about x, [0, 0, 0, ±1, 0, 0]
    cables = [_set(c, "attachment", f"[{0.05 * (i - 2.5):.3f}, 0.0, 0.0]") for i, c in enumerate(CABLES)]
    rc, _, err = _check(capsys, _robot(tmp_path, cables))
    assert rc == 1 and "rank 5 < 6" in err and "no tensions of cables 1..6 produce the wrench direction" in err
    u = np.array(json.loads(re.search(r"direction (\[[^\]]*\])", err).group(1)))
    np.testing.assert_allclose(np.abs(u), [0, 0, 0, 1, 0, 0], atol=1e-4)


def test_redundant_robot_with_one_duplicate_warns(tmp_path, capsys):
    rc, out, _ = _check(capsys, _robot(tmp_path, [CABLES8[0], CABLES8[0], *CABLES8[2:]], HEAD8))
    assert rc == 0 and "rank 6" in out and "warning: cables 1 and 2 are duplicates" in out


def test_redundant_robot_with_three_duplicates_fails(tmp_path, capsys):
    c = CABLES8
    rc, _, err = _check(capsys, _robot(tmp_path, [c[0], c[0], c[2], c[2], c[4], c[4], c[6], c[7]], HEAD8))
    assert rc == 1 and "rank 5 < 6" in err
    for i, j in ((1, 2), (3, 4), (5, 6)):
        assert f"cables {i} and {j} are duplicates" in err


def test_singular_reference_pose_alone_is_not_an_error(tmp_path, capsys):
    # anchors all at z = 4 and the reference pose at z = 4: every cable is horizontal there
    # (no vertical force, rank < 6), but a pose 10 % higher has full rank
    cables = [re.sub(r"^(anchor = \[[^,]*,[^,]*,)[^\]]*\]", r"\1 4.0]", c, flags=re.M) for c in CABLES]
    rc, out, _ = _check(capsys, _robot(tmp_path, cables))
    assert rc == 0 and "(a singular pose), 6 around it" in out


def test_reference_pose_is_the_mean_recorded_pose(tmp_path, capsys):
    rec = example_path("example02/recordings.csv")
    with rec.open() as fh:
        rows = list(csv.reader(fh))
    cols = [rows[0].index(c) for c in ("x", "y", "z", "rx", "ry", "rz")]
    mean = np.array([[float(r[j]) for j in cols] for r in rows[1:]]).mean(0)
    out_json = tmp_path / "s.json"
    rc, out, _ = _check(capsys, example_path("example02/robot.toml"), rec, "--json", out_json)
    summary = json.loads(out_json.read_text())
    assert rc == 0 and summary["structure_rank"] == 6 and summary["warnings"] == []
    np.testing.assert_allclose(summary["reference_pose"], mean, rtol=1e-12)
    assert f"reference pose {np.round(mean, 4).tolist()}" in out


def test_check_lists_dropped_lines(tmp_path, capsys):
    lines = example_path("example02/recordings.csv").read_text().splitlines()
    lines[6] = lines[6].replace(lines[6].split(",")[9], "", 1)  # empty fz on file line 7
    p = tmp_path / "r.csv"
    p.write_text("\n".join(lines) + "\n")
    rc, out, _ = _check(capsys, example_path("example02/robot.toml"), p, "--drop-invalid",
                        "--json", tmp_path / "s.json")
    assert rc == 0 and "dropped 1 invalid row(s), file lines [7]" in out
    assert "line 7: column 'fz': value is missing" in out
    assert json.loads((tmp_path / "s.json").read_text())["dropped_rows"] == [7]


def test_the_rank_rule_in_python_agrees_with_numpy_and_names_cables_along_one_line():
    from cstiffjax.core.errors import RobotFileError
    from cstiffjax.statics.degeneracy import RANK_RTOL, check_rank, degeneracies, matrix_rank, poses_around

    robot = load_robot(example_path("tcpr8.toml"))  # 8 cables, no two alike
    rng = np.random.default_rng(3)
    S = rng.normal(size=(6, 8))
    S[:, 7] = -S[:, 2]  # cables 3 and 8 along one line
    assert matrix_rank(S) == np.linalg.matrix_rank(S, tol=RANK_RTOL * np.linalg.svd(S, compute_uv=False)[0]) == 6
    assert matrix_rank(S[:, :5]) == 5 and matrix_rank(np.full((6, 8), np.nan)) == 0
    assert degeneracies(robot, S) == ["cables 3 and 8 act along the same line"]
    pose = np.array([0.1, 0.2, 0.5, 0, 0, 0])
    around = poses_around(robot, pose)
    assert len(around) == 6 and all(np.count_nonzero(q - pose) == 1 for q in around)
    deficient = np.stack([S[:, :5] @ rng.normal(size=(5, 8)) for _ in range(7)])  # rank 5 everywhere
    assert check_rank(robot, pose, np.stack([S] * 7), "r.toml") == (6, 6, ["cables 3 and 8 act along the same line"])
    with pytest.raises(RobotFileError, match=r"r\.toml: the robot cannot hold any pose: .* rank 5 < 6"):
        check_rank(robot, pose, deficient, "r.toml")
