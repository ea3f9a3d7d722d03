"""Generate ``cstiffjax/examples/csjm_recordings.csv``: a synthetic experiment like that of Yang et al. 2019 §IV.B.

The bundled CSJM (``csjm.toml``) sits at Table 3's ``R0`` (printed sign typo ``R0[2,1]``
fixed, projected on SO(3)) and carries Table 3's pre-load ``ᴬτ0 = (-0.06, -3.08, 1.07)``
N·m (external + gravity, platform frame). Reference tensions: 100 N in every cable plus the
minimum-norm correction that balances ``ᴬτ0``; the spring-law unstrained lengths ``l0``
that give them stay fixed. Row 0 is the reference pose; rows 1..85 are equilibria at
``R_k = R0 exp(hat(δζ_k))`` with ``δζ_k ~ N(0, 0.02 rad)``, and their external moments
``ᴬτ_E = -R_kᵀ (m_cables(R_k; l0) + m_gravity(R_k))`` (what counterweights must apply).
Noise from the TOML's ``[noise]``: rotation 3e-4 rad per axis (base frame), moment
0.038 N·m per axis. Columns (formats.md §2): ``time rx ry rz tx ty tz``.

Run: ``python benchmarks/make_csjm_example.py`` (deterministic, seed 0).
"""

import csv
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from cstiffjax.core import lie
from cstiffjax.csjm import model as csjm
from cstiffjax.examples import HERE
from cstiffjax.io import schema
from cstiffjax.io.robot_io import load_robot

R0_TABLE3 = np.array([[0.992, -0.060, -0.111], [0.090, 0.952, 0.292], [0.088, -0.300, 0.950]])  # [2,1] sign fixed
TAU0_TABLE3 = np.array([-0.06, -3.08, 1.07])
PRETENSION = 100.0
NUM_MEASUREMENTS = 85
STEP = 0.02  # rad


def reference_state(robot):
    """``(R0, tensions0)``: Table 3's pose and tensions that balance ``ᴬτ0`` with 100 N pretension."""
    u, _, vt = np.linalg.svd(R0_TABLE3)
    R0 = u @ vt
    J = np.asarray(csjm.jacobian(robot, R0))
    m_needed = -R0 @ TAU0_TABLE3  # cable moment, base frame: balances the applied load
    t = np.full(robot.num_cables, PRETENSION)
    t = t + np.linalg.pinv(J.T) @ (m_needed - J.T @ t)
    return R0, t


def simulate(robot, seed: int = 0):
    R0, t0 = reference_state(robot)
    l0 = csjm.unstrained_lengths(robot, R0, t0)
    rng = np.random.default_rng(seed)
    dz = np.vstack([np.zeros(3), rng.normal(scale=STEP, size=(NUM_MEASUREMENTS, 3))])
    Rs = jax.vmap(lambda d: jnp.asarray(R0) @ lie.exp(d))(dz)

    def external(R):
        return -(R.T @ (csjm.elastic_moment(robot, R, l0) + csjm.gravity_moment(robot, R)))

    tau_E = np.asarray(jax.vmap(external)(Rs))
    sig_r, sig_m = float(robot.noise.rotation), float(robot.noise.moment)
    noisy = jax.vmap(lambda n, R: lie.log(lie.exp(n) @ R))(rng.normal(scale=sig_r, size=(len(dz), 3)), Rs)
    return np.asarray(noisy), tau_E + rng.normal(scale=sig_m, size=tau_E.shape)


def main():
    robot = load_robot(HERE / "csjm.toml")
    rot, tau = simulate(robot)
    out = HERE / "csjm_recordings.csv"
    with Path(out).open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(schema.column_names(0, [schema.group(k) for k in ("time", "rotation", "joint_moment")]))
        for i, (r, t) in enumerate(zip(rot, tau, strict=True)):
            w.writerow([f"{10.0 * i:.1f}", *(f"{v:.8f}" for v in r), *(f"{v:.5f}" for v in t)])
    print(f"wrote {out}: {len(rot)} rows (row 0 = reference pose R0 with pre-load)")


if __name__ == "__main__":
    main()
