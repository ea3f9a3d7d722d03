"""Tension distribution methods against independent references.

The 2-norm problem min |t - t_m|² s.t. S t = -W, t in the box is, in null-space
coordinates (N orthonormal from scipy), the Euclidean projection of φ0 = Nᵀ(t_m - t_p)
onto a convex polygon: solved here by a tiny dense active-set enumeration (the point
itself, its projection on each of the 2m lines, every pair of lines). The min-max
problem is checked with scipy linprog, the closed forms with numpy pinv.
"""

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.linalg import null_space
from scipy.optimize import linprog

from cstiffjax.core.status import Status, code, to_codes
from cstiffjax.examples import example_path
from cstiffjax.io.robot_io import load_robot
from cstiffjax.statics import geometry as statics
from cstiffjax.stiffness.tension_methods import distribute_tensions

FEAS = 1e-9  # the reference's own feasibility tolerance (N)
METHODS = (("cfm", "2-norm"), ("icfm", "2-norm"), ("dykstra", "2-norm"), ("qp", "2-norm"), ("qp", "max"))


@pytest.fixture(scope="module")
def robot():
    return load_robot(example_path("tcpr8.toml"))


@pytest.fixture(scope="module")
def cases(robot):
    rng = np.random.default_rng(21)
    n = 8
    P = np.column_stack([rng.uniform(-0.4, 0.4, n), rng.uniform(-0.25, 0.25, n), rng.uniform(0.4, 1.4, n),
                         rng.uniform(-0.1, 0.1, (n, 3))])
    E = rng.normal(size=(n, 6)) * np.r_[120, 120, 120, 12, 12, 12]
    E[-1] = [0, 0, -5000, 0, 0, 0]  # far beyond the limits: infeasible for everyone
    return P, E


@pytest.fixture(scope="module")
def results(robot, cases):
    P, E = cases
    out = {}
    for method, objective in METHODS:
        f = jax.jit(jax.vmap(lambda p, e, method=method, objective=objective: distribute_tensions(
            robot, p, e, method=method, objective=objective, throw=False)))
        out[method, objective] = f(jnp.asarray(P), jnp.asarray(E))
    return out


def problem(robot, pose, ext):
    S = np.asarray(statics.structure_matrix_closed_form(robot, pose))
    W = np.asarray(statics.gravity_wrench(robot, pose)) + ext
    return S, W, float(robot.tension_min), float(robot.tension_max)


def reference_two_norm(S, W, tmin, tmax):
    """Exact projection of t_m on {S t = -W} ∩ box, or None when empty."""
    tm = 0.5 * (tmin + tmax)
    N = null_space(S)
    tp = np.linalg.lstsq(S, -W, rcond=None)[0]
    phi0 = N.T @ (tm - tp)
    A = np.vstack([N, -N])
    b = np.r_[tmax - tp, tp - tmin]
    cands = [phi0]
    for a, c in zip(A, b):
        cands.append(phi0 - (a @ phi0 - c) / (a @ a) * a)
    for i, j in itertools.combinations(range(len(A)), 2):
        M = np.vstack([A[i], A[j]])
        if abs(np.linalg.det(M)) > 1e-12:
            cands.append(np.linalg.solve(M, [b[i], b[j]]))
    feas = [c for c in cands if np.all(A @ c <= b + FEAS)]
    if not feas:
        return None
    best = min(feas, key=lambda c: np.sum((c - phi0) ** 2))
    return tp + N @ best


def reference_min_max(S, W, tmin, tmax):
    m = S.shape[1]
    res = linprog(np.r_[np.zeros(m), 1.0], A_ub=np.c_[np.eye(m), -np.ones(m)], b_ub=np.zeros(m),
                  A_eq=np.c_[S, np.zeros(6)], b_eq=-W, bounds=[(tmin, tmax)] * m + [(None, None)], method="highs",
                  options={"primal_feasibility_tolerance": FEAS})
    return res.fun if res.status == 0 else None


def test_two_norm_methods_match_the_exact_projection(robot, cases, results):
    P, E = cases
    constrained = 0
    for k in range(len(P)):
        S, W, tmin, tmax = problem(robot, P[k], E[k])
        ref = reference_two_norm(S, W, tmin, tmax)
        dyk, qp = results["dykstra", "2-norm"], results["qp", "2-norm"]
        if ref is None:
            for key in METHODS:  # ADMM may not detect infeasibility: never "successful" though
                allowed = (Status.infeasible, Status.not_converged) if key == ("qp", "2-norm") else (Status.infeasible,)
                assert int(to_codes(results[key].result)[k]) in [code(a) for a in allowed], (key, k)
            continue
        assert to_codes(dyk.result)[k] == code(Status.successful) and to_codes(qp.result)[k] == code(Status.successful)
        np.testing.assert_allclose(np.asarray(dyk.tensions[k]), ref, atol=1e-6)
        np.testing.assert_allclose(np.asarray(qp.tensions[k]), ref, atol=1e-5)
        tm = 0.5 * (tmin + tmax)
        cfm_t = tm - np.linalg.pinv(S) @ (W + S @ np.full(8, tm))  # Pott 2009, limits ignored
        np.testing.assert_allclose(np.asarray(results["cfm", "2-norm"].tensions[k]), cfm_t, atol=1e-9)
        inside = np.all(cfm_t >= tmin) & np.all(cfm_t <= tmax)
        assert (to_codes(results["cfm", "2-norm"].result)[k] == code(Status.successful)) == inside
        if inside:
            np.testing.assert_allclose(ref, cfm_t, atol=1e-8)
        constrained += not inside
    assert constrained >= 2  # the limits matter in some cases


def test_icfm_is_the_reduced_cfm_of_its_clamped_cables(robot, cases, results):
    P, E = cases
    icfm = results["icfm", "2-norm"]
    for k in range(len(P) - 1):
        S, W, tmin, tmax = problem(robot, P[k], E[k])
        t = np.asarray(icfm.tensions[k])
        if to_codes(icfm.result)[k] != code(Status.successful):
            continue
        assert np.all(t >= tmin - 1e-6) and np.all(t <= tmax + 1e-6)
        np.testing.assert_allclose(S @ t, -W, atol=1e-8)
        fixed = np.isclose(t, tmin, atol=1e-9) | np.isclose(t, tmax, atol=1e-9)
        free = ~fixed
        tm = 0.5 * (tmin + tmax)
        rhs = -(W + S[:, fixed] @ t[fixed]) - S[:, free] @ np.full(free.sum(), tm)
        np.testing.assert_allclose(t[free], tm + np.linalg.pinv(S[:, free]) @ rhs, atol=1e-8)
    assert int(np.sum(np.asarray(to_codes(icfm.result)) == code(Status.successful))) >= len(P) // 2


def test_min_max_matches_lp(robot, cases, results):
    P, E = cases
    mm = results["qp", "max"]
    for k in range(len(P)):
        S, W, tmin, tmax = problem(robot, P[k], E[k])
        ref = reference_min_max(S, W, tmin, tmax)
        if ref is None:
            assert to_codes(mm.result)[k] == code(Status.infeasible)
            continue
        assert to_codes(mm.result)[k] == code(Status.successful)
        assert float(jnp.max(mm.tensions[k])) == pytest.approx(ref, abs=1e-7)


def test_bad_method_is_refused(robot):
    with pytest.raises(ValueError, match="method = 'puncture'; allowed: cfm, icfm, dykstra, qp"):
        distribute_tensions(robot, jnp.zeros(6), method="puncture")
    with pytest.raises(ValueError, match="needs method = 'qp'"):
        distribute_tensions(robot, jnp.zeros(6), method="cfm", objective="max")
