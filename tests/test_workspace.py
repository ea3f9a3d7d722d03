"""Chunked, sharded sweeps: equal to a plain vmap, sharded (2 CPU devices) equal to unsharded."""

import os
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cstiffjax.workspace.sweep import Grid, sweep


def fn(pose):
    return {"a": jnp.sum(pose**2), "b": jnp.stack([jnp.sin(pose[0]), pose[2] * pose[3]])}


def test_grid_poses_and_cell_volume():
    g = Grid.regular((0.0, 1.0, 3), (-1.0, 1.0, 2), (0.5, 0.5, 1), rotation=(0.1, 0.0, 0.0))
    assert len(g) == 6 and g.shape == (3, 2, 1)
    P = g.poses()
    np.testing.assert_allclose(P[:, 0], [0, 0, 0.5, 0.5, 1, 1])
    np.testing.assert_allclose(P[:, 1], [-1, 1] * 3)
    np.testing.assert_allclose(P[:, 2:], np.tile([0.5, 0.1, 0, 0], (6, 1)))
    assert g.cell_volume == pytest.approx(0.5 * 2.0)
    with pytest.raises(ValueError, match="ny = 0 must be a positive integer"):
        Grid.regular((0, 1, 2), (0, 1, 0), (0, 1, 2))
    with pytest.raises(ValueError, match="xmax = 0.0 must exceed xmin = 1 when nx > 1"):
        Grid.regular((1, 0.0, 2), (0, 1, 2), (0, 1, 2))


def test_sweep_equals_vmap_with_padding_and_reduce():
    rng = np.random.default_rng(0)
    poses = rng.normal(size=(103, 6))
    ref = jax.vmap(fn)(jnp.asarray(poses))
    out = sweep(fn, poses, chunk_size=16, progress=False)
    np.testing.assert_allclose(out["a"], ref["a"], rtol=1e-14)
    np.testing.assert_allclose(out["b"], ref["b"], rtol=1e-14)
    total = sweep(fn, poses, chunk_size=16, progress=False, init=jnp.zeros(()),
                  reduce=lambda acc, o, valid: acc + jnp.sum(jnp.where(valid, o["a"], 0.0)))
    assert float(total) == pytest.approx(float(jnp.sum(ref["a"])), rel=1e-13)
    g = Grid.regular((-1, 1, 5), (0, 2, 4), (0.3, 0.9, 3))
    ref_g = jax.vmap(fn)(jnp.asarray(g.poses()))["a"]
    np.testing.assert_allclose(sweep(fn, g, chunk_size=7, progress=True)["a"], ref_g)


def vfn(P):  # pose-minor batch (6, b) -> trailing axis b
    return {"a": jnp.sum(P**2, axis=0), "b": jnp.stack([jnp.sin(P[0]), P[2] * P[3]])}


def test_vectorized_sweep_equals_per_pose_sweep():
    rng = np.random.default_rng(2)
    poses = rng.normal(size=(101, 6))
    ref = jax.vmap(fn)(jnp.asarray(poses))
    for bs in (None, 8, 64):
        out = sweep(vfn, poses, chunk_size=32, batch_size=bs, vectorized=True, progress=False)
        np.testing.assert_allclose(out["a"], ref["a"], rtol=1e-14)
        np.testing.assert_allclose(out["b"], ref["b"], rtol=1e-14)  # (n, 2): moved to a leading axis
    g = Grid.regular((-1, 1, 5), (0, 2, 4), (0.3, 0.9, 3), rotation=(0.0, 0.2, 0.0))
    total = sweep(vfn, g, chunk_size=9, batch_size=4, vectorized=True, progress=False, init=jnp.zeros(()),
                  reduce=lambda acc, o, valid: acc + jnp.sum(jnp.where(valid, o["a"], 0.0)))
    assert float(total) == pytest.approx(float(np.sum(g.poses() ** 2)), rel=1e-13)


def test_sweep_bad_arguments():
    with pytest.raises(ValueError, match=r"poses must have shape \(n, 6\) or be a Grid, got shape \(4, 3\)"):
        sweep(fn, np.zeros((4, 3)), chunk_size=2)
    with pytest.raises(ValueError, match="chunk_size = 0 must be a positive integer"):
        sweep(fn, np.zeros((4, 6)), chunk_size=0)
    with pytest.raises(ValueError, match="batch_size = 0 must be a positive integer or None"):
        sweep(fn, np.zeros((4, 6)), batch_size=0)
    with pytest.raises(ValueError, match="give both reduce and init"):
        sweep(fn, np.zeros((4, 6)), chunk_size=2, init=0.0)


_SHARDED = textwrap.dedent("""
    import jax, jax.numpy as jnp, numpy as np
    from cstiffjax.workspace.sweep import Grid, sweep
    assert len(jax.devices()) == 2, jax.devices()
    seen = []
    def fn(p):
        return {"a": jnp.sum(p ** 2) + jnp.prod(jnp.cos(p))}
    poses = np.random.default_rng(1).normal(size=(37, 6))
    one = sweep(fn, poses, chunk_size=8, progress=False, devices=jax.devices()[:1])
    two = sweep(fn, poses, chunk_size=8, progress=False)
    np.testing.assert_allclose(two["a"], one["a"], rtol=1e-14)
    g = Grid.regular((-1, 1, 6), (0, 1, 5), (0.2, 0.4, 3))
    red = lambda acc, o, v: acc + jnp.sum(jnp.where(v, o["a"], 0.0))
    r1 = sweep(fn, g, chunk_size=10, progress=False, reduce=red, init=0.0, devices=jax.devices()[:1])
    r2 = sweep(fn, g, chunk_size=10, progress=False, reduce=red, init=0.0)
    assert abs(float(r1) - float(r2)) < 1e-12 * abs(float(r1))
    vfn = lambda P: {"a": jnp.sum(P ** 2, axis=0) + jnp.prod(jnp.cos(P), axis=0)}
    r3 = sweep(vfn, g, chunk_size=10, batch_size=2, vectorized=True, progress=False, reduce=red, init=0.0)
    assert abs(float(r1) - float(r3)) < 1e-12 * abs(float(r1))
    v2 = sweep(vfn, poses, chunk_size=8, batch_size=2, vectorized=True, progress=False)
    np.testing.assert_allclose(v2["a"], one["a"], rtol=1e-14)
    # the chunk really is split over both devices
    from jax.sharding import Mesh, NamedSharding, PartitionSpec
    mesh = Mesh(np.array(jax.devices()), ("poses",))
    x = jax.device_put(jnp.zeros(8), NamedSharding(mesh, PartitionSpec("poses")))
    assert len(x.addressable_shards) == 2 and x.addressable_shards[0].data.shape == (4,)
    print("OK", float(r2))
""")


def test_sharded_sweep_equals_unsharded_on_two_cpu_devices():
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=2", JAX_PLATFORMS="cpu",
               JAX_ENABLE_X64="1")
    proc = subprocess.run([sys.executable, "-c", _SHARDED], env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert proc.stdout.startswith("OK")
