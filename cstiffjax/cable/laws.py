"""Cable laws: the force a cable exerts on the platform, given both end points.

:class:`CableLaw` names every law of the package, once. A *cable law* maps ``(anchor,
attachment, l0, EA, mass_per_length, gravity)`` (base frame, SI) to a :class:`CableForce`:
the force on the platform at the attachment, the force on the base at the anchor, and the
tension at both ends. :func:`cable_force` dispatches the laws that have such a force
(:data:`CABLE_FORCE_LAWS`):

- ``spring``: massless linear-elastic cable, ``t = EA (l - l0) / l0`` for ``l > l0``
  and ``0`` (slack) otherwise. Seed 004 eq. (17): ``∂t/∂l = EA / l0``.
- ``bilateral``: the spring that also pushes when ``l < l0`` (smooth: the start-up law of
  the statics solves).
- ``catenary``: elastic catenary with weight (Yuan et al. 2015 eqs 1-10, Irvine); implemented
  in :mod:`cstiffjax.cable.catenary` and dispatched from here.

Two laws exist only in forward statics (:func:`cstiffjax.statics.forward.forward_statics`):
``small_sag`` (the bilateral spring with the cable's weight to small sag, a property of
the whole equilibrium) and ``ideal`` (inextensible: tensions come from statics).

Each law is written for *one* cable; robots vmap it over their cables. Every law takes
the cable's geometry from :func:`cstiffjax.cable.path.cable_path`: optional ``radius`` and
``axis`` describe a swivel pulley at the anchor (formats.md §1 v2; defaults: no pulley,
the straight cable, whose numbers are unchanged). The spring acts on the whole path
(``l = r beta + |P - T|``), its force on the platform points from P to the tangent point T.
"""

import enum
from collections.abc import Iterable

import jax.numpy as jnp

from cstiffjax.cable.catenary import catenary_force
from cstiffjax.cable.force import CableForce
from cstiffjax.cable.path import cable_path

_NO_AXIS = (0.0, 0.0, 0.0)


class CableLaw(enum.Enum):
    """The cable laws of the package (module docstring; forward statics'
    :mod:`cstiffjax.statics.forward` describes each law's equilibrium).

    Python code passes members (``CableLaw.catenary``); text (the command line, files,
    JSON documents) holds the member's name, read by :meth:`parse` where it enters, and
    written as ``law.name``. The Python entry points do *not* accept the name as well:
    a string there is a ``TypeError`` that says how to convert it. A law is a static
    argument of the compiled functions, so two spellings of one law would be two
    compilations (and two serialized programs); and a misspelt member fails where it is
    written (``AttributeError``), not inside a solve.

    A function that supports only some laws lists them in a ``frozenset`` constant beside
    it (e.g. :data:`CABLE_FORCE_LAWS`) and checks its argument with :func:`check_law`,
    whose error names the function, the law and what it supports.
    """

    spring = "spring"
    bilateral = "bilateral"
    small_sag = "small_sag"
    catenary = "catenary"
    ideal = "ideal"

    @classmethod
    def parse(cls, text: str) -> "CableLaw":
        """The law named ``text`` (a member's name, e.g. ``"catenary"``).

        **Raises:** ``ValueError`` naming ``text`` and listing the allowed names.
        """
        try:
            return cls[text]
        except (KeyError, TypeError):
            raise ValueError(f"unknown cable law {text!r}; allowed: {law_names(cls)}") from None


ALL_LAWS = frozenset(CableLaw)
# the laws with a one-cable force (cable_force and everything summing it: elastic wrench, stiffness)
CABLE_FORCE_LAWS = frozenset({CableLaw.spring, CableLaw.bilateral, CableLaw.catenary})


def law_names(laws: Iterable[CableLaw]) -> str:
    """``'spring', 'catenary'``: the names of ``laws`` in :class:`CableLaw`'s order (messages)."""
    laws = frozenset(laws)
    return ", ".join(repr(law.name) for law in CableLaw if law in laws)


def check_law(law, supported: frozenset = ALL_LAWS, where: str = "cable law") -> CableLaw:
    """``law`` if it is a :class:`CableLaw` member in ``supported``.

    **Arguments:** ``law``: the argument to check; ``supported``: the laws the caller
    supports; ``where``: the caller's name, for the messages.

    **Raises:** ``TypeError`` when ``law`` is not a member (a name: convert it with
    :meth:`CableLaw.parse`); ``ValueError`` naming the law and listing ``supported``.
    """
    if not isinstance(law, CableLaw):
        hint = f" (CableLaw.parse({law!r}) reads a name)" if isinstance(law, str) else ""
        raise TypeError(f"{where}: the law must be a CableLaw member, e.g. CableLaw.spring{hint}; got {law!r}")
    if law not in supported:
        raise ValueError(f"{where} does not support the {law.name!r} cable law; supported: {law_names(supported)}")
    return law


def spring_tension(length, l0, EA):
    """Tension of a massless linear-elastic cable, N: ``EA (l - l0)/l0``, 0 when slack."""
    return jnp.where(length > l0, EA * (length - l0) / l0, 0.0)


def spring_force(anchor, attachment, l0, EA, radius=0.0, axis=_NO_AXIS) -> CableForce:
    """Massless spring cable from ``anchor`` (over its pulley, if any) to ``attachment``
    (base frame, m); the force on the base is the free span's, at the tangent point."""
    path = cable_path(anchor, attachment, radius, jnp.asarray(axis, dtype=jnp.float64))
    u = path.direction
    t = spring_tension(path.length, l0, EA)
    return CableForce(t * u, -t * u, t, t, path.length <= l0)


def bilateral_spring_force(anchor, attachment, l0, EA, radius=0.0, axis=_NO_AXIS) -> CableForce:
    """Spring that also pushes when ``l < l0``: smooth start-up law for the statics solves."""
    path = cable_path(anchor, attachment, radius, jnp.asarray(axis, dtype=jnp.float64))
    t = EA * (path.length - l0) / l0
    return CableForce(t * path.direction, -t * path.direction, t, t, path.length <= l0)


def cable_force(law: CableLaw, anchor, attachment, l0, EA, mass_per_length, gravity, radius=0.0,
                axis=_NO_AXIS) -> CableForce:
    """Dispatch to the cable law ``law`` for one cable (see module docstring).

    **Arguments:** ``law``: one of :data:`CABLE_FORCE_LAWS` (``small_sag`` and ``ideal``
    have no one-cable force: use :func:`cstiffjax.statics.forward.forward_statics`);
    ``anchor``, ``attachment``: end points in the base frame, m; ``l0``: unstrained length
    of the whole path, m; ``EA``: N; ``mass_per_length``: kg/m; ``gravity``: m/s²;
    ``radius`` m and ``axis`` (3,): the swivel pulley at the anchor
    (:func:`cstiffjax.cable.path.cable_path`; default none).

    **Returns:** the cable's :class:`CableForce`.
    """
    check_law(law, CABLE_FORCE_LAWS, "cable_force")
    if law is CableLaw.spring:
        return spring_force(anchor, attachment, l0, EA, radius, axis)
    if law is CableLaw.bilateral:
        return bilateral_spring_force(anchor, attachment, l0, EA, radius, axis)
    return catenary_force(anchor, attachment, l0, EA, mass_per_length, gravity, radius, axis)
