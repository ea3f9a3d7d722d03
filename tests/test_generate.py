"""Synthetic recordings with concealed effects: coverage of the cases, files readable by
the loaders, clean data consistent with the nominal model (checked with the independent
optimistix forward statics), effects and outliers where the key says."""

import numpy as np
import pytest

from cstiffjax import CableLaw, StaticsProblem, load_recordings, load_robot
from cstiffjax.commands.cli import main as cli
from cstiffjax.statics import forward as fwd
from fitting.effects import VOCABULARY
from fitting.synth.generate import default_cases, simulate, write_case


def test_cases_cover_the_vocabulary_and_the_honesty_checks():
    cases = default_cases()
    names = {c.name for c in cases}
    for e in VOCABULARY:
        assert f"proto_{e.name}" in names
    for kind in ("proto", "tcpr8"):
        for extra in ("clean", "two_effects", "outside_vocabulary", "outliers", "hardware_two_effects",
                      "pulley_kinematics", "length_gain", "tension_sensor_gain", "attachment_offset"):
            assert f"{kind}_{extra}" in names
    assert sum(1 for c in cases if len(c.expected) == 2) == 4
    hw = {"pulley_kinematics", "length_gain", "tension_sensor_gain", "attachment_offset"}
    for c in cases:  # a hardware effect together with an old one, the new one named first
        if c.name.endswith("hardware_two_effects"):
            assert c.expected[0] in hw and c.expected[1] not in hw
    assert all(not c.explained for c in cases if "outside" in c.name)


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    out = tmp_path_factory.mktemp("clean")
    case = next(c for c in default_cases() if c.name == "proto_clean")
    key = write_case(case, out, n=8, seed=3)
    rb = load_robot(out / "robot.toml")
    return key, rb, load_recordings(out / "recordings.csv", rb)


@pytest.mark.slow  # diagnosis compile (~1 min)
def test_files_load_and_clean_data_fit_the_nominal_model(clean):
    key, rb, rec = clean
    assert rec.num_samples == 8 and rec.has_tensions and "temperature" in rec.covariate_names
    assert key["expected"] == [] and key["outliers"] == []
    assert np.all(np.diff(np.asarray(rec.time)) > 0)
    z = []
    for i in range(rec.num_samples):  # forward statics of the nominal robot: residual = the noise
        fs = fwd.forward_statics(StaticsProblem(rb, rec.l0[i], rec.wrench[i], CableLaw.spring), pose0=rec.pose[i])
        z.append(np.asarray(rec.pose[i, :3] - fs.pose[:3]) / float(rb.noise.position))
        z.append(np.asarray(rec.tensions[i] - fs.tensions) / float(rb.noise.tension))
        assert np.all(np.asarray(fs.tensions) > 20.0)
    z = np.concatenate(z)
    k = z.size  # 8 x (3 + 6) = 72 unit normals: Σz² ~ χ²_k (mean k, sd √(2k) = 12)
    assert k == 72
    assert k - 3 * np.sqrt(2 * k) < np.sum(z**2) < k + 3 * np.sqrt(2 * k)  # noise-free or doubled noise fail
    assert abs(np.mean(z)) < 3 / np.sqrt(k)  # unbiased


@pytest.mark.slow
def test_concealed_bias_and_outliers_are_where_the_key_says():
    case = next(c for c in default_cases() if c.name == "proto_tension_sensor_bias")
    _rb, cols, bad = simulate(case, n=6, seed=5)
    clean_case = next(c for c in default_cases() if c.name == "proto_clean")
    _, cols0, _ = simulate(clean_case, n=6, seed=5)  # same seed: same poses, loads and noise
    diff = np.stack([cols[f"t_{i + 1}"] - cols0[f"t_{i + 1}"] for i in range(6)], 1)
    np.testing.assert_allclose(diff, np.broadcast_to(case.truth["tension_sensor_bias"]["bias"], diff.shape), atol=1e-9)
    out_case = next(c for c in default_cases() if c.name == "proto_outliers")
    _, _cols2, bad = simulate(out_case, n=12, seed=5)
    assert len(bad) == 3 and all(6 <= r <= 12 for r in bad)


def test_cli_entry_point(tmp_path, capsys):
    assert cli(["generate", "--list"]) == 0
    assert "proto_cable_mass" in capsys.readouterr().out
    assert cli(["generate", "--oov", "--list"]) == 0
    oov = capsys.readouterr().out.split()
    assert "proto_clean" in oov and "proto_cable_mass" not in oov
    assert cli(["generate", "--out", str(tmp_path), "--cases", "proto_gremlins"]) == 1
    assert "unknown case(s) ['proto_gremlins']" in capsys.readouterr().err
    assert cli(["generate", "--cases", "proto_clean"]) == 1  # no --out
    assert "--out DIR is required" in capsys.readouterr().err
    (tmp_path / "afile").write_text("x")
    assert cli(["generate", "--out", str(tmp_path / "afile"), "--cases", "proto_clean"]) == 1
    assert not list(tmp_path.glob("afile/*"))


@pytest.mark.slow  # cold generator statics (~1 min)
def test_concealed_gains_are_written_out_as_formats_defines():
    """Same seed as the clean case (same poses, loads, noise): a load-cell gain scales the
    true tension and leaves the pose alone; a winch gain leaves the first sample (l0_ref)
    where it was and moves the others."""
    cases = {c.name: c for c in default_cases()}
    _, c0, _ = simulate(cases["proto_clean"], n=6, seed=5)
    _, cg, _ = simulate(cases["proto_tension_sensor_gain"], n=6, seed=5)
    g = np.asarray(cases["proto_tension_sensor_gain"].truth["tension_sensor_gain"]["gain"])
    t0 = np.stack([c0[f"t_{i + 1}"] for i in range(6)], 1)
    tg = np.stack([cg[f"t_{i + 1}"] for i in range(6)], 1)
    # reading - clean reading = (g - 1) x true tension; the true tension is the clean reading within 4 σ
    assert np.all(np.abs((tg - t0) - (g - 1) * t0) < (g - 1) * 4 * 0.3 + 1e-9)
    assert np.all(np.abs(g - 1) > 1e-3) and np.all(np.abs(tg - t0) > 0.5 * np.abs(g - 1) * t0)  # it really moved
    np.testing.assert_array_equal(cg["x"], c0["x"])
    _, cl, _ = simulate(cases["proto_length_gain"], n=6, seed=5)
    np.testing.assert_allclose([cl[k][0] for k in "xyz"], [c0[k][0] for k in "xyz"], atol=1e-12)
    assert np.max(np.abs(cl["x"][1:] - c0["x"][1:])) > 1e-4  # a 0.3-2 % gain moves the platform


def test_case_data_do_not_depend_on_the_other_cases_and_earlier_keys_are_merged(tmp_path, capsys):
    import json

    from cstiffjax.commands.common import EXIT_USAGE
    from fitting.synth.generate import case_seed

    alone, both = tmp_path / "alone", tmp_path / "both"
    assert cli(["generate", "--out", str(alone), "--samples", "3", "--seed", "5", "--quiet",
                "--cases", "proto_anchor_offset"]) == 0
    out = capsys.readouterr().out
    assert f"wrote {alone / 'key.json'}: 1 cases" in out and "proto_anchor_offset" in out
    assert cli(["generate", "--out", str(both), "--samples", "3", "--seed", "5", "--quiet",
                "--cases", "proto_clean", "proto_anchor_offset"]) == 0  # proto_clean comes first in the list
    csv = "proto_anchor_offset/recordings.csv"
    assert (alone / csv).read_text() == (both / csv).read_text()  # its place in --cases does not matter
    key = json.loads((alone / "key.json").read_text())
    assert key[0]["seed"] == case_seed(5, "proto_anchor_offset") and key[0]["base_seed"] == 5
    assert len({case_seed(5, "a"), case_seed(5, "b"), case_seed(6, "a")}) == 3
    assert case_seed(5, "a") == case_seed(5, "a") and 0 <= case_seed(5, "a") < 2**48
    capsys.readouterr()
    # a second run into the same folder adds its cases to the key; a case made again replaces its entry
    assert cli(["generate", "--out", str(alone), "--samples", "4", "--seed", "5", "--quiet",
                "--cases", "proto_clean", "proto_anchor_offset"]) == 0
    out = capsys.readouterr().out
    assert f"replaced proto_anchor_offset (earlier: seed {case_seed(5, 'proto_anchor_offset')}, 3 samples)" in out
    key = {k["case"]: k for k in json.loads((alone / "key.json").read_text())}
    assert set(key) == {"proto_clean", "proto_anchor_offset"} and key["proto_anchor_offset"]["samples"] == 4
    assert cli(["generate", "--out", str(alone), "--samples", "3", "--seed", "5", "--quiet",
                "--cases", "proto_clean"]) == 0
    key = {k["case"]: k for k in json.loads((alone / "key.json").read_text())}
    assert set(key) == {"proto_clean", "proto_anchor_offset"} and (alone / csv).exists()  # the other case kept
    assert key["proto_anchor_offset"]["samples"] == 4 and key["proto_clean"]["samples"] == 3
    assert "1 kept from the earlier key" in capsys.readouterr().out
    (alone / "key.json").write_text('{"not": "a key"}')
    assert cli(["generate", "--out", str(alone), "--samples", "3", "--quiet", "--cases", "proto_clean"]) == EXIT_USAGE
    assert f"{alone / 'key.json'}: not an answer key written by cstiffjax generate" in capsys.readouterr().err
