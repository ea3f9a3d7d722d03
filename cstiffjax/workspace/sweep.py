"""Workspace sweeps: any per-pose function over many poses, vmapped, chunked and sharded.

:func:`sweep` evaluates ``fn(pose)`` (a pure JAX function of one pose returning a pytree of
arrays; or of a pose-minor batch ``(6, b)`` with ``vectorized=True``) over an ``(n, 6)``
array of poses or a lazy regular :class:`Grid`. Poses go through in chunks of
``chunk_size`` so memory stays bounded; each chunk is split over all devices of a 1-D
``jax.sharding.Mesh`` (axis ``"poses"``, ``jax.shard_map``: each device runs its slice as
a ``lax.map`` over batches), so the same code runs on one CPU, on several CPU devices
(``XLA_FLAGS=--xla_force_host_platform_device_count=N``), on GPUs or on TPUs. For a
:class:`Grid` nothing goes to the devices per chunk but the chunk's first index: every
device generates its own poses. With ``reduce`` the per-chunk outputs are folded into an
accumulator on the devices and never reach the host, so host memory is bounded too (CSS
volume over 1e8 poses, say).

Compiled once
-------------
The chunk program is compiled once for a given ``fn`` and ``reduce`` (told apart by
identity, or by value when they hash by value), kind of input, sizes, devices and
shapes, and kept: the last :data:`PROGRAMS_KEPT` of them per process
(:func:`clear_programs` drops them). A second ``sweep`` with the same function compiles
nothing, and the chunk loop never recompiles (the last chunk is padded and the padding
masked out). Whatever ``fn`` captures is a constant of its program, as under
``jax.jit`` of a closure: define the function once and pass it again (a new ``lambda``
per call compiles per call). A :class:`Grid`'s bounds and rotation are arguments of the
program, and so is its shape: another grid reuses it when both have at least
``chunk_size`` poses (a smaller one makes a chunk of its own size).

Sizes per backend
-----------------
With the defaults (``chunk_size=None``, ``batch_size="auto"``; :func:`launch_sizes`) a
CPU runs chunks of 65536 poses in cache-sized batches (64 poses for the pose-minor form,
1024 under ``vmap``); a GPU or TPU runs each device's whole slice in one vectorized step,
2^20 poses per device per launch (2^18 under ``vmap``, whose per-pose intermediates are
larger). Either can be given. Chunks are dispatched without waiting: while the devices
work on one, the host prepares the next (JAX's asynchronous dispatch), and with ``reduce``
the host only waits for the chunk before the one in flight.

Several hosts
-------------
The same call works under ``jax.distributed`` (one process per host, each seeing its
local devices; ``jax.devices()`` then lists all of them)::

    import jax
    jax.distributed.initialize()            # coordinator address/process id from the env
                                            # (SLURM, TPU, or JAX_COORDINATOR_ADDRESS, ...)
    from cstiffjax.workspace.sweep import Grid, sweep
    grid = Grid.regular((-0.5, 0.5, 1001), (-0.4, 0.4, 801), (0.5, 1.3, 801))
    total = sweep(fn, grid, reduce=combine, init=init0)   # the same total on every host

Every process must make the same ``sweep`` call (same poses or grid, sizes, ``fn``). The
mesh spans the devices of all processes. Each process holds the whole ``(n, 6)`` array of
poses on its host, but a chunk is assembled with ``jax.make_array_from_callback``, which
takes from each process only the poses of its own devices; a :class:`Grid`'s poses are
generated on the devices, so nothing is sent. With ``reduce`` the accumulator is
replicated (every process gets the total; the fold's sums run as collectives between
the processes); without it, every chunk's outputs are gathered to every host with
``jax.experimental.multihost_utils.process_allgather``. On CPUs the collectives between
processes run over gloo (``jax_cpu_collectives_implementation``, jaxlib's default).
Tested with two processes of two CPU devices each on one machine, coordinator on
127.0.0.1 (``tests/test_sweep_distributed.py``): the totals equal one process's exactly.
"""

import collections

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from cstiffjax.core.progress import bar as _bar

CPU_CHUNK = 65536
"""Poses per chunk on a CPU (all devices together)."""
CPU_BATCH = {True: 64, False: 1024}
"""Poses per vectorized step on a CPU device, pose-minor form (``True``) or ``vmap``."""
ACCELERATOR_SLICE = {True: 1 << 20, False: 1 << 18}
"""Poses per device per launch on a GPU or TPU (whole slices, one vectorized step)."""
PROGRAMS_KEPT = 32
"""Compiled chunk programs kept per process (least recently used dropped first)."""


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
        """Volume of one interior grid cell, m³ (product of the non-zero steps). A point on a
        face, edge or corner of the grid box stands for a half, quarter or eighth of it:
        :meth:`point_volume`; a set's volume is :meth:`volume`."""
        st = np.asarray(self.step)
        return float(np.prod(np.where(st > 0, st, 1.0)))

    def point_volume(self, position) -> jax.Array:
        """Volume each grid point stands for (trapezoid weights), m³.

        Along an axis with ``n > 1`` points an interior point counts one step, the two end
        points half a step each, so the points' volumes add up to the grid box exactly
        (``(xmax - xmin) (ymax - ymin) (zmax - zmin)``) and a set's volume
        (the sum of its member points' volumes) converges to the set's volume as the grid is refined.
        An axis with one point contributes a factor 1 (the measure is then an area or a
        length, m² or m). Works under jit/vmap and on pose-minor batches.

        **Arguments:** ``position``: grid positions with the coordinates on the leading axis,
        ``(3, ...)`` m (e.g. ``pose[:3]`` of one pose or of a ``(6, b)`` batch); each is
        taken as its nearest grid point.

        **Returns:** the volumes, shape ``position.shape[1:]``, m³.
        """
        pos = jnp.asarray(position, dtype=jnp.float64)
        if pos.ndim < 1 or pos.shape[0] != 3:
            raise ValueError(f"Grid.point_volume: position must have shape (3, ...), got {pos.shape}")
        col = (3,) + (1,) * (pos.ndim - 1)
        step = self.step.reshape(col)
        n = jnp.asarray(self.shape).reshape(col)
        index = jnp.round((pos - self.lower.reshape(col)) / jnp.where(step > 0, step, 1.0))
        end = (index <= 0) | (index >= n - 1)
        w = jnp.where(n > 1, jnp.where(end, 0.5, 1.0) * step, 1.0)
        return jnp.prod(w, axis=0)

    def point_volumes(self) -> np.ndarray:
        """:meth:`point_volume` of every grid point, shape ``grid.shape`` (numpy), m³;
        they add up to the grid box's volume."""
        mesh = np.stack(np.meshgrid(*self.axes(), indexing="ij"))
        return np.asarray(self.point_volume(mesh))

    def volume(self, member) -> float:
        """Volume of the set whose grid points are ``member``, m³: the sum of their
        :meth:`point_volume` (a set filling the grid box has exactly the box's volume).

        **Arguments:** ``member``: bool per grid point, shape ``grid.shape`` or flat ``(n,)``
        in the grid's C order.
        """
        member = np.asarray(member, dtype=bool)
        if member.size != len(self):
            raise ValueError(f"Grid.volume: member has {member.size} entries, the grid {len(self)} points")
        return float(np.sum(np.where(member.reshape(self.shape), self.point_volumes(), 0.0)))

    def axes(self):
        """The three coordinate vectors (numpy), m."""
        return [np.asarray(self.lower[i] + self.step[i] * np.arange(n)) for i, n in enumerate(self.shape)]

    def pose(self, index) -> jax.Array:
        """Pose ``[x, y, z, rx, ry, rz]`` of flat index ``index`` (works under jit/vmap)."""
        return _grid_pose(self.lower, self.step, self.rotation, self.shape, index)

    def poses(self) -> np.ndarray:
        """All poses as an ``(n, 6)`` numpy array (small grids only)."""
        return np.asarray(jax.vmap(self.pose)(jnp.arange(len(self))))


def _grid_pose(lower, step, rotation, shape, index):
    """Pose of flat index ``index`` (C order, z fastest) of the grid ``lower + ijk * step``
    with ``shape`` ``(nx, ny, nz)`` static or traced (a traced shape lets grids of every
    size share one chunk program)."""
    rest, k = jnp.divmod(index, shape[2])
    i, j = jnp.divmod(rest, shape[1])
    ijk = jnp.stack([i, j, k]).astype(jnp.float64)
    return jnp.concatenate([lower + ijk * step, rotation])


def launch_sizes(platform: str, vectorized: bool, num_devices: int = 1) -> tuple[int, int | None]:
    """The default ``(chunk_size, batch_size)`` of :func:`sweep` on a backend.

    **Arguments:** ``platform``: ``jax.Device.platform`` (``"cpu"``, ``"gpu"``, ``"tpu"``,
    ...); ``vectorized``: the pose-minor form (``True``) or ``vmap`` of the one-pose form;
    ``num_devices``: devices the chunk is split over.

    **Returns:** poses per chunk (all devices together) and per vectorized step on a
    device (``None``: the device's whole slice): :data:`CPU_CHUNK` and
    :data:`CPU_BATCH` on a CPU, :data:`ACCELERATOR_SLICE` per device and ``None`` on any
    other platform.
    """
    if platform == "cpu":
        return CPU_CHUNK, CPU_BATCH[bool(vectorized)]
    return ACCELERATOR_SLICE[bool(vectorized)] * max(int(num_devices), 1), None


def _batch_size(n, ndev, chunk_size, batch_size):
    """``(chunk, per_device, bs)``: a chunk is ``ndev`` device slices of ``per_device``
    poses, each a whole number of batches of ``bs``."""
    per_device = -(-min(int(chunk_size), max(n, 1)) // ndev)
    bs = per_device if batch_size is None else max(1, min(int(batch_size), per_device))
    per_device = -(-per_device // bs) * bs
    return per_device * ndev, per_device, bs


_PROGRAMS: collections.OrderedDict = collections.OrderedDict()  # key -> jitted chunk program, LRU order


def _program(key, build):
    """The program of ``key`` from the bounded cache, built (and kept) on a miss."""
    program = _PROGRAMS.pop(key, None)
    if program is None:
        program = build()
    _PROGRAMS[key] = program
    while len(_PROGRAMS) > PROGRAMS_KEPT:
        _PROGRAMS.popitem(last=False)
    return program


def clear_programs() -> None:
    """Drop every kept chunk program (and with it the functions and constants they hold)."""
    _PROGRAMS.clear()


class _Same:
    """Key of an object that cannot be hashed by value: equal only to itself (holds it,
    so its ``id`` stays unique while the key lives)."""

    __slots__ = ("obj",)

    def __init__(self, obj):
        self.obj = obj

    def __hash__(self):
        return id(self.obj)

    def __eq__(self, other):
        return isinstance(other, _Same) and other.obj is self.obj


def _key_of(obj):
    """``obj`` itself when it hashes (functions by identity, frozen modules by value),
    else a :class:`_Same` of it."""
    try:
        hash(obj)
    except TypeError:
        return _Same(obj)
    return obj


def _build(fn, reduce, is_grid, mesh, per_device, bs, vectorized):
    """The jitted chunk program: ``step(grid, x, start, n) -> outputs`` (sharded), or with
    ``reduce`` ``step(grid, acc, x, start, n) -> acc`` (replicated). ``grid`` is a
    :class:`Grid`'s ``(lower, step, rotation, shape)`` as arrays (``None`` for an array of
    poses), ``x`` the chunk's poses (``None`` for a grid), ``start`` the chunk's first flat
    index and ``n`` the number of poses."""
    sharded, replicated = NamedSharding(mesh, PartitionSpec("poses")), NamedSharding(mesh, PartitionSpec())

    def local(grid, x, start, n):  # one device's slice of the chunk
        index = start + jax.lax.axis_index("poses").astype(start.dtype) * per_device + jnp.arange(per_device)
        if is_grid:
            x = jnp.minimum(index, n - 1)  # the padding repeats the last pose

        def batch(xb):  # (bs, 6) poses, or (bs,) grid indices
            p = jax.vmap(lambda k: _grid_pose(*grid, k))(xb) if is_grid else xb
            if vectorized:
                return jax.tree.map(lambda a: jnp.moveaxis(a, -1, 0), fn(p.T))
            return jax.vmap(fn)(p)

        if bs == per_device:
            out = batch(x)
        else:
            out = jax.lax.map(batch, x.reshape(-1, bs, *x.shape[1:]))
            out = jax.tree.map(lambda a: a.reshape(-1, *a.shape[2:]), out)
        return out, index < n

    spec = PartitionSpec("poses")
    mapped = jax.shard_map(local, mesh=mesh, in_specs=(PartitionSpec(), spec, PartitionSpec(), PartitionSpec()),
                           out_specs=spec, check_vma=False)  # no collectives inside: each device works alone
    if reduce is None:
        def sweep_chunk(grid, x, start, n):
            return mapped(grid, x, start, n)[0]

        return jax.jit(sweep_chunk, in_shardings=(replicated, sharded, replicated, replicated),
                       out_shardings=sharded)

    def sweep_chunk_reduce(grid, acc, x, start, n):
        return reduce(acc, *mapped(grid, x, start, n))

    return jax.jit(sweep_chunk_reduce, in_shardings=(replicated, replicated, sharded, replicated, replicated),
                   out_shardings=replicated)


def _replicate(tree, sharding):
    """``tree``'s arrays placed on every device of ``sharding`` (a global, replicated
    array across processes under ``jax.distributed``)."""
    if jax.process_count() == 1:
        return jax.device_put(tree, sharding)

    def put(a):
        host = np.asarray(a)
        return jax.make_array_from_callback(host.shape, sharding, lambda idx: host[idx])

    return jax.tree.map(put, tree)


def sweep(fn, poses, *, chunk_size: int | None = None, progress: bool | None = None, reduce=None, init=None,
          devices=None, batch_size: int | str | None = "auto", vectorized: bool = False, desc: str = "sweep"):
    """Evaluate ``fn`` over many poses: batched, in chunks, sharded over devices, compiled once.

    **Arguments:**

    - ``fn``: pure JAX function of one pose ``(6,)`` returning a pytree of arrays; or,
      with ``vectorized=True``, of a pose-minor batch ``(6, b)`` returning arrays whose
      *last* axis is ``b`` (e.g. :func:`cstiffjax.stiffness.css.css_point`, whose batch form keeps
      the poses on the contiguous axis and is several times faster than ``vmap``). Its
      compiled program is kept for the next call with the same ``fn`` (module docstring,
      "Compiled once").
    - ``poses``: ``(n, 6)`` array (m, rad) or a :class:`Grid` (generated on device).
    - ``chunk_size``: poses per step, all devices together (rounded up to whole batches on
      every device); bounds memory. The last chunk is padded and the padding masked out.
      ``None``: :func:`launch_sizes` for the devices' platform.
    - ``progress``: progress bar on stderr: None (default) only on a terminal and
      outside quiet mode, True/False always/never (:mod:`cstiffjax.core.progress`).
    - ``reduce``, ``init``: optional fold ``reduce(acc, outputs, valid) -> acc`` where
      ``outputs`` is the chunk's batched pytree (leading axis = poses) and ``valid`` a
      ``(chunk,)`` bool mask; ``init`` the initial accumulator (the fold must keep its
      structure and shapes). Runs on the devices, compiled with ``fn``.
    - ``devices``: devices to shard over (default ``jax.devices()``: under
      ``jax.distributed`` those of every process); each evaluates its slice of every chunk
      (``jax.shard_map`` over a 1-D mesh, axis ``"poses"``).
    - ``batch_size``: poses per vectorized step on a device (``jax.lax.map`` over
      batches): on a CPU it keeps intermediates in cache. ``"auto"`` (default):
      :func:`launch_sizes` (a CPU: 64 for the pose-minor form, 1024 under ``vmap``; a GPU
      or TPU: the whole slice); None: the whole slice.
    - ``vectorized``: see ``fn``.

    **Returns:** without ``reduce``, the outputs as numpy arrays with a leading axis
    ``n``; with ``reduce``, the final accumulator (numpy pytree).
    """
    if not (chunk_size is None or _positive_int(chunk_size)):
        raise ValueError(f"sweep: chunk_size = {chunk_size!r} must be a positive integer (or None: per backend)")
    if not (batch_size is None or batch_size == "auto" or _positive_int(batch_size)):
        raise ValueError(f"sweep: batch_size = {batch_size!r} must be a positive integer or None (the whole "
                         "slice), or 'auto' (per backend)")
    if (reduce is None) != (init is None):
        raise ValueError("sweep: give both reduce and init, or neither")
    is_grid = isinstance(poses, Grid)
    if not is_grid:
        poses = np.asarray(poses, dtype=np.float64)
        if poses.ndim != 2 or poses.shape[1] != 6:
            raise ValueError(f"sweep: poses must have shape (n, 6) or be a Grid, got shape {poses.shape}")
    n = len(poses)
    if n == 0:
        raise ValueError("sweep: no poses (an empty (0, 6) array)")
    devices = list(jax.devices() if devices is None else devices)
    auto_chunk, auto_batch = launch_sizes(devices[0].platform, vectorized, len(devices))
    mesh = Mesh(np.array(devices), ("poses",))
    sharded, replicated = NamedSharding(mesh, PartitionSpec("poses")), NamedSharding(mesh, PartitionSpec())
    chunk, per_device, bs = _batch_size(n, len(devices), auto_chunk if chunk_size is None else chunk_size,
                                        auto_batch if isinstance(batch_size, str) else batch_size)
    key = (_key_of(fn), _key_of(reduce), is_grid, mesh, per_device, bs, bool(vectorized))
    step = _program(key, lambda: _build(fn, reduce, is_grid, mesh, per_device, bs, bool(vectorized)))
    grid = _replicate((poses.lower, poses.step, poses.rotation, np.asarray(poses.shape, dtype=np.int64)),
                      replicated) if is_grid else None
    count = np.int64(n)

    def chunk_of(start):  # the chunk's poses, padded with the last one; nothing for a grid
        if is_grid:
            return None
        host = poses[np.minimum(np.arange(start, start + chunk), n - 1)]
        return jax.make_array_from_callback(host.shape, sharded, lambda idx: host[idx])

    starts = range(0, n, chunk)
    bar = _bar(total=n, desc=desc, progress=progress, unit="pose", unit_scale=True)
    try:
        if reduce is not None:
            acc = _accumulator(step, grid, init, chunk_of(0), count, replicated)
            for k, start in enumerate(starts):
                previous, acc = acc, step(grid, acc, chunk_of(start), np.int64(start), count)
                if k:  # one chunk in flight while the host waits for the one before it
                    jax.block_until_ready(previous)
                    bar.update(chunk)
            jax.block_until_ready(acc)
            bar.update(n - chunk * (len(starts) - 1) if len(starts) else 0)
            return jax.tree.map(_to_host, acc)
        results, pending = None, None
        for start in starts:
            out = step(grid, chunk_of(start), np.int64(start), count)
            if pending is not None:  # copy the chunk before while this one runs
                results = _store(results, *pending, n)
                bar.update(chunk)
            pending = (start, out)
        if pending is not None:
            results = _store(results, *pending, n)
            bar.update(n - pending[0])
        return results
    finally:
        bar.close()


def _positive_int(x) -> bool:
    """Whether ``x`` is a whole number >= 1 (an int, or a float such as ``1e6``)."""
    return isinstance(x, int | float | np.integer | np.floating) and not isinstance(x, bool) and x >= 1 \
        and int(x) == x


def _accumulator(step, grid, init, x, count, sharding):
    """``init`` on the devices as strongly typed arrays of the dtypes the fold returns (so
    the second chunk does not recompile for a Python scalar's weak type or an integer
    promotion). The shapes are found by tracing the first chunk's call with the arguments
    it will have, which the call itself then reuses.

    **Raises** ``ValueError`` when ``reduce`` changes the accumulator's structure or shapes.
    """
    host = jax.tree.map(np.asarray, init)
    acc = _replicate(host, sharding)
    out = jax.eval_shape(step, grid, acc, x, np.int64(0), count)
    if jax.tree.structure(out) != jax.tree.structure(host) or \
            any(a.shape != o.shape for a, o in zip(jax.tree.leaves(host), jax.tree.leaves(out))):
        raise ValueError(f"sweep: reduce must return an accumulator shaped like init: init "
                         f"{jax.tree.map(np.shape, host)}, reduce returned {jax.tree.map(lambda o: o.shape, out)}")
    if all(a.dtype == o.dtype for a, o in zip(jax.tree.leaves(host), jax.tree.leaves(out))):
        return acc
    return _replicate(jax.tree.map(lambda a, o: a.astype(o.dtype), host, out), sharding)


def _store(results, start, out, n):
    """Copy a chunk's outputs (device) into ``results`` (host, allocated on first use)."""
    host = jax.tree.map(_to_host, out)
    if results is None:
        results = jax.tree.map(lambda a: np.empty((n, *a.shape[1:]), a.dtype), host)
    k = min(len(jax.tree.leaves(host)[0]), n - start)
    for dst, src in zip(jax.tree.leaves(results), jax.tree.leaves(host)):
        dst[start:start + k] = src[:k]
    return results


def _to_host(a):
    """A (possibly multi-process) array as numpy: a replicated one from this process's
    copy, a sharded one gathered from every process."""
    if getattr(a, "is_fully_addressable", True):
        return np.asarray(a)
    if a.is_fully_replicated:
        return np.asarray(a.addressable_data(0))
    from jax.experimental import multihost_utils  # several hosts

    return np.asarray(multihost_utils.process_allgather(a, tiled=True))
