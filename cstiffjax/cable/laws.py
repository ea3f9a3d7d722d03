"""Cable laws: the force a cable exerts on the platform, given both end points.

A *cable law* maps ``(anchor, attachment, l0, EA, mass_per_length, gravity)`` (base
frame, SI) to a :class:`CableForce`: the force on the platform at the attachment, the
force on the base at the anchor, and the tension at both ends. Laws:

- ``"spring"``: massless linear-elastic cable, ``t = EA (l - l0) / l0`` for ``l > l0``
  and ``0`` (slack) otherwise. Seed 004 eq. (17): ``∂t/∂l = EA / l0``.
- ``"catenary"``: elastic catenary with weight (seed 003 eqs 1-10, Irvine); implemented
  in :mod:`cstiffjax.cable.catenary` and dispatched from here.
- ``"ideal"``: inextensible; it has no force law of its own (tensions come from
  statics), see :func:`cstiffjax.statics.geometry.forward_statics`.

Each law is written for *one* cable; robots vmap it over their cables. Every law takes
the cable's geometry from :func:`cstiffjax.cable.path.cable_path`: optional ``radius`` and
``axis`` describe a swivel pulley at the anchor (formats.md §1 v2; defaults: no pulley,
the straight cable, whose numbers are unchanged). The spring acts on the whole path
(``l = r beta + |P - T|``), its force on the platform points from P to the tangent point T.
"""

import jax.numpy as jnp

from cstiffjax.cable.catenary import catenary_force
from cstiffjax.cable.force import CableForce
from cstiffjax.cable.path import cable_path

_NO_AXIS = (0.0, 0.0, 0.0)

CABLE_LAWS = ("ideal", "spring", "catenary")


def check_law(law: str) -> str:
    """Return ``law`` if it names a cable law, else raise ``ValueError`` listing them."""
    if law not in CABLE_LAWS:
        raise ValueError(f"unknown cable law {law!r}; allowed: {', '.join(map(repr, CABLE_LAWS))}")
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


def cable_force(law: str, anchor, attachment, l0, EA, mass_per_length, gravity, radius=0.0,
                axis=_NO_AXIS) -> CableForce:
    """Dispatch to the cable law ``law`` for one cable (see module docstring).

    **Arguments:** ``anchor``, ``attachment``: end points in the base frame, m; ``l0``:
    unstrained length of the whole path, m; ``EA``: N; ``mass_per_length``: kg/m;
    ``gravity``: m/s²; ``radius`` m and ``axis`` (3,): the swivel pulley at the anchor
    (:func:`cstiffjax.cable.path.cable_path`; default none).
    """
    if law == "spring":
        return spring_force(anchor, attachment, l0, EA, radius, axis)
    if law == "bilateral":
        return bilateral_spring_force(anchor, attachment, l0, EA, radius, axis)
    if law == "catenary":
        return catenary_force(anchor, attachment, l0, EA, mass_per_length, gravity, radius, axis)
    if law == "ideal":
        raise ValueError("the 'ideal' cable law has no force law; use statics.forward_statics")
    check_law(law)
