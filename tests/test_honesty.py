"""Honest failure: statuses or errors, never a wrong "ok", a silent NaN or a
false verdict. Physics functions (forward statics, stiffness), readable errors from
inside ``jit``, and the diagnosis on recordings without equilibrium, out of time order
or with dropped rows. Small sizes: 20 samples, the baseline model only (``effects=()``),
compiled functions shared through module fixtures."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cstiffjax.core.errors import DiagnosisError, SolverError
from cstiffjax.core.status import Status, code, describe, error_message, message, readable_errors, to_codes
from cstiffjax.statics import forward as fwd
from cstiffjax.statics import geometry as statics
from cstiffjax.statics.forward import StaticsProblem
from cstiffjax.stiffness.matrix import stiffness
from fitting.diagnosis.diagnose import diagnose
from fitting.diagnosis.report import markdown, validate_diagnosis, write_json
from fitting.diagnosis.sample_checks import no_equilibrium_cause, straight_distances, time_order
from tests.helpers import lab_robot

ROBOT, REC = lab_robot("example02")
POSE = jnp.array([0.1, -0.05, 0.5, 0.02, -0.01, 0.03])


def _with_l0(rec, l0):
    return eqx.tree_at(lambda r: r.l0, rec, jnp.asarray(l0))


# ------------------------------------------------------------------ forward statics
@pytest.fixture(scope="module")
def statics_cases():
    """Forward statics (throw=False) of valid and invalid inputs. Called as test_statics.py
    calls it (same robot, arguments and keywords), so the compiled solve is shared."""
    l0 = np.repeat(np.asarray(REC.l0[:1]), 5, 0)
    w = np.repeat(np.asarray(REC.wrench[:1]), 5, 0)
    l0[1] *= -1.0            # negated lengths: today 'ok' with tensions of -2e6 N
    l0[2, 3] = np.nan        # one NaN length
    l0[3, 0] = 0.0           # a zero length
    w[4, 2] = np.inf         # non-finite wrench
    return [fwd.forward_statics(StaticsProblem(ROBOT, jnp.asarray(a), jnp.asarray(b)), throw=False)
            for a, b in zip(l0, w)]


def test_forward_statics_invalid_input_status(statics_cases):
    assert [describe(s.result) for s in statics_cases] == ["ok"] + [describe(Status.invalid_input)] * 4


def test_forward_statics_valid_input_unchanged(statics_cases):
    """The valid sample still solves: tensions positive and the recorded pose reproduced."""
    assert np.all(np.asarray(statics_cases[0].tensions) > 0)
    np.testing.assert_allclose(statics_cases[0].pose[:3], REC.pose[0, :3], atol=2e-3)


def test_input_status_helper():
    l0 = jnp.asarray(REC.l0[0])
    assert fwd._input_status(l0, None) == Status.successful
    assert fwd._input_status(-l0, None) == Status.invalid_input
    assert fwd._input_status(l0, jnp.array([0, 0, jnp.nan, 0, 0, 0.0])) == Status.invalid_input


# ------------------------------------------------------------------------ stiffness
def _zero_length_pose(robot, cable=0):
    """A pose (no rotation) that puts attachment ``cable`` exactly on its anchor."""
    return jnp.concatenate([robot.anchors[cable] - robot.attachments[cable], jnp.zeros(3)])


@pytest.fixture(scope="module")
def stiffness_batch():
    """Good pose, attachment 1 on its anchor, NaN pose, attachment 1 mm below its anchor."""
    t = jnp.full((4, ROBOT.num_cables), 50.0)
    on_anchor = _zero_length_pose(ROBOT)
    poses = jnp.stack([POSE, on_anchor, POSE.at[1].set(jnp.nan), on_anchor.at[2].add(-1e-3)])
    return jax.jit(jax.vmap(lambda p, tt: stiffness(ROBOT, p, tt, throw=False)))(poses, t)


def test_stiffness_status_at_singular_and_nonfinite_poses(stiffness_batch):
    K, status = stiffness_batch.K, stiffness_batch.result
    codes = [int(v) for v in to_codes(status)]
    assert codes == [code(Status.successful), code(Status.zero_length), code(Status.invalid_input),
                     code(Status.successful)]  # a cable 1 mm long is short, not singular
    assert np.all(np.isfinite(np.asarray(K[0]))) and np.all(np.isfinite(np.asarray(K[3])))
    assert np.all(np.linalg.eigvalsh(0.5 * (K[0, :3, :3] + K[0, :3, :3].T)) > 0)  # a real, stiff pose


@pytest.fixture(scope="module")
def stiffness_jit_throw():
    return jax.jit(lambda p: stiffness(ROBOT, p, jnp.full(ROBOT.num_cables, 50.0)))


def test_stiffness_raises_readable_message_under_jax_jit(stiffness_jit_throw):
    K = stiffness_jit_throw(POSE).K  # valid pose: no error
    assert np.all(np.isfinite(np.asarray(K)))
    with pytest.raises((RuntimeError, ValueError)) as info:  # XLA's wrapper: JaxRuntimeError or ValueError
        stiffness_jit_throw(_zero_length_pose(ROBOT))
    assert message(Status.zero_length) in str(info.value)
    assert error_message(info.value) == message(Status.zero_length)
    with pytest.raises(SolverError, match=r"^a cable has zero length \(its attachment is on its anchor\)"):
        with readable_errors():
            stiffness_jit_throw(_zero_length_pose(ROBOT))


def test_filter_jit_error_is_readable():
    """Under eqx.filter_jit (every entry point) the error carries only the status text."""
    with pytest.raises(RuntimeError) as info:
        fwd.forward_statics(StaticsProblem(ROBOT, -jnp.asarray(REC.l0[0]), REC.wrench[0]))
    assert error_message(info.value) == message(Status.invalid_input)
    assert "CpuCallback" not in str(info.value)


def test_readable_errors_leaves_other_errors_alone():
    with pytest.raises(RuntimeError, match="something else"):
        with readable_errors():
            raise RuntimeError("something else")
    assert error_message(ValueError("plain")) is None


# ------------------------------------------------------------------------- diagnosis
SMALL = REC.select(np.arange(20))


def _small_diagnose(rec, **kw):
    return diagnose(ROBOT, rec, effects=(), posterior_steps=0, **kw)


@pytest.fixture(scope="module")
def partly_failed():
    """Samples 3 and 7 (1-based) with halved lengths: no equilibrium for those two."""
    l0 = np.asarray(SMALL.l0).copy()
    l0[[2, 6]] *= 0.5
    rows = list(range(102, 122))  # pretend file lines, to check they are carried through
    return _small_diagnose(_with_l0(SMALL, l0), rows=rows, dropped_rows=[100, 101])


def test_failed_samples_are_reported(partly_failed, tmp_path):
    d = partly_failed
    assert d.failed_samples == {"count": 2, "samples": [3, 7], "rows": [104, 108]}
    assert d.dropped_rows == {"count": 2, "rows": [100, 101]}
    assert d.explained and 0.5 < d.final["chi2_per_dof"] < 1.5  # the other 18 samples are clean
    doc = write_json(d, tmp_path / "d.json")
    assert doc["failed_samples"]["rows"] == [104, 108] and doc["dropped_rows"]["count"] == 2
    validate_diagnosis(doc)
    md = markdown(d)
    assert "No equilibrium in the nominal model** for 2 of 20 samples (file rows [104, 108])" in md
    assert "**Dropped** 2 invalid row(s)" in md and "[100, 101]" in md


@pytest.mark.parametrize(("key", "value"), [("failed_samples", {"count": 2, "samples": [3], "rows": None}),
                                            ("dropped_rows", {"count": 1, "rows": "7"}),
                                            ("dropped_rows", [7])])
def test_validator_checks_failed_and_dropped(partly_failed, tmp_path, key, value):
    doc = write_json(partly_failed, tmp_path / "d.json")
    doc[key] = value
    with pytest.raises(ValueError, match=key):
        validate_diagnosis(doc)


@pytest.mark.parametrize(("scale", "cause"), [(-1.0, "zero or negative"), (0.5, "shorter than the anchor-attachment"),
                                              (1e3, "wrong units")])
def test_no_verdict_when_most_samples_fail(scale, cause):
    with pytest.raises(DiagnosisError, match=f"no equilibrium for 20 of 20 samples.*{cause}"):
        _small_diagnose(_with_l0(SMALL, np.asarray(SMALL.l0) * scale))


def test_no_equilibrium_cause_on_consistent_lengths():
    msg = no_equilibrium_cause(ROBOT, SMALL, [0, 1])
    assert "robot description itself" in msg



def test_straight_distances_match_cable_lengths():
    """The numpy distances of the cause analysis against cstiffjax's autodiff-ready geometry."""
    ref = np.stack([np.asarray(statics.cable_lengths(ROBOT, p)) for p in SMALL.pose[:3]])
    np.testing.assert_allclose(straight_distances(ROBOT, np.asarray(SMALL.pose[:3])), ref, rtol=1e-12)


def _shuffled(rec):
    order = np.arange(rec.num_samples)
    order[[4, 5]] = order[[5, 4]]
    return rec.select(order)


def test_time_going_backwards_is_an_error_naming_the_row():
    rec = _shuffled(SMALL)
    with pytest.raises(DiagnosisError, match=r"row 7: time .* is earlier than .* at row 6.*--sort-by-time"):
        time_order(rec, rows=list(range(2, 22)))
    with pytest.raises(DiagnosisError, match=r"sample 6: time"):
        _small_diagnose(rec)  # raised before any fit


def test_sort_by_time_restores_the_order():
    rec, rows, was_sorted = time_order(_shuffled(SMALL), sort_by_time=True, rows=list(range(2, 22)))
    assert was_sorted and rows == [2, 3, 4, 5, 7, 6, *range(8, 22)]  # the file lines follow their samples
    np.testing.assert_array_equal(np.asarray(rec.l0), np.asarray(SMALL.l0))
    same, rows2, was = time_order(SMALL)
    assert same is SMALL and rows2 is None and not was


def test_sort_by_time_needs_every_time():
    t = np.asarray(_shuffled(SMALL).time).copy()
    t[10] = np.nan
    rec = eqx.tree_at(lambda r: r.time, _shuffled(SMALL), jnp.asarray(t))
    with pytest.raises(DiagnosisError, match="sample 11: empty time cell"):
        time_order(rec, sort_by_time=True)


@pytest.mark.slow
def test_shuffled_concealed_example_keeps_its_verdict_when_sorted():
    """The bundled concealed set shuffled: an error by default; sorted, exit friction again."""
    from cstiffjax import load_recordings, load_robot
    from cstiffjax.examples import example_path

    robot = load_robot(example_path("concealed/robot.toml"))
    rec = load_recordings(example_path("concealed/recordings.csv"), robot)
    shuffled = rec.select(np.random.default_rng(1).permutation(rec.num_samples))
    with pytest.raises(DiagnosisError):
        diagnose(robot, shuffled)
    d = diagnose(robot, shuffled, sort_by_time=True, posterior_steps=0)
    assert d.sorted_by_time and d.effects == ["exit_friction"]
