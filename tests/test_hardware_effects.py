"""The four cable-hardware effects of the diagnosis (formats.md §3 v2): names against
the contract's table, identity at the null value, the autodiff Jacobian against finite
differences, each effect's prediction against the nominal model of a robot built by hand
with the formats.md definitions written out, the assumed swivel axes, and the
generator's concealed hardware at the true parameters explained by the effect model down
to the noise (the generator writes its physics out independently of the effect code)."""

import dataclasses
import re
from pathlib import Path

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

from cstiffjax import load_recordings, load_robot
from cstiffjax.examples import example_path
from fitting.effects import (
    EFFECTS,
    VOCABULARY,
    AttachmentOffset,
    LengthGain,
    PulleyKinematics,
    TensionSensorGain,
    build_data,
    make_model,
)
from fitting.effects import model as M
from fitting.synth.generate import default_cases, nominal_robot, simulate

FORMATS = Path(__file__).resolve().parents[1] / "cstiffjax" / "io" / "formats.md"  # the package's copy of the contract
HARDWARE = (PulleyKinematics(), LengthGain(), TensionSensorGain(), AttachmentOffset())
N = 6


@pytest.fixture(scope="module")
def setup():
    rb = dataclasses.replace(load_robot(example_path("example02/robot.toml")), name="robot")
    rec = load_recordings(example_path("example02/recordings.csv"), rb).select(np.arange(N))
    data = build_data(rec)
    return rb, rec, data, make_model(rb, data, HARDWARE), make_model(rb, data, [])


def _theta(model, values):
    """θ of ``model`` with the physical ``values`` {(effect, param): array} set, the rest null."""
    phys = np.asarray(model.null).copy()
    for i, name, off, shape, _ in model.blocks:
        key = (model.effects[i].name, name)
        if key in values:
            phys[off:off + int(np.prod(shape, dtype=int))] = np.ravel(values[key])
    return jnp.asarray((phys - np.asarray(model.null)) / np.asarray(model.scale))


def test_names_follow_the_formats_table():
    """The JSON names and the table of formats.md §3 (read from the contract itself)."""
    text = FORMATS.read_text()
    table = text[text.index("| effect | physics the nominal model left out"):]
    names = re.findall(r"^\| `([a-z_]+)` \|", table.split("\n\n")[0], flags=re.M)
    assert names == [e.name for e in VOCABULARY]
    assert names[-4:] == ["pulley_kinematics", "length_gain", "tension_sensor_gain", "attachment_offset"]
    assert set(EFFECTS) == set(names)


def test_null_is_the_nominal_model(setup):
    rb, _rec, data, model, empty = setup
    r_hw, ok_hw = M.residuals_only(model, jnp.zeros(model.size), rb, data)
    r_0, ok_0 = M.residuals_only(empty, jnp.zeros(empty.size), rb, data)
    assert bool(ok_hw.all()) and bool(ok_0.all())
    # a plain description: the pulley formula at radius 0 is the straight cable to rounding
    # (~1e-14 m of length, times EA/l = 2.5e5 N/m: ~1e-9 σ of tension)
    np.testing.assert_allclose(np.asarray(r_hw), np.asarray(r_0), rtol=0, atol=1e-7)
    model_g = make_model(rb, data, HARDWARE[1:])  # gains and attachments: exactly the nominal robot
    p = model_g.unpack(jnp.zeros(model_g.size))
    for e, pe in zip(model_g.effects, p):
        out = e.robot(rb, pe)
        for f in ("anchors", "attachments", "length_gain", "tension_gain", "pulley_radius", "pulley_axis"):
            np.testing.assert_array_equal(np.asarray(getattr(out, f)), np.asarray(getattr(rb, f)), err_msg=f)


def test_stated_hardware_is_the_null(setup):
    """A description that states pulleys and gains: the null values are the stated ones."""
    rb, _rec, data, _, _ = setup
    ax = np.zeros((6, 3))
    ax[:, 2] = 1.0
    stated = eqx.tree_at(lambda r: (r.pulley_radius, r.pulley_axis, r.length_gain, r.tension_gain), rb,
                         (jnp.full(6, 0.02), jnp.asarray(ax), jnp.full(6, 1.01), jnp.full(6, 0.99)))
    model = make_model(stated, data, HARDWARE)
    assert [b[1] for b in model.blocks] == ["radius_change", "gain", "gain", "offset"]
    for e, pe in zip(model.effects, model.unpack(jnp.zeros(model.size))):
        out = e.robot(stated, pe)
        for f in ("attachments", "length_gain", "tension_gain", "pulley_radius", "pulley_axis"):
            np.testing.assert_array_equal(np.asarray(getattr(out, f)), np.asarray(getattr(stated, f)), err_msg=f)
    assert model.effects[0].note(stated, data) is None  # nothing assumed


def test_jacobian_matches_finite_differences(setup):
    rb, _rec, data, model, _ = setup
    rng = np.random.default_rng(3)
    theta = np.asarray(_theta(model, {("pulley_kinematics", "radius"): 0.02})) + \
        np.r_[np.zeros(7), rng.normal(0, 0.5, model.size - 7)]  # every effect on
    _r, J, ok = (np.asarray(a) for a in M.residuals_and_jacobian(model, jnp.asarray(theta), rb, data))
    assert ok.all()
    h = 1e-4  # θ is O(1): gains 1e-2 per unit, radius 1 cm, offsets 1 mm
    for i in range(6, model.size):  # the hardware parameters (after the 6 EA log-scales)
        tp, tm = theta.copy(), theta.copy()
        tp[i] += h
        tm[i] -= h
        fd = (np.asarray(M.residuals_only(model, jnp.asarray(tp), rb, data)[0])
              - np.asarray(M.residuals_only(model, jnp.asarray(tm), rb, data)[0])).ravel() / (2 * h)
        assert np.abs(fd).max() > 1.0, f"θ[{i}] has no effect"
        np.testing.assert_allclose(J[:, i], fd, atol=1e-5 * (1 + np.abs(fd).max()), err_msg=f"θ[{i}]")


def test_predictions_against_hand_built_robots(setup):
    """Each effect at a non-null value against the nominal model of the robot written out
    by hand: pulleys with +z axes (all six anchors are above the platform) and moved
    attachments on the robot, formats.md §1's winch formula ``l0_ref + g (l0 - l0_ref)``
    applied to the recorded lengths, and the readings divided by the load-cell gain (the
    tension residual then shrinks by that gain). The engine's pulley physics itself is
    checked against closed forms and finite differences in test_hardware/test_pulley."""
    rb, _rec, data, model, empty = setup
    g_len = np.linspace(0.985, 1.02, 6)
    g_ten = np.linspace(1.02, 0.99, 6)
    off = np.random.default_rng(0).uniform(-3e-3, 3e-3, (6, 3))
    th = _theta(model, {("pulley_kinematics", "radius"): 0.025, ("length_gain", "gain"): g_len,
                        ("tension_sensor_gain", "gain"): g_ten, ("attachment_offset", "offset"): off})
    r, ok = M.residuals_only(model, th, rb, data)
    ax = np.zeros((6, 3))
    ax[:, 2] = 1.0
    true = eqx.tree_at(lambda r: (r.pulley_radius, r.pulley_axis, r.attachments), rb,
                       (jnp.full(6, 0.025), jnp.asarray(ax), rb.attachments + off))
    l0 = np.asarray(data.l0)
    hand = dataclasses.replace(data, l0=jnp.asarray(l0[0] + g_len * (l0 - l0[0])),
                               tensions=data.tensions / jnp.asarray(g_ten))
    r_hand, ok_hand = M.residuals_only(empty, jnp.zeros(empty.size), true, hand)
    assert bool(ok.all()) and bool(ok_hand.all())
    r, r_hand = np.asarray(r), np.asarray(r_hand)
    np.testing.assert_allclose(r[:, :6], r_hand[:, :6], rtol=1e-9, atol=1e-6)
    np.testing.assert_allclose(r[:, 6:], g_ten * r_hand[:, 6:], rtol=1e-9, atol=1e-6)
    r_null = np.asarray(M.residuals_only(model, jnp.zeros(model.size), rb, data)[0])
    assert np.abs(r - r_null).max() > 100.0  # the hardware moves the prediction by far more than σ: power


def test_assumed_axes_follow_the_workspace_centre(setup):
    rb, _rec, data, model, _ = setup
    pk = model.effects[0]
    assert pk.signs == (1.0,) * 6  # proto: every anchor (z 3.8-4.2 m) above the platform (z ~0.5 m)
    note = pk.note(rb, data)
    assert "assumes vertical swivel axes" in note and "cables 1, 2, 3, 4, 5, 6; -z for those below: none" in note
    tc = nominal_robot("tcpr8")
    d8 = dataclasses.replace(data, pose=jnp.zeros((N, 6)).at[:, 2].set(0.83), l0=jnp.zeros((N, 8)))
    pk8 = PulleyKinematics().bind(tc, d8)
    assert pk8.signs == (1.0,) * 4 + (-1.0,) * 4  # top anchors z = 1.78 m up, floor anchors z = 0 down
    assert "cables 1, 2, 3, 4; -z for those below: cables 5, 6, 7, 8" in pk8.note(tc, d8)
    with pytest.raises(ValueError, match="not bound"):
        PulleyKinematics().robot(rb, {"radius": jnp.asarray(0.0)})


# one case fast (the generator's compile is shared with test_generate's clean case), the rest slow
CASES = [pytest.param("proto_pulley_kinematics", marks=pytest.mark.slow),
         pytest.param("proto_length_gain", marks=pytest.mark.slow), "proto_tension_sensor_gain",
         pytest.param("proto_attachment_offset", marks=pytest.mark.slow)]


@pytest.mark.slow  # cold generator statics per case (~45 s)
@pytest.mark.parametrize("name", CASES)
def test_generated_hardware_is_explained_at_the_truth(setup, name):
    """The generator's concealed hardware (written out in fitting.synth.generate) and the effect
    model at the true parameters: χ² of the residuals is that of the noise; at the null
    value it is far above (the recordings carry the effect)."""
    rb, _rec, _data, model, _ = setup
    case = next(c for c in default_cases() if c.name == name)
    nominal, cols, _ = simulate(case, n=N, seed=4)
    np.testing.assert_array_equal(np.asarray(nominal.anchors), np.asarray(rb.anchors))  # same frame
    rb = dataclasses.replace(nominal, name="robot")  # the generator's nominal description (same shapes)
    rec = _recordings(cols, 6)
    data = build_data(rec)
    (effect, params), = case.truth.items()
    param = {"pulley_kinematics": "radius", "attachment_offset": "offset"}.get(effect, "gain")
    r_true = np.asarray(M.residuals_only(model, _theta(model, {(effect, param): params[param]}), rb, data)[0])
    r_null = np.asarray(M.residuals_only(model, jnp.zeros(model.size), rb, data)[0])
    k = N * (6 + 6)  # unit normals: χ²_k, mean 72, sd 12
    assert k - 4 * np.sqrt(2 * k) < np.sum(r_true**2) < k + 4 * np.sqrt(2 * k)
    assert np.sum(r_null**2) > 20 * k


def _recordings(cols, m):
    from cstiffjax.io.recordings import Recordings

    n = len(cols["x"])
    col = lambda *names: np.stack([cols[c] for c in names], 1)  # noqa: E731
    ten = col(*(f"t_{i}" for i in range(1, m + 1)))
    return Recordings(l0=jnp.asarray(col(*(f"l0_{i}" for i in range(1, m + 1)))),
                      wrench=jnp.asarray(col("fx", "fy", "fz", "mx", "my", "mz")),
                      pose=jnp.asarray(col("x", "y", "z", "rx", "ry", "rz")), tensions=jnp.asarray(ten),
                      tension_mask=jnp.ones((n, m), dtype=bool), moment=jnp.zeros((n, 3)),
                      time=jnp.asarray(cols["time"]), covariates=jnp.zeros((n, 0)), source="<generated>")
