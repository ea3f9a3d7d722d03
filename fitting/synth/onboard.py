"""Synthetic recordings from on-board sensors only (formats.md §2 version 3).

A robot calibrated without an external tracker records, per static sample, its winch
lengths (zeroed at a homing pose: known up to a constant per cable and session), its load
cells, its pulleys' swivel encoders and an AHRS (roll and pitch against gravity, yaw from an
unknown zero per session). :func:`onboard_recordings` simulates that: the platform's
equilibrium for the true lengths comes from the cold start of
:func:`cstiffjax.statics.forward.forward_statics` (the fits use its warm Newton start from
other poses, so agreement is a check of one solve against the other), the sensors' readings
from :mod:`cstiffjax.statics.sensors`, plus Gaussian noise with the robot's ``[noise]``
sigmas.
"""

import jax
import numpy as np

from cstiffjax.core.status import Status
from cstiffjax.io.recordings import Recordings
from cstiffjax.statics.geometry import cable_lengths
from cstiffjax.statics.sensors import ahrs_angles, swivel_angles
from fitting.calibration.models import commanded_lengths, predict_cdpr


def hanging_lengths(robot, positions, tension: float = 60.0) -> np.ndarray:
    """Commanded lengths ``(n, m)``, m, that hang the platform near each of ``positions``
    ``(n, 3)`` (m, level platform) with every cable taut: each cable's path length there,
    shortened by the stretch of ``tension`` N, as the robot's winches (``length_gain``) must be
    commanded to pay it out (what a controller that keeps the cables taut does). A suspended
    robot with more cables than its load needs (4 cables, 3 freedoms held by its weight) keeps
    all of them taut only for lengths consistent to within that stretch; random lengths leave
    one slack."""
    poses = np.concatenate([np.asarray(positions, dtype=float), np.zeros((len(positions), 3))], axis=1)
    L = np.asarray(jax.vmap(lambda q: cable_lengths(robot, q))(poses))
    return np.asarray(commanded_lengths(robot, L / (1.0 + tension / np.asarray(robot.EA))))


def onboard_recordings(robot, l0_true, *, session=None, length_zero=None, yaw_zero=None, seed: int = 0,
                       noisy: bool = True, tensions: bool = True) -> Recordings:
    """Recordings of ``robot`` (the truth) from its on-board sensors, without ``x y z``/``rx ry rz``.

    **Arguments:**

    - ``robot``: the true :class:`~cstiffjax.io.robot.CableRobot` (with ``swivel_zero`` and
      ``pulley_axis`` on the cables whose swivel angles are recorded, and ``[noise] swivel``
      and ``ahrs`` sigmas).
    - ``l0_true`` ``(n, m)``: the lengths commanded to the winches, m (the true unstrained
      lengths at gain 1; the robot's ``length_gain`` applies, formats.md §1 v2).
    - ``session`` ``(n,)`` int: each sample's session (default all 0).
    - ``length_zero`` ``(S, m)`` m: the recorded lengths are ``l0_true - length_zero[session]``
      (default 0: absolute lengths). ``yaw_zero`` ``(S,)`` rad: the AHRS's yaw zero per session.
    - ``seed``: of the noise; ``noisy``: add it; ``tensions``: record the load cells.

    **Returns:** a :class:`~cstiffjax.io.recordings.Recordings` (``pose_mask`` false, swivel
    and AHRS masks true, tensions recorded when ``tensions``).

    **Raises:** ``ValueError`` naming the samples without an equilibrium.
    """
    l0_true = np.asarray(l0_true, dtype=float)
    n, m = l0_true.shape
    session = np.zeros(n, int) if session is None else np.asarray(session, dtype=int)
    S = int(session.max()) + 1
    length_zero = np.zeros((S, m)) if length_zero is None else np.asarray(length_zero, dtype=float)
    yaw_zero = np.zeros(S) if yaw_zero is None else np.asarray(yaw_zero, dtype=float)
    pose, t, res = predict_cdpr(robot, l0_true, np.zeros((n, 6)), method="statics")
    bad = np.flatnonzero(~np.asarray(res == Status.successful))
    if bad.size:
        raise ValueError(f"no stable equilibrium for samples {(bad + 1).tolist()}")
    swivel = np.asarray(jax.vmap(lambda p: swivel_angles(robot, p))(pose))
    ahrs = np.asarray(jax.vmap(lambda p, y: ahrs_angles(robot, p, y))(pose, yaw_zero[session]))
    t = np.asarray(t)
    if noisy:
        rng = np.random.default_rng(seed)
        nz = robot.noise
        t = t + float(nz.tension) * rng.standard_normal(t.shape)
        swivel = swivel + float(nz.swivel) * rng.standard_normal(swivel.shape)
        ahrs = ahrs + np.asarray(nz.ahrs) * rng.standard_normal(ahrs.shape)
    mask = np.full((n, m), bool(tensions))
    return Recordings(l0=l0_true - length_zero[session], wrench=np.zeros((n, 6)), pose=np.zeros((n, 6)),
                      tensions=np.where(mask, t, 0.0), tension_mask=mask, moment=np.zeros((n, 3)),
                      time=np.arange(n, dtype=float), covariates=np.zeros((n, 0)),
                      pose_mask=np.zeros((n, 6), bool), swivel=swivel, swivel_mask=np.ones((n, m), bool),
                      ahrs=ahrs, ahrs_mask=np.ones((n, 3), bool), session=session, source="<onboard>")
