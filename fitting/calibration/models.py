"""Measurement models: predicted poses/tensions of a CDPR and whitened residuals.

The CDPR model maps the *inputs* of a recording (commanded unstrained lengths ``l0``
and external wrench) to the *measurements* (pose and exit-point tensions) by forward
statics (Yuan et al. 2015 "direct kinematics"): by default the fixed-step Newton solve of
:func:`cstiffjax.statics.forward.forward_statics` (warm start) started at the measured poses, optionally
its cold start (``method="statics"``; the synthetic recordings use it, so fits of them check
one solver against the other).

Residual layout (:func:`residual_channels`): per sample ``6 + m`` columns, then the
on-board sensors' (formats.md §2 version 3) when the recordings have them

=========================  =========================================================
``x, y, z``                ``(p_meas - p_pred) / σ_position``
``rx, ry, rz``             ``log(R_meas R_predᵀ) / σ_rotation`` (base frame; its norm is
                           the geodesic ``rotation_distance`` of Yang et al. 2019 eq. 63)
``t_1 … t_m``              ``(t_meas - t_pred) / σ_tension``
``swivel_1 … swivel_m``    ``wrap(ψ_meas - ψ_pred) / σ_swivel`` (only with swivel columns)
``roll, pitch, yaw``       ``wrap(a_meas - a_pred) / σ_ahrs`` per axis (only with an AHRS)
=========================  =========================================================

Every column is ``0`` where its value was not measured (the recordings' masks).
"""

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from cstiffjax.cable.laws import ALL_LAWS, CableLaw, check_law
from cstiffjax.core import lie
from cstiffjax.core.arrays import to_device
from cstiffjax.core.status import Status
from cstiffjax.io import schema
from cstiffjax.runtime import programs
from cstiffjax.statics.forward import NEWTON_STEPS, StaticsProblem, forward_kinematics, forward_statics
from cstiffjax.statics.sensors import ahrs_angles, angle_difference, swivel_angles

SENSORS = ("swivel", "ahrs")
"""The on-board sensor channels (recordings fields) that add residual columns when measured."""


def sensor_fields(recordings) -> tuple[str, ...]:
    """Which of :data:`SENSORS` ``recordings`` measured (static: decided before tracing)."""
    return tuple(f for f in SENSORS if bool(np.any(np.asarray(getattr(recordings, f + "_mask")))))


def residual_channels(m: int, sensors: tuple[str, ...] = ()) -> tuple[str, ...]:
    """Names of the residual columns of :func:`cdpr_residuals`: the recordings columns of
    the pose and the tensions (:mod:`cstiffjax.io.schema`), then those of ``sensors``
    (:func:`sensor_fields`)."""
    fields = ("pose", "tensions", *(f for f in SENSORS if f in sensors))
    return tuple(c for f in fields for c in schema.field_columns(f, m))


def measured_mask(recordings, sensors: tuple[str, ...] = ()) -> np.ndarray:
    """``(n, columns)`` booleans, aligned with :func:`residual_channels`: where a value was measured."""
    parts = [recordings.pose_mask, recordings.tension_mask, *(getattr(recordings, f + "_mask")
                                                              for f in SENSORS if f in sensors)]
    return np.concatenate([np.asarray(a, dtype=bool) for a in parts], axis=1)


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


def session_index(recordings) -> tuple[np.ndarray, int]:
    """``(index (n,), S)``: each sample's recording session as 0..S-1 (sessions in ascending
    id order) and the number ``S`` of sessions (formats.md §2 version 3)."""
    ids = np.asarray(recordings.session)
    uniq = np.unique(ids)
    return np.searchsorted(uniq, ids).astype(np.int64), int(max(len(uniq), 1))


def session_ids(recordings) -> tuple[int, ...]:
    """The recordings' own session ids in the order of :func:`session_index`'s ``0..S-1``
    (ascending; ``(0,)`` for recordings without a ``session`` column): the names under which
    the per-session parameters are reported."""
    return tuple(int(i) for i in np.unique(np.asarray(recordings.session))) or (0,)


def start_poses(robot, recordings) -> np.ndarray:
    """Where each sample's warm forward statics starts: the measured pose where one was
    measured, else (on-board sensors only, formats.md §2 version 3) the nominal robot's
    equilibrium of the recorded inputs from a cold start
    (:func:`~cstiffjax.statics.forward.forward_statics`: the ideal-cable pose, or for fewer
    than 6 cables the least-energy pose), with a measured rotation kept.

    **Returns:** ``(n, 6)`` poses, m / rad (NumPy).

    **Raises:** ``ValueError`` naming the samples whose nominal equilibrium was not found."""
    pose, mask = np.asarray(recordings.pose, dtype=float), np.asarray(recordings.pose_mask, dtype=bool)
    if mask.all():
        return pose
    cold, res = _cold_starts(dataclasses.replace(robot, name="robot"), to_device(recordings.l0, np.float64),
                             to_device(recordings.wrench, np.float64))
    bad = np.flatnonzero(~np.asarray(res == Status.successful))
    if bad.size:
        raise ValueError(f"no equilibrium of the nominal robot '{robot.name}' found for sample(s) "
                         f"{(bad + 1).tolist()[:10]} (no x y z recorded: the fit starts there): check the "
                         f"description and the recorded lengths")
    return np.where(mask, pose, np.asarray(cold))


def _cold_starts_impl(robot, l0: Float[Array, "n m"], wrench: Float[Array, "n 6"]):
    """``(pose (n, 6), result (n,))``: :func:`predict_cdpr`'s ``method="statics"`` solve
    (the cold start of every sample, spring law, 256 steps at most) without the readings."""
    fs = _solve_all(robot, true_lengths(robot, l0), wrench, None, None, CableLaw.spring, start="cold", solver=None,
                    max_steps=256)
    return fs.pose, fs.result


# a serialized program (cstiffjax.runtime.programs): a warm command line loads it instead of
# tracing the cold-start statics again (~4 s on a 4-cable pulley robot); the robot is passed
# under a fixed name so every robot of the same shape shares it. It runs once per data set:
# compiled with programs.ONCE_OPTIONS.
_cold_starts = programs.Program(_cold_starts_impl, name="fitting.calibration.models.cold_starts",
                                like=lambda args: (0, Status.successful),
                                compiler_options=programs.ONCE_OPTIONS)


def with_start_poses(robot, recordings):
    """``recordings`` with :func:`start_poses` in place of the unmeasured pose components
    (``pose_mask`` unchanged, so no residual reads them): the pose estimate everything that
    needs one starts from. Unchanged when every pose component was measured."""
    if bool(np.all(np.asarray(recordings.pose_mask))):
        return recordings
    return eqx.tree_at(lambda r: r.pose, recordings, to_device(start_poses(robot, recordings)))


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
    measurement, rad (``‖·‖`` = geodesic distance, Yang et al. 2019 eq. 63)."""
    return lie.log(lie.exp(rv_meas) @ lie.exp(rv_pred).T)


def cdpr_residuals(pred_pose: Float[Array, "n 6"], pred_tensions: Float[Array, "n m"], recordings,
                   noise, sensors: dict | None = None) -> Float[Array, "n c"]:
    """Whitened residuals ``(measured - predicted)/σ`` of every sample (see module docstring).

    **Arguments:** predictions from :func:`predict_cdpr`; ``recordings`` a
    :class:`~cstiffjax.io.recordings.Recordings` or model data with the same fields (its
    ``pose``, ``tensions``, the sensors' values and every ``*_mask``); ``noise`` a
    :class:`~cstiffjax.io.robot.Noise` (σ's, m, rad, N); ``sensors``: ``{field: predicted
    (n, k)}`` for the on-board sensors (:func:`sensor_predictions`), in the order of
    :data:`SENSORS` (their columns are appended).

    **Returns:** ``(n, 6 + m [+ sensor columns])`` residuals, columns named by
    :func:`residual_channels`, ``0`` where nothing was measured.
    """
    meas = recordings.pose
    dp = (meas[:, :3] - pred_pose[:, :3]) / noise.position
    dr = jax.vmap(rotation_difference)(meas[:, 3:], pred_pose[:, 3:]) / noise.rotation
    dpose = jnp.where(recordings.pose_mask, jnp.concatenate([dp, dr], axis=1), 0.0)
    dt = jnp.where(recordings.tension_mask, (recordings.tensions - pred_tensions) / noise.tension, 0.0)
    cols = [dpose, dt]
    for f in SENSORS:
        if sensors is not None and f in sensors:
            d = angle_difference(getattr(recordings, f), sensors[f]) / getattr(noise, f)
            cols.append(jnp.where(getattr(recordings, f + "_mask"), d, 0.0))
    return jnp.concatenate(cols, axis=1)


def sensor_predictions(robot, pose: Float[Array, "n 6"], session: Float[Array, " n"], sensors: tuple[str, ...],
                       yaw_zero: Float[Array, " S"] | None = None,
                       swivel_offset: Float[Array, "S m"] | None = None) -> dict:
    """What the on-board ``sensors`` (:func:`sensor_fields`) read at the equilibrium poses.

    **Arguments:** ``robot`` (its swivel zeros, pulley axes and AHRS mounting); ``pose``
    ``(n, 6)`` m / rad, the platform's true poses; ``session`` ``(n,)`` each sample's session
    index (0..S-1); ``yaw_zero`` ``(S,)`` rad, the AHRS yaw zero of each session (default 0);
    ``swivel_offset`` ``(S, m)`` rad added to the swivel readings (default 0).

    **Returns:** ``{"swivel": (n, m), "ahrs": (n, 3)}`` rad, the fields in ``sensors`` only.
    """
    idx = jnp.asarray(session).astype(jnp.int32)
    out = {}
    if "swivel" in sensors:
        psi = jax.vmap(lambda p: swivel_angles(robot, p))(pose)
        out["swivel"] = psi if swivel_offset is None else psi + swivel_offset[idx]
    if "ahrs" in sensors:
        yaw = jnp.zeros(pose.shape[0]) if yaw_zero is None else yaw_zero[idx]
        out["ahrs"] = jax.vmap(lambda p, y: ahrs_angles(robot, p, y))(pose, yaw)
    return out


def num_effective(recordings, sensors: tuple[str, ...] | None = None) -> int:
    """Number of measured scalars (pose components, tensions and, by default, every
    measured on-board sensor value)."""
    sensors = sensor_fields(recordings) if sensors is None else sensors
    return int(measured_mask(recordings, sensors).sum())


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
    robot's ``[noise]`` sigmas (when ``noisy``). The default box is the Yuan et al. 2015 prototype's
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
    """``(params, rotations (N, 3)) -> (N, 3, 3)`` stiffness of a CSJM, Yang et al. 2019 eq. (45).

    ``params = {"T": (m,) cable tensions N, "k": (m,) cable-plus-drive stiffnesses N/m}``;
    the matrices come from :func:`cstiffjax.csjm.model.stiffness` (autodiff of the cable
    moment). ``quantity``: ``"K_D"`` (Yang et al.'s raw ``∂τ_A/∂ζ``, platform frame, eq.
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
