"""Static pose error with sagging cables (cstiffjax.sag) on the seed 003 prototype.

One compiled batch of 4 poses is shared by every test (compiling the nested statics
solves dominates the run time); the 8 mm robot reuses it by swapping EA and mass.
"""

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

import cstiffjax
from cstiffjax import sag, statics
from cstiffjax.examples import example_path


@pytest.fixture(scope="module")
def robots():
    r4 = cstiffjax.load_robot(example_path("prototype_4mm.toml"))
    r8 = cstiffjax.load_robot(example_path("prototype_8mm.toml"))
    # same static name => same compiled code
    r8 = eqx.tree_at(lambda r: (r.EA, r.mass_per_length), r4, (r8.EA, r8.mass_per_length))
    return r4, r8


@pytest.fixture(scope="module")
def grid_4(robots):
    """2x2 workspace corners plus nothing else: batch of 4 poses, no external load."""
    poses = sag.workspace_grid([-0.5, 0.5], [-0.5, 0.5], 0.5).reshape(-1, 6)
    return poses, sag.pose_error_batch(robots[0], poses, jnp.zeros((4, 6)))


def test_examples_match_table_2(robots):
    r4, r8 = robots
    np.testing.assert_allclose(np.asarray(r4.EA), 19.9e9 * np.pi * 0.004**2 / 4, rtol=1e-5)
    np.testing.assert_allclose(np.asarray(r8.EA), 20.1e9 * np.pi * 0.008**2 / 4, rtol=1e-5)
    assert float(r4.mass_per_length[0]) == 0.067 and float(r8.mass_per_length[0]) == 0.251


@pytest.mark.slow  # compiles the nested catenary statics (~1-2 min)
def test_grid_converges_and_split_adds_up(grid_4):
    poses, pe = grid_4
    assert np.all(np.asarray(pe.converged))
    # the ideal model returns the reference pose, and l0 are the straight lengths there
    np.testing.assert_allclose(np.asarray(pe.pose_ideal), np.asarray(poses))
    # position errors add exactly: total = axial + sag
    np.testing.assert_allclose(np.asarray(pe.error_catenary[:, :3]),
                               np.asarray(pe.error_axial[:, :3] + pe.error_sag[:, :3]), atol=1e-12)
    # axial elasticity lowers the hanging platform; sag (chord shorter than cable) lifts it
    assert np.all(np.asarray(pe.error_axial[:, 2]) < 0)
    assert np.all(np.asarray(pe.error_sag[:, 2]) > 0)


@pytest.mark.slow
def test_grid_8mm_converges_and_sag_dominates(robots, grid_4):
    """Seed 003 §5: with 8 mm cables the sag-introduced z error dominates; with 4 mm the axial one."""
    poses, pe4 = grid_4
    pe8 = sag.pose_error_batch(robots[1], poses, jnp.zeros((4, 6)))
    assert np.all(np.asarray(pe8.converged))
    assert np.all(np.abs(np.asarray(pe8.error_sag[:, 2])) > np.abs(np.asarray(pe8.error_axial[:, 2])))
    assert np.all(np.abs(np.asarray(pe4.error_sag[:, 2])) < np.abs(np.asarray(pe4.error_axial[:, 2])))


@pytest.mark.slow
def test_catenary_equilibrium_is_real(robots, grid_4):
    """Independent check of one converged pose: the net wrench is zero there."""
    _poses, pe = grid_4
    w = statics.elastic_wrench(robots[0], pe.pose_catenary[0], pe.l0[0], None, "catenary")
    assert float(jnp.max(jnp.abs(w))) < 1e-6


@pytest.mark.slow  # nested catenary statics compile (~1 min)
def test_load_sweep_models_meet_at_large_load(robots):
    """Seed 003 Fig. 7: sag matters at small load, spring and sagging models meet at large load."""
    r8 = robots[1]
    pose = jnp.array([0.0, 0.0, 0.5, 0, 0, 0])
    masses = jnp.array([10.0, 30.0, 86.0, 300.0])
    ext = sag.vertical_loads(r8, masses)
    pe = sag.pose_error_batch(r8, jnp.broadcast_to(pose, (4, 6)), ext)
    assert np.all(np.asarray(pe.converged))
    ez_sag = np.abs(np.asarray(pe.error_sag[:, 2]))
    ez_axial = np.abs(np.asarray(pe.error_axial[:, 2]))
    assert np.all(np.diff(ez_sag) < 0)  # the sag part shrinks as the load grows
    assert ez_sag[0] > ez_axial[0]  # ... dominates at 10 kg
    assert ez_sag[-1] / np.abs(np.asarray(pe.error_catenary[-1, 2])) < ez_sag[0] / np.abs(
        np.asarray(pe.error_catenary[0, 2]))


def test_impossible_load_reports_non_convergence(robots):
    """An upward load larger than the weight cannot be held by cables: not converged, no garbage."""
    r4 = robots[0]
    pose = jnp.array([0.0, 0.0, 0.5, 0, 0, 0])
    ext = jnp.zeros((4, 6)).at[0, 2].set(3000.0)
    pe = sag.pose_error_batch(r4, jnp.broadcast_to(pose, (4, 6)), ext)
    conv = np.asarray(pe.converged)
    assert not conv[0] and np.all(conv[1:])


@pytest.mark.slow
def test_sagging_inverse_statics(robots):
    r4 = robots[0]
    pose = jnp.array([0.0, 0.0, 0.5, 0, 0, 0])
    inv = sag.sagging_inverse_statics(r4, pose)
    # equilibrium with catenary cables at exactly this pose
    w = statics.elastic_wrench(r4, pose, inv.l0, None, "catenary")
    assert float(jnp.max(jnp.abs(w))) < 1e-6
    # forward statics from those lengths returns the pose
    fs = statics.forward_statics(r4, inv.l0, None, pose, law="catenary")
    np.testing.assert_allclose(np.asarray(fs.pose), np.asarray(pose), atol=1e-8)
    # Table 2 (4 mm set) lengths are within 25 mm of ours (paper: measured cut lengths)
    table = np.array([6863, 6565, 6756, 6663, 6801, 6604]) / 1000
    assert np.max(np.abs(np.asarray(inv.l0) - table)) < 0.05


@pytest.mark.slow
def test_catenary_robot_stiffness_vs_fd(robots, grid_4):
    """stiffness_from_lengths(law="catenary") (autodiff through the catenary solves) vs FD."""
    import jax

    from cstiffjax.stiffness import stiffness_from_lengths

    _, pe = grid_4
    r4, pose, l0 = robots[0], pe.pose_catenary[0], pe.l0[0]
    K = np.asarray(stiffness_from_lengths(r4, pose, l0, law="catenary"))
    W = jax.jit(lambda p: statics.elastic_wrench(r4, p, l0, None, "catenary"))
    h = 1e-6
    fd = np.stack([-(np.asarray(W(statics.apply_twist(pose, h * e))) - np.asarray(W(statics.apply_twist(pose, -h * e))))
                   / (2 * h) for e in np.eye(6)], -1)
    np.testing.assert_allclose(K, fd, rtol=1e-5, atol=1e-6 * np.abs(K).max())
    # at equilibrium with no external moment K is symmetric (stiffness module docstring)
    np.testing.assert_allclose(K, K.T, atol=1e-6 * np.abs(K).max())


@pytest.mark.slow
def test_cli_sag(tmp_path, capsys):
    from cstiffjax.cli import main

    rc = main(["sag", "prototype_4mm.toml", "--pose", "0", "0", "0.5", "0", "0", "0", "--load-sweep",
               "--masses", "20", "60", "--out", str(tmp_path)])
    out = capsys.readouterr().out
    assert rc == 0
    assert "sag-introduced" in out and "sagging inverse statics (ok)" in out
    assert (tmp_path / "load_sweep.png").stat().st_size > 1000
    assert (tmp_path / "sag.json").exists()
