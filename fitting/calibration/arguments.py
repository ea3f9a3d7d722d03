"""The checks every public entry point of ``fitting`` that takes a robot and its recordings
makes first (:func:`fitting.calibrate`, :func:`fitting.diagnose`): the types and the number of
cables, so that a wrong argument is named at the call, not deep inside a traced program
(``'str' object has no attribute 'kind'``, a broadcasting error in a matrix product)."""

from pathlib import Path

from cstiffjax.io.recordings import Recordings
from cstiffjax.io.robot import CableRobot


def check_arguments(robot, recordings, who: str) -> None:
    """Raise ``TypeError`` when ``robot`` is not a :class:`~cstiffjax.io.robot.CableRobot` or
    ``recordings`` not a :class:`~cstiffjax.io.recordings.Recordings` (a path or file name
    says how to load it), ``ValueError`` when their numbers of cables differ.

    **Arguments:** ``robot``, ``recordings`` as given to ``who``; ``who`` the function's name
    (``"diagnose"``), for the message."""
    if not isinstance(robot, CableRobot):
        hint = (f": load it first, cstiffjax.load_robot({str(robot)!r})" if isinstance(robot, str | Path)
                else " (a CSJM is identified with cstiffjax.identify_csjm)" if type(robot).__name__ ==
                "SphericalJointModule" else "")
        raise TypeError(f"{who}: robot must be a CableRobot (kind 'cdpr'), got {type(robot).__name__}{hint}")
    if not isinstance(recordings, Recordings):
        hint = (f": load them first, cstiffjax.load_recordings({str(recordings)!r}, robot)"
                if isinstance(recordings, str | Path) else "")
        raise TypeError(f"{who}: recordings must be a Recordings, got {type(recordings).__name__}{hint}")
    if recordings.num_cables != robot.num_cables:
        raise ValueError(f"{who}: recordings have {recordings.num_cables} cables (l0 columns of {recordings.source}) "
                         f"but robot '{robot.name}' has {robot.num_cables}; load them with this robot")
