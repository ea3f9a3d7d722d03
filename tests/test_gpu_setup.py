"""The test set-up lets several xdist workers share one GPU: no pre-allocation of 75% of its
memory per worker, unless the user chose an allocator setting (then it is left alone)."""

import os
import subprocess
import sys

_PROBE = ("import os, sys; sys.path.insert(0, sys.argv[1]); import conftest; "
          "print(os.environ.get('XLA_PYTHON_CLIENT_PREALLOCATE'), os.environ.get('XLA_PYTHON_CLIENT_MEM_FRACTION'))")


def _probe(**env):
    base = {k: v for k, v in os.environ.items() if not k.startswith("XLA_PYTHON_CLIENT_")}
    out = subprocess.run([sys.executable, "-c", _PROBE, os.path.dirname(os.path.abspath(__file__))],
                         env={**base, "JAX_PLATFORMS": "cpu", **env}, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    return out.stdout.split()


def test_workers_do_not_preallocate_unless_the_user_says():
    assert _probe() == ["false", "None"]
    assert _probe(XLA_PYTHON_CLIENT_PREALLOCATE="true") == ["true", "None"]
    assert _probe(XLA_PYTHON_CLIENT_MEM_FRACTION=".3") == ["None", ".3"]


def test_this_session_has_the_setting():
    assert os.environ.get("XLA_PYTHON_CLIENT_PREALLOCATE") or os.environ.get("XLA_PYTHON_CLIENT_MEM_FRACTION") \
        or os.environ.get("XLA_PYTHON_CLIENT_ALLOCATOR")
