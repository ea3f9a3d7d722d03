"""Grammar terms on top of a compiled extended model, without recompiling per term.

A diagnosis tries hundreds of grammar terms (:mod:`fitting.effects.grammar`). Compiling
one model holding every term costs minutes (and its Jacobian has a column per entry);
instead the terms act on the *data* of one compiled model, the vocabulary model plus a
:class:`Probe`:

- input terms (``l0``, ``load``, ``wrench``) transform the recorded inputs with the
  family's ``inputs`` hook, geometry terms the robot with its ``robot`` hook, and
  measurement terms (``pose``, ``tension``) remove their deviation from the recorded
  measurement (:meth:`TermFamily.correct_measurement`); the compiled model is then
  evaluated on the transformed data (same shapes: no recompilation);
- the :class:`Probe` adds a constant to every input, geometry entry and predicted
  measurement; its Jacobian columns at zero are therefore the exact per-sample
  sensitivities ``∂r_k/∂l0_k``, ``∂r_k/∂w_k``, ``∂r_k/∂pose_k``, ``∂r_k/∂t_k``,
  ``∂r/∂anchors``, ``∂r/∂attachments``, and the Jacobian of the residuals with respect to
  the term parameters is the chain rule through the transforms (autodiff of the hooks).

:class:`TermModel` looks like an :class:`~fitting.effects.model.ExtendedModel` to the
diagnosis (``effects``, ``blocks``, ``null``, ``scale``, ``start``, ``block_slice``,
``effect_index``): its θ is the compiled model's θ followed by the terms' parameters, so
the masked Levenberg-Marquardt, the Wald test and the cross-validation treat a term
exactly like a vocabulary effect.
"""

from dataclasses import dataclass
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from cstiffjax.core.arrays import to_device
from cstiffjax.runtime import programs
from cstiffjax.statics.geometry import cable_lengths
from fitting.effects.base import Effect, _spec
from fitting.effects.grammar import CABLE_WHERES, COMPONENT_WHERES, Term
from fitting.effects.model import ExtendedModel, evaluate_columns

PROBE_BLOCKS = ("l0", "wrench", "pose", "tension", "anchors", "attachments")


@dataclass(frozen=True)
class Probe(Effect):
    """Constant additive perturbation of every input, geometry entry and predicted
    measurement (identity at zero; never freed): its Jacobian columns are sensitivities."""

    name: ClassVar[str] = "probe"

    def specs(self, robot, data):
        m = robot.num_cables
        return (_spec("l0", (m,), 0.0, 1.0, "m"), _spec("wrench", (6,), 0.0, 1.0, "N, N·m"),
                _spec("pose", (6,), 0.0, 1.0, "m, rad"), _spec("tension", (m,), 0.0, 1.0, "N"),
                _spec("anchors", (m, 3), 0.0, 1.0, "m"), _spec("attachments", (m, 3), 0.0, 1.0, "m"))

    def robot(self, robot, p):
        return eqx.tree_at(lambda r: (r.anchors, r.attachments), robot,
                           (robot.anchors + p["anchors"], robot.attachments + p["attachments"]))

    def inputs(self, l0, wrench, ctx, p):
        return l0 + p["l0"], wrench + p["wrench"]

    def measure(self, pose, tensions, ctx, p):
        return pose + p["pose"], tensions + p["tension"]


class TermModel:
    """``core`` (a compiled :class:`ExtendedModel` whose last effect is a :class:`Probe`)
    plus ``terms`` (tuple of :class:`~fitting.effects.grammar.Term`); see module doc."""

    def __init__(self, core: ExtendedModel, terms, robot, data):
        if not core.effects or not isinstance(core.effects[-1], Probe):
            raise ValueError("TermModel needs a core model whose last effect is a Probe")
        self.core, self.terms = core, tuple(terms)
        self.families = tuple(dict.fromkeys(t.family for t in self.terms))
        self.fam_specs = {f: {s.name: s for s in f.specs(robot, data)} for f in self.families}
        self.effects = (*core.effects, *self.terms)
        self.num_cables = core.num_cables
        off = core.size
        blocks, null, scale = list(core.blocks), [np.asarray(core.null)], [np.asarray(core.scale)]
        for j, t in enumerate(self.terms):
            sa = self.fam_specs[t.family]["a"]
            k = len(t.entries(sa.shape))
            blocks.append((len(core.effects) + j, "a", off, (k,) if k > 1 else (), _term_unit(t)))
            null.append(np.zeros(k))
            scale.append(np.full(k, sa.scale))
            off += k
        self.blocks = tuple(blocks)
        self.null, self.scale = np.concatenate(null), np.concatenate(scale)
        self.start = np.zeros(off)
        self.law = core.law
        gather, pos = {f: ([], []) for f in self.families}, 0
        for t in self.terms:
            ent = t.entries(self.fam_specs[t.family]["a"].shape)
            gather[t.family][0].extend(int(e) for e in ent)
            gather[t.family][1].extend(range(pos, pos + len(ent)))
            pos += len(ent)
        # the transform's arguments (:func:`family_params`), built once: the same objects on every
        # evaluation (the program cache memoizes keys by the static values' identity). ``layout``:
        # per family ``(entries of a, positions in the terms' values, shape of a)``, tuples of ints
        # (static and reproducible: the transform is a serialized program); ``nulls``: the null
        # values of its other parameters (arrays, data)
        self.layout = tuple((tuple(gather[f][0]), tuple(gather[f][1]), tuple(self.fam_specs[f]["a"].shape))
                            for f in self.families)
        self.nulls = tuple({nm: to_device(s.null) for nm, s in self.fam_specs[f].items() if nm != "a"}
                           for f in self.families)

    @property
    def size(self) -> int:
        return int(self.null.shape[0])

    @property
    def base_size(self) -> int:
        """θ entries every fit frees: the core's (EA and the recordings' zeros)."""
        return self.core.base_size

    block_slice = ExtendedModel.block_slice
    effect_index = ExtendedModel.effect_index

    def evaluate(self, theta, robot, data, core_columns=None):
        """``(r (n, c), J (n·c, P + k), ok)`` at ``theta`` (core θ then term parameters); the
        core is evaluated through the masked fits' compiled loop
        (:func:`fitting.effects.model.evaluate_columns`). ``core_columns``: the core
        columns of ``J`` wanted (default all; the others are 0); the probe's columns
        that give the terms' columns are always computed: those of the probe blocks the
        terms' transforms move (a block whose transform Jacobian is exactly zero adds
        nothing to the chain rule, so its columns are skipped: an ``l0`` term needs the
        ``l0`` and ``wrench`` probes, 2m + 6 columns instead of 8m + 18)."""
        theta = np.asarray(theta, dtype=float)
        P = self.core.size
        v = self.null[P:] + self.scale[P:] * theta[P:]
        (rb, l0, w, pose, ten), jac = _transform_and_jacobian(self.families, self.layout, self.nulls, robot,
                                                              data, v)
        d2 = eqx.tree_at(lambda d: (d.l0, d.wrench, d.pose, d.tensions), data, (l0, w, pose, ten))
        moved = {nm for nm, j in zip(PROBE_BLOCKS, jac) if np.any(np.asarray(j))}
        i = len(self.core.effects) - 1
        probe = [np.zeros(0, int)] + [np.arange(o, o + int(np.prod(sh, dtype=int)))
                                      for bi, nm, o, sh, _ in self.core.blocks if bi == i and nm in moved]
        want = np.arange(P) if core_columns is None else np.asarray(core_columns, dtype=int)
        r, J, ok = evaluate_columns(self.core, theta[:P], rb, d2, np.union1d(want, np.concatenate(probe)))
        n, c = r.shape
        Jt = _chain(probe_sensitivities(self.core, J), jac, n, c) * self.scale[P:][None, :]
        return r, np.concatenate([J, Jt], axis=1), ok


def probe_sensitivities(core: ExtendedModel, J) -> dict:
    """The :class:`Probe`'s Jacobian columns of ``J`` (θ of ``core`` first): name -> (n·c, size)."""
    i = len(core.effects) - 1
    return {nm: J[:, o:o + int(np.prod(sh, dtype=int))] for bi, nm, o, sh, _ in core.blocks if bi == i}


def chain_basis(S, quantity, B, n, c):
    """Residual Jacobian ``(n·c, K)`` of a term whose ``quantity`` changes by ``B``
    (:func:`fitting.effects.grammar.basis`) per unit of each of its ``K`` entries."""
    if quantity in ("anchors", "attachments"):
        return S[quantity] @ B.reshape(-1, B.shape[-1])
    sign = -1.0 if quantity in ("pose", "tension") else 1.0  # measured side
    return sign * np.einsum("ncm,nmk->nck", S[quantity].reshape(n, c, -1), B).reshape(n * c, -1)


def _term_unit(t: Term) -> str:
    return "see discovered.parameters"


def _chain(S, jac, n, c):
    """Jacobian of the residuals w.r.t. the term values from the probe sensitivities ``S``
    (name -> (n·c, size)) and the transform Jacobians ``jac`` (per output, ``(..., k)``)."""
    dl0, dw, dpose, dten, dA, dB = (np.asarray(a) for a in jac)
    k = dl0.shape[-1]
    out = np.einsum("ncm,nmk->nck", S["l0"].reshape(n, c, -1), dl0)
    out += np.einsum("ncm,nmk->nck", S["wrench"].reshape(n, c, -1), dw)
    out -= np.einsum("ncm,nmk->nck", S["pose"].reshape(n, c, -1), dpose)  # measured side: minus
    out -= np.einsum("ncm,nmk->nck", S["tension"].reshape(n, c, -1), dten)
    out = out.reshape(n * c, k)
    out += S["anchors"] @ dA.reshape(-1, k) + S["attachments"] @ dB.reshape(-1, k)
    return out


def family_params(layout, nulls, values):
    """Per family ``{"a": array, <other parameter>: its null}`` with the terms' physical
    ``values`` set (one gather and one scatter per family; ``layout``, ``nulls``: those of
    :class:`TermModel`)."""
    out = []
    for (ent, pos, shape), null in zip(layout, nulls):
        a = jnp.zeros(int(np.prod(shape, dtype=int))).at[np.asarray(ent, dtype=int)].set(
            values[np.asarray(pos, dtype=int)])
        out.append(null | {"a": a.reshape(shape)})
    return out


def apply_terms(families, layout, nulls, robot, data, values):
    """Transformed ``(robot, l0, wrench, pose, tensions)`` of every term at ``values``."""
    params = family_params(layout, nulls, values)
    l0, w, pose, ten = data.l0, data.wrench, data.pose, data.tensions
    for f, p in zip(families, params):
        if f.where in ("anchors", "attachments"):
            robot = f.robot(robot, p)
        elif f.where == "EA":  # a stiffness: the l0 that strains the cable as EA (1 + s) would
            length = jax.vmap(lambda q, rb=robot: cable_lengths(rb, q))(data.pose)
            l0 = jax.vmap(lambda a, b, c, p=p, f=f: f.stiffness_inputs(a, b, c, p))(l0, length, data.ctx)
        elif f.where in ("l0", "load", "wrench"):
            l0, w = jax.vmap(lambda a, b, c, p=p, f=f: f.inputs(a, b, c, p))(l0, w, data.ctx)
        elif f.where in CABLE_WHERES + COMPONENT_WHERES:
            pose, ten = jax.vmap(lambda a, b, c, p=p, f=f: f.correct_measurement(a, b, c, p))(pose, ten, data.ctx)
    return robot, l0, w, pose, ten


def _transform_and_jacobian_impl(families, layout, nulls, robot, data, values):
    """:func:`apply_terms` and its forward-mode Jacobian w.r.t. ``values`` (per output:
    ``(n, m, k)``, ``(n, 6, k)``, ``(n, 6, k)``, ``(n, m, k)``, ``(m, 3, k)``, ``(m, 3, k)``)."""
    def f(v):
        rb, l0, w, pose, ten = apply_terms(families, layout, nulls, robot, data, v)
        return (l0, w, pose, ten, rb.anchors, rb.attachments), (rb, l0, w, pose, ten)

    jac, out = jax.jacfwd(f, has_aux=True)(values)
    l0j, wj, posej, tenj, aj, bj = jac
    return out, (l0j, wj, posej, tenj, aj, bj)


# serialized (cstiffjax.runtime.programs): a warm run loads the program of each set of term families
# instead of tracing it (bundled example: 6 programs, 0.21 -> 0.10 s). Elementwise work of
# microseconds per call, compiled once per set of families on a cold diagnosis's main thread:
# LLVM -O0 (programs.ONCE_OPTIONS), whose compile is the shorter
_transform_and_jacobian = programs.Program(
    _transform_and_jacobian_impl, name="fitting.effects.terms_model.transform_and_jacobian",
    like=lambda args: ((args[3], 0, 0, 0, 0), (0,) * 6), compiler_options=programs.ONCE_OPTIONS)
