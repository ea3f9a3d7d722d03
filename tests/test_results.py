"""One result vocabulary: every solver returns one result Module with a ``Status`` whatever its
``throw``; the least-squares engine's outcomes are ``Status`` members; the integer codes of a
``Status`` are read and written only in ``cstiffjax.core.status``."""

import re
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cstiffjax.core.status import Status, code, describe, from_codes, message, select, to_codes
from cstiffjax.statics.forward import ForwardKinematics, forward_kinematics
from cstiffjax.stiffness.matrix import Stiffness, StiffnessSplit, stiffness, stiffness_split
from fitting.calibration.lm import LMResult, fit_converged, fit_message, masked_levenberg_marquardt
from fitting.effects.fit import fit_masked

from .helpers import eight_cable_robot

ROOT = Path(__file__).resolve().parents[1]
BOX = eight_cable_robot()
POSE = jnp.array([0.1, -0.05, 1.5, 0.02, -0.01, 0.03])


def test_codes_round_trip_and_batched_select():
    members = [Status.successful, Status.not_converged, Status.singular, Status.no_decrease, Status.start_failed]
    codes = [code(s) for s in members]
    assert len(set(codes)) == len(codes) and codes[0] == 0
    batch = from_codes(jnp.asarray(codes))
    assert np.asarray(to_codes(batch)).tolist() == codes
    assert np.asarray(batch == Status.no_decrease).tolist() == [False, False, False, True, False]
    picked = jax.jit(lambda p: select(p, Status.singular, Status.infeasible))(jnp.array([True, False, True]))
    assert np.asarray(to_codes(picked)).tolist() == [code(Status.singular), code(Status.infeasible),
                                                      code(Status.singular)]
    assert describe(Status.successful) == "ok" and message(Status.successful) == ""
    assert describe(Status.zero_length) == message(Status.zero_length) == Status[Status.zero_length]


def test_stiffness_and_split_return_one_module_whatever_throw():
    t = jnp.linspace(80.0, 220.0, 8)
    a, b = stiffness(BOX, POSE, t), stiffness(BOX, POSE, t, throw=False)
    assert isinstance(a, Stiffness) and isinstance(b, Stiffness)
    np.testing.assert_array_equal(a.K, b.K)
    assert a.result == Status.successful and b.result == Status.successful
    on_anchor = jnp.concatenate([BOX.anchors[0] - BOX.attachments[0], jnp.zeros(3)])  # cable 0 has no length
    bad = stiffness(BOX, jnp.stack([POSE, on_anchor]), jnp.stack([t, t]), throw=False)
    assert bad.K.shape == (2, 6, 6)
    assert np.asarray(to_codes(bad.result)).tolist() == [code(Status.successful), code(Status.zero_length)]
    s, s2 = stiffness_split(BOX, POSE, t), stiffness_split(BOX, on_anchor, t, throw=False)
    assert isinstance(s, StiffnessSplit) and s.result == Status.successful
    np.testing.assert_allclose(s.K, a.K, rtol=1e-10, atol=1e-6)
    assert isinstance(s2, StiffnessSplit) and s2.result == Status.zero_length
    with pytest.raises(Exception, match="zero length"):
        stiffness_split(BOX, on_anchor, t)


def test_forward_kinematics_returns_a_module():
    l0 = jnp.linalg.norm(BOX.anchors - (BOX.attachments + POSE[:3]), axis=1)  # no rotation: exact lengths
    fk = forward_kinematics(BOX, l0, throw=False)
    assert isinstance(fk, ForwardKinematics) and fk.result == Status.successful
    np.testing.assert_allclose(fk.pose[:3], POSE[:3], atol=1e-9)
    np.testing.assert_allclose(fk.pose[3:], 0.0, atol=1e-9)


# ---------------------------------------------------------------- the least-squares engine
A = np.array([[1.0, 0.0], [1.0, 1.0], [1.0, 2.0], [1.0, 3.0]])
Y = np.array([0.1, 1.2, 1.9, 3.2])


def _linear(theta, args):
    r = A @ theta - Y
    return r[:, None], jnp.asarray(A), jnp.ones(4, bool)


def _stuck(theta, args):
    """Every sample fails away from the start: every trial is rejected until λ is at its maximum."""
    r, J, _ = _linear(theta, args)
    return r, J, jnp.broadcast_to(jnp.all(theta == 0.0), (4,))


def _failed_at_start(theta, args):
    r, J, _ = _linear(theta, args)
    return r, J, jnp.arange(4) != 2


def test_lm_outcomes_are_statuses():
    theta0 = jnp.zeros(2)
    done = masked_levenberg_marquardt(_linear, theta0, None)
    assert isinstance(done, LMResult) and done.result == Status.successful and fit_converged(done.result)
    np.testing.assert_allclose(done.theta, np.linalg.lstsq(A, Y, rcond=None)[0], rtol=1e-8)
    assert done.message() == "converged"
    short = masked_levenberg_marquardt(_linear, theta0, None, max_steps=1)
    assert short.result == Status.not_converged and not fit_converged(short.result) and int(short.steps) == 1
    stuck = masked_levenberg_marquardt(_stuck, theta0, None)
    assert stuck.result == Status.no_decrease and fit_converged(stuck.result) and bool(stuck.converged)
    assert fit_message(stuck.result) == "no further decrease" and int(stuck.steps) == 1
    np.testing.assert_array_equal(stuck.theta, theta0)
    failed = masked_levenberg_marquardt(_failed_at_start, theta0, None)
    assert failed.result == Status.start_failed and not bool(failed.converged) and int(failed.steps) == 0
    masked = fit_masked(_failed_at_start, np.zeros(2), None, np.ones(2, bool))
    assert not masked.converged and masked.message == "forward statics failed at the start for samples [2]"
    batch = jax.vmap(lambda th: masked_levenberg_marquardt(_linear, th, None, max_steps=1).result)(
        jnp.stack([theta0, jnp.asarray(np.linalg.lstsq(A, Y, rcond=None)[0])]))
    assert np.asarray(to_codes(batch)).tolist() == [code(Status.not_converged), code(Status.successful)]


PRIVATE = re.compile("|".join([  # (spelled in pieces: this file does not match itself)
    re.escape("." + "_value") + r"\b", re.escape("equinox." + "_"), re.escape("eqx." + "_"),
    "_index" + "_to_message", re.escape("jax." + "_src"), re.escape("._" + "arrays") + r"\b"]))


ALLOWED = {  # test harnesses that must fake what only an internal can (none in the packages)
    "tests/test_cache.py": "a subprocess that pretends an NVIDIA GPU is present (jax's hardware probe)",
    "tests/test_results.py": "this check's own docstrings",
    "tests/test_tracing.py": "how often vmap batches a loop body (jax's batching module; no public API counts it)",
}


def _private_accesses(root):
    adapter = root / "cstiffjax" / "core" / "internals.py"
    return [f"{p.relative_to(root)}:{i}" for folder in ("cstiffjax", "fitting", "tests", "benchmarks")
            for p in sorted((root / folder).rglob("*.py"))
            if p != adapter and str(p.relative_to(root)) not in ALLOWED
            for i, line in enumerate(p.read_text().splitlines(), 1) if PRIVATE.search(line)]


def test_private_internals_only_in_the_adapter():
    """No module but ``cstiffjax/core/internals.py`` reaches into JAX's or equinox's private
    parts (a Status's integer code, equinox's enumeration module, ``jax._src``, an array's
    buffers): the status adapter (``to_codes``/``from_codes``/``code``) and the runtime use it."""
    assert _private_accesses(ROOT) == []


def test_a_planted_private_access_is_found(tmp_path):
    """The check can fail: a copy of the packages with one private access planted is caught."""
    import shutil
    for folder in ("cstiffjax", "fitting"):
        shutil.copytree(ROOT / folder, tmp_path / folder, ignore=shutil.ignore_patterns("__pycache__"))
    target = tmp_path / "cstiffjax" / "runtime" / "programs.py"
    target.write_text(target.read_text() + "\nfrom jax." + "_src import core as _core  # planted\n")
    assert _private_accesses(tmp_path) == [f"cstiffjax/runtime/programs.py:{len(target.read_text().splitlines())}"]
