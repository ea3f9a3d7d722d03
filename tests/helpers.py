"""Shared test helpers: a small zoo of robots and numerical references."""

import math

import jax.numpy as jnp
import numpy as np

from cstiffjax.examples import example_path
from cstiffjax.io.recordings import load_recordings
from cstiffjax.io.robot import CableRobot, Noise
from cstiffjax.io.robot_io import load_robot


def forget_programs():
    """A new process's view of :mod:`cstiffjax.runtime.programs`: nothing in memory (the memoized
    callers, keys and output structures), the folder on disk as it is."""
    from cstiffjax.runtime import programs

    programs._MEMO.clear()
    programs._KEYS.clear()
    programs._OUTPUTS.clear()


def lab_robot(name="example02"):
    """The Yuan et al. 2015 prototype (8 mm cables) with recordings from the outside simulator."""
    robot = load_robot(example_path(f"{name}/robot.toml"))
    return robot, load_recordings(example_path(f"{name}/recordings.csv"), robot)


def eight_cable_robot(com=(0.0, 0.0, 0.0)):
    """An 8-cable box-frame robot: corners of a 4 x 4 x 3 m frame; lower attachments turned by 90 deg (full rank)."""
    a = np.array([[x, y, z] for z in (0.0, 3.0) for x, y in ((-2, -2), (2, -2), (2, 2), (-2, 2))], float)
    b = np.array([[x, y, z] for z in (-0.15, 0.15) for x, y in ((-0.2, -0.2), (0.2, -0.2), (0.2, 0.2), (-0.2, 0.2))])
    return CableRobot(
        anchors=a, attachments=b[[1, 2, 3, 0, 4, 5, 6, 7]], EA=np.full(8, 2e5), mass_per_length=np.zeros(8),
        platform_mass=20.0, com=np.asarray(com), inertia=np.eye(3), gravity=np.array([0, 0, -9.81]),
        noise=Noise(position=1e-5, rotation=1e-5, tension=0.1), name="box8",
    )


def central_difference(f, x, h=1e-6):
    """Jacobian of f at x by central differences (columns = inputs)."""
    x = np.asarray(x, float)
    cols = []
    for j in range(x.size):
        e = np.zeros_like(x)
        e[j] = h
        cols.append((np.asarray(f(jnp.asarray(x + e))) - np.asarray(f(jnp.asarray(x - e)))) / (2 * h))
    return np.stack(cols, -1)


# ------------------------------------------------------- independent numpy/scipy references
def np_frame(pose, twist=None):
    """(p, R) of ``pose`` moved by a base-frame twist ``[δp, δθ]`` (p + δp, exp(δθ) R), with
    scipy's rotation vectors (independent of cstiffjax.core.lie / statics)."""
    from scipy.spatial.transform import Rotation

    pose = np.array(pose, float)
    twist = np.zeros(6) if twist is None else np.array(twist, float)
    R = Rotation.from_rotvec(twist[3:]).as_matrix() @ Rotation.from_rotvec(pose[3:]).as_matrix()
    return pose[:3] + twist[:3], R


def np_cables(robot, p, R):
    """(r, d, l): lever arms R b, attachment->anchor vectors, lengths (numpy)."""
    r = np.asarray(robot.attachments) @ R.T
    d = np.asarray(robot.anchors) - p - r
    return r, d, np.linalg.norm(d, axis=1)


def np_spring_wrench(robot, l0, external, pose, twist=None):
    """Net wrench (N, N·m about the reference point) of one-sided spring cables
    t = EA (l - l0)/l0, the weight at the centre of mass and a constant ``external``."""
    p, R = np_frame(pose, twist)
    r, d, l = np_cables(robot, p, R)
    t = np.maximum(np.asarray(robot.EA) * (l - np.asarray(l0)) / np.asarray(l0), 0.0)
    f = (t / l)[:, None] * d
    weight = float(robot.platform_mass) * np.asarray(robot.gravity)
    rc = R @ np.asarray(robot.com)
    force = f.sum(0) + weight + np.asarray(external)[:3]
    moment = np.cross(r, f).sum(0) + np.cross(rc, weight) + np.asarray(external)[3:]
    return np.concatenate([force, moment])


def np_potential(robot, l0, external, pose, twist):
    """Potential energy (J) of the same system as a function of the twist from ``pose``:
    spring energy ½ EA/l0 (l - l0)² (taut), gravity -m g·(p + R c), and the constant
    external wrench's -f·δp - m·δθ (its work along the twist coordinates)."""
    p, R = np_frame(pose, twist)
    _, _, l = np_cables(robot, p, R)
    ext = np.asarray(external, float)
    stretch = np.maximum(l - np.asarray(l0), 0.0)
    springs = 0.5 * np.sum(np.asarray(robot.EA) / np.asarray(l0) * stretch**2)
    weight = float(robot.platform_mass) * np.asarray(robot.gravity)
    return springs - weight @ (p + R @ np.asarray(robot.com)) - ext[:3] @ np.asarray(twist)[:3] - ext[3:] @ np.asarray(
        twist)[3:]


def np_fd(f, n, h):
    """Central-difference Jacobian of f: R^n -> R^k at 0 (columns = inputs)."""
    cols = []
    for j in range(n):
        e = np.zeros(n)
        e[j] = h
        cols.append((np.asarray(f(e)) - np.asarray(f(-e))) / (2 * h))
    return np.stack(cols, -1)


# ------------------------------------------------------------------ JSON documents
TIMES = {"elapsed_s"}  # wall-clock fields, wherever they sit in the document


def without_times(doc):
    if isinstance(doc, dict):
        return {k: without_times(v) for k, v in doc.items() if k not in TIMES}
    if isinstance(doc, list):
        return [without_times(v) for v in doc]
    return doc


# Statistics judged against thresholds of order 1 to 10 (Wald, ΔBIC): compared to an absolute STAT_TOL.
STATISTICS = {"wald", "delta_bic", "screen_delta_bic"}
# Ratios whose denominator can be near zero (the share of the excess χ² a candidate removes, Δχ²/(χ² - dof)):
# compared to STAT_TOL relative (a decision on them is in the compared strings and flags).
RATIOS = {"explained_fraction"}
# XLA compiles for the host's instruction set (FMA contraction, vector width), so another CPU model rounds
# differently: the estimates of ill-conditioned, rejected candidates then move by up to ~1e-4 relative
# (example02's cable_mass: 6e-5 relative, 8e-5 of its own standard error, on an Intel Xeon against the
# AMD EPYC that wrote the golden files). Such moves are far below any estimate's uncertainty.
STAT_TOL = 1e-3


def differences(got, want, path="$", rel_tol=1e-7):
    """Where two documents differ: keys, lengths, types, strings exactly; floats to ``rel_tol``,
    but an estimate's ``value`` (a number or nested lists of them) to ``STAT_TOL`` of its own
    ``std`` element by element, a ``std`` to ``STAT_TOL`` relative, the statistics of
    :data:`STATISTICS` to ``STAT_TOL`` absolute and the ratios of :data:`RATIOS` to ``STAT_TOL``
    relative. A tolerance is a number (relative), ``(rel, abs)``, or a list of them matching a list."""
    if isinstance(want, dict):
        if not isinstance(got, dict) or set(got) != set(want):
            return [f"{path}: keys {sorted(got) if isinstance(got, dict) else got!r} != {sorted(want)}"]
        return [d for k in want for d in differences(got[k], want[k], f"{path}.{k}", _tolerance(want, k, rel_tol))]
    if isinstance(want, list):
        if not isinstance(got, list) or len(got) != len(want):
            return [f"{path}: {got!r} != {want!r}"]
        tols = rel_tol if isinstance(rel_tol, list) and len(rel_tol) == len(want) else [rel_tol] * len(want)
        return [d for i, (g, w, t) in enumerate(zip(got, want, tols)) for d in differences(g, w, f"{path}[{i}]", t)]
    if isinstance(want, float) and isinstance(got, (int, float)) and not isinstance(got, bool):
        rel, abs_ = rel_tol if isinstance(rel_tol, tuple) else (rel_tol, 1e-12)
        ok = math.isclose(got, want, rel_tol=rel, abs_tol=abs_) or (math.isnan(got) and math.isnan(want))
        return [] if ok else [f"{path}: {got!r} != {want!r}"]
    return [] if (type(got) is type(want) and got == want) else [f"{path}: {got!r} != {want!r}"]


def _tolerance(parent: dict, key: str, rel_tol):
    """The tolerance of ``parent[key]``: ``rel_tol``, ``(rel, abs)`` for a statistic, or the
    estimate's own scale (:func:`_on_std`, the shape of its ``std``)."""
    if not isinstance(rel_tol, (int, float)):  # already an estimate's or a statistic's
        return rel_tol
    if key == "value" and "std" in parent:
        return _on_std(parent["std"], rel_tol)
    if key == "std" and "value" in parent:
        return (max(rel_tol, STAT_TOL), 1e-12)
    if key in STATISTICS:
        return (rel_tol, STAT_TOL)
    if key in RATIOS:
        return (max(rel_tol, STAT_TOL), 1e-12)
    return rel_tol


def _on_std(std, rel_tol):
    """``(rel_tol, STAT_TOL * std)`` for each finite positive standard error in ``std`` (nested
    lists kept), ``rel_tol`` where there is none."""
    if isinstance(std, list):
        return [_on_std(s, rel_tol) for s in std]
    if isinstance(std, float) and math.isfinite(std) and std > 0:
        return (rel_tol, STAT_TOL * std)
    return rel_tol
