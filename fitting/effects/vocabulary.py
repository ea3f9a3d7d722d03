"""The formats.md §3 vocabulary: nine effects here, the four cable-hardware ones in
:mod:`fitting.effects.hardware` (see :mod:`fitting.effects`)."""

from dataclasses import dataclass
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from cstiffjax.cable.laws import CableLaw, check_law
from cstiffjax.core import lie
from fitting.effects.base import POSITIVE, Domain, Effect, _spec
from fitting.effects.hardware import AttachmentOffset, LengthGain, PulleyKinematics, TensionSensorGain
from fitting.effects.model import SPRING_MODEL_LAWS

T_REF = 100.0  # N, reference tension of the nonlinear elasticity coefficient


@dataclass(frozen=True)
class CableMass(Effect):
    """Cable weight and sag: elastic catenary (Yuan et al. 2015 eqs 1-10) with a shared mass
    per length ``mass_per_length`` (kg/m) instead of a massless spring."""

    name: ClassVar[str] = "cable_mass"
    summary: ClassVar[str] = "cable weight and sag (elastic catenary instead of a massless spring)"

    def specs(self, robot, data):
        return (_spec("mass_per_length", (), 0.0, 0.05, "kg/m", start=0.02,
                      domain=Domain(lower=0.0, reading="a cable cannot weigh less than nothing")),)

    def law(self, law):
        return CableLaw.catenary

    def robot(self, robot, p):
        w = jnp.full_like(robot.mass_per_length, p["mass_per_length"])
        return eqx.tree_at(lambda r: r.mass_per_length, robot, w)


@dataclass(frozen=True)
class CableMassScreen(CableMass):
    """``cable_mass`` on the ``small_sag`` law of :func:`cstiffjax.statics.forward.forward_statics`
    (Irvine's small-sag cable: each spring tension is its free span's mean tension, lowered
    by the sag's shortening of the chord; the platform carries half of the span's weight;
    the load cell reads the tension grown along the chord): a spring model that follows the
    elastic catenary closely (``tests/test_small_sag.py``) and compiles in a fraction of its
    time, so the diagnosis screens ``cable_mass`` with it and fits the catenary only when
    the screen could win (:meth:`fitting.diagnosis.diagnose._Diagnoser.round`). A spring baseline only."""

    def law(self, law):
        check_law(law, SPRING_MODEL_LAWS, "the small-sag screen of cable_mass")
        return CableLaw.small_sag


@dataclass(frozen=True)
class AnchorOffset(Effect):
    """Exit points are not where the description says: ``offset`` (m, 3) m, base frame.

    Without a measured position (formats.md §2 version 3: on-board sensors only) the base
    frame is fixed by nothing but the anchors: moving every anchor by the same vector moves
    the platform with them and changes no reading (``frame_from_anchors``, set by :meth:`bind`):
    :meth:`gauge` names those three directions, and the diagnosis judges and reports the
    offsets without them (zero mean). The fit itself is left free along them (with the
    mean removed inside the model, a direction of exactly zero derivative, the damped
    Gauss-Newton steps stalled)."""

    name: ClassVar[str] = "anchor_offset"
    summary: ClassVar[str] = "exit points are not where the description says"
    frame_from_anchors: bool = False

    def bind(self, robot, data):
        return AnchorOffset(frame_from_anchors=not bool(np.any(np.asarray(data.pose_mask)[:, :3])))

    def note(self, robot, data):
        if not self.bind(robot, data).frame_from_anchors:
            return None
        return ("no x y z recorded: a common shift of all anchors cannot be seen (the platform moves with it); "
                "the offsets are reported with zero mean")

    def specs(self, robot, data):
        return (_spec("offset", (robot.num_cables, 3), 0.0, 1e-3, "m"),)

    def gauge(self, m: int):
        """``(k, m·3)`` directions of ``offset`` (flattened) that no reading sees (none with a
        measured position; else the common translation)."""
        if not self.frame_from_anchors:
            return None
        return np.stack([np.tile(np.eye(3)[k], m) for k in range(3)]) / np.sqrt(m)

    def robot(self, robot, p):
        return eqx.tree_at(lambda r: r.anchors, robot, robot.anchors + p["offset"])


@dataclass(frozen=True)
class LengthOffset(Effect):
    """Constant error of each commanded length (encoder zero): ``l0 + offset``, m."""

    name: ClassVar[str] = "length_offset"
    summary: ClassVar[str] = "constant error in each commanded length (encoder zero)"

    def specs(self, robot, data):
        return (_spec("offset", (robot.num_cables,), 0.0, 1e-3, "m"),)

    def applicable(self, robot, recordings) -> str | None:
        if robot.relative_lengths:
            return ("the lengths are relative ([sensors] lengths = \"relative\"): their zeros are calibrated in "
                    "every fit, so a constant length error is not an effect")
        return super().applicable(robot, recordings)

    def inputs(self, l0, wrench, ctx, p):
        return l0 + p["offset"], wrench


@dataclass(frozen=True)
class LengthDrift(Effect):
    """Cable lengths creep with time: ``l0 + rate · (t - t_first)``, rate in m/s."""

    name: ClassVar[str] = "length_drift"
    summary: ClassVar[str] = "cable lengths creep with time"
    needs_time: ClassVar[bool] = True

    def specs(self, robot, data):
        span = max(float(np.max(np.asarray(data.ctx.time))), 1.0)
        return (_spec("rate", (robot.num_cables,), 0.0, 1e-3 / span, "m/s"),)

    def inputs(self, l0, wrench, ctx, p):
        return l0 + p["rate"] * ctx.time, wrench


@dataclass(frozen=True)
class TensionSensorBias(Effect):
    """Load cells read with a constant offset: ``t_measured = t + bias``, N."""

    name: ClassVar[str] = "tension_sensor_bias"
    summary: ClassVar[str] = "load cells read with a constant offset"
    needs_tensions: ClassVar[bool] = True

    def specs(self, robot, data):
        return (_spec("bias", (robot.num_cables,), 0.0, 1.0, "N"),)

    def measure(self, pose, tensions, ctx, p):
        return pose, tensions + p["bias"]


@dataclass(frozen=True)
class PoseFrameOffset(Effect):
    """The pose-measurement frame is misregistered against the base: the instrument
    reads ``p' = R_o p + translation`` and ``R' = R_o R`` with ``R_o = exp(rotation)``
    (rotation vector, rad; translation, m)."""

    name: ClassVar[str] = "pose_frame_offset"
    summary: ClassVar[str] = "the pose-measurement frame is misregistered against the base"

    def specs(self, robot, data):
        return (_spec("rotation", (3,), 0.0, 1e-3, "rad"), _spec("translation", (3,), 0.0, 1e-3, "m"))

    def measure(self, pose, tensions, ctx, p):
        Ro = lie.exp(p["rotation"])
        pos = Ro @ pose[:3] + p["translation"]
        rot = lie.log(Ro @ lie.exp(pose[3:]))
        return jnp.concatenate([pos, rot]), tensions


@dataclass(frozen=True)
class ExitFriction(Effect):
    """Friction at the exit point: the winch-side load cell reads
    ``t - direction · friction`` (higher after hauling in, lower after paying out), N."""

    name: ClassVar[str] = "exit_friction"
    summary: ClassVar[str] = ("friction at the exit point: measured tension depends on whether the cable "
                              "was last paid out or hauled in")
    needs_tensions: ClassVar[bool] = True

    def specs(self, robot, data):
        return (_spec("friction", (), 0.0, 1.0, "N",
                      domain=Domain(lower=0.0, reading="friction opposes the motion: the reading after hauling in "
                                                     "is the higher one")),)

    def measure(self, pose, tensions, ctx, p):
        return pose, tensions - ctx.direction * p["friction"]


@dataclass(frozen=True)
class NonlinearElasticity(Effect):
    """Tension not linear in strain: ``t = t_lin (1 + stiffening · t_lin / T_REF)`` with
    ``t_lin = EA ε`` and ``T_REF = 100 N`` (a shared dimensionless coefficient: the
    relative change of the tangent stiffness per ``T_REF/2`` of tension). Spring law only."""

    name: ClassVar[str] = "nonlinear_elasticity"
    summary: ClassVar[str] = "tension is not linear in strain"
    spring_only: ClassVar[bool] = True
    acts_through_elasticity: ClassVar[bool] = True

    def specs(self, robot, data):
        return (_spec("stiffening", (), 0.0, 0.1, "1"),)

    def tension(self, t, p):
        return t * (1.0 + p["stiffening"] * t / T_REF)


@dataclass(frozen=True)
class PlatformMass(Effect):
    """Platform mass (kg) or centre of mass (m, platform frame) differ from the description."""

    name: ClassVar[str] = "platform_mass"
    summary: ClassVar[str] = "platform mass or centre of mass differs from the description"

    def specs(self, robot, data):
        return (_spec("mass", (), float(robot.platform_mass), 0.5, "kg", domain=POSITIVE),
                _spec("com", (3,), np.asarray(robot.com), 1e-2, "m"))

    def robot(self, robot, p):
        return eqx.tree_at(lambda r: (r.platform_mass, r.com), robot, (p["mass"], p["com"]))


VOCABULARY: tuple[Effect, ...] = (
    CableMass(), AnchorOffset(), LengthOffset(), LengthDrift(), TensionSensorBias(),
    PoseFrameOffset(), ExitFriction(), NonlinearElasticity(), PlatformMass(),
    PulleyKinematics(), LengthGain(), TensionSensorGain(), AttachmentOffset(),
)
"""One instance of every effect of formats.md §3, in the table's order."""

EFFECTS: dict[str, Effect] = {e.name: e for e in VOCABULARY}


def get_effect(name: str) -> Effect:
    """The vocabulary effect called ``name`` (``ValueError`` lists the allowed names)."""
    if name not in EFFECTS:
        raise ValueError(f"unknown effect {name!r}; allowed: {', '.join(EFFECTS)}")
    return EFFECTS[name]
