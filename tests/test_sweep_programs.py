"""``sweep`` compiles its chunk program once: counted with JAX's compile events.

A second call with the same function, kind of input and chunk shape traces and compiles
nothing; the chunk loop compiles one program however many chunks there are (the last one
is padded); another grid reuses the program with its own poses; two
functions never share one (what they capture is a constant of their program).
"""

import contextlib

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.tree_util import Partial

from cstiffjax.workspace import sweep as sweep_module
from cstiffjax.workspace.sweep import PROGRAMS_KEPT, Grid, launch_sizes, sweep


@contextlib.contextmanager
def compile_events():
    """``(event, fun_name)`` of every trace / lowering / backend compile inside the block."""
    events = []

    def listen(name, secs, **kw):
        if name.startswith("/jax/core/compile/"):
            events.append((name.rsplit("/", 1)[-1], kw.get("fun_name")))

    jax.monitoring.register_event_duration_secs_listener(listen)
    try:
        yield events
    finally:
        jax.monitoring.unregister_event_duration_listener(listen)


def backend_compiles(events, name=None):
    return [f for e, f in events if e == "backend_compile_duration" and (name is None or f == f"jit({name})")]


def per_pose(p):
    return {"a": jnp.sum(p**2), "b": jnp.stack([jnp.sin(p[0]), p[2] * p[3]])}


def pose_minor(P):
    return {"a": jnp.sum(P**2, axis=0)}


def fold(acc, o, valid):
    return acc[0] + jnp.sum(jnp.where(valid, o["a"], 0.0)), acc[1] + jnp.sum(valid)


def test_second_call_compiles_nothing_and_chunks_share_one_program():
    poses = np.random.default_rng(0).normal(size=(103, 6))  # 7 chunks of 16, the last padded
    ref = jax.vmap(per_pose)(jnp.asarray(poses))
    with compile_events() as first:
        out = sweep(per_pose, poses, chunk_size=16, batch_size=4, progress=False)
    assert len(backend_compiles(first, "sweep_chunk")) == 1, first
    np.testing.assert_allclose(out["a"], ref["a"], rtol=1e-14)
    np.testing.assert_allclose(out["b"], ref["b"], rtol=1e-14)
    with compile_events() as again:
        out2 = sweep(per_pose, poses, chunk_size=16, batch_size=4, progress=False)
    assert again == []
    np.testing.assert_array_equal(out2["a"], out["a"])
    # a grid, the pose-minor form and a fold whose init is a Python float and int (weakly typed)
    g = Grid.regular((-1, 1, 5), (0, 2, 4), (0.3, 0.9, 3), rotation=(0.0, 0.2, 0.0))
    with compile_events() as first:
        s, c = sweep(pose_minor, g, chunk_size=9, batch_size=4, vectorized=True, reduce=fold, init=(0.0, 0),
                     progress=False)
    assert len(backend_compiles(first, "sweep_chunk_reduce")) == 1, first
    assert float(s) == pytest.approx(float(np.sum(g.poses() ** 2)), rel=1e-13) and int(c) == len(g) == 60
    with compile_events() as again:
        s2, c2 = sweep(pose_minor, g, chunk_size=9, batch_size=4, vectorized=True, reduce=fold, init=(0.0, 0),
                       progress=False)
    assert again == [] and float(s2) == float(s) and int(c2) == int(c)
    # another grid (other bounds, rotation and shape; chunks of the same size): same program, its own poses
    g2 = Grid.regular((0, 2, 3), (-1, 0, 7), (0.1, 0.5, 2), rotation=(0.3, 0.0, 0.0))
    with compile_events() as other:
        s3, _ = sweep(pose_minor, g2, chunk_size=9, batch_size=4, vectorized=True, reduce=fold, init=(0.0, 0),
                      progress=False)
    assert backend_compiles(other) == []
    assert float(s3) == pytest.approx(float(np.sum(g2.poses() ** 2)), rel=1e-13)


def scaled(scale, p):
    return {"a": np.asarray(scale) @ p}  # needs the captured array concrete: a constant of the program


def test_each_function_its_own_program_and_its_captured_values_concrete():
    poses = np.random.default_rng(1).normal(size=(50, 6))
    w1, w2 = np.arange(6.0), np.linspace(-1.0, 2.0, 6)
    f1, f2 = Partial(scaled, jnp.asarray(w1)), Partial(scaled, jnp.asarray(w2))
    np.testing.assert_allclose(sweep(f1, poses, chunk_size=16, progress=False)["a"], poses @ w1, rtol=1e-14)
    with compile_events() as events:  # same code, other captured values: its own program and result
        np.testing.assert_allclose(sweep(f2, poses, chunk_size=16, progress=False)["a"], poses @ w2, rtol=1e-14)
    assert len(backend_compiles(events, "sweep_chunk")) == 1
    with compile_events() as events:
        np.testing.assert_allclose(sweep(f1, poses, chunk_size=16, progress=False)["a"], poses @ w1, rtol=1e-14)
    assert events == []
    # closures, likewise
    g1 = (lambda w: lambda p: {"a": jnp.asarray(w) @ p})(w1)
    g2 = (lambda w: lambda p: {"a": jnp.asarray(w) @ p})(w2)
    np.testing.assert_allclose(sweep(g1, poses, chunk_size=16, progress=False)["a"], poses @ w1, rtol=1e-14)
    np.testing.assert_allclose(sweep(g2, poses, chunk_size=16, progress=False)["a"], poses @ w2, rtol=1e-14)


class Weights(eqx.Module):
    """A function object that does not hash (an array field): kept by identity."""

    w: jax.Array

    def __call__(self, p):
        return {"a": self.w @ p}


def test_program_cache_is_bounded_and_unhashable_functions_are_kept_by_identity():
    poses = np.random.default_rng(2).normal(size=(8, 6))
    for k in range(PROGRAMS_KEPT + 3):
        out = sweep(lambda p, k=k: {"a": p[0] + k}, poses, progress=False)
        np.testing.assert_allclose(out["a"], poses[:, 0] + k)
    assert len(sweep_module._PROGRAMS) == PROGRAMS_KEPT
    f = Weights(jnp.arange(6.0))
    with pytest.raises(TypeError):
        hash(f)
    np.testing.assert_allclose(sweep(f, poses, progress=False)["a"], poses @ np.arange(6.0))
    with compile_events() as events:
        np.testing.assert_allclose(sweep(f, poses, progress=False)["a"], poses @ np.arange(6.0))
    assert events == []
    with compile_events() as events:  # an equal-looking but distinct object: its own program
        np.testing.assert_allclose(sweep(Weights(-jnp.arange(6.0)), poses, progress=False)["a"],
                                   -poses @ np.arange(6.0))
    assert len(backend_compiles(events, "sweep_chunk")) == 1
    sweep_module.clear_programs()
    assert len(sweep_module._PROGRAMS) == 0


def test_launch_sizes_per_backend_and_defaults_on_this_cpu():
    assert launch_sizes("cpu", True) == (65536, 64)
    assert launch_sizes("cpu", False, 4) == (65536, 1024)
    assert launch_sizes("gpu", True, 2) == (2 * 2**20, None)
    assert launch_sizes("tpu", False) == (2**18, None)
    poses = np.random.default_rng(3).normal(size=(70, 6))
    auto = sweep(pose_minor, poses, vectorized=True, progress=False)  # CPU defaults: batches of 64
    np.testing.assert_allclose(auto["a"], np.sum(poses**2, axis=1), rtol=1e-14)
    assert sweep_module._batch_size(70, 1, *launch_sizes("cpu", True)) == (128, 128, 64)
    assert sweep_module._batch_size(3_000_000, 2, *launch_sizes("gpu", True, 2)) == (2**21, 2**20, 2**20)


def test_reduce_that_changes_the_accumulator_is_refused():
    with pytest.raises(ValueError, match="reduce must return an accumulator shaped like init"):
        sweep(per_pose, np.zeros((4, 6)), reduce=lambda acc, o, v: jnp.stack([acc, acc]), init=0.0,
              progress=False)
    with pytest.raises(ValueError, match=r"no poses \(an empty \(0, 6\) array\)"):
        sweep(per_pose, np.zeros((0, 6)), progress=False)
