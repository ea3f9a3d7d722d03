"""The four cable-hardware effects of the formats.md §3 vocabulary (version 2): swivel
pulleys, winch transmission, load-cell gains and attachment offsets (see
:mod:`fitting.effects` for the hooks).

They act on the robot the statics sees, through the version-2 fields of
:class:`~cstiffjax.io.robot.CableRobot` (formats.md §1): the pulley path of
:func:`cstiffjax.cable.path.cable_path`, the winch gain of
:func:`fitting.calibration.models.true_lengths` (``l0_ref + length_gain (l0 - l0_ref)`` with ``l0_ref``
the first recorded ``l0``) and the load-cell gain of :func:`fitting.calibration.models.tension_readings`
(reading = ``tension_gain`` x true tension, before any bias or friction). A description
that already states pulleys or gains is the nominal model; the effect then means "the
stated value is wrong" and its null value is the stated one.
"""

import dataclasses
from dataclasses import dataclass
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from cstiffjax.cable.path import vertical_axes
from fitting.effects.base import Domain, Effect, _spec

SMALLEST_PULLEY = 1e-3  # m: no swivel pulley is smaller (a radius below it is no evidence of one)
GAIN = Domain(lower=0.0, reading="a gain is positive")


def _stated_pulleys(robot) -> np.ndarray:
    """(m,) bool: cables whose description states a pulley (a non-zero ``pulley_axis``)."""
    return np.any(np.asarray(robot.pulley_axis) != 0, axis=1)


def _cables(idx) -> str:
    return ("cables " + ", ".join(str(int(i) + 1) for i in idx)) if len(idx) else "none"


@dataclass(frozen=True)
class PulleyKinematics(Effect):
    """The cables leave over swivel pulleys (formats.md §1 swivel-pulley path), not from
    fixed points: one shared radius, m.

    On cables whose description states no pulley, the swivel axis is assumed vertical
    (:func:`cstiffjax.cable.path.vertical_axes`): ``+z`` (the cable arrives travelling upwards)
    for anchors above the workspace centre, taken as the mean recorded platform height,
    and ``-z`` below; :meth:`note` says so for the report. The parameter is ``radius``
    (null 0) when no pulley is stated, else ``radius_change`` (null 0), added to every
    stated radius. ``signs`` (static, set by :meth:`bind`) holds the assumed axis signs.
    At null on a description without pulleys the path is the pulley formula at radius 0,
    equal to the straight cable to rounding (and differentiable in the radius there)."""

    name: ClassVar[str] = "pulley_kinematics"
    summary: ClassVar[str] = "the cables leave over swivel pulleys, not from fixed points"
    signs: tuple | None = None

    def bind(self, robot, data):
        centre = float(np.mean(np.asarray(data.pose)[:, 2]))
        signs = vertical_axes(np.asarray(robot.anchors), centre)[:, 2]
        return dataclasses.replace(self, signs=tuple(float(s) for s in signs))

    def _param(self, robot) -> str:
        return "radius_change" if _stated_pulleys(robot).any() else "radius"

    def specs(self, robot, data):
        stated = _stated_pulleys(robot)
        if stated.any():  # the stated radii may be wrong, each stays >= 0
            low = -float(np.min(np.asarray(robot.pulley_radius)[stated]))
            dom = Domain(lower=low, reading="no stated pulley radius can become negative")
        else:
            dom = Domain(lower=0.0, smallest=SMALLEST_PULLEY,
                         reading="a pulley radius is positive, and a swivel pulley is at least 1 mm")
        return (_spec(self._param(robot), (), 0.0, 1e-2, "m", domain=dom),)

    def robot(self, robot, p):
        if self.signs is None:
            raise ValueError("pulley_kinematics: the effect is not bound to recordings (make_model binds it; "
                             "the assumed swivel axes depend on the workspace centre)")
        assumed = jnp.zeros_like(robot.anchors).at[:, 2].set(jnp.asarray(self.signs))
        stated = jnp.sum(robot.pulley_axis * robot.pulley_axis, axis=1, keepdims=True) > 0
        axis = jnp.where(stated, robot.pulley_axis, assumed)
        dr = p["radius_change"] if "radius_change" in p else p["radius"]
        return eqx.tree_at(lambda r: (r.pulley_radius, r.pulley_axis), robot, (robot.pulley_radius + dr, axis))

    def note(self, robot, data):
        missing = np.flatnonzero(~_stated_pulleys(robot))
        if not missing.size or self.signs is None:
            return None
        centre = float(np.mean(np.asarray(data.pose)[:, 2]))
        s = np.asarray(self.signs)[missing]
        which = "the description states no pulleys" if missing.size == robot.num_cables else \
            f"the description states no pulley on {_cables(missing)}"
        return (f"{which}: pulley_kinematics assumes vertical swivel axes, +z (cable arriving upwards) for the "
                f"anchors above the workspace centre (mean recorded platform height z = {centre:.3f} m): "
                f"{_cables(missing[s > 0])}; -z for those below: {_cables(missing[s < 0])}")


@dataclass(frozen=True)
class LengthGain(Effect):
    """Winch transmission differs from nominal: the true unstrained length is
    ``l0_ref + gain (l0 - l0_ref)`` (formats.md §1 v2, ``l0_ref`` the first recorded
    ``l0``). ``gain`` per cable (null: the stated ``length_gain``), or with ``shared`` one
    ``gain_factor`` multiplying every stated gain (null 1)."""

    name: ClassVar[str] = "length_gain"
    summary: ClassVar[str] = "winch transmission (drum radius, encoder scale) differs from nominal"
    shared: bool = False

    def specs(self, robot, data):
        if self.shared:
            return (_spec("gain_factor", (), 1.0, 1e-2, "1", domain=GAIN),)
        return (_spec("gain", (robot.num_cables,), np.asarray(robot.length_gain), 1e-2, "1", domain=GAIN),)

    def robot(self, robot, p):
        g = robot.length_gain * p["gain_factor"] if self.shared else p["gain"]
        return eqx.tree_at(lambda r: r.length_gain, robot, g)


@dataclass(frozen=True)
class TensionSensorGain(Effect):
    """Load cells read with a gain error: reading = ``gain`` x true exit tension (before
    any bias or friction; formats.md §1 v2). ``gain`` per cable (null: the stated
    ``tension_gain``), or with ``shared`` one ``gain_factor`` multiplying every stated gain."""

    name: ClassVar[str] = "tension_sensor_gain"
    summary: ClassVar[str] = "load cells read with a gain error"
    needs_tensions: ClassVar[bool] = True
    shared: bool = False

    def specs(self, robot, data):
        if self.shared:
            return (_spec("gain_factor", (), 1.0, 1e-2, "1", domain=GAIN),)
        return (_spec("gain", (robot.num_cables,), np.asarray(robot.tension_gain), 1e-2, "1", domain=GAIN),)

    def robot(self, robot, p):
        g = robot.tension_gain * p["gain_factor"] if self.shared else p["gain"]
        return eqx.tree_at(lambda r: r.tension_gain, robot, g)


@dataclass(frozen=True)
class AttachmentOffset(Effect):
    """Platform attachment points are not where the description says: ``offset``
    (m, 3), m, platform frame."""

    name: ClassVar[str] = "attachment_offset"
    summary: ClassVar[str] = "platform attachment points are not where the description says"

    def specs(self, robot, data):
        return (_spec("offset", (robot.num_cables, 3), 0.0, 1e-3, "m"),)

    def robot(self, robot, p):
        return eqx.tree_at(lambda r: r.attachments, robot, robot.attachments + p["offset"])
