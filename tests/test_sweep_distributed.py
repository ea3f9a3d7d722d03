"""``sweep`` under ``jax.distributed``: two processes on this machine (CPU, gloo collectives,
coordinator on 127.0.0.1), two devices each, give the single-process results exactly.

Exact comparisons use sums that cannot round (dyadic grid coordinates, integer counts), so
the order in which the devices and processes add them up does not matter; the physics
case (wrench-closure over a grid of the 8-cable robot) compares its member count exactly
and its margin sum to 1e-12 against the same sweep in this process.
"""

import functools
import json
import os
import socket
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
from jax.tree_util import Partial

from cstiffjax.examples import example_path
from cstiffjax.io.robot_io import load_robot
from cstiffjax.workspace.sweep import Grid, sweep
from cstiffjax.workspace.wrench_closure import wrench_closure

_CHILD = textwrap.dedent("""
    import json, sys
    import jax
    pid, port = int(sys.argv[1]), int(sys.argv[2])
    jax.config.update("jax_cpu_collectives_implementation", "gloo")  # jaxlib's default; said, not assumed
    jax.distributed.initialize(coordinator_address=f"127.0.0.1:{port}", num_processes=2, process_id=pid,
                               initialization_timeout=60)
    import jax.numpy as jnp, numpy as np
    sys.path.insert(0, sys.argv[3])
    from test_sweep_distributed import cases
    assert jax.process_count() == 2 and len(jax.devices()) == 4 and len(jax.local_devices()) == 2, jax.devices()
    compiles = []
    jax.monitoring.register_event_duration_secs_listener(
        lambda name, secs, **kw: compiles.append(name) if name.endswith("backend_compile_duration") else None)
    out = cases()
    first = len(compiles)
    again = cases()
    assert json.dumps(again) == json.dumps(out), (again, out)
    out["compiles_first"], out["compiles_again"] = first, len(compiles) - first
    print("RESULT " + json.dumps(out), flush=True)
""")


def _dyadic(p):
    return {"s": p[0] + 2.0 * p[1] - p[2], "q": p[0] * p[1]}


def _fold(acc, o, valid):
    return (acc[0] + jnp.sum(jnp.where(valid, o["s"], 0.0)), acc[1] + jnp.sum(jnp.where(valid, o["q"], 0.0)),
            acc[2] + jnp.sum(valid))


def _closure_fold(acc, o, valid):
    m = o.member & valid
    return acc[0] + jnp.sum(m), acc[1] + jnp.sum(jnp.where(m, o.margin, 0.0))


@functools.cache
def _closure():
    """The wrench-closure batch function of the 8-cable robot (one object: compiled once)."""
    return Partial(wrench_closure, load_robot(example_path("tcpr8.toml")))


def cases(devices=None):
    """The sweeps run in both settings: ``(name -> list of numbers)``, JSON-ready."""
    grid = Grid.regular((-1.0, 1.0, 9), (-0.5, 0.5, 5), (0.0, 1.5, 7))  # 315 points, steps 1/4 (dyadic)
    poses = grid.poses()[::2] * np.array([1.0, 1.0, 1.0, 0.0, 0.0, 0.0])  # 158 poses, not a multiple of 4
    s, q, count = sweep(_dyadic, grid, chunk_size=40, reduce=_fold, init=(0.0, 0.0, 0), progress=False,
                        devices=devices)
    full = sweep(_dyadic, poses, chunk_size=24, progress=False, devices=devices)
    g8 = Grid.regular((-0.6, 0.6, 7), (-0.4, 0.4, 6), (0.2, 1.6, 9), rotation=(0.0, 0.0, 0.05))
    members, margin = sweep(_closure(), g8, chunk_size=64, vectorized=True,
                            reduce=_closure_fold, init=(0, 0.0), progress=False, devices=devices)
    return {"grid": [float(s), float(q), int(count)], "poses_s": np.asarray(full["s"]).tolist(),
            "poses_q": np.asarray(full["q"]).tolist(), "closure": [int(members), float(margin)]}


def _free_port():
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def _run_two_processes():
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=2", JAX_PLATFORMS="cpu",
               JAX_ENABLE_X64="1", PYTHONUNBUFFERED="1")
    port = _free_port()
    here = os.path.dirname(os.path.abspath(__file__))
    procs = [subprocess.Popen([sys.executable, "-c", _CHILD, str(i), str(port), here], env=env,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for i in range(2)]
    outs = []
    try:
        for p in procs:
            stdout, stderr = p.communicate(timeout=150)
            assert p.returncode == 0, stderr[-3000:]
            line = [x for x in stdout.splitlines() if x.startswith("RESULT ")]
            assert line, (stdout[-2000:], stderr[-2000:])
            outs.append(json.loads(line[0][len("RESULT "):]))
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.communicate()
    return outs


def test_two_processes_equal_one_process():
    outs = _run_two_processes()
    assert outs[0] == outs[1]  # every process gets the same totals and the same gathered outputs
    one = cases()
    got = outs[0]
    # independent references (numpy, dyadic: exact in any order)
    P = Grid.regular((-1.0, 1.0, 9), (-0.5, 0.5, 5), (0.0, 1.5, 7)).poses()
    ref_s, ref_q = P[:, 0] + 2.0 * P[:, 1] - P[:, 2], P[:, 0] * P[:, 1]
    assert got["grid"] == one["grid"] == [float(ref_s.sum()), float(ref_q.sum()), len(P)]
    assert got["poses_s"] == one["poses_s"] == ref_s[::2].tolist()
    assert got["poses_q"] == one["poses_q"] == ref_q[::2].tolist()
    assert got["closure"][0] == one["closure"][0] > 0
    np.testing.assert_allclose(got["closure"][1], one["closure"][1], rtol=1e-12)
    # each child compiled its programs once; the repeated sweeps compiled nothing
    assert got["compiles_first"] > 0 and got["compiles_again"] == 0


def test_closure_count_matches_per_pose_reference():
    """The physics case of the two-process test, checked per pose (vmap of the one-pose form)."""
    robot = load_robot(example_path("tcpr8.toml"))
    g8 = Grid.regular((-0.6, 0.6, 7), (-0.4, 0.4, 6), (0.2, 1.6, 9), rotation=(0.0, 0.0, 0.05))
    ref = jax.jit(jax.vmap(lambda p: wrench_closure(robot, p).member))(jnp.asarray(g8.poses()))
    assert cases()["closure"][0] == int(np.sum(ref))
