"""Every CPU core for the command line, and a batch axis split over the devices.

XLA runs a program on one CPU device with (mostly) one thread. JAX can present the host
as several CPU devices (``jax_num_cpu_devices``), each running its own share of a
sharded program on its own thread. The command line (:func:`cstiffjax.cli.entry`) asks
for one device per core available to the process (:func:`use_cpu_cores`) before JAX
starts; what it then splits over them:

- the diagnosis's posterior ensemble (its walkers, :func:`fitting.effects.model.walker_residuals`
  through :class:`cstiffjax.programs.Program` ``split``), the slowest part of a warm
  ``cstiffjax diagnose`` on one core;
- workspace sweeps and stiffness maps, which shard over every device already
  (:func:`cstiffjax.workspace.sweep`, :func:`cstiffjax.stiffness.stiffness`).

Every other program runs on the default device as before. A split program computes every
walker with the same arithmetic as the unsplit one (``tests/test_devices.py``).

Opting out: ``JAX_NUM_CPU_DEVICES=1`` (or any count) in the environment, or
``--xla_force_host_platform_device_count`` in ``XLA_FLAGS``: the user's choice is kept.
Python users choose for themselves (``jax.config.update("jax_num_cpu_devices", n)`` right
after ``import jax``); importing :mod:`cstiffjax` never changes it.
"""

import os

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

AXIS = "split"


def cores() -> int:
    """CPU cores this process may run on (its affinity mask where the OS has one)."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # pragma: no cover (macOS, Windows)
        return os.cpu_count() or 1


def use_cpu_cores(environ=None) -> int | None:
    """One JAX CPU device per core (:func:`cores`), unless the user chose a count
    (``JAX_NUM_CPU_DEVICES``, ``jax_num_cpu_devices``, or
    ``--xla_force_host_platform_device_count`` in ``XLA_FLAGS``) or JAX's backend is
    already running (the count cannot change then).

    **Arguments:** ``environ``: environment mapping (default ``os.environ``).

    **Returns:** the number of CPU devices set, or None when nothing was changed.
    """
    env = os.environ if environ is None else environ
    if "JAX_NUM_CPU_DEVICES" in env or "xla_force_host_platform_device_count" in env.get("XLA_FLAGS", ""):
        return None
    if jax.config.jax_num_cpu_devices != -1:
        return None
    n = cores()
    if n < 2:
        return None
    try:
        jax.config.update("jax_num_cpu_devices", n)
    except RuntimeError:  # the backend is running (e.g. main() called from Python after JAX work)
        return None
    return n


def split_count(n: int) -> int:
    """How many devices to split a leading axis of length ``n`` over: the largest divisor
    of ``n`` not above the number of this process's devices (1 with one device or in a
    multi-process run)."""
    if n < 2 or jax.process_count() != 1:
        return 1
    d = min(len(jax.local_devices()), n)
    while n % d:
        d -= 1
    return d


def split_shardings(num_leaves: int, split_leaf: int, count: int):
    """``(in_shardings, out_sharding)`` of a program over the first ``count`` local devices
    whose flat argument ``split_leaf`` (of ``num_leaves``) and every output are split along
    their leading axis; the other arguments are replicated."""
    mesh = Mesh(np.array(jax.local_devices()[:count]), (AXIS,))
    split = NamedSharding(mesh, PartitionSpec(AXIS))
    whole = NamedSharding(mesh, PartitionSpec())
    return tuple(split if i == split_leaf else whole for i in range(num_leaves)), split
