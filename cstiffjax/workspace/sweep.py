"""Workspace sweeps: any per-pose function over many poses, vmapped, chunked and sharded.

:func:`sweep` evaluates ``fn(pose)`` (a pure JAX function of one pose returning a pytree of
arrays; or of a pose-minor batch ``(6, b)`` with ``vectorized=True``) over an ``(n, 6)``
array of poses or a lazy regular :class:`Grid`. Poses go through in chunks of
``chunk_size`` so memory stays bounded; each chunk is split over all devices of a 1-D
``jax.sharding.Mesh`` (axis ``"poses"``, ``jax.shard_map``: each device runs its slice as
a ``lax.map`` over cache-sized batches), so the same code runs on one CPU, on several CPU
devices
(``XLA_FLAGS=--xla_force_host_platform_device_count=N``) or on GPUs. For a :class:`Grid`
only the flat indices go to the devices, which generate the poses.
With ``reduce`` the per-chunk outputs are folded into an accumulator on the devices and
never reach the host, so host memory is bounded too (CSS volume over 1e8 poses, say).

Several hosts
-------------
The same function works under ``jax.distributed`` (one process per host, each seeing
its local devices; ``jax.devices()`` then lists all of them)::

    import jax
    jax.distributed.initialize()            # coordinator address/process id from the env
                                            # (SLURM, TPU, or JAX_COORDINATOR_ADDRESS, ...)
    from cstiffjax.workspace.sweep import Grid, sweep
    grid = Grid.regular((-0.5, 0.5, 1001), (-0.4, 0.4, 801), (0.5, 1.3, 801))
    total = sweep(fn, grid, chunk_size=2**20, reduce=combine, init=init0)   # same on all hosts

Every process must run the same ``sweep`` call (same grid, ``chunk_size``, ``fn``). Chunks
are assembled with ``jax.make_array_from_callback``, which asks each process only for its
addressable shards, so no host holds more than its part. Use ``reduce`` (the accumulator
is replicated: every process gets the total); without it, outputs are gathered to every
host with ``jax.experimental.multihost_utils.process_allgather``.
"""


import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from cstiffjax.core.progress import bar as _bar


class Grid(eqx.Module):
    """Regular grid of positions ``lower + index * step`` with one fixed rotation vector.

    ``shape`` (static) is ``(nx, ny, nz)``; flat index ``k`` is C-ordered (z fastest).
    """

    lower: jax.Array
    step: jax.Array
    rotation: jax.Array
    shape: tuple = eqx.field(static=True)

    @classmethod
    def regular(cls, x, y, z, rotation=(0.0, 0.0, 0.0)) -> "Grid":
        """``x = (xmin, xmax, nx)`` etc. (m; ``n >= 1``; a single point when ``n = 1``)."""
        lo, st, shape = [], [], []
        for name, (a, b, n) in zip("xyz", (x, y, z)):
            if int(n) != n or n < 1:
                raise ValueError(f"Grid: n{name} = {n!r} must be a positive integer")
            if n > 1 and not b > a:
                raise ValueError(f"Grid: {name}max = {b!r} must exceed {name}min = {a!r} when n{name} > 1")
            lo.append(float(a))
            st.append((float(b) - float(a)) / (n - 1) if n > 1 else 0.0)
            shape.append(int(n))
        return cls(jnp.asarray(lo), jnp.asarray(st), jnp.asarray(rotation, dtype=jnp.float64), tuple(shape))

    def __len__(self) -> int:
        return int(np.prod(self.shape))

    @property
    def cell_volume(self) -> float:
        """Volume represented by one grid point, m³ (product of the non-zero steps)."""
        st = np.asarray(self.step)
        return float(np.prod(np.where(st > 0, st, 1.0)))

    def axes(self):
        """The three coordinate vectors (numpy), m."""
        return [np.asarray(self.lower[i] + self.step[i] * np.arange(n)) for i, n in enumerate(self.shape)]

    def pose(self, index) -> jax.Array:
        """Pose ``[x, y, z, rx, ry, rz]`` of flat index ``index`` (works under jit/vmap)."""
        ijk = jnp.stack(jnp.unravel_index(index, self.shape)).astype(jnp.float64)
        return jnp.concatenate([self.lower + ijk * self.step, self.rotation])

    def poses(self) -> np.ndarray:
        """All poses as an ``(n, 6)`` numpy array (small grids only)."""
        return np.asarray(jax.vmap(self.pose)(jnp.arange(len(self))))


def _batch_size(n, ndev, chunk_size, batch_size):
    """``(chunk, per_device, bs)``: a chunk is ``ndev`` device slices of ``per_device``
    poses, each a whole number of batches of ``bs``."""
    per_device = -(-min(int(chunk_size), max(n, 1)) // ndev)
    bs = per_device if batch_size is None else max(1, min(int(batch_size), per_device))
    per_device = -(-per_device // bs) * bs
    return per_device * ndev, per_device, bs


def _local_evaluator(fn, grid, bs, vectorized):
    """The per-device function of one chunk slice: ``lax.map`` over batches of ``bs``."""
    def poses_of(x):  # (bs, 6) poses, or (bs,) grid indices -> (bs, 6)
        return jax.vmap(grid.pose)(x) if grid is not None else x

    def batch(x):
        p = poses_of(x)
        if vectorized:
            return jax.tree.map(lambda a: jnp.moveaxis(a, -1, 0), fn(p.T))
        return jax.vmap(fn)(p)

    def local(x):
        out = jax.lax.map(batch, x.reshape(-1, bs, *x.shape[1:]))
        return jax.tree.map(lambda a: a.reshape(-1, *a.shape[2:]), out)

    return local


def sweep(fn, poses, *, chunk_size: int = 65536, progress: bool | None = None, reduce=None, init=None,
          devices=None, batch_size: int | None = 1024, vectorized: bool = False, desc: str = "sweep"):
    """Evaluate ``fn`` over many poses: batched, in chunks, sharded over devices.

    **Arguments:**

    - ``fn``: pure JAX function of one pose ``(6,)`` returning a pytree of arrays; or,
      with ``vectorized=True``, of a pose-minor batch ``(6, b)`` returning arrays whose
      *last* axis is ``b`` (e.g. :func:`cstiffjax.stiffness.css.css_point`, whose batch form keeps
      the poses on the contiguous axis and is several times faster than ``vmap``).
    - ``poses``: ``(n, 6)`` array (m, rad) or a :class:`Grid` (generated on device).
    - ``chunk_size``: poses per step (rounded up to whole batches on every device);
      bounds memory. The last chunk is padded and the padding masked out.
    - ``progress``: progress bar on stderr: None (default) only on a terminal and
      outside quiet mode, True/False always/never (:mod:`cstiffjax.core.progress`).
    - ``reduce``, ``init``: optional fold ``reduce(acc, outputs, valid) -> acc`` where
      ``outputs`` is the chunk's batched pytree (leading axis = poses) and ``valid`` a
      ``(chunk,)`` bool mask; ``init`` the initial accumulator. Runs on the devices,
      jitted with ``fn``.
    - ``devices``: devices to shard over (default ``jax.devices()``); each evaluates its
      slice of every chunk (``jax.shard_map`` over a 1-D mesh, axis ``"poses"``).
    - ``batch_size``: poses per vectorized step on a device (``jax.lax.map`` over
      batches): keeps intermediates in cache. On a CPU, ~1024 suits ``vmap`` and ~64
      the pose-minor form; None takes the whole slice at once.
    - ``vectorized``: see ``fn``.

    **Returns:** without ``reduce``, the outputs as numpy arrays with a leading axis
    ``n``; with ``reduce``, the final accumulator (numpy pytree).
    """
    if chunk_size < 1:
        raise ValueError(f"sweep: chunk_size = {chunk_size!r} must be a positive integer")
    if batch_size is not None and batch_size < 1:
        raise ValueError(f"sweep: batch_size = {batch_size!r} must be a positive integer or None")
    if (reduce is None) != (init is None):
        raise ValueError("sweep: give both reduce and init, or neither")
    is_grid = isinstance(poses, Grid)
    if not is_grid:
        poses = np.asarray(poses, dtype=np.float64)
        if poses.ndim != 2 or poses.shape[1] != 6:
            raise ValueError(f"sweep: poses must have shape (n, 6) or be a Grid, got shape {poses.shape}")
    n = len(poses)
    devices = list(jax.devices() if devices is None else devices)
    mesh = Mesh(np.array(devices), ("poses",))
    sharded = NamedSharding(mesh, PartitionSpec("poses"))
    replicated = NamedSharding(mesh, PartitionSpec())
    chunk, _, bs = _batch_size(n, len(devices), chunk_size, batch_size)
    local = jax.shard_map(_local_evaluator(fn, poses if is_grid else None, bs, vectorized), mesh=mesh,
                          in_specs=PartitionSpec("poses"), out_specs=PartitionSpec("poses"),
                          check_vma=False)  # no collectives inside: each device works alone

    def evaluate(batch, start):
        return local(batch), start + jnp.arange(chunk) < n

    if reduce is None:
        step = jax.jit(evaluate, in_shardings=(sharded, None), out_shardings=(sharded, sharded))
    else:
        def step_reduce(acc, batch, start):
            out, valid = evaluate(batch, start)
            return reduce(acc, out, valid)

        step = jax.jit(step_reduce, in_shardings=(replicated, sharded, None), out_shardings=replicated)
        acc = jax.device_put(jax.tree.map(jnp.asarray, init), replicated)

    def make_batch(start):
        if is_grid:
            host = np.minimum(np.arange(start, start + chunk), max(n - 1, 0))
        else:
            host = poses[np.minimum(np.arange(start, start + chunk), n - 1)]
        return jax.make_array_from_callback(host.shape, sharded, lambda idx: host[idx])

    bar = _bar(total=n, desc=desc, progress=progress, unit="pose", unit_scale=True)
    results = None
    try:
        for start in range(0, n, chunk):
            batch = make_batch(start)
            if reduce is not None:
                acc = jax.block_until_ready(step(acc, batch, start))  # one chunk in flight: bounded memory
            else:
                out, _ = step(batch, start)
                host = jax.tree.map(_to_host, out)
                if results is None:
                    results = jax.tree.map(lambda a: np.empty((n, *a.shape[1:]), a.dtype), host)
                k = min(chunk, n - start)
                for dst, src in zip(jax.tree.leaves(results), jax.tree.leaves(host)):
                    dst[start:start + k] = src[:k]
            bar.update(min(chunk, n - start))
    finally:
        bar.close()
    if reduce is not None:
        return jax.tree.map(_to_host, acc)
    return results


def _to_host(a):
    if getattr(a, "is_fully_addressable", True):
        return np.asarray(a)
    from jax.experimental import multihost_utils  # several hosts

    return np.asarray(multihost_utils.process_allgather(a, tiled=True))
