"""The end forces of one cable: what every cable law returns."""

import equinox as eqx
from jaxtyping import Array, Bool, Float


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
