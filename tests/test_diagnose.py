"""Mismatch diagnosis end to end: the two shared example sets (example01 hides anchor
offsets, example02 is clean), generated concealed-effect sets, outliers, the JSON
contract (formats.md §3) and its validator, the report and the CLI.

The fast tests use the spring-law candidates only (the catenary candidate's compilation
costs ~30 s on a loaded 2-core machine); the full-vocabulary runs are marked slow."""

import copy
import json
from pathlib import Path

import numpy as np
import pytest

from cstiffjax import CableLaw, load_recordings, load_robot
from cstiffjax.examples import example_path
from fitting.diagnosis.diagnose import diagnose
from fitting.diagnosis.report import document, markdown, validate_diagnosis, write_report
from fitting.effects import VOCABULARY
from fitting.synth.generate import default_cases, write_case

SPRING_EFFECTS = tuple(e for e in VOCABULARY if e.name != "cable_mass")
# Answer key of the shared examples: ../shared beside the repository root, as CI lays it out (optional).
KEY = Path(__file__).resolve().parents[1].parent / "shared" / "spec" / "examples" / "key.json"


def _load(name):
    rb = load_robot(example_path(f"{name}/robot.toml"))
    return rb, load_recordings(example_path(f"{name}/recordings.csv"), rb)


VERDICTS = []  # what example01's diagnosis handed to on_verdict


@pytest.fixture(scope="module")
def example01():
    return diagnose(*_load("example01"), effects=SPRING_EFFECTS, on_verdict=VERDICTS.append)


@pytest.fixture(scope="module")
def example02():
    return diagnose(*_load("example02"), effects=SPRING_EFFECTS)


def test_example01_is_anchor_offset(example01):
    d = example01
    assert d.effects == ["anchor_offset"]
    assert d.candidates[0].effect == "anchor_offset"
    assert d.explained and d.final["chi2_per_dof"] < 1.5 and d.baseline["chi2_per_dof"] > 100
    assert d.outliers == []
    off = d.final["parameters"]["anchor_offset"]["offset"]
    assert np.all(np.asarray(off["std"]) < 2e-4)  # identified to a fraction of a millimetre
    # grammar terms competed in round 1 (the baseline is unexplained) and none displaced the vocabulary
    assert d.discovery["rounds"][0]["model"] == [] and d.discovery["rounds"][0]["fitted"]
    assert d.discovered == []


def test_example01_offsets_match_answer_key(example01):
    """The recovered anchor offsets against the simulator's answer key (../shared)."""
    if not KEY.exists():
        pytest.skip(f"answer key {KEY} not present (it lives in ../shared beside the repository)")
    off = example01.final["parameters"]["anchor_offset"]["offset"]
    value, std = np.asarray(off["value"]), np.asarray(off["std"])
    truth = np.asarray(json.loads(KEY.read_text())[0]["anchor_offsets"])
    assert np.all(np.abs(value - truth) < 5 * std + 1e-5)


def test_example02_is_clean(example02):
    d = example02
    assert d.effects == [] and d.explained and d.outliers == []
    assert d.sensor_faults == [] and "sensor_faults" not in d.to_json()  # no false alarm on clean readings
    assert 0.8 < d.baseline["chi2_per_dof"] < 1.2
    assert all(not c.accepted for c in d.candidates)
    assert len(d.candidates) == len(SPRING_EFFECTS)  # every candidate was tried and rejected


def test_json_contract_and_report(example01, tmp_path):
    doc = json.loads(json.dumps(example01.to_json(), default=float))
    validate_diagnosis(doc)
    for key in ("robot", "samples", "baseline", "localization", "candidates", "effects", "explained", "final"):
        assert key in doc
    assert doc["samples"] == 90 and doc["robot"] == "example01"
    assert {"position", "rotation", "tension"} <= set(doc["baseline"]["rms"])
    assert len(doc["baseline"]["calibrated"]["EA"]) == 6
    bic = [c["delta_bic"] for c in doc["candidates"]]
    assert bic == sorted(bic)
    loc = doc["localization"][0]
    assert {"where", "share_of_chi2", "correlates_with", "r"} <= set(loc)
    assert sum(e["share_of_chi2"] for e in doc["localization"]) <= 1 + 1e-9
    path = write_report(example01, tmp_path)
    text = path.read_text()
    assert "anchor_offset" in text and "elapsed" in text
    assert (tmp_path / "residuals.png").exists() and (tmp_path / "chi2_shares.png").exists()
    validate_diagnosis(json.loads((tmp_path / "diagnosis.json").read_text()))


@pytest.mark.parametrize("mutate, match", [
    (lambda d: d.pop("effects"), "'effects': missing"),
    (lambda d: d.update(explained="yes"), "'explained': must be bool"),
    (lambda d: d["candidates"].reverse(), "sorted by delta_bic"),
    (lambda d: d["candidates"][0].update(effect="gremlins"), "value 'gremlins'; allowed: cable_mass"),
    (lambda d: d.update(effects=["cable_sag"]), "'effects\\[0\\]'"),
    (lambda d: d["localization"][0].update(r=1.7), "outside \\[-1, 1\\]"),
    (lambda d: d.update(outliers=[0]), "1-based sample rows"),
    (lambda d: d["baseline"]["rms"].pop("position"), "'baseline.rms.position': missing"),
])
def test_validator_rejects(example01, mutate, match):
    doc = json.loads(json.dumps(example01.to_json(), default=float))
    bad = copy.deepcopy(doc)
    mutate(bad)
    with pytest.raises(ValueError, match=match):
        validate_diagnosis(bad)


def _generated(tmp_path_factory, name, n=40, seed=11):
    case = next(c for c in default_cases() if c.name == name)
    out = tmp_path_factory.mktemp(name)
    key = write_case(case, out, n=n, seed=seed)
    rb = load_robot(out / "robot.toml")
    return case, key, rb, load_recordings(out / "recordings.csv", rb)


@pytest.mark.slow  # a second diagnosis compile (~40 s)
def test_generated_tension_bias_is_found(tmp_path_factory):
    _case, key, rb, rec = _generated(tmp_path_factory, "proto_tension_sensor_bias")
    d = diagnose(rb, rec, effects=SPRING_EFFECTS)
    assert d.effects == ["tension_sensor_bias"] and d.explained
    est = d.final["parameters"]["tension_sensor_bias"]["bias"]
    truth = np.asarray(key["truth"]["tension_sensor_bias"]["bias"])
    assert np.all(np.abs(np.asarray(est["value"]) - truth) < 5 * np.asarray(est["std"]))


@pytest.mark.slow  # a generated case and its diagnosis (~1 min)
def test_generated_outliers_are_flagged_not_an_effect(tmp_path_factory):
    _case, key, rb, rec = _generated(tmp_path_factory, "proto_outliers")
    d = diagnose(rb, rec, effects=SPRING_EFFECTS)
    assert d.effects == [] and d.explained
    assert d.outliers == key["outliers"] and len(d.outliers) == 3


def test_bad_arguments():
    rb, rec = _load("example02")
    with pytest.raises(ValueError, match="diagnose does not support the 'ideal' cable law; supported: 'spring', "
                                         "'catenary'$"):
        diagnose(rb, rec, law=CableLaw.ideal)
    with pytest.raises(TypeError, match=r"CableLaw.parse\('catenary'\) reads a name"):
        diagnose(rb, rec, law="catenary")


# ------------------------------------------------------------------- slow sweep
SWEEP = [c.name for c in default_cases() if c.robot == "proto"] + ["tcpr8_clean", "tcpr8_exit_friction"]


@pytest.mark.slow
@pytest.mark.parametrize("name", SWEEP)
def test_concealed_effect_sweep(tmp_path_factory, name):
    case, key, rb, rec = _generated(tmp_path_factory, name, n=40)
    d = diagnose(rb, rec)
    assert sorted(d.effects) == sorted(case.expected)
    if case.expected:
        assert d.effects[0] in case.expected
    assert d.explained == case.explained
    if case.explained:
        assert d.final["chi2_per_dof"] < 1.5
    assert d.outliers == key["outliers"]
    mass = next(c for c in d.candidates if c.effect == "cable_mass")
    if "cable_mass" in d.effects:  # selected on the elastic catenary, after its small-sag screen
        assert mass.law is CableLaw.catenary and mass.screen_delta_bic is not None
        assert abs(mass.screen_delta_bic - mass.delta_bic) < 0.01 * abs(mass.delta_bic)
    else:  # the spring model screened it; refitted on the catenary only when the screen could win
        assert mass.law is CableLaw.small_sag or mass.screen_delta_bic is not None
    post = d.final.get("posterior", {})
    assert list(post) == (d.effects if not d.discovered else [])  # one chain on the final fit, every effect
    if len(post) > 1:  # e.g. proto_two_effects: the same chain, each effect's null outside its 99.9% region
        assert len({(p["steps"], p["samples"], p["tau"]) for p in post.values()}) == 1
        assert all(p["agrees"] for p in post.values())


@pytest.mark.slow
def test_full_vocabulary_on_the_examples():
    d1 = diagnose(*_load("example01"))
    d2 = diagnose(*_load("example02"))
    assert d1.effects == ["anchor_offset"] and d2.effects == [] and d1.explained and d2.explained


@pytest.mark.slow
def test_cli_default_runs_the_concealed_example(tmp_path, capsys):
    from cstiffjax.commands.cli import main

    assert main(["diagnose", "--json", str(tmp_path / "d.json"), "--report", str(tmp_path / "rep"), "--quiet"]) == 0
    doc = validate_diagnosis(json.loads((tmp_path / "d.json").read_text()))
    assert doc["robot"] == "concealed" and doc["explained"] and len(doc["effects"]) == 1
    mass = next(c for c in doc["candidates"] if c["effect"] == "cable_mass")  # screened, not refitted
    assert mass["law"] == "small_sag" and mass["screen_delta_bic"] is None and "small-sag" in mass["reason"]
    assert (tmp_path / "rep" / "report.md").exists()
    assert "effects:" in capsys.readouterr().out


def test_cli_prints_a_short_summary_and_the_json_stays_complete(example01, tmp_path, monkeypatch, capsys):
    """`cstiffjax diagnose` prints a few lines (baseline, effects, explained, final, files);
    the whole formats.md §3 document goes to --json and the report (the diagnosis itself
    is the module fixture, handed to the CLI in place of a new run)."""
    import fitting.diagnosis.diagnose
    from cstiffjax.commands.cli import main

    monkeypatch.setenv("CSTIFFJAX_CACHE_DIR", "off")
    monkeypatch.setattr(fitting.diagnosis.diagnose, "diagnose", lambda *a, **k: example01)
    rb, rc = (str(example_path(f"example01/{f}")) for f in ("robot.toml", "recordings.csv"))
    assert main(["diagnose", rb, rc, "--json", str(tmp_path / "d.json"), "--report", str(tmp_path / "rep")]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert 3 <= len(out) <= 8, out
    text = "\n".join(out)
    assert f"chi2/dof {example01.baseline['chi2_per_dof']:.4g}" in text
    assert "effect    anchor_offset" in text and "explained yes" in text
    assert f"final chi2/dof {example01.final['chi2_per_dof']:.4g}" in text
    assert str(tmp_path / "d.json") in text and str(tmp_path / "rep") in text
    assert "{" not in text  # no JSON on the terminal
    doc = validate_diagnosis(json.loads((tmp_path / "d.json").read_text()))
    full = document(example01)  # to_json() and the warnings (the baseline's cable 6: EA run away)
    assert set(doc) == set(full) and len(doc["candidates"]) == len(full["candidates"])
    assert json.loads((tmp_path / "rep" / "diagnosis.json").read_text()) == doc
    assert {"residuals.png", "chi2_shares.png"} <= {p.name for p in (tmp_path / "rep").iterdir()}


# ------------------------------------------------------------- posterior check
def test_posterior_check_of_the_selected_effect(example01):
    """The emcee posterior of the final fit for the selected effect (anchor_offset
    on example01) excludes the null, its medians and widths match the final Gauss-Newton
    fit, the chain is long enough; it is in ``final`` only (one chain, on the final model)."""
    d = example01
    sel = d.candidates[0]
    assert sel.accepted and sel.effect == "anchor_offset"
    assert list(d.final["posterior"]) == d.effects == ["anchor_offset"]
    post = d.final["posterior"]["anchor_offset"]
    assert not hasattr(sel, "posterior") and all("posterior" not in it for it in d.iterations)
    assert post["agrees"] and post["null_tail"] < 1e-3
    assert 0.2 < post["acceptance_fraction"] < 1.0 and np.isfinite(post["tau"])
    assert post["converged"] == (post["steps"] - post["burn"] >= 50 * post["tau"]) and post["converged"]
    assert 100 <= post["steps"] <= 300  # 100 steps, extended from the measured tau, capped at posterior_steps
    p, ls = post["parameters"]["offset"], d.final["parameters"]["anchor_offset"]["offset"]
    med, lo, hi = (np.asarray(v) for v in (p["median"], *p["interval90"]))
    value, std, null = np.asarray(ls["value"]), np.asarray(ls["std"]), np.asarray(ls["null"])
    assert med.shape == value.shape == (6, 3)
    assert np.all((null < lo) | (null > hi))  # the 90% interval excludes the null ...
    assert np.all(np.asarray(p["null_outside_999"]))  # ... and so does the 99.9% one (|z| > 5 on this case)
    assert np.all(np.abs(med - value) < 3 * std)  # posterior median vs least squares
    width = (hi - lo) / (2 * 1.6449 * std)  # posterior 90% width vs the Gauss-Newton one
    assert np.all((0.7 < width) & (width < 1.4))
    doc = json.loads(json.dumps(d.to_json(), default=float))
    validate_diagnosis(doc)
    assert doc["final"]["posterior"]["anchor_offset"]["agrees"] is True
    assert all("posterior" not in c for c in doc["candidates"])
    assert "## Posterior check (emcee)" in markdown(d) and "- **anchor_offset**: agrees" in markdown(d)


def test_on_verdict_gets_the_diagnosis_before_its_posterior(example01):
    """``on_verdict`` is called once, with the final verdict and everything but the
    posterior (the command line's figures are drawn from it while the walkers sample)."""
    (early,) = VERDICTS
    assert "posterior" not in early.final and "posterior" in example01.final
    assert early.effects == example01.effects and early.explained == example01.explained
    assert {k: v for k, v in example01.final.items() if k != "posterior"}.keys() == early.final.keys()
    assert early.final["chi2"] == example01.final["chi2"]
    for k, v in early.arrays.items():
        assert v is example01.arrays[k]  # the same arrays: the figures drawn from them are the report's


def test_no_posterior_without_a_selected_effect(example02):
    assert "posterior" not in example02.final
    assert all("posterior" not in c.to_json() for c in example02.candidates)


def test_posterior_steps_argument():
    rb, rec = _load("example02")
    with pytest.raises(ValueError, match="posterior_steps must be 0 \\(skip\\) or an integer >= 40, got 10"):
        diagnose(rb, rec, posterior_steps=10)


def test_localization_never_names_a_channels_own_reading_as_its_driver():
    """A load cell read with a 5 % gain error (residual ∝ its reading) and a set-point the
    load cell tracks: neither the reading ``t_1``, nor ``sag_1`` (computed from it), nor the
    set-point ``t_set_1`` (r > 0.99 with it) is the driver; the temperature that drives the
    part of the misfit the reading does not explain is, and the own reading's r is kept."""
    from types import SimpleNamespace

    from cstiffjax.io.recordings import Recordings
    from fitting.diagnosis.localize import localize

    rng = np.random.default_rng(2)
    n, m = 80, 2
    t = rng.uniform(20, 120, (n, m))
    temperature = rng.normal(21, 2, n)
    rec = Recordings(l0=rng.uniform(1, 2, (n, m)), wrench=np.zeros((n, 6)), pose=np.zeros((n, 6)), tensions=t,
                     tension_mask=np.ones((n, m), bool), moment=np.zeros((n, 3)), time=np.arange(n, dtype=float),
                     covariates=np.stack([t[:, 0] + rng.normal(0, 0.5, n), temperature], axis=1),
                     pose_mask=np.zeros((n, 6), bool), covariate_names=("t_set_1", "temperature"))
    r = np.zeros((n, 6 + m))
    r[:, 6] = 0.05 * (t[:, 0] - t[:, 0].mean()) / 0.5 + 0.8 * (temperature - 21) + rng.normal(0, 0.3, n)
    r[:, 7] = rng.normal(0, 0.3, n)
    data = SimpleNamespace(sensors=(), ctx=SimpleNamespace(direction=np.zeros((n, m))))
    out = localize(rec, data, r, np.ones(n, bool))
    top, own = out["channels"][0], out["own_readings"][0]
    assert top["where"] == "tension t_1" and top["correlates_with"] == "temperature"
    np.testing.assert_allclose(top["r"], np.corrcoef(r[:, 6], temperature)[0, 1], rtol=1e-12)
    assert sorted(own["not_drivers"]) == ["sag_1", "t_1", "t_set_1"]
    np.testing.assert_allclose(own["r"], np.corrcoef(r[:, 6], t[:, 0])[0, 1], rtol=1e-12)
    assert abs(np.corrcoef(r[:, 6], t[:, 0])[0, 1]) > abs(top["r"])  # the reading itself would have won
