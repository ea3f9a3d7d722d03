"""Robot descriptions as data: :class:`CableRobot` (6-DOF CDPR) and
:class:`SphericalJointModule` (the CSJM of Yang et al. 2019).

Both are final ``eqx.Module``s whose leaves are float64 arrays; names and the kind are
static metadata. The TOML reader/writer lives in :mod:`cstiffjax.io.robot_io`.
"""

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from cstiffjax.core import config as _config  # noqa: F401
from cstiffjax.core.arrays import f64 as _f64


def _f64_or_none(x):
    return None if x is None else _f64(x)


class Noise(eqx.Module):
    """One-sigma measurement noise of the recordings (formats.md §1 ``[noise]``).

    ``position`` m per axis, ``rotation`` rad per axis, ``tension`` N per cable,
    ``moment`` N·m per axis (CSJM load cells). Version 3 (on-board sensors): ``swivel`` rad
    per pulley swivel encoder, ``ahrs`` ``(3,)`` rad for the AHRS roll, pitch and yaw. Each
    is optional, ``nan`` = not stated: recordings need the sigmas of the channels they hold
    (:mod:`cstiffjax.io.sigmas`).
    """

    position: Float[Array, ""] = eqx.field(converter=_f64, default=float("nan"))
    rotation: Float[Array, ""] = eqx.field(converter=_f64, default=float("nan"))
    tension: Float[Array, ""] = eqx.field(converter=_f64, default=float("nan"))
    moment: Float[Array, ""] = eqx.field(converter=_f64, default=float("nan"))
    swivel: Float[Array, ""] = eqx.field(converter=_f64, default=float("nan"))
    ahrs: Float[Array, "3"] = eqx.field(converter=_f64, default=(float("nan"),) * 3)

    def __check_init__(self):
        if self.ahrs.shape != (3,):
            raise ValueError(f"Noise.ahrs must have shape (3,), got {self.ahrs.shape}")



class _CableModule(eqx.Module):
    """Fields shared by both robot kinds (see :class:`CableRobot` for their meaning)."""

    anchors: Float[Array, "m 3"] = eqx.field(converter=_f64)
    attachments: Float[Array, "m 3"] = eqx.field(converter=_f64)
    EA: Float[Array, " m"] = eqx.field(converter=_f64)
    mass_per_length: Float[Array, " m"] = eqx.field(converter=_f64)
    platform_mass: Float[Array, ""] = eqx.field(converter=_f64)
    com: Float[Array, "3"] = eqx.field(converter=_f64)
    inertia: Float[Array, "3 3"] = eqx.field(converter=_f64)
    gravity: Float[Array, "3"] = eqx.field(converter=_f64)
    noise: Noise
    tension_min: Float[Array, ""] = eqx.field(converter=_f64, default=0.0)
    tension_max: Float[Array, ""] = eqx.field(converter=_f64, default=float("inf"))
    name: str = eqx.field(static=True, default="robot")
    # formats.md §1 version 2 (optional per-cable hardware). ``None`` at construction
    # means the version-1 meaning: no pulley (radius 0, axis 0), gains 1.
    pulley_radius: Float[Array, " m"] = eqx.field(converter=_f64_or_none, default=None)
    pulley_axis: Float[Array, "m 3"] = eqx.field(converter=_f64_or_none, default=None)
    length_gain: Float[Array, " m"] = eqx.field(converter=_f64_or_none, default=None)
    tension_gain: Float[Array, " m"] = eqx.field(converter=_f64_or_none, default=None)
    # formats.md §1 version 3 (on-board sensors). ``None``: no swivel encoder zero stated
    # (zeros), the AHRS mounted aligned with the platform frame (zeros).
    swivel_zero: Float[Array, "m 3"] = eqx.field(converter=_f64_or_none, default=None)
    ahrs_mounting: Float[Array, "3"] = eqx.field(converter=_f64_or_none, default=None)
    relative_lengths: bool = eqx.field(static=True, default=False)

    def __post_init__(self):
        m = jnp.shape(self.anchors)[0]
        for name, value, shape in (("pulley_radius", 0.0, (m,)), ("pulley_axis", 0.0, (m, 3)),
                                   ("length_gain", 1.0, (m,)), ("tension_gain", 1.0, (m,)),
                                   ("swivel_zero", 0.0, (m, 3)), ("ahrs_mounting", 0.0, (3,))):
            if getattr(self, name) is None:
                object.__setattr__(self, name, _f64(np.full(shape, value)))

    def __check_init__(self):
        m = self.anchors.shape[0]
        for name, shape in (("anchors", (m, 3)), ("attachments", (m, 3)), ("EA", (m,)),
                            ("mass_per_length", (m,)), ("com", (3,)), ("inertia", (3, 3)), ("gravity", (3,)),
                            ("pulley_radius", (m,)), ("pulley_axis", (m, 3)), ("length_gain", (m,)),
                            ("tension_gain", (m,)), ("swivel_zero", (m, 3)), ("ahrs_mounting", (3,))):
            got = getattr(self, name).shape
            if got != shape:
                raise ValueError(f"{type(self).__name__}.{name} must have shape {shape}, got {got}")

    @property
    def num_cables(self) -> int:
        return self.anchors.shape[0]

    @property
    def weight(self) -> Float[Array, "3"]:
        """Platform weight as a force in the base frame, N."""
        return self.platform_mass * self.gravity


class CableRobot(_CableModule):
    """A 6-DOF cable-driven parallel robot with ``m`` cables.

    **Fields** (SI units):

    - ``anchors`` ``(m, 3)``: cable exit points on the base, base frame, m.
    - ``attachments`` ``(m, 3)``: attachment points on the platform, platform frame, m.
    - ``EA`` ``(m,)``: axial stiffness, N. ``mass_per_length`` ``(m,)``: kg/m.
    - ``platform_mass`` kg, ``com`` ``(3,)`` platform frame m, ``inertia`` ``(3, 3)`` kg m²
      about the com in the platform frame (``nan`` when the TOML omits it), ``gravity``
      ``(3,)`` m/s².
    - ``noise``: :class:`Noise`; ``tension_min``/``tension_max``: N (``0``/``inf`` when the
      TOML has no ``[limits]``).
    - ``name`` (static).
    - Version 2 per-cable hardware: ``pulley_radius`` ``(m,)`` m, ``pulley_axis`` ``(m, 3)``
      (zeros: no pulley), ``length_gain`` / ``tension_gain`` ``(m,)``.
    - Version 3 on-board sensors: ``swivel_zero`` ``(m, 3)`` base-frame unit vector, normal to
      ``pulley_axis``, where the swivel encoder reads 0 (zeros: not stated); ``ahrs_mounting``
      ``(3,)`` rad, the AHRS frame's rotation vector in the platform frame;
      ``relative_lengths`` (static): the recorded ``l0_i`` are known only up to a constant per
      cable and session (encoders zeroed at a homing pose).

    Poses are 6-vectors ``[x, y, z, rx, ry, rz]``: the platform reference point in the
    base frame and the platform orientation as a rotation vector.
    """

    @property
    def kind(self) -> str:
        return "cdpr"


class SphericalJointModule(_CableModule):
    """Cable-driven spherical joint module (Yang et al. 2019, Fig. 1).

    ``anchors`` are the base holes B_i and ``attachments`` the platform holes A_i, both
    relative to the joint centre O (base and platform frame respectively), m. The pose is
    a rotation only. Other fields as in :class:`CableRobot`.
    """

    @property
    def kind(self) -> str:
        return "csjm"


def robot_summary(robot, hardware: bool = True) -> str:
    """A short human-readable description (used by the CLI); ``hardware``: append
    :func:`hardware_summary` (``check`` prints the hardware on lines of its own)."""
    ea = np.asarray(robot.EA)
    w = np.asarray(robot.mass_per_length)
    return (
        f"{robot.kind} '{robot.name}': {robot.num_cables} cables, "
        f"platform {float(robot.platform_mass):g} kg, EA {ea.min():.4g}..{ea.max():.4g} N, "
        f"mass/length {w.min():.4g}..{w.max():.4g} kg/m" + (hardware_summary(robot) if hardware else "")
    )


def hardware_summary(robot) -> str:
    """``"; pulleys ...; length gains ...; tension gains ..."`` for the version-2 hardware
    fields that differ from the defaults (empty for a version-1 description)."""
    parts = []
    radius = np.asarray(robot.pulley_radius)
    has = np.any(np.asarray(robot.pulley_axis) != 0, axis=1)
    if has.any():
        cables = ", ".join(str(i + 1) for i in np.flatnonzero(has))
        parts.append(f"swivel pulleys on cables {cables} (radius {radius[has].min():.4g}..{radius[has].max():.4g} m)")
    for name, label in (("length_gain", "winch length gains"), ("tension_gain", "load-cell gains")):
        g = np.asarray(getattr(robot, name))
        if np.any(g != 1.0):
            parts.append(f"{label} {g.min():.6g}..{g.max():.6g}")
    return "".join(f"; {p}" for p in parts)
