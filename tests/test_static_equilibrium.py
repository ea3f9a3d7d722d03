"""Static-equilibrium workspace of robots with fewer than 6 cables, against references that
share no code with the package: the structure matrix and weight in numpy from the anchors,
attachments and a scipy rotation; a linear program per pose and per extreme wrench (scipy
linprog, HiGHS: max δ with tmin + δ <= t <= tmax - δ, the equalities on the span of S by
numpy SVD, the part of the load outside it checked on its own); the equilibrium rotation by
scipy least squares; stability by forward statics from the unstrained lengths of those
tensions; the volume by a hand count of cell weights."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.optimize import least_squares, linprog
from scipy.spatial.transform import Rotation

from cstiffjax.cable.laws import CableLaw
from cstiffjax.commands.cli import main
from cstiffjax.commands.common import EXIT_OK, EXIT_USAGE
from cstiffjax.core.status import Status
from cstiffjax.examples import example_path
from cstiffjax.io.robot import CableRobot, Noise
from cstiffjax.io.robot_io import load_robot
from cstiffjax.statics.forward import StaticsProblem, forward_statics
from cstiffjax.statics.geometry import gravity_wrench, structure_matrix
from cstiffjax.workspace.static_equilibrium import static_equilibrium, tension_margin
from cstiffjax.workspace.sweep import Grid, sweep
from cstiffjax.workspace.wrench_feasible import WrenchSet

LP_OPTIONS = {"primal_feasibility_tolerance": 1e-10, "dual_feasibility_tolerance": 1e-10}
BALANCE = 1e-6  # |S t + W| <= 1e-6 (|W| + 1): an equilibrium (the contract of inverse statics)
ROBOTS = {"suspended3": (load_robot(example_path("suspended3.toml")), 1.709),
          "suspended4": (load_robot(example_path("suspended4.toml")), 1.5656)}


def point_mass(m, tension_max=60.0, anchors=None):
    """m cables from the corners of a square / triangle (or ``anchors``) to one platform point
    (com there too): the moment balance holds by itself, rank 3, a null space for m = 4."""
    ang = 2 * np.pi * np.arange(m) / m
    if anchors is None:
        anchors = np.stack([2 * np.cos(ang), 2 * np.sin(ang), np.full(m, 3.0)], 1)
    return CableRobot(anchors=anchors, attachments=np.zeros((m, 3)), EA=np.full(m, 1e5),
                      mass_per_length=np.zeros(m), platform_mass=5.0, com=np.zeros(3), inertia=np.eye(3),
                      gravity=[0.0, 0.0, -9.81], noise=Noise(position=1e-3, rotation=1e-3, tension=0.5),
                      tension_min=1.0, tension_max=tension_max, name=f"point{m}")


def numpy_statics(robot, pose):
    """``(S, W_g)`` of straight cables by hand (numpy, scipy rotation)."""
    R = Rotation.from_rotvec(np.asarray(pose[3:], float)).as_matrix()
    A, a = np.asarray(robot.anchors), np.asarray(robot.attachments) @ R.T
    u = A - (np.asarray(pose[:3]) + a)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    S = np.concatenate([u, np.cross(a, u)], 1).T
    f = np.asarray(robot.platform_mass) * np.asarray(robot.gravity)
    return S, np.concatenate([f, np.cross(R @ np.asarray(robot.com), f)])


def lp_margin(S, b, lo, hi):
    """max δ with S t = b, lo + δ <= t <= hi - δ (None when b is not in the span; ``hi = inf``: no
    upper rows, ``inf`` when the LP is unbounded)."""
    U, sv, _ = np.linalg.svd(S, full_matrices=False)
    Ur = U[:, sv > 1e-9 * sv[0]]
    inside = np.linalg.norm(b - Ur @ (Ur.T @ b)) <= BALANCE * (np.linalg.norm(b) + 1)
    if not inside:
        return None
    m = S.shape[1]
    upper = np.isfinite(hi)
    A_ub = np.block([[-np.eye(m), np.ones((m, 1))], [np.eye(m), np.ones((m, 1))]])[:2 * m if upper else m]
    b_ub = np.concatenate([-np.full(m, lo), np.full(m, hi)])[:2 * m if upper else m]
    r = linprog(np.r_[np.zeros(m), -1.0], A_ub=A_ub, b_ub=b_ub, A_eq=np.c_[Ur.T @ S, np.zeros(len(Ur.T))],
                b_eq=Ur.T @ b, bounds=[(None, None)] * (m + 1), method="highs", options=LP_OPTIONS)
    if r.status == 3:  # unbounded (only without an upper limit)
        assert not upper
        return np.inf
    assert r.status == 0, r.message
    return -r.fun


def numpy_least_eigenvalue(robot, pose, h=1e-6):
    """Least eigenvalue of the symmetric part of ``D K D`` (``D = diag(1, 1, 1, 1/0.2 x 3)``), ``K``
    the stiffness of spring cables cut to the least-squares tensions at ``pose``, the weight's
    term included, by central differences of the net wrench over base-frame twists."""
    S, Wg = numpy_statics(robot, pose)
    t = np.linalg.lstsq(S, -Wg, rcond=None)[0]
    A, b, EA = np.asarray(robot.anchors), np.asarray(robot.attachments), np.asarray(robot.EA)
    R0 = Rotation.from_rotvec(pose[3:]).as_matrix()
    l0 = np.linalg.norm(A - pose[:3] - b @ R0.T, axis=1) * EA / (EA + t)

    def net(tw):
        R = Rotation.from_rotvec(tw[3:]).as_matrix() @ R0
        a = b @ R.T
        v = A - (pose[:3] + tw[:3] + a)
        length = np.linalg.norm(v, axis=1)
        f = (EA * np.maximum(length - l0, 0) / l0 / length)[:, None] * v
        w = np.asarray(robot.platform_mass) * np.asarray(robot.gravity)
        return np.r_[f.sum(0) + w, np.cross(a, f).sum(0) + np.cross(R @ np.asarray(robot.com), w)]

    K = -np.stack([(net(h * e) - net(-h * e)) / (2 * h) for e in np.eye(6)], 1)
    d = np.r_[np.ones(3), np.full(3, 1 / 0.2)]
    Ks = d[:, None] * K * d[None]
    return np.linalg.eigvalsh(0.5 * (Ks + Ks.T))[0]


@pytest.fixture(scope="module")
def fns():
    """One compiled batch function per robot and orientation (shared by the tests)."""
    return {(n, o): jax.jit(jax.vmap(lambda p, r=r, o=o: static_equilibrium(r, p, orientation=o)))
            for n, (r, _) in ROBOTS.items() for o in ("free", "given")}


def grid_poses(z0):
    """A small grid around the hanging pose, out to the frame and up to the anchors (outside)."""
    x, y, z = np.meshgrid([-1.9, -0.9, 0.0, 0.7, 1.6], [-1.4, 0.0, 0.6, 1.4], [0.4, z0, 2.6, 2.95], indexing="ij")
    return np.stack([x.ravel(), y.ravel(), z.ravel(), *np.zeros((3, x.size))], 1)


# ------------------------------------------------------------------------- the LP alone
@pytest.mark.parametrize("m", [3, 4, 5])
def test_tension_margin_matches_lp_full_rank_and_redundant(m):
    rng = np.random.default_rng(m)
    f = jax.jit(tension_margin)
    for case in range(12):
        S = rng.normal(size=(6, m))
        if case % 3 == 0:  # rank deficient: a null space to search (as a point-mass platform's)
            S[:, -1] = S[:, 0] + 0.5 * S[:, 1]
        t0 = rng.uniform(0.0, 100.0, m)
        t0[case % m] = [0.0, -1e-3, 1e-3, 100.0 + 1e-3][case % 4]  # on, just outside, just inside the limits
        b = S @ t0
        s, res, t = f(jnp.asarray(S), jnp.asarray(b), 0.0, 100.0)
        ref = lp_margin(S, b, 0.0, 100.0)
        assert res < 1e-9 and ref is not None
        np.testing.assert_allclose(float(s), ref, atol=1e-7)
        np.testing.assert_allclose(S @ np.asarray(t), b, atol=1e-8)
        assert np.min(np.minimum(np.asarray(t), 100.0 - np.asarray(t))) >= float(s) - 1e-7
    S = rng.normal(size=(6, m))
    s, res, _ = f(jnp.asarray(S), jnp.asarray(rng.normal(size=6)), 0.0, 100.0)  # not in the span
    assert res > 0.1


@pytest.mark.parametrize("m", [3, 4, 5])
def test_tension_margin_without_upper_limit_matches_lp(m):
    """tension_max = inf: the margin is the distance above tension_min alone; bounded for a full
    rank S and for a null vector of mixed signs, +inf (linprog: unbounded) for a positive one."""
    rng = np.random.default_rng(10 + m)
    f = jax.jit(tension_margin)
    kinds = []
    for case in range(12):
        S = rng.normal(size=(6, m))
        if case % 3 == 1:  # a null vector of mixed signs
            S[:, -1] = S[:, 0] - 0.5 * S[:, 1]
        elif case % 3 == 2:  # a positive null vector: an internal force pulls every cable
            S[:, -1] = -(S[:, :-1] @ rng.uniform(0.5, 2.0, m - 1))
        t0 = rng.uniform(-20.0, 100.0, m)
        b = S @ t0
        s, res, t = f(jnp.asarray(S), jnp.asarray(b), 2.0, jnp.inf)
        ref = lp_margin(S, b, 2.0, np.inf)
        assert res < 1e-9 and ref is not None
        kinds.append(np.isinf(ref))
        assert np.isinf(ref) == (case % 3 == 2)
        if np.isinf(ref):
            assert float(s) == np.inf
            assert np.min(np.asarray(t)) >= 2.0 - 1e-7  # every cable lifted to the limit
        else:
            np.testing.assert_allclose(float(s), ref, atol=1e-7 * (1 + abs(ref)))
            assert np.min(np.asarray(t)) - 2.0 >= float(s) - 1e-7
        np.testing.assert_allclose(S @ np.asarray(t), b, atol=1e-7 * (1 + np.abs(t0).max()))
    assert any(kinds) and not all(kinds)


def test_point_mass_without_upper_limit_matches_lp_and_reports_unbounded():
    """4 cables, no upper limit: below a square of anchors (every cable pulls up) the margin is
    bounded (the LP's); inside a tetrahedron of anchors (one below) an internal force pulls every
    cable: linprog is unbounded and the margin +inf, a member."""
    ws = WrenchSet.box([-2, -2, -3, 0, 0, 0], [2, 2, 3, 0, 0, 0])
    tetra = np.array([[2.0, 0.0, 3.0], [-1.0, 1.7, 3.0], [-1.0, -1.7, 3.0], [0.0, 0.0, -0.5]])
    P = np.array([[x, y, z, 0, 0, 0] for x in (-0.3, 0.4) for y in (-0.3, 0.3) for z in (1.5, 2.0, 2.9)]
                 + [[0.0, 0.0, -1.0, 0, 0, 0], [3.0, 0.0, 1.0, 0, 0, 0]])  # outside the tetrahedron
    for robot, inside in ((point_mass(4, np.inf), False), (point_mass(4, np.inf, tetra), True)):
        out = jax.device_get(jax.jit(jax.vmap(lambda p, r=robot: static_equilibrium(r, p, ws, orientation="given")))(
            jnp.asarray(P)))
        for k, p in enumerate(P):
            S, Wg = numpy_statics(robot, p)
            ref = min(lp_margin(S, -(Wg + w), 1.0, np.inf) for w in ws.extreme_points())
            if np.isinf(ref):
                assert out.margin[k] == np.inf
            else:
                np.testing.assert_allclose(out.margin[k], ref, atol=1e-6 * (1 + abs(ref)))
            assert out.member[k] == (ref >= 0)
        assert (np.isinf(out.margin[:-2]) == inside).all() and not np.isinf(out.margin[-2:]).any()
        assert out.member[:-2].all()


# ------------------------------------------------------------------------- per pose
@pytest.mark.parametrize("name", ["suspended3", "suspended4"])
def test_free_orientation_matches_an_independent_equilibrium_and_lp(name, fns):
    robot, z0 = ROBOTS[name]
    P = grid_poses(z0)
    out = jax.device_get(fns[name, "free"](jnp.asarray(P)))
    lo, hi = float(robot.tension_min), float(robot.tension_max)
    low = P[:, 2] < 2.9  # at 2.95 the attachments reach the anchors' height: cables nearly level
    assert out.solved[low].all() and 0 < out.member.sum() < len(P)
    assert not out.member[~out.solved].any() and (out.margin[~out.solved] == -np.inf).all()
    for k, p in enumerate(P):
        if not out.solved[k]:
            continue
        pose = np.r_[p[:3], out.rotation[k]]
        S, Wg = numpy_statics(robot, pose)
        ref = lp_margin(S, -Wg, lo, hi)
        assert ref is not None, (name, p)
        np.testing.assert_allclose(out.margin[k], ref, atol=1e-6 * (1 + abs(ref)))
        assert out.member[k] == (ref >= 0 and out.stable[k])
        assert out.stable[k] == (numpy_least_eigenvalue(robot, pose) > 0), (name, p)

        def unbalanced(th, p=p):
            S, W = numpy_statics(robot, np.r_[p[:3], th])
            return W - S @ np.linalg.lstsq(S, W, rcond=None)[0]
        if robot.num_cables == 3:  # isolated: the same rotation from scipy
            th = least_squares(unbalanced, np.zeros(3), xtol=1e-15, ftol=1e-15, gtol=1e-15).x
            np.testing.assert_allclose(out.rotation[k], th, atol=1e-8)
        else:
            assert np.linalg.norm(unbalanced(out.rotation[k])) < 1e-9 * (np.linalg.norm(Wg) + 1)
    assert (~out.member & (out.margin >= 0)).sum() == (~out.stable & (out.margin >= 0)).sum()


@pytest.mark.slow  # ~75 s: forward statics compiles once per robot
@pytest.mark.parametrize("name", ["suspended3", "suspended4"])
def test_free_members_are_where_the_platform_settles(name, fns):
    """Forward statics with spring cables cut to the members' tensions returns the same pose,
    stable (Status.successful): the rotation found is where the platform hangs."""
    robot, z0 = ROBOTS[name]
    P = np.array([[0.0, 0.0, z0, 0, 0, 0], [0.7, -0.6, 1.1, 0, 0, 0], [-0.9, 0.6, 2.2, 0, 0, 0]])
    out = jax.device_get(fns[name, "free"](jnp.asarray(P)))
    assert out.member.all()
    for k, p in enumerate(P):
        pose = np.r_[p[:3], out.rotation[k]]
        S, Wg = numpy_statics(robot, pose)
        t = np.linalg.lstsq(S, -Wg, rcond=None)[0]
        lengths = np.linalg.norm(np.asarray(robot.anchors) - pose[:3] -
                                 np.asarray(robot.attachments) @ Rotation.from_rotvec(pose[3:]).as_matrix().T, axis=1)
        l0 = lengths * np.asarray(robot.EA) / (np.asarray(robot.EA) + t)
        fs = forward_statics(StaticsProblem(robot, jnp.asarray(l0), law=CableLaw.spring), pose0=jnp.asarray(pose),
                             throw=False)
        assert fs.result == Status.successful
        np.testing.assert_allclose(np.asarray(fs.pose), pose, atol=1e-8)


@pytest.mark.parametrize("name", ["suspended3", "suspended4"])
def test_given_orientation_matches_lp_at_and_off_equilibria(name, fns):
    robot, z0 = ROBOTS[name]
    P = grid_poses(z0)[::3]
    rot = jax.device_get(fns[name, "free"](jnp.asarray(P))).rotation
    P, rot = P[P[:, 2] < 2.9], rot[P[:, 2] < 2.9]  # where the free rotation is found
    tilted = np.r_[P[:, :3].T, rot.T].T  # equilibria: the given rotation is where it hangs
    nudged = tilted + np.r_[0, 0, 0, 2e-3, 0, 0]  # 2 mrad off: no longer balanced
    lo, hi = float(robot.tension_min), float(robot.tension_max)
    for poses, balanced in ((tilted, True), (nudged, False), (P, False)):
        out = jax.device_get(fns[name, "given"](jnp.asarray(poses)))
        for k, p in enumerate(poses):
            S, Wg = numpy_statics(robot, p)
            ref = lp_margin(S, -Wg, lo, hi)
            if poses is P:  # level: balanced only where the free rotation is level too (the symmetry axis)
                balanced = bool(np.allclose(rot[k], 0, atol=1e-12))
            assert (ref is not None) == balanced == bool(out.solved[k]), (p, ref)
            if balanced:
                np.testing.assert_allclose(out.margin[k], ref, atol=1e-6 * (1 + abs(ref)))
                assert out.member[k] == (ref >= 0)
            else:
                left = -Wg - S @ np.linalg.lstsq(S, -Wg, rcond=None)[0]
                assert not out.member[k] and out.margin[k] == -np.inf
                np.testing.assert_allclose(out.residual[k], np.linalg.norm(left), rtol=1e-6)
        np.testing.assert_array_equal(out.rotation, poses[:, 3:])


@pytest.mark.parametrize("m", [3, 4])
def test_point_mass_with_a_wrench_box_matches_lp_per_vertex(m):
    """A point-mass platform (given orientation: a volume; with 4 cables a redundant LP) holds
    a box of forces iff every vertex is held (convexity)."""
    robot = point_mass(m)
    ws = WrenchSet.box([-2, -2, -3, 0, 0, 0], [2, 2, 3, 0, 0, 0])
    f = jax.jit(jax.vmap(lambda p: static_equilibrium(robot, p, ws, orientation="given")))
    x, y, z = np.meshgrid(np.linspace(-1.6, 1.6, 5), np.linspace(-1.6, 1.6, 5), [0.5, 1.5, 2.5, 2.9], indexing="ij")
    P = np.stack([x.ravel(), y.ravel(), z.ravel(), *np.zeros((3, x.size))], 1)
    out = jax.device_get(f(jnp.asarray(P)))
    for k, p in enumerate(P):
        S, Wg = numpy_statics(robot, p)
        refs = [lp_margin(S, -(Wg + w), 1.0, 60.0) for w in ws.extreme_points()]
        assert all(r is not None for r in refs)
        np.testing.assert_allclose(out.margin[k], min(refs), atol=1e-6)
        assert out.member[k] == (min(refs) >= 0)
    assert 0 < out.member.sum() < len(P)


# ------------------------------------------------------------------------- sweeps and volume
def test_sweep_volume_matches_a_hand_count_and_jit_equals_vmap(fns):
    robot, _ = ROBOTS["suspended3"]
    axes = ((-1.5, 1.5, 4), (-1.0, 2.0, 4), (0.5, 2.5, 3))
    grid = Grid.regular(*axes)

    def fn(pose):
        r = static_equilibrium(robot, pose)
        return {"member": r.member, "margin": r.margin}

    out = jax.device_get(sweep(fn, grid, chunk_size=16, progress=False))  # two chunks, the last padded
    poses = grid.poses()
    one = jax.jit(lambda p: static_equilibrium(robot, p))
    single = [one(jnp.asarray(p)) for p in poses]
    batch = jax.device_get(fns["suspended3", "free"](jnp.asarray(poses)))
    member = np.array([bool(s.member) for s in single])
    np.testing.assert_array_equal(out["member"], member)
    np.testing.assert_array_equal(batch.member, member)
    np.testing.assert_allclose(out["margin"], [float(s.margin) for s in single], rtol=1e-10, atol=1e-9)
    np.testing.assert_allclose(batch.margin, out["margin"], rtol=1e-10, atol=1e-9)
    weights = []
    for lo, hi, n in axes:  # every member stands for its own cell: half a cell on the faces
        w = np.full(n, (hi - lo) / (n - 1))
        w[[0, -1]] /= 2
        weights.append(w)
    cell = np.einsum("i,j,k->ijk", *weights).ravel()
    assert 0 < member.sum() < len(member)
    np.testing.assert_allclose(grid.volume(out["member"].reshape(grid.shape)), cell[member].sum(), rtol=1e-12)


# ------------------------------------------------------------------------- the command line
def test_command_on_a_robot_with_no_upper_limit(tmp_path, capsys):
    """onboard4 states no tension_max: the workspace of taut cables (t >= tension_min), said so in
    the text and summary.json; each pose's margin is linprog's at the equilibrium rotation found
    (its structure matrix and weight from the package: onboard4's pulleys move the cable exits,
    which numpy_statics leaves out; the pulley geometry has its own tests)."""
    robot = load_robot(example_path("onboard4/robot.toml"))
    assert np.isinf(float(robot.tension_max))
    out = tmp_path / "w"
    assert main(["workspace", "onboard4/robot.toml", "--kind", "static-equilibrium", "--pose-grid",
                 "-1.5", "2.6", "2", "-1", "1", "2", "1", "2.5", "2", "--no-progress", "--out", str(out)]) == EXIT_OK
    assert "no upper limit" in capsys.readouterr().out
    import json
    info = json.loads((out / "summary.json").read_text())
    res = np.load(out / "results.npz")
    assert info["tension_limits_N"] == [0.0, None] and "no upper limit" in info["limits"]
    assert info["margin_unit"] == "tension margin above tension_min [N]" and info["unbounded_margin_poses"] == 0
    assert info["members"] == int(res["member"].sum()) > 0
    x, y, z = np.meshgrid(res["x"], res["y"], res["z"], indexing="ij")
    for idx in np.ndindex(res["member"].shape):
        if not res["solved"][idx]:
            continue
        pose = np.r_[x[idx], y[idx], z[idx], res["equilibrium_rotation"][idx]]
        S, Wg = np.asarray(structure_matrix(robot, pose)), np.asarray(gravity_wrench(robot, pose))
        ref = lp_margin(S, -Wg, 0.0, np.inf)
        assert ref is not None, pose
        np.testing.assert_allclose(res["margin"][idx], ref, atol=1e-6 * (1 + abs(ref)))
        assert res["member"][idx] == (ref >= 0 and res["stable"][idx])
    assert res["solved"].sum() > 0 and not res["member"].all()  # x = 2.6 lies beyond the anchors at 2


def test_command_writes_the_workspace_and_refuses_with_the_reason(tmp_path, capsys):
    grid = ["--pose-grid", "-1", "1", "3", "-1", "1", "3", "1", "2", "2"]
    out = tmp_path / "w"
    assert main(["workspace", "suspended3.toml", "--kind", "static-equilibrium", *grid, "--no-progress",
                 "--out", str(out)]) == EXIT_OK
    import json
    info = json.loads((out / "summary.json").read_text())
    res = np.load(out / "results.npz")
    assert info["kind"] == "static-equilibrium" and info["orientation"] == "free"
    assert info["members"] == int(res["member"].sum()) > 0 and info["margin_unit"] == "tension margin [N]"
    assert res["equilibrium_rotation"].shape == (3, 3, 2, 3) and info["no_equilibrium_poses"] == 0
    assert (out / "workspace_3d.png").stat().st_size > 0
    capsys.readouterr()
    bad = [(["suspended4.toml", "--kind", "wrench-feasible", "--wrench-box", *["0"] * 12],
            "use the static-equilibrium workspace (cstiffjax workspace --kind static-equilibrium"),
           (["tcpr8.toml", "--kind", "static-equilibrium"], "robot 'tcpr8' has 8: use the wrench-feasible workspace"),
           (["suspended4.toml", "--kind", "wrench-closure", "--orientation", "given"],
            "--orientation: only used with --kind static-equilibrium")]
    for args, message in bad:
        assert main(["workspace", *args, *grid, "--out", str(tmp_path / "bad")]) == EXIT_USAGE
        assert message in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()
