"""Whitened nonlinear least squares: Levenberg-Marquardt and the Gauss-Newton covariance.

:func:`solve_least_squares` is the calibration entry of the package's one least-squares
engine (:func:`fitting.calibration.lm.masked_levenberg_marquardt`, a ``lax.while_loop``; the
diagnosis's masked fits use the same): every calibration (CDPR, CSJM, any user model) builds a
residual function ``r(θ, args)`` of *whitened* residuals ``(measured - predicted) / σ`` in
an unconstrained parameter vector ``θ`` and hands it here. At the optimum the Jacobian
``J = ∂r/∂θ`` (forward-mode autodiff, through any inner implicit solve) gives the
Gauss-Newton covariance ``C = (JᵀJ)⁺``, which is the exact posterior covariance of a
linear-Gaussian model with a flat prior.
"""

import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from cstiffjax.cable.laws import CableLaw, check_law
from cstiffjax.core.arrays import to_device
from cstiffjax.core.errors import SolverError
from cstiffjax.core.status import Status, raise_if_failed
from cstiffjax.io.sigmas import fit_noise
from cstiffjax.runtime import programs
from cstiffjax.statics.forward import NEWTON_STEPS
from fitting.calibration.arguments import check_arguments
from fitting.calibration.lm import masked_levenberg_marquardt
from fitting.calibration.models import (
    FIT_LAWS,
    METHODS,
    cdpr_residuals,
    num_effective,
    predict_cdpr,
    predict_cdpr_state,
    residual_channels,
    sensor_fields,
    sensor_predictions,
    session_ids,
    session_index,
    with_start_poses,
)
from fitting.calibration.parameters import (
    ParameterSpec,
    apply_to_robot,
    cdpr_spec,
    cdpr_values,
    corrected_inputs,
    measured_outputs,
)

WARM_STEPS = 2  # Newton steps from poses predicted at a nearby parameter point (posterior sampling)


class IdentifiabilityWarning(UserWarning):
    """A combination of free parameters the recordings can hardly separate (a :class:`Fit`'s
    ``weak``), issued by the calibrations; a caller that reports ``Fit.weak`` itself (the
    ``fit`` command) ignores this category only."""


class LSResult(eqx.Module):
    """Result of :func:`solve_least_squares` (all in the unconstrained ``θ`` coordinates).

    - ``theta`` ``(p,)``: the optimum. ``residuals`` ``(n,)``: whitened residuals there.
    - ``jacobian`` ``(n, p)``: ``∂r/∂θ`` at the optimum (autodiff).
    - ``chi2``: ``Σ r²``. ``dof``: ``num_data - p``. ``chi2_per_dof``: ``chi2 / dof``
      (``nan`` when ``dof <= 0``).
    - ``covariance`` ``(p, p)``: ``pinv(JᵀJ)``, the Gauss-Newton covariance of ``θ``
      for unit-variance residuals (not rescaled by ``chi2_per_dof``).
    - ``result``: a :class:`~cstiffjax.core.status.Status`: ``successful`` (converged, or no
      further decrease possible), ``not_converged`` (``max_steps`` accepted steps) or
      ``invalid_input`` (non-finite residuals or Jacobian at ``theta0``).
      ``num_steps``: LM iterations.
    """

    theta: Float[Array, " p"]
    residuals: Float[Array, " n"]
    jacobian: Float[Array, "n p"]
    chi2: Float[Array, ""]
    dof: Int[Array, ""]
    chi2_per_dof: Float[Array, ""]
    covariance: Float[Array, "p p"]
    result: Status
    num_steps: Int[Array, ""]


def _value_and_jacfwd(residual_fn, theta, args):
    """``(r, ∂r/∂θ)`` in one batched forward-mode pass (``p`` JVPs, one primal)."""
    basis = jnp.eye(theta.shape[0], dtype=theta.dtype)
    r, J = jax.vmap(lambda v: jax.jvp(lambda t: residual_fn(t, args), (theta,), (v,)), out_axes=(None, 1))(basis)
    return r, J


class _Dense(eqx.Module):
    """``(θ, args) -> (r, J, ok (1,))`` of a residual function: the engine's ``fun`` with
    every entry free and one "sample" (the whole vector, ok when finite)."""

    residual_fn: object = eqx.field(static=True)

    def __call__(self, theta, args):
        r, J = _value_and_jacfwd(self.residual_fn, theta, args)
        return r, J, (jnp.all(jnp.isfinite(r)) & jnp.all(jnp.isfinite(J)))[None]


def _solve_impl(residual_fn, theta0, args, max_steps, rtol, num_data):
    out = masked_levenberg_marquardt(_Dense(residual_fn), theta0, args, max_steps=max_steps, rtol=rtol,
                                     covariance=False)
    r, J = out.residuals, out.jacobian
    dof = jnp.asarray(num_data - theta0.shape[0])
    chi2_dof = jnp.where(dof > 0, out.chi2 / jnp.maximum(dof, 1), jnp.nan)
    cov = jnp.linalg.pinv(J.T @ J, hermitian=True)
    failed = Status.where(out.result == Status.start_failed, Status.invalid_input, Status.not_converged)
    result = Status.where(out.converged, Status.successful, failed)
    return LSResult(out.theta, r, J, out.chi2, dof, chi2_dof, cov, result, out.steps)


# compiled; a serialized program when cstiffjax.runtime.programs is on (a warm `cstiffjax fit`
# loads it instead of tracing the statics again)
_solve = programs.Program(_solve_impl, name="fitting.calibration.least_squares._solve",
                          like=lambda args: LSResult(0, 0, 0, 0, 0, 0, 0, Status.successful, 0))


def solve_least_squares(
    residual_fn, theta0: Float[Array, " p"], args, *, solver=None, max_steps: int = 200,
    throw: bool = True, num_data: int | None = None, rtol: float = 1e-10,
) -> LSResult:
    """Minimise ``½‖r(θ, args)‖²`` with Levenberg-Marquardt
    (:func:`fitting.calibration.lm.masked_levenberg_marquardt`, every entry free). Works under
    ``jax.jit`` and ``jax.vmap``.

    **Arguments:**

    - ``residual_fn``: ``(theta, args) -> (n,)`` whitened residuals (dimensionless;
      NaN-free; masked entries must be exactly 0). Must be a hashable function (it is
      static under jit).
    - ``theta0``: ``(p,)`` float64 start, unconstrained coordinates.
    - ``args``: a pytree passed through to ``residual_fn`` (robot, recordings, ...).
    - ``solver``: deprecated and ignored (it was an ``optx`` solver; there is one
      engine now); passing one warns.
    - ``max_steps``: accepted LM steps at most. ``rtol``: converged when a step lowers
      χ² by at most ``rtol·χ² + 1e-12``. ``throw``: raise (``EqxRuntimeError``, also under
      jit) when the solve fails; else check ``result``.
    - ``num_data``: number of effective data (residual entries that are not masked
      zeros) for the degrees of freedom; default the residual length.

    **Returns:** an :class:`LSResult`.
    """
    if solver is not None:
        warnings.warn("solve_least_squares: `solver` is deprecated and ignored; the fit uses "
                      "fitting.calibration.lm.masked_levenberg_marquardt", DeprecationWarning, stacklevel=2)
    theta0 = jnp.asarray(theta0, dtype=jnp.float64)
    if theta0.ndim != 1:
        raise ValueError(f"theta0 must be a 1-D parameter vector, got shape {theta0.shape}")
    if not isinstance(theta0, jax.core.Tracer) and not bool(jnp.all(jnp.isfinite(theta0))):
        raise ValueError(f"theta0 contains NaN or inf: {theta0}")
    if num_data is None:
        num_data = int(jax.eval_shape(residual_fn, theta0, args).shape[0])
    out = _solve(residual_fn, theta0, args, jnp.asarray(max_steps, jnp.int32), jnp.asarray(rtol, jnp.float64),
                 int(num_data))  # strong dtypes: a weakly typed argument is never serialized
    return raise_if_failed(out.result, out, throw)


# =============================================================================== fits
class Fit(eqx.Module):
    """A calibrated model.

    - ``values``: ``{name: array}`` physical values of every parameter (free ones fitted).
    - ``std``: ``{free name: array}`` one-sigma uncertainties (Gauss-Newton, physical units).
    - ``covariance`` ``(p, p)`` and ``correlation`` ``(p, p)`` of the free values,
      ordered as ``names`` (``spec.flat_names()``).
    - ``residuals``: whitened residuals per sample (``(n, 6+m)`` for a CDPR, columns
      ``channels``), priors excluded. ``chi2``, ``dof``, ``chi2_per_dof``: data + priors,
      with ``[noise]`` sigmas (1 = explained down to the noise).
    - ``weak``: human-readable weakly/non-identifiable parameter combinations.
    - ``ls``: the underlying :class:`LSResult` (θ coordinates). ``spec``, ``law`` (the CDPR
      calibration's :class:`~cstiffjax.cable.laws.CableLaw`, None for other models): static.
    - ``residual_fn``, ``args``: the whitened residual ``r(θ, args)`` that was minimised
      (data then priors), for :func:`fitting.posterior.sampler.sample_posterior`.
    """

    values: dict
    std: dict
    covariance: Float[Array, "p p"]
    correlation: Float[Array, "p p"]
    residuals: Float[Array, "n c"]
    chi2: Float[Array, ""]
    dof: Int[Array, ""]
    chi2_per_dof: Float[Array, ""]
    ls: LSResult
    spec: object = eqx.field(static=True)
    names: tuple = eqx.field(static=True)
    channels: tuple = eqx.field(static=True, default=())
    weak: tuple = eqx.field(static=True, default=())
    law: CableLaw | None = eqx.field(static=True, default=None)
    priors: dict | None = None
    residual_fn: object = eqx.field(static=True, default=None)
    args: object = None

    @property
    def result(self):
        return self.ls.result

    def summary(self) -> str:
        """A table: parameter, value, std, unit."""
        flat = self.spec.free_vector(self.values)
        sd = np.sqrt(np.diag(np.asarray(self.covariance)))
        units = [self.spec.unit(n.split("[")[0].split(".")[0]) for n in self.names]
        lines = [f"{'parameter':<22}{'value':>16}{'std':>14}  unit"]
        lines += [f"{n:<22}{v:>16.8g}{s:>14.4g}  {u}" for n, v, s, u in zip(self.names, np.asarray(flat), sd, units)]
        lines.append(f"chi2/dof = {float(self.chi2_per_dof):.4g} (chi2 {float(self.chi2):.6g}, dof {int(self.dof)})")
        lines += [f"warning: {w}" for w in self.weak]
        return "\n".join(lines)


def identifiability(jacobian, names, *, weak: float = 1e-8) -> list[str]:
    """Weakly or non-identifiable parameter combinations of a least-squares problem.

    The Fisher matrix ``F = JᵀJ`` is scaled to unit diagonal (``F_ij / sqrt(F_ii F_jj)``,
    so units do not matter) and eigen-decomposed; an eigenvalue below ``weak`` times the
    largest marks a direction the data hardly constrain (its std is at least
    ``1/sqrt(weak)`` times that of the best-determined one, in correlation units). Each
    is described by its eigenvector's large components, e.g.
    ``"0.707*EA[1] - 0.707*length_offset[1]"``.

    **Returns:** one message per such direction (empty when all are identifiable).
    """
    J = np.asarray(jacobian)
    F = J.T @ J
    d = np.sqrt(np.diag(F))
    msgs = [f"parameter {names[i]} has no effect on the residuals (not identifiable)" for i in np.flatnonzero(d == 0)]
    ok = d > 0
    if ok.sum() == 0:
        return msgs
    Fs = F[np.ix_(ok, ok)] / np.outer(d[ok], d[ok])
    lam, vec = np.linalg.eigh(Fs)
    sub = [n for n, k in zip(names, ok, strict=True) if k]
    for val, v in zip(lam, vec.T, strict=True):
        if val < weak * lam[-1]:
            big = np.argsort(-np.abs(v))[: min(6, len(v))]
            terms = " ".join(f"{'+' if v[i] >= 0 else '-'} {abs(v[i]):.3g}*{sub[i]}" for i in big if abs(v[i]) > 0.05)
            kind = "non-identifiable" if val < 1e-13 * lam[-1] else "weakly identifiable"
            msgs.append(f"{kind} parameter combination (relative eigenvalue {val / lam[-1]:.2e} of the "
                        f"correlation-scaled JᵀJ): {terms.lstrip('+ ')}")
    return msgs


def _finish(spec, values0, ls, residuals, *, channels=(), law=None, priors=None, fn=None, args=None,
            notes=()) -> "Fit":
    values = spec.from_theta(ls.theta, values0)
    G = spec.value_jacobian(ls.theta)
    cov = G @ ls.covariance @ G.T
    sd = jnp.sqrt(jnp.clip(jnp.diag(cov), 0.0))
    corr = cov / jnp.where(jnp.outer(sd, sd) > 0, jnp.outer(sd, sd), 1.0)
    names = tuple(spec.flat_names())
    weak = (*notes, *identifiability(ls.jacobian, names))
    for w in weak:
        warnings.warn(w, IdentifiabilityWarning, stacklevel=3)
    return Fit(values, spec.unflatten(sd), cov, corr, residuals, ls.chi2, ls.dof, ls.chi2_per_dof, ls, spec, names,
               tuple(channels), weak, law, priors, fn, args)


# ------------------------------------------------------------------------ CDPR calibration
class CDPRResidual(eqx.Module):
    """Whitened residual function of a CDPR calibration (static: spec, law, solver settings).

    ``args = (robot, recordings, values0, priors, start)`` with ``start = (poses (n, 6),
    end forces (n, 2, m) or None)``: where each sample's forward statics starts (the
    measured poses and no forces in :func:`calibrate`; a previous solution in
    :meth:`warm_started`); returns data residuals (flattened ``(n, 6+m)``, masked tensions
    0) followed by the prior residuals. ``method``/``steps``/``max_steps`` as in
    :func:`fitting.calibration.models.predict_cdpr`.
    """

    spec: object = eqx.field(static=True)
    law: CableLaw = eqx.field(static=True)
    method: str = eqx.field(static=True, default="newton")
    steps: int = eqx.field(static=True, default=NEWTON_STEPS)
    max_steps: int = eqx.field(static=True, default=256)
    sensors: tuple[str, ...] = eqx.field(static=True, default=())  # on-board sensors measured (models.SENSORS)

    def data(self, theta, args):
        """``(residuals (n, 6+m), result (n,) Status, physical values, (true poses (n, 6),
        end forces (n, 2, m)))``; the last two only with ``method="newton"`` (else ``None``)."""
        robot, rec, values0, _, start = args
        pose0, forces0 = start
        values = self.spec.from_theta(theta, values0)
        rb = apply_to_robot(robot, values)
        l0 = corrected_inputs(rec.l0, values, rec.session)  # rec.session: session indices (calibrate)
        if self.method == "newton":
            pose, t, res, forces = predict_cdpr_state(rb, l0, rec.wrench, pose0, law=self.law, steps=self.steps,
                                                      forces0=forces0)
            state = (pose, forces)
        else:
            pose, t, res = predict_cdpr(rb, l0, rec.wrench, law=self.law, pose0=pose0, method=self.method,
                                        max_steps=self.max_steps)
            state = None
        sensors = sensor_predictions(rb, pose, rec.session, self.sensors, values.get("yaw_zero"),
                                     values.get("swivel_offset"))
        mpose, t = measured_outputs(pose, t, values)
        return cdpr_residuals(mpose, t, rec, robot.noise, sensors), res, values, state

    def checked(self, theta, args):
        """``(residuals, ok)``: :meth:`__call__`'s vector and whether every sample's
        statics converged (the posterior sampler turns ``ok = False`` into ``-inf``)."""
        r, res, values, _ = self.data(theta, args)
        flat = jnp.concatenate([r.ravel(), self.spec.prior_residuals(values, args[3])])
        return flat, jnp.all(res == Status.successful)

    def __call__(self, theta, args):
        return self.checked(theta, args)[0]

    def warm_started(self, theta, args, steps: int = WARM_STEPS):
        """``(fn, args)``: the same residual with each sample's statics started at the
        solution at ``theta`` (e.g. the least-squares optimum: poses, and catenary end
        forces) and only ``steps`` Newton steps: near ``theta`` they converge (checked
        through :meth:`checked`), at a fraction of the cost. Used by
        :func:`fitting.posterior.sampler.sample_posterior`."""
        if self.method != "newton":
            return self, args
        state = _cdpr_data(self, jnp.asarray(theta), args)[3]
        return CDPRResidual(self.spec, self.law, self.method, int(steps), self.max_steps, self.sensors), \
            (*args[:4], state)


@eqx.filter_jit
def _cdpr_data(fn, theta, args):
    return fn.data(theta, args)


def _fitted_residuals_impl(fn, theta, args):
    return fn.data(theta, args)[:2]


# (residuals, Status) at the fit; serialized like _solve (a warm `cstiffjax fit` skips its trace)
_fitted_residuals = programs.Program(_fitted_residuals_impl, name="fitting.calibration.least_squares._fitted_residuals",
                                     like=lambda args: (0, Status.successful))


def check_recordings(robot, recordings):
    """Raise ``TypeError`` / ``ValueError`` when ``recordings`` cannot be fitted with ``robot``
    (:func:`fitting.calibration.arguments.check_arguments`, then their values)."""
    check_arguments(robot, recordings, "calibrate")
    for f in ("l0", "wrench", "pose", "tensions"):
        a = np.asarray(getattr(recordings, f))
        bad = ~np.isfinite(a)
        if bad.any():
            i, j = np.argwhere(bad)[0]
            raise ValueError(f"recordings.{f} has a non-finite value ({a[i, j]}) at sample {i + 1}, column {j + 1}; "
                             f"drop or fill such rows (load_recordings(..., drop_invalid=True))")
    inputs = np.concatenate([np.asarray(recordings.l0), np.asarray(recordings.wrench)], axis=1)
    if recordings.num_samples > 1 and np.all(np.ptp(inputs, axis=0) == 0):
        raise ValueError(f"all {recordings.num_samples} samples have the same inputs (l0 and wrench); "
                         f"nothing beyond one operating point is identifiable: vary the lengths or the load")


def recording_zeros(robot, sensors: tuple[str, ...], free) -> tuple[str, ...]:
    """``free`` (names, or a string with commas) plus the recordings' unknown zeros that
    every fit calibrates: ``length_zero`` for relative lengths, ``yaw_zero`` with an AHRS."""
    free = tuple(f.strip() for f in free.split(",") if f.strip()) if isinstance(free, str) else tuple(free)
    extra = (("length_zero",) if robot.relative_lengths else ()) + (("yaw_zero",) if "ahrs" in sensors else ())
    return free + tuple(e for e in extra if e not in free)


def calibrate(robot, recordings, free=("EA",), *, law: CableLaw = CableLaw.spring, priors=None, bounds=None,
              initial=None, solver=None, max_steps: int = 100, throw: bool = True, statics: str = "newton") -> Fit:
    """Calibrate CDPR parameters on recordings by whitened least squares.

    Predicts each sample by forward statics (:func:`fitting.calibration.models.predict_cdpr`,
    started at the measured pose), whitens the residuals with the robot's ``[noise]``
    sigmas and minimises them with Levenberg-Marquardt (:func:`solve_least_squares`);
    gradients are autodiff through the statics (and catenary) solves (exact
    implicit-function derivatives).

    **Arguments:**

    - ``robot``: nominal :class:`~cstiffjax.io.robot.CableRobot` (its values are the
      starting point and the fixed values). ``recordings``: a
      :class:`~cstiffjax.io.recordings.Recordings` of the same robot.
    - ``free``: names from :data:`fitting.calibration.parameters.CDPR_PARAMETERS` (sequence or
      ``"EA,length_offset"``). ``law``: :data:`~fitting.calibration.models.FIT_LAWS`
      (``CableLaw.spring`` or ``CableLaw.catenary``).
    - ``priors``: ``{name: (mean, std)}`` Gaussian priors (physical units).
      ``bounds``: ``{name: (lo, hi)}``. ``initial``: ``{name: value}`` starting values.
    - ``solver`` (deprecated, ignored), ``max_steps``, ``throw``: as in :func:`solve_least_squares`.
    - ``statics``: the forward-statics solve, ``"newton"`` (default; fixed Newton steps
      from the measured poses: the warm start of
      :func:`cstiffjax.statics.forward.forward_statics`) or ``"statics"`` (its optimistix
      cold start, about 5-50 times slower; same equilibrium while every cable is taut).

    **Returns:** a :class:`Fit`. Weakly identifiable combinations are reported with
    ``warnings.warn`` (an :class:`IdentifiabilityWarning`) and in ``Fit.weak``.

    **Raises:** :class:`~cstiffjax.core.errors.RecordingsError` when a recorded channel has no
    ``[noise]`` sigma (a channel not recorded needs none: :func:`cstiffjax.io.sigmas.fit_noise`).
    """
    check_law(law, FIT_LAWS, "calibrate")
    if statics not in METHODS:
        raise ValueError(f"calibrate: statics must be one of {METHODS}, got {statics!r}")
    check_recordings(robot, recordings)
    robot = fit_noise(robot, recordings)  # a recorded channel needs its sigma; the others a placeholder
    sensors = sensor_fields(recordings)
    free = recording_zeros(robot, sensors, free)
    index, sessions = session_index(recordings)
    spec = cdpr_spec(robot.num_cables, free, bounds, sessions, session_ids(recordings))
    values0 = cdpr_values(robot, sessions)
    values0.update(initial or {})
    values0 = spec.check_values(values0)
    priors = {n: (jnp.asarray(mu, dtype=jnp.float64), jnp.asarray(sd, dtype=jnp.float64))
              for n, (mu, sd) in spec.check_priors(priors).items()}
    fn = CDPRResidual(spec, law, statics, sensors=sensors)
    recordings = with_start_poses(robot, recordings)
    recordings = eqx.tree_at(lambda r: r.session, recordings, to_device(index))  # the sessions as 0..S-1
    args = (robot, recordings, values0, priors, (recordings.pose, None))
    n_prior = sum(spec.size(n) for n in priors)
    ls = solve_least_squares(fn, spec.to_theta(values0), args, solver=solver, max_steps=max_steps, throw=throw,
                             num_data=num_effective(recordings, sensors) + n_prior)
    r, res = _fitted_residuals(fn, ls.theta, args)
    if throw and not bool(jnp.all(res == Status.successful)):
        bad = np.flatnonzero(~np.asarray(res == Status.successful)) + 1
        raise SolverError(f"forward statics failed at the fitted parameters for samples {bad.tolist()}")
    notes = ()
    if "anchors" in spec.free and not recordings.has_position:
        notes = ("anchors: without x y z a common shift of all anchors moves the platform with them and changes no "
                 "reading (3 combinations below); fix one anchor or give the anchors priors",)
    return _finish(spec, values0, ls, r, channels=residual_channels(robot.num_cables, sensors), law=law, priors=priors,
                   notes=notes,
                   fn=fn, args=args)


# ------------------------------------------------------------------------ generic models
class ModelResidual(eqx.Module):
    """Whitened residuals ``(measurements - model_fn(params, inputs))/sigma`` of a generic model."""

    model_fn: object = eqx.field(static=True)
    spec: object = eqx.field(static=True)

    def data(self, theta, args):
        inputs, meas, sigma, mask, values0, _ = args
        values = self.spec.from_theta(theta, values0)
        pred = jnp.reshape(self.model_fn(values, inputs), meas.shape)
        return jnp.where(mask, (meas - pred) / sigma, 0.0), values

    def __call__(self, theta, args):
        r, values = self.data(theta, args)
        return jnp.concatenate([r.ravel(), self.spec.prior_residuals(values, args[5])])


def calibrate_model(model_fn, params0: dict, inputs, measurements, sigma, *, free=None, transforms=None,
                    priors=None, mask=None, solver=None, max_steps: int = 200, throw: bool = True) -> Fit:
    """Fit any model ``model_fn(params: dict, inputs) -> predicted measurements``.

    **Arguments:** ``params0``: ``{name: starting/fixed value}``; ``inputs``: any pytree
    with samples along axis 0 (must not be the same for every sample);
    ``measurements``: array (n, ...); ``sigma``: one-sigma noise, broadcastable to it;
    ``free``: names to fit (default all); ``transforms``: ``{name: "log" | ("bounded",
    lo, hi)}`` (default identity); ``priors``: ``{name: (mean, std)}``; ``mask``: true
    where a measurement exists (default: where it is finite; NaN elsewhere is an error).

    **Returns:** a :class:`Fit` (residuals shaped like ``measurements``).
    """
    names = tuple(params0)
    transforms = transforms or {}
    spec = ParameterSpec(names, tuple(tuple(np.shape(params0[n])) for n in names),
                         tuple(transforms.get(n, "identity") for n in names), tuple("" for _ in names),
                         tuple(names if free is None else ([free] if isinstance(free, str) else free)))
    meas = jnp.asarray(measurements, dtype=jnp.float64)
    mask = jnp.ones(meas.shape, bool) if mask is None else jnp.broadcast_to(jnp.asarray(mask, bool), meas.shape)
    if not bool(jnp.all(jnp.isfinite(jnp.where(mask, meas, 0.0)))):
        raise ValueError("measurements contain NaN or inf where mask is true; pass mask=False there")
    sigma = jnp.broadcast_to(jnp.asarray(sigma, dtype=jnp.float64), meas.shape)
    if not bool(jnp.all(sigma > 0)):
        raise ValueError(f"sigma must be > 0 everywhere, got min {float(jnp.min(sigma))}")
    leaves = [np.asarray(x) for x in jax.tree.leaves(inputs)]
    if meas.shape[0] > 1 and leaves and all(np.all(x == x[:1]) for x in leaves):
        raise ValueError(f"all {meas.shape[0]} samples have the same inputs; nothing beyond one operating point "
                         f"is identifiable: vary the inputs")
    values0 = spec.check_values(params0)
    priors = {n: (jnp.asarray(mu, dtype=jnp.float64), jnp.asarray(sd, dtype=jnp.float64))
              for n, (mu, sd) in spec.check_priors(priors).items()}
    fn = ModelResidual(model_fn, spec)
    args = (inputs, jnp.where(mask, meas, 0.0), sigma, mask, values0, priors)
    n_prior = sum(spec.size(n) for n in priors)
    ls = solve_least_squares(fn, spec.to_theta(values0), args, solver=solver, max_steps=max_steps, throw=throw,
                             num_data=int(jnp.sum(mask)) + n_prior)
    r, _ = fn.data(ls.theta, args)
    return _finish(spec, values0, ls, r, priors=priors, fn=fn, args=args)


def calibrate_csjm_stiffness(robot, rotations, K_measured, sigma, *, T0, k0, quantity: str = "K_D",
                             free=("T", "k"), priors=None, **kwargs) -> Fit:
    """Fit cable tensions ``T`` and cable-plus-drive stiffnesses ``k`` of a CSJM to
    identified stiffness matrices (Yang et al. 2019 eq. 45 / eq. 48a), with uncertainty.

    **Arguments:** ``robot``: a :class:`~cstiffjax.io.robot.SphericalJointModule`;
    ``rotations`` ``(N, 3)`` poses (rotation vectors, rad) where the matrices were
    identified; ``K_measured`` ``(N, 3, 3)`` N·m/rad and ``sigma`` (broadcastable) their
    one-sigma errors; ``T0``, ``k0`` ``(m,)`` starting values (N, N/m; both kept
    positive by log transforms); ``quantity`` see :func:`fitting.calibration.models.csjm_stiffness_model`.
    One pose gives 9 numbers for ``2m`` unknowns: use several poses (or priors).

    **Returns:** a :class:`Fit` with ``values["T"]``, ``values["k"]``.
    """
    from fitting.calibration.models import csjm_stiffness_model

    model = csjm_stiffness_model(robot, quantity=quantity)
    params0 = {"T": jnp.asarray(T0, dtype=jnp.float64), "k": jnp.asarray(k0, dtype=jnp.float64)}
    return calibrate_model(model, params0, jnp.atleast_2d(jnp.asarray(rotations, dtype=jnp.float64)),
                           K_measured, sigma, free=free, transforms={"T": "log", "k": "log"}, priors=priors, **kwargs)
