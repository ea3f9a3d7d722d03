"""Candidate physics for the mismatch diagnosis: one small class per effect of the
vocabulary of ``cstiffjax/io/formats.md`` §3, each a differentiable *model extension*.

An effect is a frozen dataclass (hashable, so it can be static under ``jax.jit``) that
declares its parameters and overrides any of four hooks; effects in a list are applied
together (composition), in list order:

====================  ==========================================================
``law(law)``          cable law to use (``cable_mass`` switches to ``CableLaw.catenary``)
``robot(robot, p)``   the robot the statics sees (anchors, masses, ...)
``inputs(l0, w, ctx, p)``   per-sample inputs: unstrained lengths ``l0`` (m,) m,
                      external wrench ``w`` (6,) N/N·m; ``ctx`` a :class:`SampleContext`
``tension(t, p)``     tension of a straight elastic cable from its linear-spring
                      value ``t = EA (l - l0)/l0`` (spring law only), N
``measure(pose, t, ctx, p)``  what the instruments read from the true pose (6,) and
                      exit-point tensions (m,)
====================  ==========================================================

``p`` is a dict ``{parameter name: array}`` in physical units. Every hook is the
identity when the parameters sit at their ``null`` values, so an effect set with
frozen parameters *is* the nominal model; this lets :mod:`fitting.diagnosis.diagnose` compile
one residual function for all effects at once and free parameters by masking.

How to add an effect
--------------------
1. Subclass :class:`Effect` as a ``@dataclass(frozen=True)``; set ``name`` (used in
   the JSON) and ``summary`` (one line: the physics left out).
2. Implement ``specs(robot, data)`` returning a tuple of :class:`ParamSpec`
   ``(name, shape, null, scale, unit, start, domain)``: ``null`` is the value at which the
   effect vanishes, ``scale`` a typical magnitude (conditions the least squares), ``domain``
   a :class:`~fitting.effects.base.Domain` (bounds, the smallest size hardware could produce
   and what they mean; an estimate outside it is no evidence for the effect).
3. Override the hooks it needs, written for one sample with ``jax.numpy`` (no Python
   control flow on values), identity at ``null``.
4. Optionally ``applicable(robot, recordings) -> str | None`` (why not, e.g. no
   tensions recorded), ``bind(robot, data)`` (static settings fixed from the data, e.g.
   the pulley axes assumed from the workspace centre) and ``note(robot, data)`` (an
   assumption the report must state), and add an instance to :data:`VOCABULARY`.
"""

from fitting.effects.base import Effect, ParamSpec, SampleContext
from fitting.effects.model import ExtendedModel, build_data, make_model
from fitting.effects.vocabulary import (
    EFFECTS,
    T_REF,
    VOCABULARY,
    AnchorOffset,
    AttachmentOffset,
    CableMass,
    CableMassScreen,
    ExitFriction,
    LengthDrift,
    LengthGain,
    LengthOffset,
    NonlinearElasticity,
    PlatformMass,
    PoseFrameOffset,
    PulleyKinematics,
    TensionSensorBias,
    TensionSensorGain,
    get_effect,
)

__all__ = [
    "EFFECTS", "T_REF", "VOCABULARY", "AnchorOffset", "AttachmentOffset", "CableMass", "CableMassScreen", "Effect",
    "ExitFriction",
    "ExtendedModel", "LengthDrift", "LengthGain", "LengthOffset", "NonlinearElasticity", "ParamSpec",
    "PlatformMass", "PoseFrameOffset", "PulleyKinematics", "SampleContext", "TensionSensorBias",
    "TensionSensorGain", "build_data", "get_effect", "make_model",
]
