"""Named, transformed, optionally-free model parameters.

A :class:`ParameterSpec` (static metadata) says which named quantities a fit knows,
their shapes, units and transforms, and which ones are *free*. It converts between

- a dict of **physical values** ``{name: array}`` (every known parameter), and
- a flat **unconstrained vector** ``θ`` holding only the free ones, with
  ``value = transform(θ)``: ``"identity"``; ``"log"`` (``value = exp θ``, keeps
  positive things positive); ``("bounded", lo, hi)`` (``lo + (hi-lo) sigmoid θ``).

Optional Gaussian priors ``{name: (mean, std)}`` (physical units, broadcast to the
parameter's shape) become extra whitened residuals ``(value - mean)/std``, i.e. the
fit maximizes the posterior.

:func:`cdpr_spec` builds the spec of the CDPR calibration parameters:

=================  =======  =====  ==========================================================
name               shape    unit   meaning
=================  =======  =====  ==========================================================
``EA``             (m,)     N      axial stiffness per cable (log)
``mass_per_length`` (m,)    kg/m   cable mass per length (log; only matters for ``catenary``)
``length_offset``  (m,)     m      ``l0_true = l0_commanded + length_offset`` (encoder zero)
``tension_offset`` (m,)     N      ``t_measured = t_true + tension_offset`` (load-cell bias)
``anchors``        (m, 3)   m      exit points, base frame
``attachments``    (m, 3)   m      attachment points, platform frame
``platform_mass``  ()       kg     (log)
``com``            (3,)     m      centre of mass, platform frame
``frame_rotation`` (3,)     rad    pose-measurement frame: rotation vector ``ρ`` and
``frame_translation`` (3,)  m      translation ``c``: ``p_meas = exp(ρ) p + c``, ``R_meas = exp(ρ) R``
``pulley_radius``  (m,)     m      swivel-pulley radius per cable (formats.md §1 v2; identity)
``length_gain``    (m,)     1      winch transmission gain per cable (log)
``tension_gain``   (m,)     1      load-cell gain per cable (log)
``shared_pulley_radius`` () m      added to every cable's ``pulley_radius`` (nominal 0)
``shared_length_gain``   () 1      multiplies every ``length_gain`` (nominal 1; log)
``shared_tension_gain``  () 1      multiplies every ``tension_gain`` (nominal 1; log)
``length_zero``    (S, m)   m      relative lengths (``[sensors] lengths = "relative"``): the
                                   constant of each cable and session, ``l0_true = l0 + c``
``yaw_zero``       (S,)     rad    the AHRS's yaw zero of each session
``ahrs_mounting``  (3,)     rad    rotation vector of the AHRS frame in the platform frame
``swivel_offset``  (S, m)   rad    added to every predicted swivel reading of a cable and session
=================  =======  =====  ==========================================================

``S`` is the number of recording sessions (formats.md §2 version 3; 1 for a file without a
``session`` column). :func:`fitting.calibration.least_squares.calibrate` frees
``length_zero`` when the lengths are relative and ``yaw_zero`` when an AHRS was recorded:
they are the recordings' unknown zeros, not properties of the robot.

The hardware parameters act through the robot (:func:`apply_to_robot`), hence through the
cable path (:mod:`cstiffjax.cable.path`) and the gains of :func:`fitting.calibration.models.predict_cdpr`.
A fitted pulley radius needs swivel axes on the robot (stated, or assumed by the
``pulley_kinematics`` effect). Parameters that trade off against each other are listed by
:func:`known_trade_offs`.
"""

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from cstiffjax.core import lie


@dataclasses.dataclass(frozen=True)
class ParameterSpec:
    """Static description of the parameters of a model (hashable; safe as jit static).

    ``names``/``shapes``/``transforms``/``units`` are aligned tuples over every known
    parameter; ``free`` the free names in that order; ``session_ids`` the recordings' own
    session ids (formats.md §2 ``session``) of the per-session parameters' rows, in row order
    (empty: rows ``0..S-1``, as a file without a ``session`` column numbers its one session).
    """

    names: tuple[str, ...]
    shapes: tuple[tuple[int, ...], ...]
    transforms: tuple
    units: tuple[str, ...]
    free: tuple[str, ...]
    session_ids: tuple[int, ...] = ()

    def __post_init__(self):
        unknown = [f for f in self.free if f not in self.names]
        if unknown:
            raise ValueError(f"unknown free parameter(s) {unknown}; allowed: {', '.join(self.names)}")
        if not self.free:
            raise ValueError(f"no free parameter given; choose among: {', '.join(self.names)}")
        if len(set(self.free)) != len(self.free):
            raise ValueError(f"free parameter listed twice: {list(self.free)}")

    # ------------------------------------------------------------------ bookkeeping
    def shape(self, name):
        return self.shapes[self.names.index(name)]

    def transform(self, name):
        return self.transforms[self.names.index(name)]

    def unit(self, name):
        return self.units[self.names.index(name)]

    def size(self, name) -> int:
        return int(np.prod(self.shape(name), dtype=int))

    @property
    def num_free(self) -> int:
        return sum(self.size(n) for n in self.free)

    def session_id(self, row: int) -> int:
        """The recordings' session id of row ``row`` of a per-session parameter."""
        return int(self.session_ids[row]) if self.session_ids else int(row)

    def flat_names(self) -> list[str]:
        """One label per entry of ``θ``, e.g. ``EA[1]``, ``anchors[2].z`` (1-based cables),
        ``yaw_zero[session 7]`` (the recordings' own session id, :attr:`session_ids`)."""
        out = []
        for n in self.free:
            shape = self.shape(n)
            if shape == ():
                out.append(n)
            elif len(shape) == 1:
                xyz = n in ("com", "frame_rotation", "frame_translation", "ahrs_mounting")
                out += [f"{n}.{'xyz'[i]}" if xyz else f"{n}[session {self.session_id(i)}]" if n in SESSION_PARAMETERS
                        else f"{n}[{i + 1}]" for i in range(shape[0])]
            elif n in SESSION_PARAMETERS:  # (sessions, cables)
                out += [f"{n}[session {self.session_id(i)}][{j + 1}]" for i in range(shape[0]) for j in range(shape[1])]
            else:
                out += [f"{n}[{i + 1}].{'xyz'[j]}" if shape[1] == 3 else f"{n}[{i + 1}][{j + 1}]"
                        for i in range(shape[0]) for j in range(shape[1])]
        return out

    # ------------------------------------------------------------------ transforms
    def check_values(self, values: dict) -> dict:
        """``values`` as float64 arrays of the right shapes; positive where log-transformed."""
        missing = [n for n in self.names if n not in values]
        if missing:
            raise ValueError(f"parameter values missing for {missing}")
        out = {}
        for n in self.names:
            v = jnp.asarray(values[n], dtype=jnp.float64)
            if v.shape != self.shape(n):
                raise ValueError(f"parameter {n!r} must have shape {self.shape(n)}, got {v.shape}")
            if not isinstance(v, jax.core.Tracer) and n in self.free:
                _check_in_domain(n, np.asarray(v), self.transform(n))
            out[n] = v
        return out

    def to_theta(self, values: dict) -> jax.Array:
        """Flat unconstrained vector of the free parameters."""
        parts = [_inverse(self.transform(n), jnp.asarray(values[n], dtype=jnp.float64)).ravel() for n in self.free]
        return jnp.concatenate(parts)

    def from_theta(self, theta, values: dict) -> dict:
        """Physical values: the free ones from ``theta``, the rest from ``values``."""
        out = dict(values)
        i = 0
        for n in self.free:
            k = self.size(n)
            out[n] = _forward(self.transform(n), theta[i:i + k]).reshape(self.shape(n))
            i += k
        return out

    def free_vector(self, values: dict) -> jax.Array:
        """The free physical values, flattened in ``θ`` order."""
        return jnp.concatenate([jnp.asarray(values[n]).ravel() for n in self.free])

    def value_jacobian(self, theta) -> jax.Array:
        """``∂(free physical values)/∂θ`` (diagonal for these element-wise transforms)."""
        dummy = {n: jnp.zeros(s) for n, s in zip(self.names, self.shapes, strict=True)}
        return jax.jacfwd(lambda t: self.free_vector(self.from_theta(t, dummy)))(theta)

    def log_abs_det_jacobian(self, theta) -> jax.Array:
        """``log|∂v/∂θ|`` of the (element-wise) transforms: turns a density flat in the
        physical values into one over ``θ`` (used by the posterior sampler)."""
        total, i = jnp.zeros(()), 0
        for n in self.free:
            k, tr = self.size(n), self.transform(n)
            u = theta[i:i + k]
            if tr == "log":
                total = total + jnp.sum(u)
            elif isinstance(tr, tuple):
                total = total + jnp.sum(jnp.log(tr[2] - tr[1]) + jax.nn.log_sigmoid(u) + jax.nn.log_sigmoid(-u))
            i += k
        return total

    def prior_residuals(self, values: dict, priors) -> jax.Array:
        """Whitened prior residuals ``(value - mean)/std`` (empty without priors)."""
        if not priors:
            return jnp.zeros(0)
        return jnp.concatenate([((values[n] - jnp.asarray(mu)) / jnp.asarray(sd)).ravel() * jnp.ones(self.size(n))
                                for n, (mu, sd) in priors.items()])

    def check_priors(self, priors):
        if not priors:
            return {}
        for n, ms in priors.items():
            if n not in self.names:
                raise ValueError(f"prior on unknown parameter {n!r}; allowed: {', '.join(self.names)}")
            if len(ms) != 2 or np.any(np.asarray(ms[1]) <= 0):
                raise ValueError(f"prior on {n!r} must be (mean, std) with std > 0, got {ms!r}")
        return dict(priors)

    def unflatten(self, flat) -> dict:
        """Split a flat vector in ``θ`` order into ``{free name: array}``."""
        out, i = {}, 0
        for n in self.free:
            k = self.size(n)
            out[n] = jnp.asarray(flat[i:i + k]).reshape(self.shape(n))
            i += k
        return out


def _forward(tr, u):
    if tr == "identity":
        return u
    if tr == "log":
        return jnp.exp(u)
    _, lo, hi = tr
    return lo + (hi - lo) * jax.nn.sigmoid(u)


def _inverse(tr, v):
    if tr == "identity":
        return v
    if tr == "log":
        return jnp.log(v)
    _, lo, hi = tr
    s = (v - lo) / (hi - lo)
    return jnp.log(s) - jnp.log1p(-s)


def _check_in_domain(name, v, tr):
    if not np.all(np.isfinite(v)):
        raise ValueError(f"parameter {name!r} has a non-finite value {v}")
    if tr == "log" and np.any(v <= 0):
        raise ValueError(f"free parameter {name!r} must be > 0 (log transform), got {v}; "
                         f"give a positive starting value")
    if isinstance(tr, tuple) and np.any((v <= tr[1]) | (v >= tr[2])):
        raise ValueError(f"free parameter {name!r} must lie strictly inside ({tr[1]}, {tr[2]}), got {v}")


# --------------------------------------------------------------------- CDPR parameters
HARDWARE_PARAMETERS = ("pulley_radius", "length_gain", "tension_gain", "shared_pulley_radius",
                       "shared_length_gain", "shared_tension_gain")
SENSOR_PARAMETERS = ("length_zero", "yaw_zero", "ahrs_mounting", "swivel_offset")  # formats.md version 3
CDPR_PARAMETERS = ("EA", "mass_per_length", "length_offset", "tension_offset", "anchors", "attachments",
                   "platform_mass", "com", "frame_rotation", "frame_translation", *HARDWARE_PARAMETERS,
                   *SENSOR_PARAMETERS)
_UNITS = {"EA": "N", "mass_per_length": "kg/m", "length_offset": "m", "tension_offset": "N", "anchors": "m",
          "attachments": "m", "platform_mass": "kg", "com": "m", "frame_rotation": "rad", "frame_translation": "m",
          "pulley_radius": "m", "length_gain": "1", "tension_gain": "1", "shared_pulley_radius": "m",
          "shared_length_gain": "1", "shared_tension_gain": "1", "length_zero": "m", "yaw_zero": "rad",
          "ahrs_mounting": "rad", "swivel_offset": "rad"}
_LOG = ("EA", "mass_per_length", "platform_mass", "length_gain", "tension_gain", "shared_length_gain",
        "shared_tension_gain")

# Pairs of free parameters whose effects on the recordings are nearly alike, and why.
TRADE_OFFS = (
    (("pulley_radius", "shared_pulley_radius"), ("anchors",),
     "a pulley radius lengthens every cable by about r*beta and moves its free span's start by about r: "
     "anchor positions absorb most of it"),
    (("length_gain", "shared_length_gain"), ("length_offset",),
     "a winch gain changes l0 by (g-1)(l0 - l0_ref): over a small range of lengths it looks like a length offset"),
    (("length_gain", "shared_length_gain"), ("EA",),
     "a winch gain scales the commanded length changes as a softer or stiffer cable would"),
    (("tension_gain", "shared_tension_gain"), ("platform_mass", "tension_offset"),
     "a load-cell gain scales the readings: with little load variation it looks like a heavier platform "
     "or a tension bias"),
    (("pulley_radius",), ("shared_pulley_radius",), "the shared radius is the mean of the per-cable ones"),
    (("length_gain",), ("shared_length_gain",), "the shared gain multiplies the per-cable ones"),
    (("tension_gain",), ("shared_tension_gain",), "the shared gain multiplies the per-cable ones"),
    (("length_zero",), ("anchors", "attachments", "length_offset"),
     "a length zero (encoders homed at one pose) moves every length of a cable by a constant, as an anchor or "
     "attachment moved along the cable at the homing pose does: only poses far from the homing pose separate them"),
    (("length_zero",), ("length_gain", "shared_length_gain"),
     "a winch gain scales the changes from the homing pose, a length zero shifts them all"),
    (("yaw_zero",), ("ahrs_mounting",), "a rotation of the sensor about the vertical is the yaw zero of every session"),
    (("swivel_offset",), ("anchors",), "an anchor moved sideways turns a pulley's plane by a nearly constant angle"),
)


def known_trade_offs(free) -> list[str]:
    """Messages naming the free parameters of ``free`` that trade off (:data:`TRADE_OFFS`)."""
    free = set(free)
    return [f"{'/'.join(sorted(free & set(a)))} trades off against {'/'.join(sorted(free & set(b)))}: {why}"
            for a, b, why in TRADE_OFFS if free & set(a) and free & set(b)]


SESSION_PARAMETERS = ("length_zero", "yaw_zero", "swivel_offset")
"""The parameters with one row per recording session (named by the recordings' session ids)."""


def cdpr_spec(m: int, free, bounds=None, sessions: int = 1, session_ids=()) -> ParameterSpec:
    """:class:`ParameterSpec` of the CDPR calibration parameters (module table) for ``m`` cables.

    **Arguments:** ``free``: names (a string with commas or a sequence); ``bounds``:
    optional ``{name: (lo, hi)}`` replacing that parameter's transform by a bounded one;
    ``sessions``: the number ``S`` of recording sessions (the per-session zeros' rows);
    ``session_ids``: their ids in the recordings, ascending (default ``0..S-1``).
    """
    if isinstance(free, str):
        free = tuple(f.strip() for f in free.split(",") if f.strip())
    shapes = {"EA": (m,), "mass_per_length": (m,), "length_offset": (m,), "tension_offset": (m,),
              "anchors": (m, 3), "attachments": (m, 3), "platform_mass": (), "com": (3,),
              "frame_rotation": (3,), "frame_translation": (3,), "pulley_radius": (m,), "length_gain": (m,),
              "tension_gain": (m,), "shared_pulley_radius": (), "shared_length_gain": (),
              "shared_tension_gain": (), "length_zero": (sessions, m), "yaw_zero": (sessions,),
              "ahrs_mounting": (3,), "swivel_offset": (sessions, m)}
    bounds = bounds or {}
    for n in bounds:
        if n not in CDPR_PARAMETERS:
            raise ValueError(f"bounds given for unknown parameter {n!r}; allowed: {', '.join(CDPR_PARAMETERS)}")
    tr = tuple(("bounded", float(bounds[n][0]), float(bounds[n][1])) if n in bounds
               else ("log" if n in _LOG else "identity") for n in CDPR_PARAMETERS)
    return ParameterSpec(CDPR_PARAMETERS, tuple(shapes[n] for n in CDPR_PARAMETERS), tr,
                         tuple(_UNITS[n] for n in CDPR_PARAMETERS), tuple(free),
                         tuple(int(i) for i in session_ids))


def cdpr_values(robot, sessions: int = 1) -> dict:
    """Nominal physical values of every CDPR parameter (offsets zero) from ``robot``, with
    ``sessions`` rows of the per-session zeros."""
    m = robot.num_cables
    return {"EA": robot.EA, "mass_per_length": robot.mass_per_length, "length_offset": jnp.zeros(m),
            "tension_offset": jnp.zeros(m), "anchors": robot.anchors, "attachments": robot.attachments,
            "platform_mass": robot.platform_mass, "com": robot.com, "frame_rotation": jnp.zeros(3),
            "frame_translation": jnp.zeros(3), "pulley_radius": robot.pulley_radius,
            "length_gain": robot.length_gain, "tension_gain": robot.tension_gain,
            "shared_pulley_radius": jnp.zeros(()), "shared_length_gain": jnp.ones(()),
            "shared_tension_gain": jnp.ones(()), "length_zero": jnp.zeros((sessions, m)),
            "yaw_zero": jnp.zeros(sessions), "ahrs_mounting": robot.ahrs_mounting,
            "swivel_offset": jnp.zeros((sessions, m))}


def _hardware_values(values: dict) -> dict:
    """Per-cable hardware fields combined with their shared factors (nominal: unchanged)."""
    out = {}
    if "pulley_radius" in values:
        out["pulley_radius"] = values["pulley_radius"] + values.get("shared_pulley_radius", 0.0)
    for g in ("length_gain", "tension_gain"):
        if g in values:
            out[g] = values[g] * values.get(f"shared_{g}", 1.0)
    return out


def apply_to_robot(robot, values: dict):
    """``robot`` with its physical fields replaced by ``values`` (those present)."""
    values = {**values, **_hardware_values(values)}
    fields = [f for f in ("EA", "mass_per_length", "anchors", "attachments", "platform_mass", "com",
                          "pulley_radius", "length_gain", "tension_gain", "ahrs_mounting") if f in values]
    return eqx.tree_at(lambda r: [getattr(r, f) for f in fields], robot, [values[f] for f in fields])


def corrected_inputs(l0, values: dict, session=None):
    """True unstrained lengths from the commanded ones: ``l0 + length_offset`` (+ the
    session's ``length_zero`` when ``session``, ``(n,)`` indices 0..S-1, is given), m."""
    l0 = l0 + values["length_offset"] if "length_offset" in values else l0
    if session is not None and "length_zero" in values:
        l0 = l0 + values["length_zero"][jnp.asarray(session).astype(jnp.int32)]
    return l0


def measured_outputs(pose, tensions, values: dict):
    """What the instruments read for a true ``pose`` (n, 6) and exit tensions (n, m):
    pose in the measurement frame (``frame_rotation``, ``frame_translation``) and
    tensions plus ``tension_offset``."""
    if "frame_rotation" in values:
        Rf = lie.exp(values["frame_rotation"])
        p = pose[:, :3] @ Rf.T + values["frame_translation"]
        rv = jax.vmap(lambda v: lie.log(Rf @ lie.exp(v)))(pose[:, 3:])
        pose = jnp.concatenate([p, rv], axis=1)
    if "tension_offset" in values:
        tensions = tensions + values["tension_offset"]
    return pose, tensions
