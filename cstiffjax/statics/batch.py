"""Batches of forward-statics problems: a :class:`~cstiffjax.statics.forward.StaticsProblem`
whose ``l0`` (and ``external``) carry leading batch axes is solved one problem at a time
under ``jax.vmap``, and the results get the batch axes back.

The solver itself (:func:`cstiffjax.statics.forward.forward_statics`,
:func:`~cstiffjax.statics.forward.solve_unknowns`) is written for one problem; this module
only flattens the batch axes, maps and reshapes. The robot and the ``tension`` hook are
shared by every problem of the batch; the start (``pose0``, ``forces0``) and a ``solved``
may be shared (their one-problem shape) or given per problem (the batch axes in front).
"""

import dataclasses
import math

import jax
import jax.numpy as jnp

from cstiffjax.core.status import Status, code, from_codes, to_codes


def batch_shape(l0, external) -> tuple[int, ...]:
    """The batch axes of a problem: those of ``l0`` (``(*batch, m)``) and ``external``
    (``(*batch, 6)`` or None) broadcast together; ``()`` for one problem. A ``ValueError``
    when they do not broadcast."""
    shapes = [l0.shape[:-1]] + ([] if external is None else [external.shape[:-1]])
    try:
        return tuple(jnp.broadcast_shapes(*shapes))
    except ValueError:
        raise ValueError(f"StaticsProblem: the batch axes of l0 {l0.shape} and external {external.shape} do not "
                         f"broadcast together") from None


def _per_problem(x, name, tail, batch, n):
    """``(x, axis)``: ``x`` shared (its one-problem shape ``tail``, axis None) or one per
    problem (``batch + tail``, flattened to ``(n, *tail)``, axis 0); else a ``ValueError``."""
    if x is None:
        return None, None
    x = jnp.asarray(x, dtype=jnp.float64)
    if x.shape == tail:
        return x, None
    if x.shape != batch + tail:
        raise ValueError(f"forward statics: {name} has shape {x.shape}; {tail} (shared by the batch) or "
                         f"{batch + tail} (one per problem) is expected for a problem batch {batch}")
    return x.reshape((n, *tail)), 0


def over_batch(one, problem, batch, pose0, forces0, solved):
    """``one(problem_i, pose0_i, forces0_i, solved_i)`` (a function of one problem, its
    ``throw`` off) for every problem of the batch ``batch`` under ``jax.vmap``; every output
    leaf gets the batch axes in front.

    **Arguments:** ``problem`` a ``StaticsProblem`` with batch axes ``batch``
    (:func:`batch_shape`); ``pose0`` (6,) or ``(*batch, 6)`` or None; ``forces0`` (2, m) or
    ``(*batch, 2, m)`` or None; ``solved`` None or a ``Solved`` with the batch axes in front.

    **Returns:** ``one``'s output with the batch axes in front."""
    n, m = math.prod(batch), problem.l0.shape[-1]
    l0 = jnp.broadcast_to(problem.l0, (*batch, m)).reshape(n, m)
    ext = None if problem.external is None else jnp.broadcast_to(problem.external, (*batch, 6)).reshape(n, 6)
    pose0, p_axis = _per_problem(pose0, "pose0", (6,), batch, n)
    forces0, f_axis = _per_problem(forces0, "forces0", (2, m), batch, n)
    if solved is not None:
        solved = jax.tree.map(lambda x: x.reshape((n, *x.shape[len(batch):])), solved)

    def single(l0_i, ext_i, pose0_i, forces0_i, solved_i):
        return one(dataclasses.replace(problem, l0=l0_i, external=ext_i), pose0_i, forces0_i, solved_i)

    axes = (0, None if ext is None else 0, p_axis, f_axis, None if solved is None else 0)
    out = jax.vmap(single, in_axes=axes)(l0, ext, pose0, forces0, solved)
    return jax.tree.map(lambda x: x.reshape((*batch, *x.shape[1:])), out)


def first_failure(result: Status) -> Status:
    """The status of the first failed problem of a batched ``result`` (``successful`` when
    none failed): what a batch raises with ``throw=True``."""
    codes = to_codes(result).reshape(-1)
    return from_codes(codes[jnp.argmax(codes != code(Status.successful))])
