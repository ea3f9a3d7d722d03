"""Result codes shared by the solvers (an ``eqx.Enumeration``, like ``optx.RESULTS``)."""

import equinox as eqx
import jax.numpy as jnp


class Status(eqx.Enumeration):
    """Outcome of a cstiffjax solve. ``Status.successful`` is the only good one."""

    successful = ""
    not_converged = "the solver did not converge within max_steps (or to the tolerance)"
    singular = "the structure matrix is rank deficient at this pose (fewer than 6 independent cable directions)"
    infeasible = "no cable tensions within [tension_min, tension_max] hold this pose under this load"
    slack = "a cable is slack (its tension would be negative)"
    invalid_input = "invalid input (non-positive length, EA <= 0, NaN, or span_x <= 0)"


def raise_if_failed(result: Status, value, throw: bool):
    """Return ``value``; when ``throw`` and ``result`` is not successful, raise (also under jit)."""
    if not throw:
        return value
    return result.error_if(value, result != Status.successful)


def describe(result: Status) -> str:
    """Human text of a (concrete, unbatched) result: ``"ok"`` or the failure message."""
    msg = Status._index_to_message[int(result._value)]
    return msg or "ok"


def select(pred, if_true: Status, if_false: Status) -> Status:
    """Elementwise ``Status.where`` for a batched predicate (``Status.where`` takes a scalar)."""
    code = jnp.where(pred, if_true._value, if_false._value)
    return eqx.tree_at(lambda s: s._value, Status.successful, code)
