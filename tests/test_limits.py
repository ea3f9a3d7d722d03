"""Limits: no deadlock on large batches (the statics' small linear solves make no LAPACK
call, :mod:`cstiffjax.core.linalg`), no silent finite garbage (a non-finite pose or an
attachment on its anchor is a status and a clear command-line error), stiff cables judged
by what float64 resolves (:func:`cstiffjax.statics.forward.wrench_floor`), and the
watchdog of ``benchmarks/bench_limits.py`` (which runs the heavy cases). The 6 000-sample
``cstiffjax fit`` is marked slow (about 40 s on an idle 2-core machine, several minutes
under load)."""

import re
import sys

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from benchmarks.bench_limits import _first_pose, _tensions, cli, environment, ring_robot, run_watched, tiled_recordings
from cstiffjax.cable.laws import CableLaw
from cstiffjax.commands.cli import main
from cstiffjax.core.linalg import solve
from cstiffjax.core.status import Status, to_codes
from cstiffjax.examples import example_path
from cstiffjax.io.robot_io import load_robot
from cstiffjax.statics import forward as fwd
from cstiffjax.statics import geometry
from cstiffjax.statics.sag import pose_error, sagging_inverse_statics
from cstiffjax.stiffness.tensions import feasible_tensions
from tests.helpers import lab_robot


def _fs(robot, l0, external, pose0, law="spring", **options):
    """Forward statics of one sample under the law named ``law``."""
    problem = fwd.StaticsProblem(robot, l0, external, CableLaw.parse(law))
    return fwd.forward_statics(problem, pose0=pose0, **options)

ROBOT, REC = lab_robot("example02")
POSE = jnp.array([3.0, 0.1, 0.5, 0.01, -0.02, 0.03])
NAN_POSE = POSE.at[0].set(jnp.nan)


def on_anchor(robot, cable=0):
    """A pose (no rotation) that puts attachment ``cable`` exactly on its anchor."""
    return jnp.concatenate([robot.anchors[cable] - robot.attachments[cable], jnp.zeros(3)])


# ------------------------------------------------------------------ the small solve
@pytest.mark.parametrize("k", [1, 2, 6, 22])
def test_solve_matches_numpy(k):
    rng = np.random.default_rng(k)
    a = rng.normal(size=(40, k, k))
    if k > 1:
        a[:, 0, 0] = 0.0  # partial pivoting needed
    b = rng.normal(size=(40, k, 3))
    x = np.asarray(jax.vmap(solve)(a, b))
    np.testing.assert_allclose(x, np.linalg.solve(a, b), rtol=1e-9, atol=1e-9 * np.abs(x).max())
    backward = np.abs(a @ x - b).max() / (np.abs(a).max() * np.abs(x).max())
    assert backward < 1e-14
    np.testing.assert_allclose(solve(a[0], b[0, :, 0]), np.linalg.solve(a[0], b[0, :, 0]), rtol=1e-9)


def test_solve_singular_is_not_finite():
    assert not np.all(np.isfinite(np.asarray(solve(jnp.ones((3, 3)), jnp.ones(3)))))


def test_solve_derivatives_match_lapack_solve():
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(6, 6)), rng.normal(size=6)
    da, db = rng.normal(size=(6, 6)), rng.normal(size=6)
    _, mine = jax.jvp(solve, (a, b), (da, db))
    _, ref = jax.jvp(jnp.linalg.solve, (a, b), (da, db))
    np.testing.assert_allclose(mine, ref, rtol=1e-10)


# ------------------------------------------------------------------ no batched LAPACK call
def batched_lapack_calls(text: str) -> list[str]:
    """The LAPACK custom calls of a lowered program that have a batch axis (jaxlib 0.10.2's
    batched kernels, which can deadlock the CPU thread pool)."""
    calls = (re.search(r'custom_call @(lapack_\w+)\(.*num_batch_dims = "([1-9][0-9]*)"', line)
             for line in text.splitlines())
    return [c.group(1) for c in calls if c]


@pytest.mark.parametrize("law,start", [("spring", "warm"), ("catenary", "cold")])
def test_batched_statics_and_derivatives_have_no_batched_lapack_call(law, start):
    """What ``cstiffjax fit`` runs on 6 000 samples (6000 x 6 x 6 float64 = 1.7 MiB, above
    jaxlib's parallel split): the statics of every sample, with tangents in EA."""
    l0, w, p = (jnp.broadcast_to(x[0], (6000, x.shape[1])) for x in (REC.l0, REC.wrench, REC.pose))

    def sample(ea, l, e, q):
        robot = eqx.tree_at(lambda r: r.EA, ROBOT, ea)
        return _fs(robot, l, e, q, law=law, start=start, throw=False).tensions

    basis = jnp.eye(6) * 1e3
    program = jax.jit(jax.vmap(lambda l, e, q: jax.vmap(
        lambda v: jax.jvp(lambda ea: sample(ea, l, e, q), (ROBOT.EA,), (v,))[1])(basis)))
    text = program.lower(l0, w, p).as_text()
    assert not batched_lapack_calls(text)
    assert "lapack_" not in text  # the small solves make no LAPACK call at all


def test_batched_lapack_calls_finds_a_batched_solve():
    text = jax.jit(jax.vmap(jnp.linalg.solve)).lower(jnp.ones((5, 6, 6)), jnp.ones((5, 6))).as_text()
    assert "lapack_dtrsm_ffi" in batched_lapack_calls(text)


@pytest.mark.slow
def test_fit_on_6000_samples_returns(tmp_path):
    """``cstiffjax fit`` on 6 000 samples finishes (it used to stop using CPU after a few
    seconds and never return: a deadlock in jaxlib 0.10.2's batched triangular solve)."""
    rec = tiled_recordings(6000, tmp_path / "recordings.csv")
    out = run_watched(cli("fit", example_path("example02/robot.toml"), rec, "--quiet"), timeout_s=1800, stall_s=60,
                      env=environment(), cwd=tmp_path)
    assert out.how == "exit", f"{out.how} after {out.wall_s:.0f} s (CPU {out.cpu_s:.0f} s)"
    assert out.rc == 0, out.output[-2000:]
    assert re.search(r"chi2/dof = 0\.9", out.output)


# ------------------------------------------------------------------ the watchdog
def test_watchdog_tells_an_idle_process_from_a_busy_one():
    idle = run_watched([sys.executable, "-c", "import time; time.sleep(60)"], timeout_s=60, stall_s=2.0,
                       poll_s=0.1)
    assert idle.how == "hang" and idle.wall_s < 10
    busy = run_watched([sys.executable, "-c", "import time\nt = time.time()\nwhile time.time() - t < 3: pass"],
                       timeout_s=60, stall_s=2.0, poll_s=0.1)
    assert busy.how == "exit" and busy.rc == 0 and busy.cpu_s > 0.1
    late = run_watched([sys.executable, "-c", "while True: pass"], timeout_s=1.5, stall_s=10.0, poll_s=0.1)
    assert late.how == "timeout" and late.rc is None



def test_bench_ring_tensions_balance_within_bounds():
    """The bench's simulated tensions: a redundant ring's balance the weight with every cable
    in [pretension / 4, tension_max / 2] (scipy's linear program, checked here by the
    residual and the bounds); a unique solution above the half is refused."""
    rng = np.random.default_rng(3)
    for m in (7, 16):
        robot = ring_robot(m)
        found = 0  # a redundant ring holds a few per cent of these poses within the bounds
        for _ in range(200):
            pose = np.concatenate([np.array([0, 0, 1.5]) + rng.uniform(-0.3, 0.3, 3), rng.uniform(-0.02, 0.02, 3)])
            S = np.asarray(geometry.structure_matrix_closed_form(robot, pose))
            w = np.asarray(geometry.gravity_wrench(robot, pose))
            t = _tensions(S, w, 200.0, float(robot.tension_max))
            if t is None:
                continue
            found += 1
            assert np.abs(S @ t + w).max() < 1e-6 * np.abs(w).max()
            assert t.min() >= 50.0 - 1e-6 and t.max() <= 0.5 * float(robot.tension_max) + 1e-6
        assert found >= 2, f"{m} cables: {found} of 200 poses"
    S6 = np.asarray(geometry.structure_matrix_closed_form(ring_robot(6), np.array([0, 0, 1.5, 0, 0, 0.0])))
    w6 = np.array([0, 0, -9.81 * 30.0, 0, 0, 0])
    t6 = _tensions(S6, w6, 0.0, 1e4)
    np.testing.assert_allclose(S6 @ t6, -w6, atol=1e-9)
    assert _tensions(S6, w6, 0.0, 2.0 * 0.99 * t6.max()) is None


def test_bench_first_pose_reads_the_pose_columns(tmp_path):
    rec = tmp_path / "r.csv"
    rec.write_text("time,l0_1,x,y,z,rx,ry,rz,t_1\n100,2.5,0.1,-0.2,1.3,0.01,-0.02,0.03,80\n160,2.6,9,9,9,9,9,9,81\n")
    assert _first_pose(rec) == ["0.1", "-0.2", "1.3", "0.01", "-0.02", "0.03"]


# ------------------------------------------------------------------ no silent finite garbage
def test_lengths_at_a_nan_pose_are_nan_and_on_the_anchor_zero():
    assert np.all(np.isnan(np.asarray(geometry.cable_lengths(ROBOT, NAN_POSE))))
    pose = on_anchor(ROBOT)
    lengths = np.asarray(geometry.cable_lengths(ROBOT, pose))
    assert lengths[0] == 0.0 and np.all(lengths[1:] > 0.1)
    # the derivatives stay finite (the safe square root), the zero-length column is zero
    S = np.asarray(geometry.structure_matrix(ROBOT, pose))
    assert np.all(np.isfinite(S)) and np.all(S[:, 0] == 0.0)
    np.testing.assert_allclose(S[:, 1:], np.asarray(geometry.structure_matrix_closed_form(ROBOT, pose))[:, 1:],
                               atol=1e-12)


def test_geometry_status():
    assert geometry.geometry_status(ROBOT, POSE) == Status.successful
    assert geometry.geometry_status(ROBOT, NAN_POSE) == Status.invalid_input
    assert geometry.geometry_status(ROBOT, POSE, jnp.array([0, 0, jnp.inf, 0, 0, 0.0])) == Status.invalid_input
    assert geometry.geometry_status(ROBOT, on_anchor(ROBOT, 3)) == Status.zero_length
    assert geometry.geometry_status(ROBOT, on_anchor(ROBOT, 3).at[2].add(-1e-3)) == Status.successful


def test_inverse_statics_says_invalid_input_not_rank_deficient():
    assert geometry.inverse_statics(ROBOT, POSE, throw=False).result == Status.successful
    assert geometry.inverse_statics(ROBOT, NAN_POSE, throw=False).result == Status.invalid_input
    assert geometry.inverse_statics(ROBOT, on_anchor(ROBOT), throw=False).result == Status.zero_length


def test_feasible_tensions_say_invalid_input():
    robot = load_robot(example_path("tcpr8.toml"))
    pose = jnp.array([0.02, -0.01, 0.83, 0.0, 0.0, 0.0])
    assert feasible_tensions(robot, pose, throw=False).result == Status.successful
    assert feasible_tensions(robot, pose.at[2].set(jnp.nan), throw=False).result == Status.invalid_input
    assert feasible_tensions(robot, on_anchor(robot, 2), throw=False).result == Status.zero_length


def test_sag_functions_say_invalid_input():
    assert sagging_inverse_statics(ROBOT, NAN_POSE, throw=False).result == Status.invalid_input
    pe = pose_error(ROBOT, NAN_POSE)
    assert pe.result_spring == Status.invalid_input and pe.result_catenary == Status.invalid_input
    assert not bool(pe.converged)


def test_forward_statics_with_a_nan_start_pose_is_invalid_input():
    l0, w, p = REC.l0[0], REC.wrench[0], REC.pose[0]
    assert _fs(ROBOT, l0, w, p, start="warm", throw=False).result == Status.successful
    bad = _fs(ROBOT, l0, w, p.at[1].set(jnp.nan), start="warm", throw=False)
    assert bad.result == Status.invalid_input


def test_cli_refuses_a_nan_pose(capsys):
    with pytest.raises(SystemExit) as e:
        main(["sag", "example02/robot.toml", "--pose", "nan", "0", "0.5", "0", "0", "0"])
    assert e.value.code == 1
    assert "argument --pose: 'nan' is not a finite number" in capsys.readouterr().err


def test_cli_refuses_an_attachment_on_its_anchor(capsys):
    pose = [f"{v:.6g}" for v in np.asarray(on_anchor(ROBOT))]
    for command in (["tensions", "example02/robot.toml", "--method", "cfm"], ["sag", "example02/robot.toml"]):
        assert main([*command, "--pose", *pose]) == 1, command
        err = capsys.readouterr().err  # the precise cause, not "outside the frame"
        assert "--pose 5.352 -2.124 4.193 0 0 0: a cable has zero length" in err, command


# ------------------------------------------------------------------ stiff cables
@pytest.mark.parametrize("name", ["example01", "example02", "concealed", "pulleys8"])
def test_wrench_floor_is_far_below_the_tolerance_for_ordinary_cables(name):
    """EA ~ 1e6 N: ``max(tol, floor)`` is ``tol``, every decision as before the floor."""
    robot, rec = lab_robot(name)
    floor = jax.vmap(lambda l, p, w: fwd.wrench_floor(robot, l, p, fwd.wrench_scale(robot, w)))(
        rec.l0, rec.pose, rec.wrench)
    assert float(jnp.max(floor)) < 1e-2 * min(fwd.TOL.values())


@pytest.mark.parametrize("law,start", [("spring", "cold"), ("bilateral", "warm"), ("catenary", "cold")])
@pytest.mark.parametrize("ea", [1e10, 1e12])
def test_stiff_cables_converge(ea, law, start):
    """At EA = 1e10 and 1e12 N float64 cannot balance the wrench to 1e-9: the solves are
    converged to what it resolves (a quarter of the floor at most), and reported so."""
    robot = eqx.tree_at(lambda r: r.EA, ROBOT, jnp.full(6, ea))
    l0, w, p = REC.l0[:4], REC.wrench[:4], REC.pose[:4]
    out = jax.vmap(lambda l, e, q: _fs(robot, l, e, q, law=law, start=start, throw=False))(l0, w, p)
    assert np.all(np.asarray(to_codes(out.result)) == 0)
    scale = jax.vmap(lambda e: fwd.wrench_scale(robot, e))(w)
    floor = jax.vmap(lambda l, q, s: fwd.wrench_floor(robot, l, q, s))(l0, out.pose, scale)
    assert np.all(np.max(np.abs(np.asarray(out.residual)), 1) / np.asarray(scale) < 0.5 * np.asarray(floor))


def test_stiff_cables_still_report_a_solve_that_did_not_converge():
    robot = eqx.tree_at(lambda r: r.EA, ROBOT, jnp.full(6, 1e12))
    far = REC.pose[0].at[0].add(0.2)  # one Newton step of at most 5 cm from 20 cm away
    out = _fs(robot, REC.l0[0], REC.wrench[0], far, start="warm", steps=1, throw=False)
    assert out.result == Status.not_converged


# ------------------------------------------------------------------ sag refuses a pose no tensions hold
def _held_by_lp(robot, pose) -> bool:
    """Independent reference: scipy's linear program (HiGHS) for ``S t = -W``, ``t >= t_min``."""
    from scipy.optimize import linprog

    S = np.asarray(geometry.structure_matrix_closed_form(robot, pose))
    w = np.asarray(geometry.gravity_wrench(robot, pose))
    res = linprog(np.zeros(S.shape[1]), A_eq=S, b_eq=-w, bounds=(float(robot.tension_min), None), method="highs")
    return res.status == 0


def test_sag_hold_check_agrees_with_a_linear_program():
    from cstiffjax.statics.hold import nearest_pulling

    rng = np.random.default_rng(7)
    for m, tmin in ((7, 0.0), (16, 0.0), (8, 150.0)):
        robot = eqx.tree_at(lambda r: r.tension_min, ring_robot(m), jnp.asarray(tmin))
        agree = {True: 0, False: 0}
        poses = [np.array([0, 0, 1.5, 0, 0, 0.0])] + [
            np.concatenate([np.array([0, 0, 1.5]) + rng.uniform(-0.6, 0.6, 3), rng.uniform(-0.3, 0.3, 3)])
            for _ in range(40)]
        for pose in poses:
            t, unbalanced, load = nearest_pulling(robot, pose, None)
            held = unbalanced <= geometry.BALANCE_TOL * (load + 1.0)
            assert held == _held_by_lp(robot, pose), (m, pose)
            assert np.all(t >= float(robot.tension_min))
            agree[held] += 1
        assert agree[True] and agree[False], (m, tmin, agree)  # both answers occur: the check can fail


def test_sag_refuses_a_redundant_pose_no_tensions_hold(tmp_path, capsys):
    from cstiffjax.io.robot_io import save_robot

    save_robot(ring_robot(8), tmp_path / "ring8.toml")
    centre = ["0", "0", "1.5", "0", "0", "0"]
    assert not _held_by_lp(ring_robot(8), np.array([0, 0, 1.5, 0, 0, 0.0]))
    assert main(["sag", str(tmp_path / "ring8.toml"), "--pose", *centre]) == 2
    err = capsys.readouterr().err
    assert "no cable tensions >= 0 N hold this pose" in err and "unbalanced" in err


def test_sag_prints_milli_newton_tensions():
    from cstiffjax.commands.sag import _newtons

    assert _newtons([0.0027021, 81.0549]).split() == ["0.002702", "81.05"]  # not 0.00
