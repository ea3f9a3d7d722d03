"""Fingerprints of the main compiled programs, to prove a refactor behaviour-preserving.

Lowers forward statics (spring, bilateral, small-sag, catenary laws, and the Jacobian of
each), the stiffness (one pose, a batch), CSS membership (one pose, a batch), wrench-feasible
membership and the diagnosis model's residuals and Jacobian, and writes each program's
StableHLO text and an ``index.json`` of SHA-256 digests::

    python benchmarks/hlo_fingerprint.py OUT_BEFORE     # on the old checkout
    python benchmarks/hlo_fingerprint.py OUT_AFTER      # on the new one
    diff OUT_BEFORE/index.json OUT_AFTER/index.json

:func:`_api` finds each function under its current module or its module before the
package was split into layers, so one script serves both checkouts. Output names
(``jax.result_info``) follow the result's pytree: a result Module instead of a tuple
changes only them (compare with those attributes stripped).
"""
import hashlib
import importlib
import json
import sys
from pathlib import Path

import numpy as np


def _api():
    import cstiffjax  # noqa: F401  (float64)

    def first(*names):
        for n in names:
            mod, _, attr = n.rpartition(".")
            try:
                return getattr(importlib.import_module(mod), attr)
            except (ImportError, AttributeError):
                continue
        raise ImportError(names)

    ws_new, ws_old = "cstiffjax.workspace.wrench_feasible", "cstiffjax.wrench_workspace"
    fs = first("cstiffjax.statics.forward.forward_statics", "cstiffjax.equilibrium.forward_statics")
    try:  # the law as a type and the problem as a Module; before them, strings and positional arrays
        from cstiffjax.cable.laws import CableLaw
        from cstiffjax.statics.forward import StaticsProblem

        def forward_statics(robot, l0, w, law, **kw):
            return fs(StaticsProblem(robot, l0, w, CableLaw.parse(law)), **kw)
    except ImportError:
        def forward_statics(robot, l0, w, law, **kw):
            return fs(robot, l0, w, law=law, **kw)

    return dict(
        forward_statics=forward_statics,
        stiffness=first("cstiffjax.stiffness.matrix.stiffness", "cstiffjax.stiffness.stiffness"),
        css_point=first("cstiffjax.stiffness.css.css_point", "cstiffjax.css.css_point"),
        target_stiffness=first("cstiffjax.stiffness.css.target_stiffness", "cstiffjax.css.target_stiffness"),
        wrench_feasible=first(f"{ws_new}.wrench_feasible", f"{ws_old}.wrench_feasible"),
        WrenchSet=first(f"{ws_new}.WrenchSet", f"{ws_old}.WrenchSet"),
        inverse_statics=first("cstiffjax.statics.geometry.inverse_statics", "cstiffjax.statics.inverse_statics"),
        load_robot=first("cstiffjax.io.robot_io.load_robot", "cstiffjax.robot_io.load_robot"),
        load_recordings=first("cstiffjax.io.recordings.load_recordings", "cstiffjax.recordings.load_recordings"),
        example_path=first("cstiffjax.examples.example_path"),
        build_data=first("fitting.effects.build_data"),
        make_model=first("fitting.effects.make_model"),
        VOCABULARY=first("fitting.effects.VOCABULARY"),
        residuals=first("fitting.effects.model.residuals"),
        residuals_and_jacobian=first("fitting.effects.model.residuals_and_jacobian"),
    )


def _lowered(f, *args) -> str:
    import jax

    return jax.jit(f).lower(*args).as_text()


def programs() -> dict:
    """``{name: StableHLO text}`` of every fingerprinted program."""
    import jax
    import jax.numpy as jnp

    A = _api()
    texts = {}
    ex = A["example_path"]
    rb = A["load_robot"](ex("example02/robot.toml"))
    rec = A["load_recordings"](ex("example02/recordings.csv"), rb)
    l0, w = rec.l0[0], rec.wrench[0]
    fs = A["forward_statics"]
    for law in ("spring", "bilateral", "small_sag", "catenary"):
        def solve(l0, w, law=law):
            return fs(rb, l0, w, law, throw=False)

        texts[f"forward_statics_{law}"] = _lowered(solve, l0, w)
        texts[f"jac_forward_statics_{law}"] = _lowered(jax.jacfwd(lambda l0, w, s=solve: s(l0, w).pose), l0, w)
    tc = A["load_robot"](ex("tcpr8.toml"))
    pose = jnp.array([0.0, 0.0, 0.85, 0.0, 0.0, 0.0])
    t = A["inverse_statics"](tc, pose, throw=False).tensions

    def stiff(p, t):
        return A["stiffness"](tc, p, t, throw=False)

    texts["stiffness"] = _lowered(stiff, pose, t)
    P = jnp.tile(pose[:, None], (1, 64))  # pose-minor batch (6, 64)
    texts["stiffness_batch"] = _lowered(stiff, P.T, jnp.tile(t[None], (64, 1)))
    kc = A["target_stiffness"](tc, pose, inherent="paper").K
    texts["css_point"] = _lowered(lambda p, k: A["css_point"](tc, p, k, 0.05, inherent="paper"), pose, kc)
    texts["css_point_batch"] = _lowered(lambda p, k: A["css_point"](tc, p, k, 0.05), P, kc)
    box = A["WrenchSet"].box(-np.ones(6), np.ones(6))
    texts["wrench_feasible"] = _lowered(lambda p, b: A["wrench_feasible"](tc, p, b, length_scale=0.5), P, box)
    data = A["build_data"](rec)
    spring = [e for e in A["VOCABULARY"] if e.name != "cable_mass"]
    for name, effects in (("none", []), ("spring_vocabulary", spring)):
        model = A["make_model"](rb, data, effects)
        theta = jnp.zeros(model.size)
        texts[f"diagnosis_residuals_{name}"] = _lowered(
            lambda th, d, m=model: A["residuals"](m, th, rb, d), theta, data)
        texts[f"diagnosis_rJ_{name}"] = _lowered(
            lambda th, d, m=model: A["residuals_and_jacobian"](m, th, rb, d), theta, data)
    return texts


def main(out):
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    index = {}
    for k, v in programs().items():
        (out / f"{k}.mlir").write_text(v)
        index[k] = hashlib.sha256(v.encode()).hexdigest()
    (out / "index.json").write_text(json.dumps(index, indent=1, sort_keys=True))
    print(json.dumps(index, indent=1, sort_keys=True))


if __name__ == "__main__":
    main(sys.argv[1])
