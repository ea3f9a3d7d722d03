"""Result codes shared by the solvers (an ``eqx.Enumeration``, like ``optx.RESULTS``).

Every solver of the toolkit returns one result Module whose ``result`` field (or property)
is a :class:`Status`, whatever its ``throw``: the physics solves of ``cstiffjax`` and the
least-squares engine of ``fitting`` (:mod:`fitting.calibration.lm`) share this vocabulary.

This module is also the one adapter between a :class:`Status` and integer codes (for host
code, ``jnp.where`` over batches and values that pass where only arrays may, e.g. a
``custom_jvp``): :func:`to_codes`, :func:`from_codes`, :func:`code`, :func:`select`,
:func:`describe`. Nothing else reads a Status's internals.

With ``throw=True`` a failed solve raises from inside ``jit`` through ``eqx.error_if``.
Under ``eqx.filter_jit`` (every cstiffjax entry point) that is an
``EquinoxRuntimeError`` whose message is the status text; under a plain ``jax.jit`` of
the caller's own, XLA wraps it in a ``JaxRuntimeError`` that starts with ``INTERNAL:
CpuCallback error calling callback`` and carries the text further down.
:func:`error_message` extracts the text from either, and :func:`readable_errors`
re-raises both as :class:`~cstiffjax.core.errors.SolverError` with just that text.

The public solvers are wrapped in :func:`solver_errors`, so a failure of a call made
outside any ``jit`` of the caller's raises ``SolverError`` with the status text (not
equinox's error, whose "stack inside of JIT" is the one recorded when the program was
traced, possibly by another call). Under the caller's own ``jax.jit`` the error surfaces
where the caller's program runs, outside the solver: it is JAX's ``JaxRuntimeError``
carrying the text; wrap that call in ``with readable_errors():`` to get a ``SolverError``.
"""

import contextlib
import functools
import logging

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Int

from cstiffjax.core import internals
from cstiffjax.core.errors import SolverError

_MARKERS = ("equinox.EquinoxRuntimeError: ", "_EquinoxRuntimeError: ")


class Status(eqx.Enumeration):
    """Outcome of a solve. ``Status.successful`` is the only good one, except in the
    least-squares engine (:mod:`fitting.calibration.lm`): there ``no_decrease`` (the damping
    reached its maximum without lowering χ²: the point is a minimum to rounding) counts as
    converged too, its iteration limit is ``not_converged`` and ``start_failed`` means a
    required sample failed at the start point (nothing was fitted)."""

    successful = ""
    not_converged = "the solver did not converge within max_steps (or to the tolerance)"
    singular = "the structure matrix is rank deficient at this pose (fewer than 6 independent cable directions)"
    infeasible = "no cable tensions within [tension_min, tension_max] hold this pose under this load"
    slack = "a cable is slack (its tension would be negative)"
    invalid_input = "invalid input (non-positive length, EA <= 0, NaN, or span_x <= 0)"
    zero_length = "a cable has zero length (its attachment is on its anchor): no cable direction, no stiffness"
    no_decrease = "no further decrease"
    start_failed = "failed at the start"
    unstable = ("the equilibrium is unstable: its stiffness (the weight's term included) is not positive definite "
                "(a saddle, or a direction with no restoring force)")


def to_codes(result: Status) -> Int[Array, "..."] | np.ndarray:
    """The integer codes of a (possibly batched, possibly traced) ``result``: a host array for a
    constant member, the array (or tracer) it holds otherwise. For host code and ``jnp.where``."""
    return internals.enum_codes(result)


def from_codes(codes: Int[Array, "..."]) -> Status:
    """The :class:`Status` of integer ``codes`` (any shape; traced or not): the inverse of
    :func:`to_codes`."""
    return internals.enum_with_codes(Status.successful, codes)


def code(result: Status) -> int:
    """The integer code of a concrete, unbatched ``result`` (a constant member, or a solver's
    output after the solve), as a Python ``int``: no device program runs."""
    return int(np.asarray(internals.enum_codes(result)))


def raise_if_failed(result: Status, value, throw: bool):
    """Return ``value``; when ``throw`` and ``result`` is not successful, raise (also under jit)."""
    if not throw:
        return value
    return result.error_if(value, result != Status.successful)


def message(result: Status) -> str:
    """The message of a concrete, unbatched ``result`` (``""`` for ``successful``)."""
    return internals.enum_message(Status, code(result))


def describe(result: Status) -> str:
    """Human text of a (concrete, unbatched) result: ``"ok"`` or the failure message."""
    return message(result) or "ok"


def select(pred, if_true: Status, if_false: Status) -> Status:
    """Elementwise ``Status.where`` for a batched predicate (``Status.where`` takes a scalar)."""
    return from_codes(jnp.where(pred, to_codes(if_true), to_codes(if_false)))


def error_message(exc: BaseException) -> str | None:
    """The message of an error raised by :func:`raise_if_failed` (or any ``eqx.error_if``)
    inside ``jit``, without XLA's and equinox's wrapping (a :class:`~cstiffjax.core.errors.SolverError`:
    its text, what :func:`solver_errors` made of it); ``None`` if ``exc`` is not one."""
    if isinstance(exc, SolverError):
        return str(exc)
    text = str(exc)
    for marker in _MARKERS:
        if marker in text:
            return text.split(marker, 1)[1].split("\n\n", 1)[0].strip()
    return None


@contextlib.contextmanager
def readable_errors():
    """Context manager: an error raised inside ``jit`` by a failed ``throw=True`` solve
    leaves it as :class:`~cstiffjax.core.errors.SolverError` carrying only the readable message
    (``with readable_errors(): jax.jit(f)(x)``). Other exceptions pass unchanged."""
    log = logging.getLogger(internals.CALLBACK_LOGGER)  # jax logs the callback's traceback too: the message says it all
    quiet = _QuietCallbackLog()
    log.addFilter(quiet)
    try:
        yield
    except (RuntimeError, ValueError) as e:  # XLA raises either, depending on the dispatch path
        msg = error_message(e)
        if msg is None:
            raise
        raise SolverError(msg) from None
    finally:
        log.removeFilter(quiet)


def solver_errors(fn):
    """``fn`` (a public solver, usually an ``eqx.filter_jit`` function) called inside
    :func:`readable_errors`: its ``throw=True`` failures raise
    :class:`~cstiffjax.core.errors.SolverError` with the status text. Nothing changes in
    what is traced (the wrapper is plain Python); under the caller's own ``jit`` see the
    module docstring. ``__wrapped__`` stays the function without ``jit`` (``fn.__wrapped__``
    for a jitted ``fn``), for callers that trace it inline."""

    @functools.wraps(fn, updated=())  # a jitted fn's fields stay its own
    def call(*args, **kwargs):
        with readable_errors():
            return fn(*args, **kwargs)

    call.__wrapped__ = getattr(fn, "__wrapped__", fn)
    return call


class _QuietCallbackLog(logging.Filter):
    def filter(self, record) -> bool:
        return not (record.name == internals.CALLBACK_LOGGER and record.getMessage() == "jax.pure_callback failed")
