"""The public API's answers to misuse: wrong shapes and types named at the entry point, a failed
``throw=True`` solve raised as ``cj.SolverError`` with its status text, a NaN pose's structure
matrix NaN, and a batch of forward-statics problems solved as the problems one by one.
References: numpy written here (the structure matrix ``[u; r x u]``, the spring law's net
wrench) and the single-problem solves."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import cstiffjax as cj
import fitting
from cstiffjax.core.status import Status, code, message, readable_errors, to_codes
from cstiffjax.examples import example_path
from cstiffjax.statics.batch import first_failure
from tests.helpers import eight_cable_robot, lab_robot, np_cables, np_frame, np_spring_wrench

ROBOT, REC = lab_robot("example02")  # 6 cables
ROBOT8 = eight_cable_robot()
POSE = jnp.array([0.1, -0.05, 0.5, 0.02, -0.01, 0.03])
L0 = jnp.asarray(REC.l0[:2])  # (2, 6): two problems
SOLVE = dict(pose0=jnp.asarray(REC.pose[:2]), start="warm")  # one start per problem
ROBOT_FILE = str(example_path("example02/robot.toml"))
REC_FILE = str(example_path("example02/recordings.csv"))


def _problem(l0, external=None):
    return cj.StaticsProblem(ROBOT, l0, external)


MISUSE = {
    # (4) a pose of 5 or 7 numbers, named where it enters
    "inverse_statics pose (5,)": (lambda: cj.inverse_statics(ROBOT, jnp.zeros(5)), ValueError,
                                  r"^inverse_statics: pose has shape \(5,\); one pose \[x, y, z, rx, ry, rz\]"),
    "inverse_statics pose (7,)": (lambda: cj.inverse_statics(ROBOT, jnp.zeros(7)), ValueError,
                                  r"^inverse_statics: pose has shape \(7,\)"),
    "cable_lengths pose (5,)": (lambda: cj.cable_lengths(ROBOT, [0.0] * 5), ValueError,
                                r"^cable_lengths: pose has shape \(5,\)"),
    "cable_lengths pose (7,)": (lambda: cj.cable_lengths(ROBOT, jnp.zeros(7)), ValueError,
                                r"^cable_lengths: pose has shape \(7,\)"),
    "structure_matrix poses (2, 6)": (lambda: cj.structure_matrix(ROBOT, jnp.zeros((2, 6))), ValueError,
                                      r"^structure_matrix: pose has shape \(2, 6\).*vmap for a batch"),
    "gravity_wrench pose (3,)": (lambda: cj.gravity_wrench(ROBOT, jnp.zeros(3)), ValueError,
                                 r"^gravity_wrench: pose has shape \(3,\)"),
    "inverse_statics external (5,)": (lambda: cj.inverse_statics(ROBOT, POSE, jnp.zeros(5)), ValueError,
                                      r"^external wrench has shape \(5,\); \[fx, fy, fz, mx, my, mz\]"),
    "feasible_tensions pose (7,)": (lambda: cj.feasible_tensions(ROBOT, jnp.zeros(7)), ValueError,
                                    r"pose has shape \(7,\)"),
    "stiffness pose (5,)": (lambda: cj.stiffness(ROBOT, jnp.zeros(5), jnp.ones(6)), ValueError,
                            r"^stiffness: pose has shape \(5,\) and tensions \(6,\)"),
    "stiffness tensions (7,)": (lambda: cj.stiffness(ROBOT, POSE, jnp.ones(7)), ValueError,
                                r"^stiffness: .* tensions \(\.\.\., 6\) with the same leading axes"),
    "forward_statics pose0 (5,)": (lambda: cj.forward_statics(_problem(L0[0]), pose0=jnp.zeros(5), start="warm"),
                                   ValueError, r"^forward statics \(pose0\): pose has shape \(5,\)"),
    # (5) batches: what does not match is named
    "batch axes that do not broadcast": (lambda: _problem(L0, jnp.zeros((3, 6))), ValueError,
                                         r"batch axes of l0 \(2, 6\) and external \(3, 6\) do not broadcast"),
    "pose0 of another batch": (lambda: cj.forward_statics(_problem(L0), pose0=jnp.zeros((3, 6)), start="warm"),
                               ValueError, r"pose0 has shape \(3, 6\); \(6,\) \(shared by the batch\) or \(2, 6\)"),
    # (3) a failed throw=True solve: SolverError with the status text only
    "forward_statics failure": (lambda: cj.forward_statics(_problem(-L0[0])), cj.SolverError,
                                "^" + message(Status.invalid_input).replace("(", r"\(").replace(")", r"\)") + "$"),
    "forward_statics failure in a batch": (lambda: cj.forward_statics(_problem(L0.at[1, 0].set(-1.0))),
                                           cj.SolverError, r"^invalid input \(non-positive length"),
    "inverse_statics failure": (lambda: cj.inverse_statics(ROBOT, POSE.at[2].set(9.0)), cj.SolverError,
                                r"^no cable tensions within \[tension_min, tension_max\] hold this pose"),
    "stiffness failure": (lambda: cj.stiffness(ROBOT, POSE.at[0].set(jnp.nan), jnp.ones(6)), cj.SolverError,
                          r"^invalid input"),
    # (6) fitting's entry points check their arguments as calibrate does
    "diagnose robot8 rec6": (lambda: fitting.diagnose(ROBOT8, REC), ValueError,
                             r"^diagnose: recordings have 6 cables .* robot 'box8' has 8; load them with this robot"),
    "diagnose robot file name": (lambda: fitting.diagnose(ROBOT_FILE, REC), TypeError,
                                 r"^diagnose: robot must be a CableRobot .*got str: load it first, "
                                 r"cstiffjax.load_robot\('.*robot.toml'\)"),
    "diagnose recordings file name": (lambda: fitting.diagnose(ROBOT, REC_FILE), TypeError,
                                      r"^diagnose: recordings must be a Recordings, got str: load them first"),
    "calibrate robot file name": (lambda: fitting.calibrate(ROBOT_FILE, REC), TypeError,
                                  r"^calibrate: robot must be a CableRobot"),
    "calibrate robot8 rec6": (lambda: fitting.calibrate(ROBOT8, REC), ValueError,
                              r"^calibrate: recordings have 6 cables"),
}


@pytest.mark.parametrize("case", list(MISUSE))
def test_misuse_is_named_at_the_entry_point(case):
    call, error, pattern = MISUSE[case]
    with pytest.raises(error, match=pattern) as info:
        call()
    assert "EquinoxRuntimeError" not in str(info.value) and "CpuCallback" not in str(info.value)


def test_a_solver_error_under_your_own_jit_carries_the_text():
    """Under the caller's jax.jit the failure surfaces outside the solver (JAX's error with the
    text); readable_errors turns it into the SolverError."""
    f = jax.jit(lambda l0: cj.forward_statics(_problem(l0)).pose)
    assert np.all(np.isfinite(np.asarray(f(L0[0]))))
    with pytest.raises((RuntimeError, ValueError), match="invalid input") as info:  # XLA raises either
        f(-L0[0])
    assert not isinstance(info.value, cj.SolverError)
    with pytest.raises(cj.SolverError, match=r"^invalid input"), readable_errors():
        f(-L0[0])


# ----------------------------------------------------------------------------- (2) NaN pose
def _numpy_structure_matrix(robot, pose):
    """``[u; r x u]`` with scipy's rotation (tests.helpers), unit vectors towards the anchors."""
    r, d, l = np_cables(robot, *np_frame(pose))
    u = d / l[:, None]
    return np.vstack([u.T, np.cross(r, u).T])


@pytest.mark.parametrize("component", [0, 4])
def test_structure_matrix_of_a_nan_pose_is_nan(component):
    S = np.asarray(cj.structure_matrix(ROBOT, POSE))
    np.testing.assert_allclose(S, _numpy_structure_matrix(ROBOT, np.asarray(POSE)), atol=1e-12)
    bad = POSE.at[component].set(jnp.nan)
    assert np.all(np.isnan(np.asarray(cj.structure_matrix(ROBOT, bad))))
    assert np.all(np.isnan(np.asarray(cj.cable_lengths(ROBOT, bad))))


# ----------------------------------------------------------------------------- (5) batches
def test_a_batch_of_problems_is_the_problems_one_by_one():
    ext = jnp.asarray(REC.wrench[:2])
    batch = cj.forward_statics(_problem(L0, ext), **SOLVE)
    assert batch.pose.shape == (2, 6) and batch.tensions.shape == (2, 6) and batch.forces.shape == (2, 2, 6)
    for i in range(2):
        one = cj.forward_statics(_problem(L0[i], ext[i]), pose0=SOLVE["pose0"][i], start="warm")
        assert one.result == Status.successful
        np.testing.assert_allclose(batch.pose[i], one.pose, atol=1e-12)
        np.testing.assert_allclose(batch.tensions[i], one.tensions, rtol=1e-10)
        res = np_spring_wrench(ROBOT, np.asarray(L0[i]), np.asarray(ext[i]), np.asarray(batch.pose[i]))
        assert np.max(np.abs(res)) < 1e-6 * (np.linalg.norm(np.asarray(ROBOT.weight)) + 1.0)
    # one set of lengths and one start shared by two wrenches: broadcast
    shared = cj.forward_statics(_problem(L0[0], jnp.stack([ext[0], ext[0]])), pose0=SOLVE["pose0"][0], start="warm")
    np.testing.assert_allclose(shared.pose, np.stack([batch.pose[0]] * 2), atol=1e-12)
    # without throw each problem keeps its own status; the first failure is what a throw raises
    bad = cj.forward_statics(_problem(L0.at[1, 0].set(-1.0), ext), throw=False, **SOLVE)
    assert [int(c) for c in to_codes(bad.result)] == [code(Status.successful), code(Status.invalid_input)]
    assert first_failure(bad.result) == Status.invalid_input
