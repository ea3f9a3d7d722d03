"""Model selection separates each hardware effect from the old effect it resembles:
swivel pulleys vs anchor offsets, a winch gain vs length offsets, a load-cell
gain vs a heavier platform. Blind diagnoses of generated recordings (fitting.synth.generate
writes the hardware out independently of the effect code).

Slow tests (the fast suite's time budget): three proto cases of 20 samples
diagnosed with the six effects of the three pairs, sharing one compiled model (the compile
is the cost, ~2 min on 2 cores; each diagnosis then takes seconds); every hardware case of
both robots with the whole vocabulary at 40 samples. The blind benchmark
(``benchmarks/bench_diagnose.py``) runs the same separations at 90 samples."""

import numpy as np
import pytest

from cstiffjax import load_recordings, load_robot
from fitting.diagnosis.diagnose import diagnose
from fitting.diagnosis.report import markdown, validate_diagnosis
from fitting.effects import EFFECTS
from fitting.synth.generate import default_cases, write_case

PAIRS = ("anchor_offset", "length_offset", "platform_mass", "pulley_kinematics", "length_gain",
         "tension_sensor_gain")
RESEMBLES = {"pulley_kinematics": "anchor_offset", "length_gain": "length_offset",
             "tension_sensor_gain": "platform_mass"}
HW_CASES = [c.name for c in default_cases() if c.name.split("_", 1)[1] in
            ("pulley_kinematics", "length_gain", "tension_sensor_gain", "attachment_offset", "hardware_two_effects")]


def _case(tmp_path_factory, name, n, seed):
    case = next(c for c in default_cases() if c.name == name)
    out = tmp_path_factory.mktemp(name)
    write_case(case, out, n=n, seed=seed)
    rb = load_robot(out / "robot.toml")
    return case, rb, load_recordings(out / "recordings.csv", rb)


@pytest.fixture(scope="module")
def diagnosed(tmp_path_factory):
    effects = tuple(EFFECTS[e] for e in PAIRS)
    out = {}
    for effect in RESEMBLES:
        case, rb, rec = _case(tmp_path_factory, f"proto_{effect}", 20, 11)
        out[effect] = case, diagnose(rb, rec, effects=effects, folds=3, posterior_steps=0, discover=False,
                                     progress=False)
    return out


@pytest.mark.slow
@pytest.mark.parametrize("effect", list(RESEMBLES))
def test_new_effect_is_named_not_its_look_alike(diagnosed, effect):
    case, d = diagnosed[effect]
    assert d.effects == [effect] and d.explained and d.final["chi2_per_dof"] < 1.5
    by = {c.effect: c for c in d.candidates}
    assert by[effect].accepted and by[effect].delta_bic < by[RESEMBLES[effect]].delta_bic
    # the look-alike alone leaves residual well above the noise (and above the new effect's fit)
    assert by[RESEMBLES[effect]].chi2_per_dof > max(1.5, 1.5 * by[effect].chi2_per_dof)
    (param, truth), = case.truth[effect].items()
    est = d.final["parameters"][effect][param]
    assert np.all(np.abs(np.asarray(est["value"]) - np.asarray(truth)) < 5 * np.asarray(est["std"]))


@pytest.mark.slow
def test_report_states_the_assumed_pulley_axes(diagnosed):
    d = diagnosed["pulley_kinematics"][1]
    doc = validate_diagnosis(d.to_json())
    note = doc["assumptions"]["pulley_kinematics"]
    assert "the description states no pulleys" in note and "vertical swivel axes" in note
    assert "cables 1, 2, 3, 4, 5, 6; -z for those below: none" in note  # proto: every anchor above
    assert f"**Assumed** (`pulley_kinematics`): {note}." in markdown(d)


# Known, reported gap: both effects of this pair are found and
# explained, but selection is greedy by evidence and the anchor offsets remove far more chi2
# than the 1.2 % load-cell gain, so anchor_offset is named first (also in bench_diagnose.py).
# The order check stays: it passes the day the new effect comes first.
EVIDENCE_ORDER = {"tcpr8_hardware_two_effects": "anchor_offset selected before tension_sensor_gain (greedy by "
                                                "evidence); both found and explained"}


@pytest.mark.slow
@pytest.mark.parametrize("name", HW_CASES)
def test_hardware_sweep_full_vocabulary(tmp_path_factory, name):
    case, rb, rec = _case(tmp_path_factory, name, 40, 5)
    d = diagnose(rb, rec)
    assert sorted(d.effects) == sorted(case.expected)
    assert d.explained and d.final["chi2_per_dof"] < 1.5
    if name in EVIDENCE_ORDER and d.effects[:1] != case.expected[:1]:
        pytest.xfail(EVIDENCE_ORDER[name])
    assert d.effects[:1] == case.expected[:1]
