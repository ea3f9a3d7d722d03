"""A generated grammar of correction terms outside the vocabulary.

A *term* is ``where × form × driver × sharing``:

- **where**: an input (``l0`` commanded lengths, ``load`` the whole external wrench,
  ``wrench`` one component of it), a measurement (``pose`` one component of the measured
  position/orientation, ``tension`` the load cells) or the geometry (``anchors``,
  ``attachments``);
- **form** (``x`` the quantity, ``d`` the driver, ``a`` the parameter, ``c`` a centre
  fixed at the recorded mean): ``offset`` ``x + a``; ``gain`` ``x (1 + a)``; ``linear``
  ``x + a (d - c)``; ``cgain`` ``x (1 + a (d - c))``; ``step`` ``x + a · dir`` (the
  direction of the cable's last length change); ``quadratic`` ``x + a (x - c)²``;
- **driver** (``linear``/``cgain`` only): ``time``, ``index`` (sample number), any numeric
  covariate (``cov:k``), a recorded wrench component (``w:j``), the cable's own commanded
  length (``own_l0``, cable wheres) or a predicted tension (``t:i``, measured pose only:
  the predicted tensions exist only after the equilibrium);
- **sharing**: one parameter for all cables, or one per cable (cable wheres).

The terms are not listed by hand: :func:`generate_grammar` builds, for every valid
``(where, form, sharing)``, one :class:`TermFamily` (an :class:`~fitting.effects.Effect`
using the same hooks as the vocabulary) whose parameter ``a`` has one column per driver
(and one row per component for ``wrench``/``pose``). A single term is a *mask* over that
block (:func:`family_terms`), so every term of the grammar lives in one compiled model
and candidates differ only by which entries of θ are free. Each family is the identity
at ``a = 0``; the centres ``c`` are a second parameter block that is never freed.
Geometry terms are constant (the ``robot`` hook has no per-sample context), so they take
the forms ``gain`` (a scale of the frame or the platform) only.
"""

from dataclasses import dataclass

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from cstiffjax.io import schema
from cstiffjax.runtime import programs
from cstiffjax.statics.geometry import cable_lengths
from fitting.effects.base import Domain, Effect, _spec

CABLE_WHERES = ("l0", "tension", "EA")
COMPONENT_WHERES = ("wrench", "pose")
FORMS = ("offset", "gain", "linear", "cgain", "step", "quadratic")
DRIVEN = ("linear", "cgain")
WRENCH_NAMES = schema.field_columns("wrench", 0)  # the recordings columns (cstiffjax.io.schema)
POSE_NAMES = schema.field_columns("pose", 0)
# typical magnitude of a correction of the quantity (parameter scales; conditioning only)
_SIZE = {"l0": 1e-3, "tension": 1.0, "wrench": 1.0, "pose": 1e-4, "load": 1.0}
_REL = 1e-3  # typical relative gain
_REL_EA = 5e-2  # typical relative change of a cable's stiffness (a polymer's modulus moves by percent per kelvin)


def _valid(where, form, per_cable):
    if where == "EA":  # a stiffness that follows a driver (temperature: a polymer cable softening)
        return form == "cgain"
    if where in ("anchors", "attachments"):
        return form == "gain" and not per_cable
    if where == "load":
        return form == "gain" and not per_cable
    if where in COMPONENT_WHERES:
        return form in ("offset", "gain", "linear", "quadratic") and not per_cable
    return True  # cable wheres: every form, shared or per cable


@dataclass(frozen=True)
class TermFamily(Effect):
    """Every term of one ``(where, form, sharing)`` of the grammar; ``drivers`` (static)
    are the driver keys of the columns of ``a`` (``linear``/``cgain`` only)."""

    where: str = "l0"
    form: str = "offset"
    per_cable: bool = False
    drivers: tuple = ()
    m: int = 0

    def __post_init__(self):
        if not _valid(self.where, self.form, self.per_cable):
            raise ValueError(f"no grammar term {self.where!r} × {self.form!r} (per_cable={self.per_cable})")
        if (self.form in DRIVEN) != bool(self.drivers):
            raise ValueError(f"form {self.form!r} needs drivers iff it is linear/cgain, got {self.drivers!r}")

    @property
    def name(self) -> str:
        return f"grammar:{self.where}:{self.form}:{'per_cable' if self.per_cable else 'shared'}"

    @property
    def needs_tensions(self) -> bool:
        return self.where == "tension"

    # -------------------------------------------------------------- layout
    def _rows(self):
        if self.where in COMPONENT_WHERES:
            return (6,)
        if self.where in CABLE_WHERES and self.per_cable:
            return (self.m,)
        return ()

    def specs(self, robot, data):
        rows = self._rows()
        nd = len(self.drivers)
        if self.form in DRIVEN:
            D = driver_matrix(self.drivers, data)  # (n, m or 1, nd)
            centre = np.mean(D, axis=0)  # (m or 1, nd)
            std = np.maximum(np.std(D, axis=(0, 1)), 1e-12)  # (nd,)
            size = _SIZE.get(self.where, 1.0)
            per = size / std if self.form == "linear" else (_REL_EA if self.where == "EA" else _REL) / std
            cshape = (self.m, nd) if self.where in CABLE_WHERES else (nd,)
            centre = np.broadcast_to(centre, (self.m, nd)) if self.where in CABLE_WHERES else centre[0]
            return (_spec("a", (*rows, nd), 0.0, float(np.median(per)), "mixed"),
                    _spec("centre", cshape, centre, 1.0, "driver unit"))
        if self.form == "quadratic":
            x, w = quantity_values(self.where, data)  # (n, m) or (n, 6), and the mask of recorded values
            cnt = np.maximum(w.sum(0), 1)
            xc = np.sum(np.where(w, x, 0.0), 0) / cnt
            var = np.sum(np.where(w, (x - xc) ** 2, 0.0), 0) / cnt
            var = float(np.mean(var[var > 0])) if np.any(var > 0) else 1.0
            return (_spec("a", rows, 0.0, _SIZE.get(self.where, 1.0) / var, "mixed"),
                    _spec("centre", xc.shape, xc, 1.0, "quantity unit"))
        if self.form in ("gain",):  # x (1 + a): a scale stays positive
            return (_spec("a", rows, 0.0, _REL, "1", domain=Domain(lower=-1.0, reading="a scale factor 1 + a > 0")),)
        return (_spec("a", rows, 0.0, _SIZE.get(self.where, 1.0), "quantity unit"),)

    # -------------------------------------------------------------- hooks
    def _apply(self, x, p, ctx, tensions=None):
        a = p["a"]
        if self.form == "offset":
            return x + a
        if self.form == "gain":
            return x * (1.0 + a)
        if self.form == "step":
            return x + a * ctx.direction
        if self.form == "quadratic":
            return x + a * (x - p["centre"]) ** 2
        D = _drivers_one(self.drivers, ctx, tensions, self.where in CABLE_WHERES)
        s = jnp.sum(a * (D - p["centre"]), axis=-1)
        return x + s if self.form == "linear" else x * (1.0 + s)

    def robot(self, robot, p):
        if self.where in ("anchors", "attachments"):
            return eqx.tree_at(lambda r: getattr(r, self.where), robot, getattr(robot, self.where) * (1.0 + p["a"]))
        return robot

    def stiffness_inputs(self, l0, length, ctx, p):
        """``where = "EA"``: the unstrained lengths ``l0`` (m,) m that give a cable of stiffness
        ``EA (1 + s)``, ``s = a (d - c)``, the strain a cable of ``EA`` would have at the length
        ``length`` (m,) m (the recorded pose's): ``l0 (1 + ε) / (1 + (1 + s) ε)``, ``ε = length/l0 - 1``
        (exact for a straight spring at that length; the equilibrium moves it at second order)."""
        D = _drivers_one(self.drivers, ctx, None, True)
        s = jnp.sum(p["a"] * (D - p["centre"]), axis=-1)
        eps = length / l0 - 1.0
        return l0 * (1.0 + eps) / (1.0 + (1.0 + s) * eps)

    def inputs(self, l0, wrench, ctx, p):
        if self.where == "l0":
            return self._apply(l0, p, ctx), wrench
        if self.where in ("load", "wrench"):
            return l0, self._apply(wrench, p, ctx)
        return l0, wrench

    def correct_measurement(self, pose, tensions, ctx, p):
        """The recorded measurement with this term's deviation removed, evaluated at the
        recorded value: ``y - (measure(y) - y)`` (exact for the additive forms, to first
        order in ``a`` for ``gain``/``cgain``/``quadratic``)."""
        pm, tm = self.measure(pose, tensions, ctx, p)
        return 2.0 * pose - pm, 2.0 * tensions - tm

    def measure(self, pose, tensions, ctx, p):
        if self.where == "tension":
            return pose, self._apply(tensions, p, ctx)
        if self.where == "pose":
            return self._apply(pose, p, ctx, tensions), tensions
        return pose, tensions


def _drivers_one(keys, ctx, tensions, cable):
    """Driver values of one sample: ``(m, nd)`` for cable wheres, else ``(nd,)``."""
    cols = []
    for k in keys:
        if k == "time":
            v = ctx.time
        elif k == "index":
            v = ctx.index
        elif k == "own_l0":
            v = ctx.l0
        elif k.startswith("cov:"):
            v = ctx.covariates[int(k[4:])]
        elif k.startswith("w:"):
            v = ctx.wrench[int(k[2:])]
        elif k.startswith("t:"):
            v = tensions[int(k[2:])]
        else:
            raise ValueError(f"unknown driver key {k!r}")
        cols.append(jnp.broadcast_to(v, ctx.l0.shape) if cable else v)
    return jnp.stack(cols, axis=-1)


def driver_matrix(keys, data) -> np.ndarray:
    """Recorded driver values ``(n, m, nd)`` (``m`` = 1 for scalar drivers; predicted
    tensions ``t:i`` are approximated by the measured ones, for centring and scales only)."""
    ctx = data.ctx
    n, m = np.asarray(data.l0).shape
    cols = []
    for k in keys:
        if k == "time":
            v = np.asarray(ctx.time)[:, None]
        elif k == "index":
            v = np.asarray(ctx.index)[:, None]
        elif k == "own_l0":
            v = np.asarray(ctx.l0)
        elif k.startswith("cov:"):
            v = np.asarray(ctx.covariates)[:, int(k[4:])][:, None]
        elif k.startswith("w:"):
            v = np.asarray(ctx.wrench)[:, int(k[2:])][:, None]
        elif k.startswith("t:"):
            i = int(k[2:])
            t, mask = np.asarray(data.tensions)[:, i], np.asarray(data.tension_mask)[:, i]
            v = np.where(mask, t, np.mean(t[mask]) if mask.any() else 0.0)[:, None]
        else:
            raise ValueError(f"unknown driver key {k!r}")
        cols.append(np.broadcast_to(v, (n, m)))
    return np.stack(cols, axis=-1)


def recorded_lengths(robot, data) -> np.ndarray:
    """``(n, m)`` m: every cable's path length at its sample's recorded pose, on ``robot``'s
    geometry (pulleys included, :func:`cstiffjax.statics.geometry.cable_lengths`)."""
    key = (id(robot), id(data))
    if _LENGTHS.get("key") != key:
        _LENGTHS.update(key=key, keep=(robot, data), value=np.asarray(_path_lengths(robot, data.pose)))
    return _LENGTHS["value"]


_LENGTHS: dict = {}  # the last robot/data's recorded lengths (the search asks for them every round)


def _path_lengths_impl(robot, pose):
    """``(n, m)`` m: :func:`~cstiffjax.statics.geometry.cable_lengths` at every row of ``pose``."""
    return jax.vmap(lambda p: cable_lengths(robot, p))(pose)


# one compiled program (serialized, cstiffjax.runtime.programs): eager, the vmap dispatches op by op
# (bundled example: 1.8 s on a loaded machine)
_path_lengths = programs.Program(_path_lengths_impl, name="fitting.effects.grammar.path_lengths", like=lambda args: 0)


def quantity_values(where, data) -> tuple[np.ndarray, np.ndarray]:
    """Recorded values of the quantity a term acts on, ``(n, m)`` or ``(n, 6)``, and the
    mask of the recorded entries (missing tensions are False)."""
    x = np.asarray({"l0": data.l0, "tension": data.tensions, "wrench": data.wrench, "pose": data.pose}[where])
    mask = np.asarray(data.tension_mask) if where == "tension" else np.ones(x.shape, dtype=bool)
    return x, mask


def scalar_drivers(data) -> tuple[str, ...]:
    """Driver keys of every per-sample scalar that varies and is finite: ``time``,
    ``index``, each covariate column, each recorded wrench component."""
    keys = []
    t = np.asarray(data.ctx.time)
    if np.ptp(t) > 0:
        keys.append("time")
    keys.append("index")
    cov = np.asarray(data.ctx.covariates)
    for k in range(cov.shape[1]):
        if np.all(np.isfinite(cov[:, k])) and np.ptp(cov[:, k]) > 0:
            keys.append(f"cov:{k}")
    w = np.asarray(data.ctx.wrench)
    keys += [f"w:{j}" for j in range(6) if np.ptp(w[:, j]) > 0]
    return tuple(keys)


def generate_grammar(robot, data, *, has_tensions: bool = True) -> tuple[TermFamily, ...]:
    """Every valid ``(where, form, sharing)`` family on ``robot`` and ``data``
    (:class:`~fitting.effects.model.ModelData`), with the drivers the data supports."""
    m = robot.num_cables
    scal = scalar_drivers(data)
    fams = []
    wheres = ("l0", "load", "wrench", "pose", "anchors", "attachments") + (("tension",) if has_tensions else ()) + (
        ("EA",) if has_tensions else ())
    for where in wheres:
        for form in FORMS:
            for per_cable in (False, True):
                if not _valid(where, form, per_cable):
                    continue
                drivers = ()
                if form in DRIVEN:
                    drivers = scal
                    if where == "tension":
                        drivers = (*scal, "own_l0")
                    if where == "pose" and has_tensions:
                        drivers = (*scal, *(f"t:{i}" for i in range(m)))
                fams.append(TermFamily(where, form, per_cable, drivers, m))
    return tuple(fams)


@dataclass(frozen=True)
class Term:
    """One grammar term: a :class:`TermFamily` and the entries of its ``a`` block that it
    frees: ``row`` (component for ``wrench``/``pose``, else None) and ``column`` (driver
    index for ``linear``/``cgain``, else None). ``name`` is its key in a diagnosis."""

    family: TermFamily
    row: int | None
    column: int | None

    @property
    def driver(self) -> str | None:
        """Driver key (``time``, ``cov:k``, ...), ``dir`` for the step form, else None."""
        if self.column is not None:
            return self.family.drivers[self.column]
        return "dir" if self.family.form == "step" else None

    @property
    def name(self) -> str:
        f = self.family
        parts = [f.where + ("" if self.row is None else f"[{self.row}]"), f.form, self.driver or "-",
                 "per_cable" if f.per_cable else "shared"]
        return "term:" + "|".join(parts)

    def entries(self, shape) -> np.ndarray:
        """Flat indices, in the family's ``a`` block of ``shape``, of this term's parameters."""
        idx = np.arange(int(np.prod(shape, dtype=int))).reshape(shape)
        if self.row is not None:
            idx = idx[self.row]
        if self.column is not None:
            idx = idx[..., self.column]
        return np.atleast_1d(idx).ravel()


def family_terms(families) -> list[Term]:
    """Every single term of every family (one per row and driver column)."""
    out = []
    for e in families:
        rows = range(6) if e.where in COMPONENT_WHERES else [None]
        cols = range(len(e.drivers)) if e.drivers else [None]
        out += [Term(e, r, c) for r in rows for c in cols]
    return out


IMPLAUSIBLE = 60.0  # extra evidence (BIC units) a correction without a physical reading needs
UNDRIVEN_LOADS = ("time", "index")  # drivers no applied load follows (besides the covariates)


def plausibility(term: Term, covariate_names=()) -> tuple[float, str]:
    """``(penalty, reading)``: the extra evidence, in BIC units, that ``term`` needs before
    it may be selected, by the quantity it acts on and its driver, and why. A correction a
    lab could have (a stiffness, a length, a load cell or a tracker that follows the
    temperature or the time: thermal expansion, creep, drift) costs nothing; one that only a
    fudge could produce, an external force or moment that follows a covariate, the time or the
    sample number (no load a lab applies does), costs :data:`IMPLAUSIBLE`."""
    k = term.driver
    if term.family.where in ("load", "wrench") and k is not None and (k in UNDRIVEN_LOADS or k.startswith("cov:")):
        name = covariate_names[int(k[4:])] if k.startswith("cov:") and int(k[4:]) < len(covariate_names) else k
        what = "external load" if term.family.where == "load" else f"external {WRENCH_NAMES[term.row]}"
        return IMPLAUSIBLE, f"an {what} that follows the {name}: no applied load does"
    return 0.0, ""


def is_term(name: str) -> bool:
    """Whether an entry of a diagnosis's model list is a grammar term (not a vocabulary name)."""
    return name.startswith("term:")


def basis(family: TermFamily, data, robot) -> tuple[str, np.ndarray]:
    """Closed-form derivative of what ``family`` changes, with respect to every entry of its
    ``a`` block at ``a = 0``, from the recorded data (the screening step of the search).

    **Returns:** ``(quantity, B)`` with quantity one of ``l0 wrench pose tension anchors
    attachments`` and ``B`` ``(n, dims, K)`` (``(m, 3, K)`` for geometry), ``K`` the size of
    the block (C order). For measurement terms ``B`` is the derivative of the *corrected*
    recorded measurement (:meth:`TermFamily.correct_measurement`), i.e. minus the forward one.
    """
    f = family
    if f.where in ("anchors", "attachments"):
        return f.where, np.asarray(getattr(robot, f.where))[..., None]
    specs = {s.name: s for s in f.specs(robot, data)}

    qty = {"l0": "l0", "load": "wrench", "wrench": "wrench", "pose": "pose", "tension": "tension", "EA": "l0"}[f.where]
    x, _ = quantity_values(qty if qty != "wrench" else "wrench", data)
    n, dims = x.shape
    if f.where == "EA":  # d l0 / d s at s = 0 (TermFamily.stiffness_inputs): -l0 (L - l0) / L
        L = recorded_lengths(robot, data)
        g = (-x * (L - x) / L)[..., None] * (driver_matrix(f.drivers, data) - np.asarray(specs["centre"].null))
    elif f.form == "offset":
        g = np.ones((n, dims, 1))
    elif f.form == "gain":
        g = x[..., None]
    elif f.form == "step":
        g = np.asarray(data.ctx.direction)[..., None]
    elif f.form == "quadratic":
        g = ((x - np.asarray(specs["centre"].null)) ** 2)[..., None]
    else:
        D = driver_matrix(f.drivers, data)  # (n, m, nd)
        if f.where not in CABLE_WHERES:
            D = np.broadcast_to(D[:, :1, :], (n, dims, D.shape[-1]))
        g = D - np.asarray(specs["centre"].null)
        if f.form == "cgain":
            g = x[..., None] * g
    sign = -1.0 if f.where in ("pose", "tension") else 1.0
    rows = f._rows()
    if not rows:  # shared: one entry (per driver)
        return qty, sign * g
    # one row per cable/component: entry (i, j) acts on dims i only
    nd = g.shape[-1]
    B = np.zeros((n, dims, dims * nd))
    for i in range(dims):
        B[:, i, i * nd:(i + 1) * nd] = g[:, i, :]
    return qty, sign * B
