"""No effect claimed on information the recordings do not carry, and recordings no cable
robot produces reported:

1. a platform of 1e-6 kg (every tension below the load cells' noise): the cables'
   elasticity is unobservable, so ``nonlinear_elasticity`` (seen only through the strain)
   is not claimed, and the diagnosis says why in its ``warnings``;
2. a tension reading far below zero is named (line, column, value, the noise sigma);
   readings within the noise band of zero pass;
3. copies of a sample (equal to within 1e-6 noise sigmas) are named, held-out folds keep every copy in one fold, and
   recordings with too few distinct samples get an error instead of a verdict.

The recordings are simulated (:func:`fitting.synth.generate.simulate`) on the 6-cable
prototype with few samples; the diagnoses fit one or two effects, without the posterior
check or the grammar search, to stay short."""

import json
from pathlib import Path

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

from cstiffjax import DiagnosisError, load_recordings, load_robot
from cstiffjax.commands.cli import main as cli
from cstiffjax.io import screening
from cstiffjax.io.recordings import write_recordings
from cstiffjax.io.robot_io import save_robot
from fitting.diagnosis.diagnose import diagnose
from fitting.diagnosis.report import document, validate_diagnosis
from fitting.diagnosis.sample_checks import held_out_folds
from fitting.effects import NonlinearElasticity, TensionSensorBias
from fitting.synth import generate
from tests.helpers import differences

QUICK = dict(posterior_steps=0, discover=False)


def _write(tmp, robot, cols):
    save_robot(robot, tmp / "robot.toml")
    write_recordings(cols, tmp / "recordings.csv")
    rb = load_robot(tmp / "robot.toml")
    return rb, load_recordings(tmp / "recordings.csv", rb)


@pytest.fixture(scope="module")
def featherweight(tmp_path_factory):
    """The prototype with a 1e-6 kg platform and no external load: tensions ~1e-5 N against
    a load-cell noise of 0.3 N, stretch ~1e-10 m against a pose noise of 2e-5 m."""
    nominal = generate.nominal_robot
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(generate, "nominal_robot", lambda kind: eqx.tree_at(
            lambda r: r.platform_mass, nominal("proto"), jnp.asarray(1e-6)))
        mp.setitem(generate.WORKSPACE, "feather", dict(generate.WORKSPACE["proto"], fz=(0.0, 0.0), fxy=0.0,
                                                        t_min=0.0))
        robot, cols, _ = generate.simulate(generate.Case("feather", "feather"), n=40, seed=3)
    return _write(tmp_path_factory.mktemp("feather"), robot, cols)


@pytest.fixture(scope="module")
def proto(tmp_path_factory):
    """Clean prototype recordings, 24 samples (tensions of tens to hundreds of N)."""
    robot, cols, _ = generate.simulate(generate.Case("clean", "proto"), n=24, seed=5)
    return robot, cols, tmp_path_factory


# ------------------------------------------------------------------ 1. below the noise
def test_no_effect_claimed_below_the_noise(featherweight):
    robot, rec = featherweight
    t = np.asarray(rec.tensions)
    assert np.max(np.abs(t)) < 5 * float(robot.noise.tension)  # the premise: readings are noise
    d = diagnose(robot, rec, effects=(NonlinearElasticity(), TensionSensorBias()), **QUICK)
    doc = validate_diagnosis(document(d))
    assert d.effects == [] and doc["effects"] == []
    assert "nonlinear_elasticity" not in [c.effect for c in d.candidates]
    assert "elasticity" in d.not_applicable["nonlinear_elasticity"]
    elastic = [w for w in doc["warnings"] if "no information about the cables' elasticity" in w]
    assert len(elastic) == 1 and "0.3 N" in elastic[0]
    # every cable's EA is reported as undetermined, at its nominal value, in the baseline and the final fit
    for stage in ("baseline", "final"):
        cal = doc[stage]["calibrated"]
        assert [u["cable"] for u in cal["unidentified"]] == list(range(1, 7))
        assert np.allclose(cal["EA"], np.asarray(robot.EA))
    # the sensor bias is still tried (the readings carry it) and rejected on this noise
    assert [c.effect for c in d.candidates] == ["tension_sensor_bias"] and not d.candidates[0].accepted


# ------------------------------------------------------------------ 2. negative tensions
def _negative(proto):
    robot, cols, factory = proto
    cols = {k: np.array(v, dtype=float) for k, v in cols.items()}
    cols["t_3"][4] = -4.0  # -13 sigma: a load cell cannot read this off a cable; file line 6
    cols["t_2"][5] = -0.5  # -1.7 sigma: noise around zero, fine
    return _write(factory.mktemp("negative"), robot, cols)


def test_negative_tension_named(proto):
    robot, rec = _negative(proto)
    (msg,) = screening.negative_tensions(rec, float(robot.noise.tension))
    assert "1 measured tension(s) below zero" in msg
    assert "line 6, column 't_3': -4 N" in msg and "sigma = 0.3 N" in msg and "tension_sensor_bias" in msg
    assert "t_2" not in msg  # within the noise of zero
    assert screening.negative_tensions(rec, 1.0) == []  # -4 N is only 4 sigma of a 1 N load cell
    # samples named by position when the rows are not known
    (msg,) = screening.negative_tensions(rec, 0.3, rows=())
    assert "sample 5, column 't_3'" in msg


def test_check_reports_negative_tensions(proto, tmp_path, capsys):
    _robot, rec = _negative(proto)
    out = tmp_path / "check.json"
    robot_toml = str(Path(rec.source).with_name("robot.toml"))
    assert cli(["check", robot_toml, rec.source, "--json", str(out)]) == 0
    assert "line 6, column 't_3': -4 N" in capsys.readouterr().out
    assert any("line 6, column 't_3'" in w for w in json.loads(out.read_text())["warnings"])


# ------------------------------------------------------------------ 3. duplicate samples
def test_duplicate_groups_and_folds():
    rng = np.random.default_rng(3)
    n = 40
    groups = rng.integers(0, 15, n)
    groups = np.unique(groups, return_inverse=True)[1]  # 0.. in some order
    folds = held_out_folds(groups, 5)
    for g in np.unique(groups):
        assert len(set(folds[groups == g].tolist())) == 1  # every copy in one fold
    # without copies: exactly the per-sample folds (seed 0), so no old verdict moves
    assert np.array_equal(held_out_folds(np.arange(n), 5), np.random.default_rng(0).permutation(n) % 5)


def test_duplicates_named_and_grouped(proto):
    robot, cols, factory = proto
    cols = {k: np.concatenate([v, v[[2, 2, 7]]]) for k, v in cols.items()}  # sample 3 twice more, sample 8 once
    _rb, rec = _write(factory.mktemp("dup"), robot, cols)
    groups = screening.duplicate_groups(rec)
    assert groups.max() + 1 == 24 and groups[24] == groups[25] == 2 and groups[26] == 7
    assert np.array_equal(groups[:24], np.arange(24))
    (msg,) = screening.duplicate_samples(rec)
    assert "3 of 27 samples are copies of another (identical" in msg and "24 distinct" in msg
    assert "line 4 is repeated at line 26, line 27" in msg and "line 9 is repeated at line 28" in msg
    sigma = float(robot.noise.tension)
    # within 1e-6 sigma (a rewritten file's rounding) a reading is still a copy; at 1e-3 sigma it is not
    cols["t_1"][26] += 0.5e-6 * sigma
    cols["t_2"][25] -= 0.9e-6 * sigma
    _, rec2 = _write(factory.mktemp("dup2"), robot, cols)
    assert screening.duplicate_groups(rec2).max() + 1 == 26  # without the noise: compared exactly (two differ)
    assert np.array_equal(screening.duplicate_groups(rec2, robot.noise), groups)
    (msg,) = screening.duplicate_samples(rec2, noise=robot.noise)
    assert "3 of 27 samples are copies of another (commanded lengths, wrench and readings equal to within 1e-06 " \
           "of each channel's noise sigma; 24 distinct)" in msg and "line 4 is repeated at line 26, line 27" in msg
    cols["t_1"][26] += 1e-3 * sigma
    _, rec3 = _write(factory.mktemp("dup3"), robot, cols)
    assert screening.duplicate_groups(rec3, robot.noise).max() + 1 == 25


def test_near_copies_against_a_pairwise_reference():
    """The grouping against a brute-force reference (every pair compared, connected components
    by repeated relabelling): random samples on a coarse grid of sigmas, so that many agree
    in some channels and some in all, with offsets just inside and just outside 1e-6 sigma."""
    from types import SimpleNamespace

    rng = np.random.default_rng(5)
    n, m = 60, 3
    noise = SimpleNamespace(position=1e-3, rotation=2e-3, tension=0.5, moment=np.nan, swivel=np.nan,
                            ahrs=np.full(3, np.nan))
    base = rng.integers(0, 2, (n, m)).astype(float)
    t = base * 0.5 + rng.choice([0.0, 0.4e-6, 0.8e-6, 3e-6], (n, m)) * 0.5  # offsets in sigmas x sigma
    rec = SimpleNamespace(l0=np.ones((n, m)) + rng.integers(0, 2, (n, 1)) * 1e-3, wrench=np.zeros((n, 6)),
                          pose=np.zeros((n, 6)), pose_mask=np.zeros((n, 6), bool), tensions=t,
                          tension_mask=np.ones((n, m), bool), moment=np.zeros((n, 0)), swivel=np.zeros((n, m)),
                          swivel_mask=np.zeros((n, m), bool), ahrs=np.zeros((n, 3)), ahrs_mask=np.zeros((n, 3), bool),
                          session=rng.integers(0, 2, n))
    key = np.hstack([rec.l0 / 1e-3, t / 0.5, rec.session[:, None] * 1e9])
    near = np.all(np.abs(key[:, None] - key[None]) <= 1e-6 * (1 + 1e-9), axis=2)
    label = np.arange(n)
    for _ in range(n):  # components: every sample takes the smallest label among its neighbours
        label = np.min(np.where(near, label[None], n), axis=1)
    want = np.unique(label, return_inverse=True)[1]
    got = screening.duplicate_groups(rec, noise)
    assert np.array_equal(got, want)
    assert 1 < got.max() + 1 < n  # the case holds copies and distinct samples


def test_copies_need_equal_swivel_ahrs_and_session():
    """On-board readings count: samples equal in lengths and tensions but not in a swivel
    angle, an AHRS angle or the session (its own length zeros) are not copies."""
    from types import SimpleNamespace

    n, m = 5, 4
    base = dict(l0=np.ones((n, m)), wrench=np.zeros((n, 6)), pose=np.zeros((n, 6)), pose_mask=np.zeros((n, 6), bool),
                tensions=np.ones((n, m)), tension_mask=np.ones((n, m), bool), moment=np.zeros((n, 0)),
                swivel=np.zeros((n, m)), swivel_mask=np.ones((n, m), bool), ahrs=np.zeros((n, 3)),
                ahrs_mask=np.ones((n, 3), bool), session=np.zeros(n, int))
    assert screening.duplicate_groups(SimpleNamespace(**base)).tolist() == [0] * n
    rec = dict(base, swivel=base["swivel"].copy(), ahrs=base["ahrs"].copy(), session=base["session"].copy(),
               pose=np.full((n, 6), np.nan))  # an unmeasured pose is not compared
    rec["swivel"][1, 2], rec["ahrs"][2, 0], rec["session"][3] = 1e-3, 1e-3, 1
    assert screening.duplicate_groups(SimpleNamespace(**rec)).tolist() == [0, 1, 2, 3, 0]


def test_copies_of_one_sample_get_no_verdict(proto):
    robot, cols, factory = proto
    rb, rec = _write(factory.mktemp("copies"), robot, {k: np.repeat(v[:1], 90) for k, v in cols.items()})
    with pytest.raises(DiagnosisError, match=r"only 1 distinct samples \(89 of the 90 samples are copies "
                                             r"of another\); a diagnosis needs at least 10 .*no verdict"):
        diagnose(rb, rec, effects=(TensionSensorBias(),), **QUICK)


def test_diagnosis_reports_negative_tensions_and_copies(proto):
    """One diagnosis of clean data with a -13 sigma reading and two copied rows: both named
    in ``warnings``; the elasticity is observable here (no such warning), nothing claimed."""
    robot, cols, factory = proto
    cols = {k: np.array(v, dtype=float) for k, v in cols.items()}
    cols["t_3"][4] = -4.0
    order = [*range(11), 10, 11, *range(11, 24)]  # samples 11 and 12 taken twice (lines 12-13, 14-15)
    cols = {k: v[order] for k, v in cols.items()}
    rb, rec = _write(factory.mktemp("both"), robot, cols)
    d = diagnose(rb, rec, effects=(TensionSensorBias(),), rows=list(rec.rows), detect_outliers=False, **QUICK)
    doc = validate_diagnosis(document(d))
    text = "\n".join(doc["warnings"])
    assert "line 6, column 't_3': -4 N" in text and "sigma = 0.3 N" in text
    assert "line 12 is repeated at line 13; line 14 is repeated at line 15" in text
    assert "counts each distinct sample once" in text
    assert "elasticity" not in text


def test_copies_are_one_measurement_of_evidence(proto):
    """Every copy of every sample taken ten times: the diagnosis is the one of the distinct
    samples (same chi2, dof, localization and verdict), not ten times the evidence (with each
    copy counted, residual correlations below the noise turn "significant")."""
    robot, cols, factory = proto
    tiled = {k: np.tile(v, 10) for k, v in cols.items()}
    if "time" in cols:  # the copies taken later (the first of them keeps its time)
        t = np.asarray(cols["time"], dtype=float)
        tiled["time"] = np.concatenate([t + k * (np.ptp(t) + 1.0) for k in range(10)])
    docs = []
    for name, c in (("once", cols), ("tenfold", tiled)):
        rb, rec = _write(factory.mktemp(name), robot, c)
        docs.append(validate_diagnosis(document(diagnose(rb, rec, effects=(TensionSensorBias(),), **QUICK))))
    once, tenfold = docs
    assert once["baseline"]["dof"] == tenfold["baseline"]["dof"]
    np.testing.assert_allclose(tenfold["baseline"]["chi2"], once["baseline"]["chi2"], rtol=1e-9)
    assert differences(tenfold["localization"], once["localization"]) == []
    assert (tenfold["effects"], tenfold["explained"]) == (once["effects"], once["explained"])
    assert any("216 of 240 samples are copies" in w for w in tenfold["warnings"])


def test_fit_counts_copies_once(proto, tmp_path, capsys):
    """``fit`` on samples taken three times, two of the copies with ``t_1`` off by a relative
    1e-12 (a rewritten file's rounding), fits the distinct ones: the same EA and std as the
    samples taken once (counted, the copies would shrink them by sqrt(3)); the copies are named."""
    robot, cols, factory = proto
    cols = {k: v for k, v in cols.items() if k != "time"}
    tiled = {k: np.tile(v, 3) for k, v in cols.items()}
    tiled["t_1"] = np.concatenate([cols["t_1"], cols["t_1"] * (1 + 1e-12), cols["t_1"] * (1 - 1e-12)])
    docs = []
    for name, c in (("fit1", cols), ("fit3", tiled)):
        folder = factory.mktemp(name)
        _write(folder, robot, c)
        out = tmp_path / f"{name}.json"
        assert cli(["fit", str(folder / "robot.toml"), str(folder / "recordings.csv"), "--json", str(out)]) == 0
        docs.append(json.loads(out.read_text()))
    once, doc = docs
    assert doc["samples"] == 24 and len(doc["residuals"]) == 24
    np.testing.assert_allclose(doc["std"]["EA"], once["std"]["EA"], rtol=1e-9)
    np.testing.assert_allclose(doc["values"]["EA"], once["values"]["EA"], rtol=1e-9)
    assert any("48 of 72 samples are copies of another" in w and "1e-06 of each channel's noise sigma" in w
               for w in doc["warnings"])
    assert "72 samples (24 distinct)" in capsys.readouterr().out
