"""Effect base class, parameter specs and the per-sample context (see :mod:`fitting.effects`)."""

from dataclasses import dataclass
from typing import ClassVar

import equinox as eqx
import numpy as np
from jaxtyping import Array, Float

from cstiffjax.cable.laws import CableLaw


@dataclass(frozen=True)
class ParamSpec:
    """One parameter block of an effect: ``name``, ``shape``, ``null`` (array, the value
    where the effect vanishes), ``scale`` (typical magnitude), ``unit`` (text)."""

    name: str
    shape: tuple
    null: np.ndarray
    scale: float
    unit: str
    start: np.ndarray | None = None  # where the fit starts when freed (default: null)


class SampleContext(eqx.Module):
    """Per-sample auxiliary inputs every hook may read (covariates reach the model).

    - ``time`` s since the first sample (0 when the recordings have no time);
    - ``direction`` (m,) sign of the last commanded length change ``sign(l0[k] - l0[k-1])``
      (+1 paid out, -1 hauled in, 0 for the first row);
    - ``index`` the sample's 0-based position in the recordings (float);
    - ``covariates`` (k,) every extra numeric column (temperature, humidity, ...), in the
      order of :attr:`ModelData.covariate_names <fitting.effects.model.ModelData>`;
    - ``l0`` (m,) m and ``wrench`` (6,) N, N·m: the *recorded* inputs (what an effect's
      driver means by "the sample's own inputs", unchanged by other effects' hooks).
    """

    time: Float[Array, ""]
    direction: Float[Array, " m"]
    index: Float[Array, ""]
    covariates: Float[Array, " k"]
    l0: Float[Array, " m"]
    wrench: Float[Array, " 6"]


def _spec(name, shape, null, scale, unit, start=None):
    null = np.broadcast_to(np.asarray(null, dtype=float), shape).copy()
    start = None if start is None else np.broadcast_to(np.asarray(start, dtype=float), shape).copy()
    return ParamSpec(name, tuple(shape), null, float(scale), unit, start)


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


