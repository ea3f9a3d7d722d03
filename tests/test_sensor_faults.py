"""Load-cell faults found before the physics (fitting.diagnosis.sensor_faults): the detectors
on arrays with known answers, on generated recordings (fitting.synth.generate's fault cases,
the predicted readings from an independent reference: the 6-cable robot's statics solved at
the measured poses, ``S t = -w``), no fault on clean data, and (slow) the whole diagnosis:
the fault named, the fit repeated on the corrected readings, no look-alike effect chosen."""

import json

import numpy as np
import pytest

from cstiffjax import load_recordings, load_robot
from cstiffjax.examples import example_path
from cstiffjax.statics import geometry as statics
from fitting.diagnosis import sensor_faults as sf
from fitting.effects import VOCABULARY
from fitting.synth.generate import apply_faults, default_cases, write_case

SIGMA = 0.5
SPRING_EFFECTS = tuple(e for e in VOCABULARY if e.name != "cable_mass")


def _readings(n=40, m=4, seed=0):
    """Predicted readings (tens of N apart, varying per sample) and readings = predictions + noise."""
    rng = np.random.default_rng(seed)
    p = rng.uniform(40.0, 250.0, (n, m))
    return p + rng.normal(0, SIGMA, (n, m)), p


def _kinds(faults):
    return sorted((f.kind, f.channels) for f in faults)


# ------------------------------------------------------------------ detectors on arrays
def test_clean_readings_give_no_fault():
    for seed in range(20):
        t, p = _readings(seed=seed)
        faults, tc, mc = sf.find_faults(t, np.ones_like(t, bool), p, SIGMA)
        assert faults == [] and np.array_equal(tc, t) and mc.all()


def test_quantization_step():
    rng = np.random.default_rng(1)
    x = rng.uniform(50, 200, 40)
    assert sf.quantization_step(x) is None  # continuous
    assert sf.quantization_step(np.round(x / 1.5) * 1.5) == pytest.approx(1.5)
    assert sf.quantization_step(np.round(x / 0.3) * 0.3 + 0.07) == pytest.approx(0.3)  # decimal step, offset
    assert sf.quantization_step(np.round(x, 6)) is None or sf.quantization_step(np.round(x, 6)) < 1e-5
    assert sf.quantization_step([1.0, 1.0, 2.0]) is None  # too few distinct values


def test_quantization_is_a_fault_only_well_above_the_noise():
    t, p = _readings()
    coarse = t.copy()
    coarse[:, 2] = np.round(t[:, 2] / (3 * SIGMA)) * 3 * SIGMA
    assert _kinds(sf.find_quantization(coarse, np.ones_like(t, bool), SIGMA)) == [("quantization", (2,))]
    fine = np.round(t / SIGMA) * SIGMA  # every channel at the noise level: no fault
    assert sf.find_faults(fine, np.ones_like(t, bool), p, SIGMA)[0] == []


def test_saturation_and_stuck():
    t, p = _readings(n=60)
    full = np.percentile(t[:, 1], 80)
    sat = t.copy()
    sat[:, 1] = np.minimum(t[:, 1], full)
    faults = sf.find_stuck(sat, np.ones_like(t, bool), p, SIGMA)
    assert _kinds(faults) == [("saturation", (1,))]
    assert faults[0].rows == tuple(np.flatnonzero(t[:, 1] > full)) and faults[0].value == full
    stuck = t.copy()
    stuck[20:27, 3] = 123.25  # a stuck reading in the middle of the range
    faults = sf.find_stuck(stuck, np.ones_like(t, bool), p, SIGMA)
    assert _kinds(faults) == [("stuck", (3,))] and faults[0].rows == tuple(range(20, 27))
    two = t.copy()
    two[[3, 9], 0] = 100.0  # twice is not enough
    assert sf.find_stuck(two, np.ones_like(t, bool), p, SIGMA) == []
    top = p.copy()
    top[[3, 9, 11], 0] = t[:, 0].max() + 1.0  # three repeats at the top whose predictions agree: no fault
    t3 = t.copy()
    t3[[3, 9, 11], 0] = top[[3, 9, 11], 0]
    assert sf.find_stuck(t3, np.ones_like(t, bool), top, SIGMA) == []


def test_exchanged_pair():
    t, p = _readings(m=6)
    sw = t.copy()
    sw[:, [1, 4]] = t[:, [4, 1]]
    faults, tc, mc = sf.find_faults(sw, np.ones_like(t, bool), p, SIGMA)
    assert mc.all()
    assert _kinds(faults) == [("exchanged", (1, 4))] and faults[0].to_json()["channel"] == "t_2,t_5"
    np.testing.assert_array_equal(tc, t)  # swapped back


def test_near_identical_channels_exchanged_are_no_fault():
    """Two cables that always carry the same tension (within the noise): an exchange is
    indistinguishable, never reported (the likelihood ratio is ~±2√N, far under the threshold)."""
    for seed in range(10):
        t, p = _readings(seed=seed)
        p[:, 2] = p[:, 1]
        t[:, 2] = p[:, 2] + np.random.default_rng(seed + 100).normal(0, SIGMA, len(t))
        for cols in ([1, 2], [2, 1]):
            sw = t.copy()
            sw[:, [1, 2]] = t[:, cols]
            assert sf.find_exchanged(sw, np.ones_like(t, bool), p, SIGMA) == []


@pytest.mark.parametrize("shift", [1, 2, 3])
def test_delay(shift):
    t, p = _readings(m=5)
    late = t.copy()
    late[shift:, 3] = t[:-shift, 3]
    faults, tc, mc = sf.find_faults(late, np.ones_like(t, bool), p, SIGMA)
    assert _kinds(faults) == [("delay", (3,))] and faults[0].value == shift
    assert not mc[-shift:, 3].any() and mc[:-shift].all()
    np.testing.assert_array_equal(tc[:-shift, 3], t[:-shift, 3])  # shifted back


def test_every_channel_delayed():
    t, p = _readings(m=8)
    late = t.copy()
    late[1:] = t[:-1]
    faults = sf.find_faults(late, np.ones_like(t, bool), p, SIGMA)[0]
    assert _kinds(faults) == [("delay", (j,)) for j in range(8)]


def test_samples_without_predictions_are_not_judged():
    t, p = _readings()
    valid = np.ones(len(t), bool)
    valid[5] = False
    p[5] = np.nan  # no prediction there
    faults, tc, mc = sf.find_faults(t, np.ones_like(t, bool), p, SIGMA, valid)
    assert faults == [] and mc.all() and np.array_equal(tc, t)  # the unjudged readings stay recorded


def test_validate_rejects():
    doc = {"samples": 10, "sensor_faults": [{"kind": "delay", "channel": "t_1", "detail": "late"}]}
    sf.validate(doc)
    for bad, match in (({"kind": "gremlin"}, "kind': value 'gremlin'; allowed: saturation"),
                       ({"channel": 3}, "channel': must be a string"),
                       ({"rows": [0]}, "rows': must be a list of 1-based sample rows in 1..10")):
        d = json.loads(json.dumps(doc))
        d["sensor_faults"][0].update(bad)
        with pytest.raises(ValueError, match=match):
            sf.validate(d)


# ---------------------------------------------------------------- generated recordings
def _nominal_predictions(rb, rec):
    """Readings of the nominal 6-cable robot at the measured poses: ``S t = -w`` (an
    independent reference: no fit, no forward statics)."""
    out = []
    for pose, w in zip(np.asarray(rec.pose), np.asarray(rec.wrench), strict=True):
        S = np.asarray(statics.structure_matrix_closed_form(rb, pose))
        out.append(-np.linalg.solve(S, np.asarray(statics.gravity_wrench(rb, pose)) + w))
    return np.array(out)


CASES = {c.name: c for c in default_cases()}


def _generated(tmp_path, name, n=30, seed=11):
    key = write_case(CASES[name], tmp_path / name, n=n, seed=seed)
    rb = load_robot(tmp_path / name / "robot.toml")
    return key, rb, load_recordings(tmp_path / name / "recordings.csv", rb)


def test_generator_faults():
    ten = np.arange(40.0).reshape(10, 4) + 0.1
    assert np.array_equal(apply_faults(ten, {}), ten)
    sat = apply_faults(ten, {"tension_saturation": {"channel": 2, "percentile": 80.0}})
    assert np.sum(sat[:, 1] == sat[:, 1].max()) == 2 and np.array_equal(np.delete(sat, 1, 1), np.delete(ten, 1, 1))
    assert np.array_equal(apply_faults(ten, {"tension_channels_swapped": {"channels": [1, 3]}}), ten[:, [2, 1, 0, 3]])
    late = apply_faults(ten, {"tension_delay": {"channels": [4], "samples": 1}})
    assert np.array_equal(late[1:, 3], ten[:-1, 3]) and late[0, 3] == ten[0, 3]
    q = apply_faults(ten, {"tension_quantization": {"channels": [1], "step": 1.5}})
    assert np.allclose(q[:, 0] / 1.5, np.round(q[:, 0] / 1.5)) and np.all(np.abs(q[:, 0] - ten[:, 0]) <= 0.75)
    for kind in ("proto", "tcpr8"):  # each fault case, its key; a fine grid is no fault
        names = [f"{kind}_tension_{f}" for f in ("saturation", "channels_swapped", "delay", "quantization",
                                                  "quantization_fine")]
        assert all(CASES[nm].faults and CASES[nm].expected == [] for nm in names)
        assert CASES[names[-1]].sensor_faults == [] and all(CASES[nm].sensor_faults for nm in names[:-1])


@pytest.mark.parametrize("fault", ["saturation", "channels_swapped", "delay", "quantization"])
def test_fault_found_on_generated_recordings(tmp_path, fault):
    key, rb, rec = _generated(tmp_path, f"proto_tension_{fault}")
    faults, *_ = sf.find_faults(np.asarray(rec.tensions), np.asarray(rec.tension_mask),
                                _nominal_predictions(rb, rec), float(rb.noise.tension))
    assert [{"kind": f.kind, "channel": f.to_json()["channel"]} for f in faults] == key["sensor_faults"]
    if fault == "saturation":
        j = key["faults"]["tension_saturation"]["channel"] - 1
        t = np.asarray(rec.tensions)[:, j]
        assert faults[0].rows == tuple(np.flatnonzero(t == t.max())) and len(faults[0].rows) == 6  # 20 % of 30


@pytest.mark.parametrize("name", ["proto_clean", "proto_tension_quantization_fine", "proto_tension_sensor_gain"])
def test_no_fault_on_generated_recordings(tmp_path, name):
    """Clean data, every channel rounded to its noise σ, and a load-cell gain error (the
    saturation's look-alike, a physical effect, not a fault)."""
    _key, rb, rec = _generated(tmp_path, name)
    faults, *_ = sf.find_faults(np.asarray(rec.tensions), np.asarray(rec.tension_mask),
                                _nominal_predictions(rb, rec), float(rb.noise.tension))
    assert faults == []


def test_no_fault_in_the_example_recordings():
    """The bundled 6-cable examples' readings against their robots' statics (the whole
    diagnosis on example02: tests/test_diagnose.py)."""
    for name in ("example01", "example02", "concealed"):
        rb = load_robot(example_path(f"{name}/robot.toml"))
        rec = load_recordings(example_path(f"{name}/recordings.csv"), rb)
        faults, *_ = sf.find_faults(np.asarray(rec.tensions), np.asarray(rec.tension_mask),
                                    _nominal_predictions(rb, rec), float(rb.noise.tension))
        assert faults == [], name


# ------------------------------------------------------------------ the whole diagnosis
@pytest.mark.slow  # one diagnosis compile and three diagnoses (~45 s on a quiet 2-core machine)
def test_diagnosis_names_the_fault_and_fits_the_corrected_readings(tmp_path):
    from fitting.diagnosis.diagnose import diagnose
    from fitting.diagnosis.report import document, markdown, validate_diagnosis

    for fault in ("saturation", "channels_swapped", "delay"):
        key, rb, rec = _generated(tmp_path, f"proto_tension_{fault}", n=40)
        d = diagnose(rb, rec, effects=SPRING_EFFECTS, posterior_steps=0)
        doc = validate_diagnosis(document(d))
        assert [{k: f[k] for k in ("kind", "channel")} for f in doc["sensor_faults"]] == key["sensor_faults"]
        assert d.effects == [] and d.explained and d.final["chi2_per_dof"] < 1.5, fault  # no look-alike
        assert "Sensor faults" in markdown(d)
        if fault == "saturation":  # its readings left out of every fit
            j = key["faults"]["tension_saturation"]["channel"] - 1
            rows = np.asarray(doc["sensor_faults"][0]["rows"]) - 1
            assert not np.asarray(d.arrays["r_final"])[rows, 6 + j].any()
