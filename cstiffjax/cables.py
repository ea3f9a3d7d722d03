"""Cable laws: the force a cable exerts on the platform, given both end points.

A *cable law* maps ``(anchor, attachment, l0, EA, mass_per_length, gravity)`` (base
frame, SI) to a :class:`CableForce`: the force on the platform at the attachment, the
force on the base at the anchor, and the tension at both ends. Laws:

- ``"spring"``: massless linear-elastic cable, ``t = EA (l - l0) / l0`` for ``l > l0``
  and ``0`` (slack) otherwise. Seed 004 eq. (17): ``∂t/∂l = EA / l0``.
- ``"catenary"``: elastic catenary with weight (seed 003 eqs 1-10, Irvine); implemented
  in :mod:`cstiffjax.catenary` and dispatched from here.
- ``"ideal"``: inextensible; it has no force law of its own (tensions come from
  statics), see :func:`cstiffjax.statics.forward_statics`.

Each law is written for *one* cable; robots vmap it over their cables.
"""

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

CABLE_LAWS = ("ideal", "spring", "catenary")


class CableForce(eqx.Module):
    """End forces of one cable (base frame, N).

    ``on_platform``: force the cable applies to the platform at the attachment.
    ``on_anchor``: force it applies to the base at the exit point.
    ``tension_anchor`` / ``tension_attachment``: tension magnitudes at the two ends
    (the exit point is where load cells measure, formats.md §2).
    ``slack``: true when the cable carries no tension.
    """

    on_platform: Float[Array, "3"]
    on_anchor: Float[Array, "3"]
    tension_anchor: Float[Array, ""]
    tension_attachment: Float[Array, ""]
    slack: Bool[Array, ""]


def check_law(law: str) -> str:
    """Return ``law`` if it names a cable law, else raise ``ValueError`` listing them."""
    if law not in CABLE_LAWS:
        raise ValueError(f"unknown cable law {law!r}; allowed: {', '.join(map(repr, CABLE_LAWS))}")
    return law


def _safe_length(v):
    sq = jnp.sum(v * v)
    return jnp.sqrt(jnp.where(sq > 0, sq, 1.0))


def spring_tension(length, l0, EA):
    """Tension of a massless linear-elastic cable, N: ``EA (l - l0)/l0``, 0 when slack."""
    return jnp.where(length > l0, EA * (length - l0) / l0, 0.0)


def spring_force(anchor, attachment, l0, EA) -> CableForce:
    """Massless spring cable between ``attachment`` and ``anchor`` (base frame, m)."""
    d = anchor - attachment
    length = _safe_length(d)
    u = d / length
    t = spring_tension(length, l0, EA)
    return CableForce(t * u, -t * u, t, t, length <= l0)


def bilateral_spring_force(anchor, attachment, l0, EA) -> CableForce:
    """Spring that also pushes when ``l < l0``: smooth start-up law for the statics solves."""
    d = anchor - attachment
    length = _safe_length(d)
    t = EA * (length - l0) / l0
    return CableForce(t * d / length, -t * d / length, t, t, length <= l0)


def cable_force(law: str, anchor, attachment, l0, EA, mass_per_length, gravity) -> CableForce:
    """Dispatch to the cable law ``law`` for one cable (see module docstring).

    **Arguments:** ``anchor``, ``attachment``: end points in the base frame, m; ``l0``:
    unstrained length, m; ``EA``: N; ``mass_per_length``: kg/m; ``gravity``: m/s².
    """
    if law == "spring":
        return spring_force(anchor, attachment, l0, EA)
    if law == "bilateral":
        return bilateral_spring_force(anchor, attachment, l0, EA)
    if law == "catenary":
        from .catenary import catenary_force  # local import: optional heavy module

        return catenary_force(anchor, attachment, l0, EA, mass_per_length, gravity)
    if law == "ideal":
        raise ValueError("the 'ideal' cable law has no force law; use statics.forward_statics")
    check_law(law)
