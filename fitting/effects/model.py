"""The extended CDPR measurement model: nominal robot + a list of effects, one flat
parameter vector, whitened residuals and their Jacobian compiled once per effect list.

Parameter vector ``θ`` (unconstrained, dimensionless): the first ``m`` entries are
``log(EA / EA_nominal)`` (the baseline calibration), then every effect's parameter
blocks in order, each as ``value = null + scale · θ`` (see :class:`~fitting.effects.ParamSpec`).
Freeing or freezing parameters is done by the caller (a mask over ``θ``), so one
compiled :func:`residuals_and_jacobian` serves the baseline and every candidate.

Forward statics (seed 003 "direct kinematics") is solved here rather than with
:func:`cstiffjax.statics.forward_statics` because effects change the cable law (the
``tension`` hook) and because the diagnosis needs thousands of cheap, differentiable
solves: a fixed number of Newton steps in base-frame twist coordinates from the
measured pose (a start point only), under ``stop_gradient``, then one Newton step with
gradients, whose derivative is exactly the implicit-function derivative
``-J⁻¹ ∂W/∂θ`` at convergence. With ``cable_mass`` (law ``"catenary"``) the pose and
every cable's end forces ``(H, V_B)`` are solved together (``6 + 2m`` unknowns; the span
equations are the closed form :func:`cstiffjax.catenary.end_point`, seed 003 eqs 23-24),
so no root find is nested inside another and the compiled graph stays small. A sample
whose wrench residual does not vanish is reported through ``ok`` (never silent NaN).

The spring law is used *bilateral* (a cable shorter than ``l0`` would push): recordings
of a CDPR are taken with taut cables, and the smooth law keeps the fits away from the
slack kink, where a misfitted intermediate model would otherwise stall the least
squares; a prediction with a negative tension simply misfits the measured one. The
generator (:mod:`fitting.generate`) uses the independent solvers of
:mod:`cstiffjax.statics` / :mod:`cstiffjax.catenary`, so agreement is a real check.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from cstiffjax import lie
from cstiffjax.catenary import end_point
from cstiffjax.statics import moved_frame

from ..models import cdpr_residuals
from .base import Effect, SampleContext

NEWTON_STEPS = 12
NEWTON_TOL = 1e-7  # largest residual wrench relative to |weight| + |external| + 1


class ModelData(eqx.Module):
    """The recordings as the model needs them (arrays only, so it is cheap under jit).

    ``weight`` (n,) is 1 for samples in the fit and 0 for samples left out (outliers,
    held-out folds)."""

    l0: Float[Array, "n m"]
    wrench: Float[Array, "n 6"]
    pose: Float[Array, "n 6"]
    tensions: Float[Array, "n m"]
    tension_mask: Bool[Array, "n m"]
    ctx: SampleContext
    weight: Float[Array, " n"]


def build_data(recordings, weight=None) -> ModelData:
    """:class:`ModelData` of a :class:`~cstiffjax.recordings.Recordings` (``weight``
    default all ones). Time is counted from the first sample (0 if not recorded)."""
    l0 = np.asarray(recordings.l0)
    t = np.asarray(recordings.time, dtype=float)
    t = t - t[0] if np.all(np.isfinite(t)) else np.zeros_like(t)
    direction = np.zeros_like(l0)
    direction[1:] = np.sign(np.diff(l0, axis=0))
    w = np.ones(len(l0)) if weight is None else np.asarray(weight, dtype=float)
    return ModelData(jnp.asarray(l0), jnp.asarray(recordings.wrench), jnp.asarray(recordings.pose),
                     jnp.asarray(recordings.tensions), jnp.asarray(recordings.tension_mask),
                     SampleContext(jnp.asarray(t), jnp.asarray(direction)), jnp.asarray(w))


class ExtendedModel(eqx.Module):
    """Nominal robot + ``effects`` (static), with the flat parameter layout.

    ``blocks`` (static): ``(effect index, name, offset, shape, unit)`` per parameter
    block; ``null``/``scale``/``start`` ``(P,)``: physical null values, scales and the
    θ start of every entry (the first ``m`` are the EA log-scales)."""

    effects: tuple[Effect, ...] = eqx.field(static=True)
    law: str = eqx.field(static=True)
    num_cables: int = eqx.field(static=True)
    blocks: tuple = eqx.field(static=True)
    null: Float[Array, " P"]
    scale: Float[Array, " P"]
    start: Float[Array, " P"]

    @property
    def size(self) -> int:
        return int(self.null.shape[0])

    def block_slice(self, i_effect: int) -> slice:
        """θ indices of effect ``i_effect``'s parameters."""
        bl = [b for b in self.blocks if b[0] == i_effect]
        if not bl:
            return slice(0, 0)
        return slice(bl[0][2], bl[-1][2] + int(np.prod(bl[-1][3], dtype=int)))

    def unpack(self, theta) -> list[dict]:
        """Physical parameter dicts, one per effect."""
        phys = self.null + self.scale * theta
        out = [{} for _ in self.effects]
        for i, name, off, shape, _ in self.blocks:
            size = int(np.prod(shape, dtype=int))
            out[i][name] = phys[off:off + size].reshape(shape)
        return out


def make_model(robot, data: ModelData, effects, law: str = "spring") -> ExtendedModel:
    """Lay out the parameters of ``effects`` on ``robot`` (``data`` fixes data-dependent
    scales, e.g. the drift rate's). Raises ``ValueError`` for incompatible effects."""
    effects = tuple(effects)
    for e in effects:
        law = e.law(law)
    m = robot.num_cables
    null, scale, start, blocks = [np.zeros(m)], [np.ones(m)], [np.zeros(m)], []
    off = m
    for i, e in enumerate(effects):
        if e.spring_only and law != "spring":
            raise ValueError(f"effect {e.name!r} needs the spring cable law, got law {law!r}")
        for s in e.specs(robot, data):
            size = int(np.prod(s.shape, dtype=int))
            blocks.append((i, s.name, off, s.shape, s.unit))
            null.append(s.null.ravel())
            scale.append(np.full(size, s.scale))
            st = np.zeros(size) if s.start is None else (s.start.ravel() - s.null.ravel()) / s.scale
            start.append(st)
            off += size
    cat = lambda xs: jnp.asarray(np.concatenate(xs))  # noqa: E731
    return ExtendedModel(effects, law, m, tuple(blocks), cat(null), cat(scale), cat(start))


# ------------------------------------------------------------------ one sample
def _tension_fn(effects, plist):
    def fn(t):
        for e, p in zip(effects, plist):
            t = e.tension(t, p)
        return t
    return fn


def _wrench(robot, p, R, l0, ext, law, tension):
    """Net wrench (6,) on the platform and exit tensions (m,) of straight spring cables."""
    r = robot.attachments @ R.T
    att = p + r
    d = robot.anchors - att
    length = jnp.sqrt(jnp.sum(d * d, axis=-1))
    t = tension(robot.EA * (length - l0) / l0)  # bilateral: smooth for the fits (see module doc)
    f = t[:, None] * d / length[:, None]
    t_exit = t
    wg = robot.platform_mass * robot.gravity
    W = jnp.concatenate([jnp.sum(f, 0) + wg + ext[:3],
                         jnp.sum(jnp.cross(r, f), 0) + jnp.cross(R @ robot.com, wg) + ext[3:]])
    return W, t_exit


def _spring_newton(robot, l0, ext, pose_start, effects, plist, scale, steps):
    """Twist solving the spring-law equilibrium (no gradients), and its wrench function."""
    def F(tw, rb, l, w, pl):
        return _wrench(rb, *moved_frame(pose_start, tw), l, w, "spring", _tension_fn(effects, pl))[0] / scale

    frozen = jax.lax.stop_gradient((robot, l0, ext, plist))
    tw, J = _newton(lambda z: F(z, *frozen), jnp.zeros(6), steps)
    return tw, J, F


def _newton(fn, z0, steps, max_step=0.05):
    """``steps`` clipped Newton steps on ``fn(z) = 0`` (no gradients); returns ``(z, J)``
    with ``J`` the Jacobian at the last iterate but one (used for the implicit step)."""
    def body(_, carry):
        z, _ = carry
        J, f = jax.jacfwd(lambda y: (fn(y), fn(y)), has_aux=True)(z)
        step = jnp.linalg.solve(J, f)
        step = step * jnp.minimum(1.0, max_step / (jnp.max(jnp.abs(step)) + 1e-300))
        return jnp.where(jnp.all(jnp.isfinite(step)), z - step, z), J

    n = z0.shape[0]
    return jax.lax.stop_gradient(jax.lax.fori_loop(0, steps, body, (z0, jnp.eye(n))))


def _implicit_step(F, z, J, live):
    """One Newton step whose derivative is the implicit-function derivative ``-J⁻¹ ∂F/∂θ``."""
    return z - jnp.linalg.solve(J, F(z, *live))


def _catenary_residual(z, robot, l0, ext, pose_start, scale):
    """Joint residual of the pose twist and each cable's end forces ``(H, V_B)/scale``:
    platform wrench balance (6) and the catenary span equations (2m), seed 003 eqs 23-24."""
    m = l0.shape[0]
    p, R = moved_frame(pose_start, z[:6])
    r = robot.attachments @ R.T
    up = -robot.gravity / jnp.linalg.norm(robot.gravity)
    d = p + r - robot.anchors  # anchor (A) -> attachment (B)
    sz = d @ up
    hvec = d - sz[:, None] * up
    sx = jnp.sqrt(jnp.sum(hvec * hvec, axis=-1))
    ex = hvec / sx[:, None]
    H, VB = z[6:6 + m] * scale, z[6 + m:] * scale
    w = robot.mass_per_length * jnp.linalg.norm(robot.gravity)
    x_c, z_c = end_point(H, VB, l0, robot.EA, w)
    f = -H[:, None] * ex - VB[:, None] * up
    wg = robot.platform_mass * robot.gravity
    W = jnp.concatenate([jnp.sum(f, 0) + wg + ext[:3],
                         jnp.sum(jnp.cross(r, f), 0) + jnp.cross(R @ robot.com, wg) + ext[3:]])
    return jnp.concatenate([W / scale, (x_c - sx) / l0, (z_c - sz) / l0]), jnp.hypot(H, VB - w * l0)


def equilibrium(robot, l0, ext, pose_start, law, effects, plist, steps: int = NEWTON_STEPS):
    """Pose (6,), exit tensions (m,) and ``ok`` of one sample (see module docstring).

    ``law="catenary"`` solves pose and every cable's end forces together (``6 + 2m``
    unknowns, :func:`cstiffjax.catenary.end_point` closed form), started from the
    spring solution, so no solver is nested inside another."""
    scale = jnp.linalg.norm(robot.platform_mass * robot.gravity) + jnp.linalg.norm(ext) + 1.0
    tw, J, F = _spring_newton(robot, l0, ext, pose_start, effects, plist, scale, steps)
    if law == "spring":
        tw = _implicit_step(F, tw, J, (robot, l0, ext, plist))
        p, R = moved_frame(pose_start, tw)
        W, t_exit = _wrench(robot, p, R, l0, ext, law, _tension_fn(effects, plist))
        res = W / scale
        pose = jnp.concatenate([p, lie.log(R)])
    else:
        p, R = moved_frame(pose_start, tw)
        d = robot.anchors - p - robot.attachments @ R.T
        length = jnp.sqrt(jnp.sum(d * d, axis=-1))
        t = jnp.maximum(robot.EA * (length - l0) / l0, 1e-3 * scale)
        up = -robot.gravity / jnp.linalg.norm(robot.gravity)
        u = d / length[:, None]  # attachment -> anchor
        vb = -t * (u @ up)
        h = jnp.sqrt(jnp.maximum(t * t - vb * vb, 0.0))
        z0 = jnp.concatenate([tw, h / scale, vb / scale])

        def G(z, rb, l, w):
            return _catenary_residual(z, rb, l, w, pose_start, scale)[0]

        frozen = jax.lax.stop_gradient((robot, l0, ext))
        z, J = _newton(lambda z: G(z, *frozen), z0, steps, max_step=0.5)
        z = _implicit_step(G, z, J, (robot, l0, ext))
        res, t_exit = _catenary_residual(z, robot, l0, ext, pose_start, scale)
        p, R = moved_frame(pose_start, z[:6])
        pose = jnp.concatenate([p, lie.log(R)])
    ok = jnp.all(jnp.isfinite(res)) & (jnp.max(jnp.abs(res)) < NEWTON_TOL) & jnp.all(jnp.isfinite(t_exit))
    return pose, t_exit, ok


def model_robot(model: ExtendedModel, theta, robot):
    """The robot the statics sees: EA calibrated, robot hooks applied."""
    rb = eqx.tree_at(lambda r: r.EA, robot, robot.EA * jnp.exp(theta[:model.num_cables]))
    for e, p in zip(model.effects, model.unpack(theta)):
        rb = e.robot(rb, p)
    return rb


def predict(model: ExtendedModel, theta, robot, data: ModelData):
    """Predicted *measurements* of every sample: ``(pose (n, 6), tensions (n, m), ok (n,))``."""
    plist = model.unpack(theta)
    rb = model_robot(model, theta, robot)

    def one(l0, w, pose_meas, ctx):
        for e, p in zip(model.effects, plist):
            l0, w = e.inputs(l0, w, ctx, p)
        pose, t, ok = equilibrium(rb, l0, w, pose_meas, model.law, model.effects, plist)
        for e, p in zip(model.effects, plist):
            pose, t = e.measure(pose, t, ctx, p)
        return pose, t, ok

    return jax.vmap(one)(data.l0, data.wrench, data.pose, data.ctx)


def residuals(model: ExtendedModel, theta, robot, data: ModelData):
    """Weighted whitened residuals ``(n, 6 + m)`` (:func:`fitting.models.cdpr_residuals`
    layout, rows of weight 0 are zero) and ``ok`` ``(n,)``."""
    pose, t, ok = predict(model, theta, robot, data)
    r = cdpr_residuals(pose, t, data, robot.noise)
    r = jnp.where(ok[:, None], r, 0.0) * data.weight[:, None]
    return r, ok


@eqx.filter_jit
def residuals_and_jacobian(model: ExtendedModel, theta, robot, data: ModelData):
    """``(r (n, 6+m), J (n·(6+m), P), ok (n,))``: residuals and their θ-Jacobian (forward
    mode through the equilibrium). Compiled once per effect list and data shape."""
    def flat(th):
        r, ok = residuals(model, th, robot, data)
        return r.ravel(), (r, ok)

    J, (r, ok) = jax.jacfwd(flat, has_aux=True)(theta)
    return r, J, ok


@eqx.filter_jit
def residuals_only(model: ExtendedModel, theta, robot, data: ModelData):
    """``(r (n, 6+m), ok (n,))`` without the Jacobian (cheaper, for held-out scoring)."""
    return residuals(model, theta, robot, data)
