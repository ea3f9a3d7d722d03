"""The extended CDPR measurement model: nominal robot + a list of effects, one flat
parameter vector, whitened residuals and their Jacobian compiled once per effect list.

Parameter vector ``θ`` (unconstrained, dimensionless): the first ``m`` entries are
``log(EA / EA_nominal)`` (the baseline calibration), then every effect's parameter
blocks in order, each as ``value = null + scale · θ`` (see :class:`~fitting.effects.ParamSpec`).
Freeing or freezing parameters is done by the caller (a mask over ``θ``), so one
compiled :func:`residuals_and_jacobian` serves the baseline and every candidate.

Forward statics (Yuan et al. 2015 "direct kinematics") is the warm start of
:func:`cstiffjax.statics.forward.forward_statics` (Newton steps from the measured pose until converged,
plus one implicit step, bilateral springs or joint pose + catenary end-force solve); the
effects' ``tension`` hooks enter through its ``tension`` argument (a
:class:`TensionHooks` holding their parameters, so they get the implicit-function
derivative). The generator (:mod:`fitting.synth.generate`) writes its concealed effects out
independently of the effect code and checks every true equilibrium with the per-cable
catenary solver of :mod:`cstiffjax.cable.catenary`, so agreement is a real check.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from cstiffjax.cable.laws import CableLaw, check_law
from cstiffjax.core.arrays import to_device
from cstiffjax.core.status import Status
from cstiffjax.runtime import programs
from cstiffjax.statics.forward import Solved, StaticsProblem, forward_statics, solve_unknowns
from fitting.calibration.lm import evaluate
from fitting.calibration.models import (
    cdpr_residuals,
    residual_channels,
    sensor_fields,
    sensor_predictions,
    session_index,
    tension_readings,
    true_lengths,
)
from fitting.effects.base import Effect, ParamSpec, SampleContext

__all__ = ["MODEL_LAWS", "SPRING_MODEL_LAWS", "ExtendedModel", "ModelData", "SampleStatics", "TensionHooks",
           "build_data", "chord_start", "column_chunks", "equilibria",
           "evaluate_columns", "jacobian_width", "make_model", "model_rJ", "model_robot", "predict",
           "residuals", "residuals_and_jacobian", "residuals_only", "solutions", "solved_like", "walker_residuals"]


MODEL_LAWS = frozenset({CableLaw.spring, CableLaw.small_sag, CableLaw.catenary})  # the laws of a model
SPRING_MODEL_LAWS = frozenset({CableLaw.spring, CableLaw.small_sag})  # tension hooks apply (small_sag: the screen)


class ModelData(eqx.Module):
    """The recordings as the model needs them (arrays only, so it is cheap under jit).

    ``weight`` (n,) is 1 for samples in the fit and 0 for samples left out (outliers,
    held-out folds). ``pose`` is each sample's measured pose where ``pose_mask`` is true and
    an estimate elsewhere (the statics start there; formats.md §2 version 3: ``x y z`` may be
    unmeasured). The on-board sensors' readings and masks (``swivel``, ``ahrs``) are those of
    the recordings; ``sensors`` (static) names the ones measured
    (:func:`~fitting.calibration.models.sensor_fields`), ``num_sessions`` (static) the
    number of sessions (``ctx.session`` holds each sample's index 0..S-1)."""

    l0: Float[Array, "n m"]
    wrench: Float[Array, "n 6"]
    pose: Float[Array, "n 6"]
    tensions: Float[Array, "n m"]
    tension_mask: Bool[Array, "n m"]
    ctx: SampleContext
    weight: Float[Array, " n"]
    pose_mask: Bool[Array, "n 6"]
    swivel: Float[Array, "n m"]
    swivel_mask: Bool[Array, "n m"]
    ahrs: Float[Array, "n 3"]
    ahrs_mask: Bool[Array, "n 3"]
    covariate_names: tuple[str, ...] = eqx.field(static=True, default=())
    sensors: tuple[str, ...] = eqx.field(static=True, default=())
    num_sessions: int = eqx.field(static=True, default=1)


def build_data(recordings, weight=None) -> ModelData:
    """:class:`ModelData` of a :class:`~cstiffjax.io.recordings.Recordings` (``weight``
    default all ones; unmeasured poses filled first with
    :func:`~fitting.calibration.models.with_start_poses`). Time is counted from the first
    sample (0 if not recorded); the context (:class:`SampleContext`) also carries the sample
    index, its session index, every numeric covariate column and the recorded inputs."""
    l0 = np.asarray(recordings.l0, dtype=float)
    wrench = np.asarray(recordings.wrench, dtype=float)
    n = len(l0)
    t = np.asarray(recordings.time, dtype=float)
    t = t - t[0] if np.all(np.isfinite(t)) else np.zeros_like(t)
    direction = np.zeros_like(l0)
    direction[1:] = np.sign(np.diff(l0, axis=0))
    cov = np.asarray(recordings.covariates, dtype=float).reshape(n, len(recordings.covariate_names))
    w = np.ones(n) if weight is None else np.asarray(weight, dtype=float)
    session, sessions = session_index(recordings)
    put = to_device  # (no conversion programs, cstiffjax.core.arrays)
    ctx = SampleContext(put(t), put(direction), put(np.arange(n, dtype=float)), put(cov), put(l0), put(wrench),
                        put(session.astype(float)))
    return ModelData(put(l0), put(wrench), put(recordings.pose), put(recordings.tensions),
                     put(recordings.tension_mask), ctx, put(w), put(recordings.pose_mask), put(recordings.swivel),
                     put(recordings.swivel_mask), put(recordings.ahrs), put(recordings.ahrs_mask),
                     tuple(recordings.covariate_names), sensor_fields(recordings), sessions)


class ExtendedModel(eqx.Module):
    """Nominal robot + ``effects`` (static), with the flat parameter layout.

    ``blocks`` (static): ``(effect index, name, offset, shape, unit)`` per parameter
    block; ``null``/``scale``/``start`` ``(P,)``: physical null values, scales and the
    θ start of every entry (the first ``m`` are the EA log-scales). ``zeros`` (static):
    ``(name, offset, shape, unit)`` of the recordings' unknown zeros that follow the EA
    entries (:func:`recording_zero_specs`: relative lengths, the AHRS yaw); with the EA
    entries they form the baseline block of :attr:`base_size` entries every fit frees."""

    effects: tuple[Effect, ...] = eqx.field(static=True)
    law: CableLaw = eqx.field(static=True)
    num_cables: int = eqx.field(static=True)
    blocks: tuple = eqx.field(static=True)
    null: Float[Array, " P"]
    scale: Float[Array, " P"]
    start: Float[Array, " P"]
    zeros: tuple = eqx.field(static=True, default=())

    @property
    def size(self) -> int:
        return int(self.null.shape[0])

    @property
    def base_size(self) -> int:
        """θ entries always fitted: the EA log-scales and the recordings' zeros."""
        return self.num_cables + sum(int(np.prod(sh, dtype=int)) for _, _, sh, _ in self.zeros)

    def zero_values(self, theta) -> dict:
        """The recordings' zeros at ``θ``, ``{name: array}`` in their units."""
        phys = self.null + self.scale * theta
        return {nm: phys[off:off + int(np.prod(sh, dtype=int))].reshape(sh) for nm, off, sh, _ in self.zeros}

    def effect_index(self, name: str) -> int:
        """Index in ``effects`` of the effect called ``name``."""
        return next(j for j, e in enumerate(self.effects) if e.name == name)

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


def make_model(robot, data: ModelData, effects, law: CableLaw = CableLaw.spring) -> ExtendedModel:
    """Lay out the parameters of ``effects`` on ``robot`` (``data`` fixes data-dependent
    scales, e.g. the drift rate's) on the cable law ``law`` (:data:`MODEL_LAWS`; an effect
    may change it: ``cable_mass`` to ``catenary``). Raises ``ValueError`` for incompatible
    effects."""
    check_law(law, MODEL_LAWS, "make_model")
    effects = tuple(e.bind(robot, data) for e in effects)
    for e in effects:
        law = e.law(law)
    check_law(law, MODEL_LAWS, "make_model (the law after the effects)")
    m = robot.num_cables
    null, scale, start, blocks, zeros = [np.zeros(m)], [np.ones(m)], [np.zeros(m)], [], []
    off = m
    for s in recording_zero_specs(robot, data):
        size = int(np.prod(s.shape, dtype=int))
        zeros.append((s.name, off, s.shape, s.unit))
        null.append(s.null.ravel())
        scale.append(np.full(size, s.scale))
        start.append(np.zeros(size))
        off += size
    for i, e in enumerate(effects):
        if e.spring_only and law not in SPRING_MODEL_LAWS:
            raise ValueError(f"effect {e.name!r} needs the spring cable law, got law {law.name!r}")
        for s in e.specs(robot, data):
            size = int(np.prod(s.shape, dtype=int))
            blocks.append((i, s.name, off, s.shape, s.unit))
            null.append(s.null.ravel())
            scale.append(np.full(size, s.scale))
            st = np.zeros(size) if s.start is None else (s.start.ravel() - s.null.ravel()) / s.scale
            start.append(st)
            off += size
    cat = lambda xs: to_device(np.concatenate(xs))  # noqa: E731
    return ExtendedModel(effects, law, m, tuple(blocks), cat(null), cat(scale), cat(start), tuple(zeros))


def recording_zero_specs(robot, data: ModelData) -> list[ParamSpec]:
    """The recordings' unknown zeros (formats.md §2 version 3), calibrated by every fit and
    never reported as an effect: ``length_zero`` ``(S, m)`` m when ``[sensors] lengths =
    "relative"`` (true unstrained length = ``l0 + c``), ``yaw_zero`` ``(S,)`` rad when an AHRS
    was recorded."""
    S, m = data.num_sessions, robot.num_cables
    out = []
    if robot.relative_lengths:
        out.append(ParamSpec("length_zero", (S, m), np.zeros((S, m)), 1e-3, "m"))
    if "ahrs" in data.sensors:
        out.append(ParamSpec("yaw_zero", (S,), np.zeros(S), 1e-2, "rad"))
    return out


def model_robot(model: ExtendedModel, theta, robot):
    """The robot the statics sees: EA calibrated, robot hooks applied."""
    rb = eqx.tree_at(lambda r: r.EA, robot, robot.EA * jnp.exp(theta[:model.num_cables]))
    for e, p in zip(model.effects, model.unpack(theta)):
        rb = e.robot(rb, p)
    return rb


class TensionHooks(eqx.Module):
    """The effects' ``tension`` hooks applied in order: the modified spring law handed to
    :func:`~cstiffjax.statics.forward.forward_statics` (its parameters are leaves, so they get
    the implicit-function derivative)."""

    effects: tuple = eqx.field(static=True)
    plist: list

    def __call__(self, t):
        for e, p in zip(self.effects, self.plist):
            t = e.tension(t, p)
        return t


def _setting(model: ExtendedModel, theta, robot):
    """``(plist, robot, law, hooks)`` the statics of every sample share at ``θ``."""
    plist = model.unpack(theta)
    rb = model_robot(model, theta, robot)
    spring = model.law in SPRING_MODEL_LAWS
    law = CableLaw.bilateral if model.law is CableLaw.spring else model.law  # small_sag is smooth as it is
    return plist, rb, law, TensionHooks(model.effects, plist) if spring else None


def _sample_inputs(model: ExtendedModel, plist, law, l0, w, pose_meas, ctx, s, zeros=None):
    """One sample's ``(l0, wrench, pose0, forces0)`` after the recordings' length zeros
    (``zeros``: :meth:`ExtendedModel.zero_values`) and the effects' input hooks."""
    if zeros and "length_zero" in zeros:
        l0 = l0 + zeros["length_zero"][ctx.session.astype(jnp.int32)]
    for e, p in zip(model.effects, plist):
        l0, w = e.inputs(l0, w, ctx, p)
    pose0, forces0 = (pose_meas, None) if s is None else s
    return l0, w, pose0, forces0 if law is CableLaw.catenary else None


def _solutions(model: ExtendedModel, theta, robot, data: ModelData, start=None):
    """Per sample: the forward statics' converged unknowns at ``θ``
    (:func:`~cstiffjax.statics.forward.solve_unknowns`, batched :class:`~cstiffjax.statics.forward.Solved`,
    no gradients), for :func:`_statics`'s ``solved`` with the same ``start`` (see
    :func:`predict`; default: the measured poses)."""
    plist, rb, law, hooks = _setting(model, theta, robot)
    zeros = model.zero_values(theta)

    def one(l0, w, pose_meas, ctx, s):
        l0, w, pose0, forces0 = _sample_inputs(model, plist, law, l0, w, pose_meas, ctx, s, zeros)
        return solve_unknowns(StaticsProblem(rb, l0, w, law, hooks), pose0=pose0, start="warm", forces0=forces0)

    return jax.vmap(one)(true_lengths(rb, data.l0), data.wrench, data.pose, data.ctx, start)


# run once per posterior check (the walkers' centre): LLVM -O0 halves its compile, which a
# cold diagnosis waits for (bundled example: the main thread waited 0.6 s for it), and adds
# a few ms to its one call
solutions = programs.Program(_solutions, name="fitting.effects.model.solutions",
                             like=lambda args: Solved(0, 0, 0, 0), compiler_options=programs.ONCE_OPTIONS)


def solved_like(model: ExtendedModel, n: int) -> Solved:
    """Zeros shaped as :func:`solutions` returns them for ``n`` samples, built without
    tracing (to lower :func:`walker_residuals` ahead of the fit it will start from; numpy:
    ``jnp.zeros`` would compile a program per shape)."""
    k = 6 + 2 * model.num_cables if model.law is CableLaw.catenary else 6
    return Solved(np.zeros((n, k)), np.zeros((n, k, k)), np.zeros(n, bool), np.zeros(n, np.int32))


class SampleStatics(eqx.Module):
    """The statics of every sample (:func:`_statics`): the predicted measurements and the
    equilibrium behind them.

    ``pose`` (n, 6) m / rad and ``tensions`` (n, m) N: the predicted measurements (after the
    load-cell gains and the effects' measurement hooks); ``ok`` (n,): the statics converged;
    ``equilibrium_pose`` (n, 6) m / rad: the platform's pose at equilibrium (before the
    hooks); ``forces`` (n, 2, m) N: every cable's end forces ``(H, V_B)`` there;
    ``sensors``: the on-board sensors' predicted readings at the equilibrium
    (:func:`~fitting.calibration.models.sensor_predictions`; empty without them).
    """

    pose: Float[Array, "n 6"]
    tensions: Float[Array, "n m"]
    ok: Bool[Array, " n"]
    equilibrium_pose: Float[Array, "n 6"]
    forces: Float[Array, "n 2 m"]
    sensors: dict = eqx.field(default_factory=dict)

    @property
    def start(self):
        """``(equilibrium_pose, forces)``: a ``start`` for :func:`predict`."""
        return self.equilibrium_pose, self.forces


def _statics(model: ExtendedModel, theta, robot, data: ModelData, start=None, solved=None,
             derivatives=True) -> SampleStatics:
    """Per sample: the predicted measurements and the equilibrium, a :class:`SampleStatics`.
    ``solved``: :func:`_solutions` at the primal ``θ``, with ``start`` None (the solves
    are then skipped, only the implicit steps are taken: same values and derivatives);
    ``derivatives``: :func:`~cstiffjax.statics.forward.forward_statics`' (False: values only).

    Values only, ``forward_statics`` is traced inline, not as a nested ``jit``: the
    posterior's ensemble vmaps this over walkers as well as samples, and batching the
    nested program's jaxpr a second time (its Newton ``while_loop`` re-batched to a fixed
    point) cost the bundled example's ensemble ~0.55 s more to trace, under the interpreter
    lock that the diagnosis's main thread needs (benchmarks/LATENCY.md). The
    fitting loop keeps the nested ``jit`` (inline it traced ~0.17 s slower)."""
    plist, rb, law, hooks = _setting(model, theta, robot)
    zeros = model.zero_values(theta)
    statics = forward_statics if derivatives else forward_statics.__wrapped__  # the same function, inline

    def one(l0, w, pose_meas, ctx, s, sv):
        l0, w, pose0, forces0 = _sample_inputs(model, plist, law, l0, w, pose_meas, ctx, s, zeros)
        fs = statics(StaticsProblem(rb, l0, w, law, hooks), pose0=pose0, start="warm", throw=False,
                     forces0=forces0, solved=sv, derivatives=derivatives)
        pose, t, ok = fs.pose, fs.tensions, fs.result == Status.successful
        t = tension_readings(rb, t)  # the description's load-cell gains (formats.md §1 v2)
        for e, p in zip(model.effects, plist):
            pose, t = e.measure(pose, t, ctx, p)
        sensors = sensor_predictions(rb, fs.pose[None], ctx.session[None], data.sensors,
                                     zeros.get("yaw_zero"))
        return SampleStatics(pose, t, ok, fs.pose, fs.forces, {k: v[0] for k, v in sensors.items()})

    # the description's winch gains (formats.md §1 v2; exactly l0 at gain 1)
    return jax.vmap(one)(true_lengths(rb, data.l0), data.wrench, data.pose, data.ctx, start, solved)


def predict(model: ExtendedModel, theta, robot, data: ModelData, start=None):
    """Predicted *measurements* of every sample: ``(pose (n, 6), tensions (n, m), ok (n,))``.

    ``start`` (optional): ``(pose (n, 6), forces (n, 2, m))`` to warm-start the forward
    statics from, e.g. :func:`equilibria` of a nearby ``θ`` (the catenary law then skips
    its spring stage and starts from these end forces; the spring laws use the pose only).
    Default: the measured pose. Either start converges to the same equilibrium (to the
    Newton tolerance); a nearby one takes fewer steps."""
    out = _statics(model, theta, robot, data, start)
    return out.pose, out.tensions, out.ok


def equilibria(model: ExtendedModel, theta, robot, data: ModelData):
    """The model's equilibria at ``θ``, warm-started from the measured poses: ``(pose (n,
    6) m/rad, forces (n, 2, m) N)`` (catenary: every cable's ``(H, V_B)`` at its
    attachment), a ``start`` that :func:`predict` takes."""
    return _statics(model, theta, robot, data).start


def chord_start(model: ExtendedModel, theta, robot, data: ModelData, centre, solved):
    """The equilibria at ``θ`` predicted from those at ``centre``: one Newton step at ``θ``
    from the equilibria at ``centre`` with their Jacobian, ``z_c - J_c⁻¹ F(z_c; θ)`` (a chord
    step; ``solved`` = :func:`solutions` at ``centre``: :func:`~cstiffjax.statics.forward.forward_statics`'
    implicit step evaluated at ``θ``; one residual evaluation, no solve, values only).
    Mathematically its derivative at ``centre`` is the implicit-function derivative of the
    equilibria, so it is ``eq(centre) + ∂eq/∂θ · (θ - centre)`` to first order, off at
    second order (example02, EA 1 % / 2 % from the centre: 2.4e-7 / 9.7e-7 m spring,
    2.8e-9 / 1.1e-8 m catenary; the Taylor prediction through a forward-mode pass, used
    before: 1.2e-7 / 4.8e-7 m and 1.3e-7 / 5.1e-7 m). From it the walkers' Newton
    (``derivatives=False``) ends after one linearization while its first step is within
    :data:`~cstiffjax.statics.root_finding.CHORD_STEP`: example02, spring, up to ~1 % of EA from the
    centre (89 of 90 samples at 1 %, 8 at 2 %; the Taylor start 90 and 70), catenary at
    every offset to 5 % (the Taylor start: 2 of 90 at 3 %); a posterior standard deviation
    is well below 1 %, and the bundled example's warm diagnosis took no longer. Shaped as
    :func:`equilibria`, a ``start`` for :func:`predict`. Catenary: a second evaluation, at
    ``centre``, keeps every horizontal end force above half its value there
    (:func:`_keep_horizontal`). Meant to be traced (``jit``): called eagerly it runs
    operation by operation (the statics are not a nested program here)."""
    pose, forces = _statics(model, theta, robot, data, None, solved, derivatives=False).start
    if model.law is not CableLaw.catenary:
        return pose, forces
    return pose, _keep_horizontal(forces, _statics(model, centre, robot, data, None, solved, derivatives=False).forces)


def _keep_horizontal(forces, reference):
    """``forces`` ``(n, 2, m)`` (catenary ``(H, V_B)``) with every ``H`` raised to at least half
    of ``reference``'s: a nearly slack cable extrapolated to ``H <= 0`` would be a start the
    catenary cannot take (a start only)."""
    return forces.at[:, 0].set(jnp.maximum(forces[:, 0], 0.5 * reference[:, 0]))


def residuals(model: ExtendedModel, theta, robot, data: ModelData, start=None, solved=None, derivatives=True):
    """Weighted whitened residuals ``(n, 6 + m)`` (:func:`fitting.calibration.models.cdpr_residuals`
    layout, rows of weight 0 are zero) and ``ok`` ``(n,)`` (``start``: see :func:`predict`;
    ``solved``: the equilibria's unknowns at the primal ``θ``, :func:`_statics`)."""
    out = _statics(model, theta, robot, data, start, solved, derivatives)
    r = cdpr_residuals(out.pose, out.tensions, data, robot.noise, out.sensors)
    r = jnp.where(out.ok[:, None], r, 0.0) * data.weight[:, None]
    return r, out.ok


CHUNK = 16  # Jacobian columns per forward-mode pass (tangents pushed through the equilibrium at once)


def _chunked(cols, P):
    """``cols`` as ``(C, CHUNK)`` int, ``-1``-padded (``None``: every column ``0..P-1``)."""
    cols = jnp.arange(P) if cols is None else jnp.asarray(cols)
    pad = -cols.shape[0] % CHUNK
    return jnp.concatenate([cols, jnp.full((pad,), -1, cols.dtype)]).reshape(-1, CHUNK)


@eqx.filter_jit
def residuals_and_jacobian(model: ExtendedModel, theta, robot, data: ModelData, cols=None):
    """``(r (n, 6+m), J (n·(6+m), P), ok (n,))``: residuals and their θ-Jacobian (forward
    mode through the equilibrium). Compiled once per effect list, data shape and length
    of ``cols``.

    ``cols`` ``(k,)`` int (optional, data): compute only these columns of ``J`` (``-1``
    entries are padding); the other columns are 0. They are taken :data:`CHUNK` at a
    time, one forward-mode pass of ``CHUNK`` tangents per chunk holding a column, in a
    loop whose trip count is data: a fit of 7 free entries of a 145-entry model pushes 16
    tangents through the equilibrium, not the model's whole width, with the same compiled
    program as a fit of 40 (three passes). The loop stops after the last chunk that holds a
    column, so give the wanted columns first (sorted, padding last) to run the fewest
    passes. The equilibria are solved once per call (:func:`_solutions`); each pass takes
    only the implicit steps from there (the same numbers as solving in every pass;
    measurements: benchmarks/LATENCY.md)."""
    P = theta.shape[0]
    chunks = _chunked(cols, P)

    solved = _solutions(model, theta, robot, data)  # the equilibria once, not once per chunk

    def chunk(c):
        B = jax.nn.one_hot(c, P, dtype=theta.dtype)  # -1: a zero row

        def along(u):
            r, ok = residuals(model, theta + u @ B, robot, data, solved=solved)
            return r.ravel(), (r, ok)

        Jk, (r, ok) = jax.jacfwd(along, has_aux=True)(jnp.zeros(CHUNK, theta.dtype))
        return r, Jk @ B, ok

    n, c = data.l0.shape[0], len(residual_channels(model.num_cables, data.sensors))  # residuals()' shape
    zeros = (jnp.zeros((n, c), theta.dtype), jnp.zeros((n * c, P), theta.dtype), jnp.zeros((n,), bool))
    last = jnp.max(jnp.where(jnp.any(chunks >= 0, axis=1), jnp.arange(1, chunks.shape[0] + 1), 0))
    used = jnp.maximum(last, 1)  # up to the last chunk holding a column; chunk 0 always (it gives r and ok)

    def body(i, acc):
        r, J, ok = chunk(chunks[i])
        return r, acc[1] + J, ok

    return jax.lax.fori_loop(0, used, body, zeros)


def model_rJ(theta, args):
    """:func:`residuals_and_jacobian` as the engine's ``fun(θ, args)`` with ``args = (model,
    robot, data)`` or ``(model, robot, data, cols)``
    (:func:`fitting.calibration.lm.masked_levenberg_marquardt`: the model, the robot, the data
    and the Jacobian columns are arguments, so every weighting and every free set shares one
    compilation)."""
    model, robot, data, *cols = args
    return residuals_and_jacobian(model, theta, robot, data, *cols)


def jacobian_width(model) -> int:
    """Jacobian columns the diagnosis asks for per compiled call of ``model`` (the length
    of ``cols``): every entry but those of a trailing
    :class:`~fitting.effects.terms_model.Probe` (never freed: its columns are only read
    in chunks, :func:`column_chunks`), rounded up to a multiple of :data:`CHUNK`."""
    width = model.size
    if model.effects and model.effects[-1].name == "probe":
        width = model.block_slice(len(model.effects) - 1).start
    return -(-width // CHUNK) * CHUNK


def column_chunks(want, width: int) -> list[np.ndarray]:
    """The sorted column indices ``want`` as ``(width,)`` int arrays padded with ``-1``
    (at least one, possibly all padding)."""
    want = np.unique(np.asarray(want, dtype=int))
    out = [want[i:i + width] for i in range(0, max(len(want), 1), width)]
    return [np.concatenate([c, np.full(width - len(c), -1)]) for c in out]


def fitted_once(model) -> bool:
    """Whether ``model`` is fitted about once per diagnosis round, so that its fitting loop
    is compiled for compile time (``quick`` of :func:`fitting.calibration.lm.masked_levenberg_marquardt`):
    the small-sag screen of ``cable_mass`` (one fit per round, never a held-out check)."""
    return model.law is CableLaw.small_sag


def evaluate_columns(model, theta, robot, data: ModelData, want):
    """``(r, J, ok)`` (numpy) of ``model`` at ``theta`` with the columns ``want`` of ``J``
    filled (the others 0), through the masked fits' compiled loop
    (:func:`fitting.calibration.lm.evaluate`, one call per :func:`column_chunks` chunk)."""
    theta = np.asarray(theta, dtype=np.float64)
    J = None
    for cols in column_chunks(want, jacobian_width(model)):
        r, Jc, ok = (np.asarray(a) for a in evaluate(model_rJ, theta, (model, robot, data, np.asarray(cols)),
                                                              num_samples=data.l0.shape[0], quick=fitted_once(model)))
        J = Jc if J is None else J + Jc
    return r, J, ok


def _residuals_only(model: ExtendedModel, theta, robot, data: ModelData):
    """``(r (n, 6+m), ok (n,))`` without the Jacobian (one model evaluation, no tangents;
    the diagnosis scores held-out folds through its fitting loop's program instead, one
    compilation less, :meth:`fitting.diagnosis.fitter.Fitter.scorer`)."""
    return residuals(model, theta, robot, data)


residuals_only = programs.Program(_residuals_only, name="fitting.effects.model.residuals_only")


def _walker_residuals(model: ExtendedModel, thetas, robot, data: ModelData, centre, solved):
    """:func:`residuals_only` at every row of ``thetas`` ``(w, P)`` in one vmapped program:
    ``(r (w, n, 6+m), ok (w, n))``. The posterior check's ensemble: one call per step for
    all walkers.

    Every walker's statics start at :func:`chord_start` from ``centre`` (the fitted θ;
    ``solved``: :func:`solutions` there): the walkers sit within a few posterior standard
    deviations of it, where the prediction is off at second order, and are
    solved for values only (``derivatives=False``): Newton applies one step, and the step
    after it, formed with the same Jacobian from one residual evaluation, confirms
    convergence (from the measured poses: two steps and a third linearization; catenary:
    the spring stage is skipped as well); the equilibria agree with those from the measured
    poses to rounding, the ``ok`` flags exactly (measurements: benchmarks/LATENCY.md)."""
    return jax.vmap(lambda th: residuals(model, th, robot, data, chord_start(model, th, robot, data, centre, solved),
                                         derivatives=False))(thetas)


# compiled by the diagnosis's background thread while its main thread finishes its fits and
# then waits for it: XLA's code generation over both cores (not concurrent_compiles' one
# thread), which is faster here (benchmarks/LATENCY.md)
walker_residuals = programs.Program(_walker_residuals, name="fitting.effects.model.walker_residuals",
                                    concurrent=False)
