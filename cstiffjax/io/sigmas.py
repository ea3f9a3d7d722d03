"""Which ``[noise]`` sigma the recordings need (formats.md §1), and the sigmas a fit uses.

Every ``[noise]`` key is optional in the robot description (``nan`` in
:class:`~cstiffjax.io.robot.Noise`: not stated). Recordings need the sigma of every channel
they hold a value of, because the fits weigh its residuals by it (:data:`WEIGHED`); a
channel without values needs none. Where the description meets the recordings (the loader,
:func:`fitting.calibration.least_squares.calibrate`, :func:`fitting.diagnosis.diagnose`),
:func:`check_sigmas` refuses a recorded channel without its sigma, and :func:`fit_noise`
gives each channel not recorded a finite :data:`PLACEHOLDER` sigma: its residuals are masked
out, and a finite sigma keeps them, and the gradients through them, finite (a ``nan`` sigma
behind a mask still makes ``nan`` gradients). ``moment`` (a CSJM's ``tx ty tz``) is weighed by
no fit and stays optional.
"""

import equinox as eqx
import numpy as np

from cstiffjax.core.errors import RecordingsError
from cstiffjax.io import schema
from cstiffjax.io.robot import Noise

WEIGHED = {"position": "noise.position = sigma (m)", "rotation": "noise.rotation = sigma (rad)",
           "tension": "noise.tension = sigma (N)", "swivel": "noise.swivel = sigma (rad)",
           "ahrs": "noise.ahrs = [roll, pitch, yaw sigmas] (rad)"}
"""The channels (schema group keys, also the :class:`~cstiffjax.io.robot.Noise` fields) whose
residuals the fits weigh by a sigma, with the ``[noise]`` key each needs."""

PLACEHOLDER = 1.0
"""The sigma (in the channel's unit) a fit uses for a channel not recorded: it never enters
the fit (every residual of the channel is masked out)."""


def _recorded(recordings, channel: str) -> np.ndarray:
    """``(k,)`` whether each column of ``channel`` holds a value in some sample."""
    mask = {"position": lambda r: np.asarray(r.pose_mask)[:, :3], "rotation": lambda r: np.asarray(r.pose_mask)[:, 3:],
            "tension": lambda r: np.asarray(r.tension_mask), "swivel": lambda r: np.asarray(r.swivel_mask),
            "ahrs": lambda r: np.asarray(r.ahrs_mask)}[channel](recordings)
    if recordings.kind not in schema.group(channel).used:
        return np.zeros(mask.shape[1], bool)  # read and ignored (a CSJM's x y z: the joint centre)
    return mask.any(axis=0)


def check_sigmas(robot, recordings) -> None:
    """Raise :class:`~cstiffjax.core.errors.RecordingsError` when ``recordings`` hold a
    channel of :data:`WEIGHED` whose sigma ``robot``'s ``[noise]`` does not state, naming the
    recordings (``source``), the columns and the key to add."""
    for channel, key in WEIGHED.items():
        have = _recorded(recordings, channel)
        if have.any() and not np.all(np.isfinite(np.asarray(getattr(robot.noise, channel)))):
            cols = " ".join(c for c, h in zip(schema.group(channel).columns(robot.num_cables), have, strict=True) if h)
            raise RecordingsError(f"{recordings.source}: columns {cols} need {key} in the [noise] table of the robot "
                                  f"description '{robot.name}' (their residuals are weighted by it)")


def fit_noise(robot, recordings):
    """``robot`` with the sigmas a fit of ``recordings`` uses: the description's, and
    :data:`PLACEHOLDER` for a channel not recorded whose sigma is not stated.

    **Arguments:** ``robot`` a :class:`~cstiffjax.io.robot.CableRobot` (or CSJM);
    ``recordings`` a :class:`~cstiffjax.io.recordings.Recordings` of it.

    **Returns:** the robot (unchanged when every sigma is stated).

    **Raises:** :class:`~cstiffjax.core.errors.RecordingsError` (:func:`check_sigmas`).
    """
    check_sigmas(robot, recordings)
    n = robot.noise
    sig = {f: np.asarray(getattr(n, f)) for f in ("position", "rotation", "tension", "moment", "swivel", "ahrs")}
    fill = {f: np.full(sig[f].shape, PLACEHOLDER) for f in WEIGHED if not np.all(np.isfinite(sig[f]))}
    if not fill:
        return robot
    return eqx.tree_at(lambda r: r.noise, robot, Noise(**(sig | fill)))
