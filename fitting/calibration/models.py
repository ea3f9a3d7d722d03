"""Measurement models: predicted poses/tensions of a CDPR and whitened residuals.

The CDPR model maps the *inputs* of a recording (commanded unstrained lengths ``l0``
and external wrench) to the *measurements* (pose and exit-point tensions) by forward
statics (seed 003 "direct kinematics"): by default the fixed-step Newton solve of
:func:`cstiffjax.statics.forward.forward_statics` (warm start) started at the measured poses, optionally
its cold start (``method="statics"``; the synthetic recordings use it, so fits of them check
one solver against the other).

Residual layout (:func:`residual_channels`): per sample ``6 + m`` columns

====================  =========================================================
``x, y, z``           ``(p_meas - p_pred) / σ_position``
``rx, ry, rz``        ``log(R_meas R_predᵀ) / σ_rotation`` (base frame; its norm is
                      the geodesic ``rotation_distance`` of seed 000 eq. 63)
``t_1 … t_m``         ``(t_meas - t_pred) / σ_tension`` where a tension was
                      recorded, ``0`` elsewhere
====================  =========================================================
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from cstiffjax.cable.laws import ALL_LAWS, CableLaw, check_law
from cstiffjax.core import lie
from cstiffjax.core.status import Status
from cstiffjax.io import schema
from cstiffjax.statics.forward import NEWTON_STEPS, StaticsProblem, forward_kinematics, forward_statics


def residual_channels(m: int) -> tuple[str, ...]:
    """Names of the ``6 + m`` residual columns of :func:`cdpr_residuals`: the recordings
    columns of the pose and the tensions (:mod:`cstiffjax.io.schema`)."""
    return (*schema.field_columns("pose", m), *schema.field_columns("tensions", m))


METHODS = ("newton", "statics")
# the laws recordings are fitted on: predict_cdpr's method "newton", calibrate, the diagnosis's baseline
FIT_LAWS = frozenset({CableLaw.spring, CableLaw.catenary})


@eqx.filter_jit
def predict_cdpr(robot, l0: Float[Array, "n m"], wrench: Float[Array, "n 6"], *, law: CableLaw = CableLaw.spring,
                 pose0: Float[Array, "n 6"] | None = None, method: str = "newton", steps: int = NEWTON_STEPS,
                 solver=None, max_steps: int = 256, forces0: Float[Array, "n 2 m"] | None = None):
    """Forward statics of every sample (vmapped, never raises: check ``result``).

    **Arguments:**

    - ``robot`` a :class:`~cstiffjax.io.robot.CableRobot`; ``l0`` ``(n, m)`` unstrained
      lengths, m; ``wrench`` ``(n, 6)`` external wrench (N, N·m).
    - ``law``: a :class:`~cstiffjax.cable.laws.CableLaw`: :data:`FIT_LAWS` (``spring``,
      ``catenary``) with ``method="newton"``, every law with ``method="statics"``.
    - ``pose0`` ``(n, 6)`` per-sample start poses (use the measured poses, or poses
      predicted at a nearby parameter point: the solve then starts next to the answer);
      default the ideal-cable pose of ``l0``.
    - ``method``: ``"newton"`` (default): the warm start of
      :func:`cstiffjax.statics.forward.forward_statics` (``steps`` clipped Newton steps plus
      the implicit step, bilateral springs, a few ms per 100 samples); ``"statics"``: its
      cold start (optimistix ``solver``, ``max_steps``; one-sided springs, any start).
    - ``forces0`` ``(n, 2, m)``: catenary end forces ``(H, V_B)`` to warm-start from
      with ``pose0`` (method ``"newton"``).

    The robot's winch and load-cell gains apply (:func:`true_lengths` of ``l0``, with the
    first row as ``l0_ref``; :func:`tension_readings`); at gains 1 nothing changes.

    **Returns:** ``(pose (n, 6), tension readings (n, m) at the exit points, result (n,))``;
    ``result`` a batched :class:`~cstiffjax.core.status.Status` (``not_converged`` where the
    equilibrium residual is not below tolerance).
    """
    if method not in METHODS:
        raise ValueError(f"predict_cdpr: method must be one of {METHODS}, got {method!r}")
    check_law(law, FIT_LAWS if method == "newton" else ALL_LAWS, f"predict_cdpr(method={method!r})")
    if method == "newton":
        pose, tensions, result, _ = predict_cdpr_state(robot, l0, wrench, pose0, law=law, steps=steps,
                                                       forces0=forces0)
        return pose, tensions, result
    fs = _solve_all(robot, true_lengths(robot, l0), wrench, pose0, None, law, start="cold", solver=solver,
                    max_steps=max_steps)
    return fs.pose, tension_readings(robot, fs.tensions), fs.result


def true_lengths(robot, l0: Float[Array, "n m"], l0_ref: Float[Array, " m"] | None = None) -> Float[Array, "n m"]:
    """Winch transmission (formats.md §1 v2): the true unstrained lengths
    ``l0_ref + length_gain (l0 - l0_ref)`` of the commanded ``l0`` (n, m), m, with
    ``l0_ref`` the first recorded commanded lengths (default ``l0[0]``). Written as
    ``l0 + (g - 1)(l0 - l0_ref)``: a gain of exactly 1 returns ``l0`` unchanged."""
    l0 = jnp.asarray(l0, dtype=jnp.float64)
    ref = l0[0] if l0_ref is None else jnp.asarray(l0_ref, dtype=jnp.float64)
    return l0 + (robot.length_gain - 1.0) * (l0 - ref)


def commanded_lengths(robot, l0_true: Float[Array, "n m"]) -> Float[Array, "n m"]:
    """Inverse of :func:`true_lengths` with ``l0_ref = l0_true[0]`` (the first command is
    where the true and commanded lengths agree), m: what a winch of gain ``length_gain``
    must be commanded to pay out ``l0_true``."""
    return l0_true + (1.0 / robot.length_gain - 1.0) * (l0_true - l0_true[0])


def tension_readings(robot, tensions: Float[Array, "n m"]) -> Float[Array, "n m"]:
    """Load cells (formats.md §1 v2): reading = ``tension_gain`` x true exit tension, N."""
    return robot.tension_gain * tensions


def _solve_all(robot, l0, wrench, pose0, forces0, law: CableLaw, **kw):
    """Forward statics of every sample under ``law`` (``kw``: the solver options)."""
    l0 = jnp.asarray(l0, dtype=jnp.float64)
    wrench = jnp.asarray(wrench, dtype=jnp.float64)
    if pose0 is None:
        pose0 = jax.vmap(lambda l: forward_kinematics(robot, l, throw=False).pose)(l0)
    pose0 = jnp.asarray(pose0, dtype=jnp.float64)

    def one(l, w, p, f=None):
        return forward_statics(StaticsProblem(robot, l, w, law), pose0=p, forces0=f, throw=False, **kw)

    if forces0 is None:
        return jax.vmap(one)(l0, wrench, pose0)
    return jax.vmap(one)(l0, wrench, pose0, jnp.asarray(forces0, dtype=jnp.float64))


def predict_cdpr_state(robot, l0: Float[Array, "n m"], wrench: Float[Array, "n 6"],
                       pose0: Float[Array, "n 6"] | None, *, law: CableLaw = CableLaw.spring,
                       steps: int = NEWTON_STEPS, forces0: Float[Array, "n 2 m"] | None = None):
    """Warm-started forward statics of every sample (``law`` one of :data:`FIT_LAWS`:
    ``spring`` is solved as bilateral springs, ``catenary`` as catenaries).

    **Returns:** ``(pose (n, 6), exit tensions (n, m), result (n,) Status, forces (n, 2, m))``
    with ``forces`` the cables' end forces ``(H, V_B)``, N (the warm start of a later solve).
    """
    check_law(law, FIT_LAWS, "predict_cdpr_state")
    catenary = law is CableLaw.catenary
    fs = _solve_all(robot, true_lengths(robot, l0), wrench, pose0, forces0 if catenary else None,
                    law if catenary else CableLaw.bilateral, start="warm", steps=steps)
    return fs.pose, tension_readings(robot, fs.tensions), fs.result, fs.forces


def rotation_difference(rv_meas: Float[Array, "3"], rv_pred: Float[Array, "3"]) -> Float[Array, "3"]:
    """``log(R_meas R_predᵀ)``: the base-frame rotation taking the prediction to the
    measurement, rad (``‖·‖`` = geodesic distance, seed 000 eq. 63)."""
    return lie.log(lie.exp(rv_meas) @ lie.exp(rv_pred).T)


def cdpr_residuals(pred_pose: Float[Array, "n 6"], pred_tensions: Float[Array, "n m"], recordings,
                   noise) -> Float[Array, "n 6+m"]:
    """Whitened residuals ``(measured - predicted)/σ`` of every sample (see module docstring).

    **Arguments:** predictions from :func:`predict_cdpr`; ``recordings`` a
    :class:`~cstiffjax.io.recordings.Recordings` (its ``pose``, ``tensions``,
    ``tension_mask``); ``noise`` a :class:`~cstiffjax.io.robot.Noise` (σ's, m, rad, N).

    **Returns:** ``(n, 6 + m)`` residuals, columns named by :func:`residual_channels`.
    """
    meas = recordings.pose
    dp = (meas[:, :3] - pred_pose[:, :3]) / noise.position
    dr = jax.vmap(rotation_difference)(meas[:, 3:], pred_pose[:, 3:]) / noise.rotation
    dt = jnp.where(recordings.tension_mask, (recordings.tensions - pred_tensions) / noise.tension, 0.0)
    return jnp.concatenate([dp, dr, dt], axis=1)


def num_effective(recordings) -> int:
    """Number of recorded scalars: 6 pose components per sample plus the recorded tensions."""
    return int(6 * recordings.num_samples + jnp.sum(recordings.tension_mask))


@eqx.filter_jit
def cdpr_model_residuals(robot, recordings, *, law: CableLaw = CableLaw.spring, method: str = "newton", solver=None,
                         max_steps: int = 256):
    """Residuals of ``robot`` on ``recordings`` with per-sample start at the measured pose
    (``law``, ``method``, ``solver``, ``max_steps`` as in :func:`predict_cdpr`).

    **Returns:** ``(residuals (n, 6+m), result (n,))``.
    """
    pose, t, res = predict_cdpr(robot, recordings.l0, recordings.wrench, law=law, pose0=recordings.pose,
                                method=method, solver=solver, max_steps=max_steps)
    return cdpr_residuals(pose, t, recordings, robot.noise), res


# ------------------------------------------------------------------ synthetic recordings
def _sample_inputs(robot, key, n, box, force_scale):
    k1, k2, k3, k4 = jax.random.split(key, 4)
    lo, hi = jnp.asarray(box[0], dtype=jnp.float64), jnp.asarray(box[1], dtype=jnp.float64)
    pos = lo + (hi - lo) * jax.random.uniform(k1, (n, 3), dtype=jnp.float64)
    rot = 0.03 * (2 * jax.random.uniform(k2, (n, 3), dtype=jnp.float64) - 1)
    fxy = force_scale[0] * jax.random.normal(k3, (n, 2), dtype=jnp.float64)
    fz = -force_scale[1] * jax.random.uniform(k4, (n, 1), dtype=jnp.float64)
    wrench = jnp.concatenate([fxy, fz, jnp.zeros((n, 3))], axis=1)
    return jnp.concatenate([pos, rot], axis=1), wrench


@eqx.filter_jit
def _draw_targets(robot, key, n: int, box, force_scale):
    """``n`` random target poses and wrenches (:func:`_sample_inputs`) with their
    inverse-statics tensions, in one compiled program (op-by-op dispatch of the vmapped
    inverse statics compiled every primitive separately)."""
    from cstiffjax.statics.geometry import inverse_statics

    pose_t, wrench = _sample_inputs(robot, key, n, box, force_scale)
    t = jax.vmap(lambda p, w: inverse_statics(robot, p, w, throw=False).tensions)(pose_t, wrench)
    return pose_t, wrench, t


@eqx.filter_jit
def _commanded(robot, pose_t, t):
    """Commanded lengths ``l0`` (n, m) that hold ``pose_t`` with tensions ``t`` (spring law)."""
    from cstiffjax.statics.geometry import cable_lengths

    l = jax.vmap(lambda p: cable_lengths(robot, p))(pose_t)
    return commanded_lengths(robot, l / (1.0 + t / robot.EA))


@eqx.filter_jit
def _add_noise(robot, key, pose, tens):
    """Gaussian noise with the robot's ``[noise]`` sigmas on poses (position, and rotation
    composed on the left) and tensions."""
    n = pose.shape[0]
    k1, k2, k3 = jax.random.split(key, 3)
    nz = robot.noise
    dp = nz.position * jax.random.normal(k1, (n, 3), dtype=jnp.float64)
    dr = nz.rotation * jax.random.normal(k2, (n, 3), dtype=jnp.float64)
    rv = jax.vmap(lambda d, r: lie.log(lie.exp(d) @ lie.exp(r)))(dr, pose[:, 3:])
    pose = jnp.concatenate([pose[:, :3] + dp, rv], axis=1)
    return pose, tens + nz.tension * jax.random.normal(k3, tens.shape, dtype=jnp.float64)


def synthetic_recordings(robot, key, n: int, *, law: CableLaw = CableLaw.spring, noisy: bool = True,
                         box=((2.5, -0.35, 0.2), (3.4, 0.35, 0.8)), force_scale=(3.0, 390.0),
                         tension_margin: float = 10.0, measure_tensions: bool = True, method: str = "statics"):
    """Recordings simulated with ``robot`` (the "truth") by forward statics, plus noise.

    Target poses are drawn uniformly in ``box`` (m; rotations within ±0.03 rad) with an
    external force ``[N(0, fs0), N(0, fs0), -U(0, fs1)]`` N; the commanded lengths are
    ``l0 = l / (1 + t/EA)`` for the inverse-statics tensions ``t`` (draws with a tension
    below ``tension_margin`` N are discarded), and the recorded pose/tensions are the
    forward statics of ``l0`` under ``law`` (a :class:`~cstiffjax.cable.laws.CableLaw`;
    ``method="statics"``, default: the cold start of
    :func:`cstiffjax.statics.forward.forward_statics`, independent of the fits' Newton solve;
    ``"newton"``: the fits' own solve, cheaper to compile) plus Gaussian noise with the
    robot's ``[noise]`` sigmas (when ``noisy``). The default box is the seed 003 prototype's
    central workspace. Used by the tests, notebooks and benchmarks.

    **Returns:** a :class:`~cstiffjax.io.recordings.Recordings` with ``n`` samples.
    """
    from cstiffjax.io.recordings import Recordings

    kin, knoise = jax.random.split(key)
    pose_t, wrench, t = _draw_targets(robot, kin, 4 * n, tuple(map(tuple, box)), tuple(force_scale))
    keep = np.flatnonzero(np.all(np.asarray(t) > tension_margin, axis=1))[:n]
    if keep.shape[0] < n:
        raise ValueError(f"only {keep.shape[0]} of {n} feasible poses found in box {box}; enlarge it")
    pose_t, wrench, t = pose_t[keep], wrench[keep], t[keep]
    l0 = _commanded(robot, pose_t, t)  # the winch gain's command for these lengths
    pose, tens, res = predict_cdpr(robot, l0, wrench, law=law, pose0=pose_t, method=method)
    if not bool(jnp.all(res == Status.successful)):
        raise ValueError("forward statics failed on some synthetic samples")
    if noisy:
        pose, tens = _add_noise(robot, knoise, pose, tens)
    m = robot.num_cables
    mask = jnp.full((n, m), measure_tensions)
    return Recordings(l0=l0, wrench=wrench, pose=pose, tensions=jnp.where(mask, tens, 0.0), tension_mask=mask,
                      moment=jnp.zeros((n, 3)), time=jnp.arange(n, dtype=jnp.float64),
                      covariates=jnp.zeros((n, 0)), source="<synthetic>")


# ------------------------------------------------------------------------ CSJM stiffness
def csjm_stiffness_model(robot, *, quantity: str = "K_D"):
    """``(params, rotations (N, 3)) -> (N, 3, 3)`` stiffness of a CSJM, seed 000 eq. (45).

    ``params = {"T": (m,) cable tensions N, "k": (m,) cable-plus-drive stiffnesses N/m}``;
    the matrices come from :func:`cstiffjax.csjm.model.stiffness` (autodiff of the cable
    moment). ``quantity``: ``"K_D"`` (seed 000's raw ``∂τ_A/∂ζ``, platform frame, eq.
    48a: what §III identifies), ``"covariant_body"`` (``K_D + K_L`` with the corrected
    ½ coefficient) or ``"K"`` (base-frame ``-∂m/∂θ``).
    """
    from cstiffjax.csjm import model as csjm

    if quantity not in ("K_D", "covariant_body", "K"):
        raise ValueError(f"quantity must be 'K_D', 'covariant_body' or 'K', got {quantity!r}")

    def model(params, rotations):
        def one(rv):
            return getattr(csjm.stiffness(robot, rv, params["T"], params["k"]), quantity)

        return jax.vmap(one)(jnp.asarray(rotations, dtype=jnp.float64))

    return model
