"""cstiffjax: stiffness, cable statics and calibration of cable-driven robots in JAX.

Importing the package enables float64 (``jax_enable_x64``) for the whole process and,
before JAX's backend starts, a faster-compiling XLA CPU emitter (``cstiffjax._config``:
what, why, measured, and how to opt out with ``CSTIFFJAX_XLA_FAST_COMPILE=0``).
"""

from . import (
    _config,  # noqa: F401  (float64 first)
    cables,
    catenary,
    csjm,
    csjm_identify,
    css,
    dsm,
    dynamics,
    interference,
    lie,
    recordings,
    robot,
    robot_io,
    sag,
    statics,
    stiffness,
    tension_methods,
    tensions,
    workspace,
    wrench_closure,
    wrench_workspace,
)
from .errors import RecordingsError, RobotFileError, SolverError
from .recordings import Recordings, load_recordings
from .robot import CableRobot, Noise, SphericalJointModule
from .robot_io import load_robot, save_robot
from .status import Status

__all__ = [
    "CableRobot",
    "Noise",
    "Recordings",
    "RecordingsError",
    "RobotFileError",
    "SolverError",
    "SphericalJointModule",
    "Status",
    "cables",
    "catenary",
    "csjm",
    "csjm_identify",
    "css",
    "dsm",
    "dynamics",
    "interference",
    "lie",
    "load_recordings",
    "load_robot",
    "recordings",
    "robot",
    "robot_io",
    "sag",
    "save_robot",
    "statics",
    "stiffness",
    "tension_methods",
    "tensions",
    "workspace",
    "wrench_closure",
    "wrench_workspace",
]
