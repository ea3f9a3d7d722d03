"""Effect base class, parameter specs and the per-sample context (see :mod:`fitting.effects`)."""

from dataclasses import dataclass
from typing import ClassVar

import equinox as eqx
import numpy as np
from jaxtyping import Array, Float

from cstiffjax.cable.laws import CableLaw

BOUND_SIGMAS = 2.0  # an estimate within this many standard deviations of its bound is at the bound


@dataclass(frozen=True)
class Domain:
    """Where a parameter can lie physically (the bound part of dynamax's ``ParameterProperties``):
    ``lower``/``upper`` bounds in the parameter's unit (``±inf``: free), ``smallest`` the
    least departure from the null value that hardware could produce (0: any size is
    physical), and ``reading``: what the bound means, for the report (e.g. "a radius
    cannot be negative").

    The fit itself is not constrained (the diagnosis fits ``null + scale·θ`` unbounded, so
    an estimate beyond the bound shows a model that does not fit); :meth:`problem` says
    whether an estimate is evidence for the effect."""

    lower: float = -np.inf
    upper: float = np.inf
    smallest: float = 0.0
    reading: str = ""

    def problem(self, name: str, value, std, null, unit: str) -> str | None:
        """Why the estimate ``value ± std`` (arrays, the parameter's unit; ``std`` already
        inflated) of parameter ``name`` is no evidence for its effect, else ``None``: an
        estimate at or beyond a bound (within :data:`BOUND_SIGMAS` standard deviations of it,
        any entry), or one whose every entry departs from ``null`` by less than ``smallest``."""
        v, s, z = (np.ravel(np.asarray(a, dtype=float)) for a in (value, std, null))
        s = np.where(np.isfinite(s), s, np.inf)
        why = f" ({self.reading})" if self.reading else ""
        for bound, side, near in ((self.lower, ">", v - BOUND_SIGMAS * s <= self.lower),
                                  (self.upper, "<", v + BOUND_SIGMAS * s >= self.upper)):
            if np.isfinite(bound) and np.any(near):
                j = int(np.flatnonzero(near)[0])
                entry = name if v.size == 1 else f"{name}[{j + 1}]"
                return (f"{entry} = {v[j]:.3g} ± {s[j]:.2g} {unit} is at or beyond its physical bound "
                        f"{name} {side} {bound:.3g} {unit}{why}")
        if self.smallest > 0 and np.all(np.abs(v - z) < self.smallest):
            j = int(np.argmax(np.abs(v - z)))
            return (f"{name} departs from {z[j]:.3g} {unit} by only {abs(v[j] - z[j]):.3g} {unit}, less than "
                    f"the {self.smallest:.3g} {unit} hardware could produce{why}")
        return None


FREE = Domain()
POSITIVE = Domain(lower=0.0, reading="a physical magnitude")


@dataclass(frozen=True)
class ParamSpec:
    """One parameter block of an effect: ``name``, ``shape``, ``null`` (array, the value
    where the effect vanishes), ``scale`` (typical magnitude), ``unit`` (text), ``start``
    (where the fit starts when freed, default ``null``) and ``domain`` (a :class:`Domain`,
    where the value can lie physically; the same for every entry)."""

    name: str
    shape: tuple
    null: np.ndarray
    scale: float
    unit: str
    start: np.ndarray | None = None
    domain: Domain = FREE


class SampleContext(eqx.Module):
    """Per-sample auxiliary inputs every hook may read (covariates reach the model).

    - ``time`` s since the first sample (0 when the recordings have no time);
    - ``direction`` (m,) sign of the last commanded length change ``sign(l0[k] - l0[k-1])``
      (+1 paid out, -1 hauled in, 0 for the first row);
    - ``index`` the sample's 0-based position in the recordings (float);
    - ``covariates`` (k,) every extra numeric column (temperature, humidity, ...), in the
      order of :attr:`ModelData.covariate_names <fitting.effects.model.ModelData>`;
    - ``l0`` (m,) m and ``wrench`` (6,) N, N·m: the *recorded* inputs (what an effect's
      driver means by "the sample's own inputs", unchanged by other effects' hooks);
    - ``session`` the sample's recording session as an index 0..S-1 (float; formats.md §2
      version 3; 0 for recordings without sessions).
    """

    time: Float[Array, ""]
    direction: Float[Array, " m"]
    index: Float[Array, ""]
    covariates: Float[Array, " k"]
    l0: Float[Array, " m"]
    wrench: Float[Array, " 6"]
    session: Float[Array, ""]


def _spec(name, shape, null, scale, unit, start=None, domain: Domain = FREE):
    null = np.broadcast_to(np.asarray(null, dtype=float), shape).copy()
    start = None if start is None else np.broadcast_to(np.asarray(start, dtype=float), shape).copy()
    return ParamSpec(name, tuple(shape), null, float(scale), unit, start, domain)


@dataclass(frozen=True)
class Effect:
    """Base class: the nominal model (all hooks are the identity)."""

    name: ClassVar[str] = "none"
    summary: ClassVar[str] = ""
    needs_tensions: ClassVar[bool] = False
    needs_time: ClassVar[bool] = False
    spring_only: ClassVar[bool] = False
    acts_through_elasticity: ClassVar[bool] = False  # visible only through the cables' strain (EA)

    def specs(self, robot, data) -> tuple[ParamSpec, ...]:
        return ()

    def applicable(self, robot, recordings) -> str | None:
        """``None`` if the effect can be fitted to ``recordings``, else the reason."""
        if self.needs_tensions and not recordings.has_tensions:
            return "no tensions recorded"
        if self.needs_time and not bool(np.all(np.isfinite(np.asarray(recordings.time)))):
            return "no time column"
        return None

    def bind(self, robot, data) -> "Effect":
        """The effect as used on ``robot`` and ``data``: static settings that depend on
        them are fixed here (:func:`~fitting.effects.make_model` calls it; default ``self``).
        The result must stay hashable and should depend on the data only coarsely, so that
        data sets of one robot share the compiled model."""
        return self

    def note(self, robot, data) -> str | None:
        """An assumption the effect makes on ``robot`` and ``data`` that the report must
        state (``None``: none)."""
        return None

    def gauge(self, m: int):
        """``(k, P_e)`` orthonormal directions of the effect's parameter vector (its blocks
        flattened in order, θ units) that no recording can see on an ``m``-cable robot, e.g. a
        common shift of every anchor when no position is measured; ``None``: none. The
        diagnosis judges the effect on the other directions only."""
        return None

    def law(self, law: CableLaw) -> CableLaw:
        """The :class:`~cstiffjax.cable.laws.CableLaw` of a model holding this effect, given the
        law so far (default: unchanged)."""
        return law

    def robot(self, robot, p):
        return robot

    def inputs(self, l0, wrench, ctx: SampleContext, p):
        return l0, wrench

    def tension(self, t, p):
        return t

    def measure(self, pose, tensions, ctx: SampleContext, p):
        return pose, tensions


