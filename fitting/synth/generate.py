"""Synthetic recordings with concealed effects, to prove the diagnosis blind.

``cstiffjax generate --out DIR`` (:mod:`fitting.commands.generate`) writes one folder per
case, ``DIR/CASE/robot.toml`` (the *nominal* description the diagnosis is given) and ``DIR/CASE/recordings.csv``, plus
``DIR/key.json``: what each case hides (the answer key, never read by the diagnosis).

Robots: ``proto`` (Yuan et al. 2015 prototype, geometry and noise of
``cstiffjax/examples/prototype_8mm.toml``, described as massless like
the bundled ``example01``/``example02``) and ``tcpr8`` (8 cables, ``cstiffjax/examples/tcpr8.toml``).
Each sample is a random pose and load in the workspace; the commanded lengths are those
that would hold it with a centred tension distribution; then the *true* robot (with the
concealed effects) settles where its physics says, and the instruments read it with
their own effects and Gaussian noise of the ``[noise]`` sigmas.

The cable-hardware cases (formats.md §1 v2) build the true robot by hand: swivel pulleys
at the anchors with vertical axes (``+z`` above the workspace centre, ``-z`` below), moved
attachments, the winch formula ``l0_ref + gain (l0 - l0_ref)`` on the commanded lengths
(``l0_ref`` the first command) and the load-cell gain on the true tensions.

The true equilibrium is solved independently of :mod:`fitting.effects` (the concealed
effects are written out here): by the cold start of
:func:`cstiffjax.statics.forward.forward_statics` (the nonlinear law through its ``tension``
hook), and every solution is checked by re-evaluating its wrench independently
(:func:`cstiffjax.statics.geometry.elastic_wrench`, per-cable catenary solves of
:mod:`cstiffjax.cable.catenary`, or the written-out nonlinear wrench); a failure raises.
"""

import hashlib
from dataclasses import dataclass, field
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from cstiffjax.cable.laws import CableLaw
from cstiffjax.core import lie
from cstiffjax.core.status import Status
from cstiffjax.examples import example_path
from cstiffjax.io import schema
from cstiffjax.io.recordings import write_recordings
from cstiffjax.io.robot_io import load_robot, save_robot
from cstiffjax.statics import geometry as statics
from cstiffjax.statics.forward import StaticsProblem, forward_statics

T_REF = 100.0  # N, as fitting.effects.T_REF (nonlinear law t = t_lin (1 + k t_lin / T_REF))


@dataclass
class Case:
    """One synthetic data set: ``robot`` (``proto``/``tcpr8``), ``truth`` {effect: parameters}
    (formats.md §3 names, plus ``periodic_length`` outside the vocabulary) and ``outliers``
    (number of gross outliers). ``expected`` is what a correct diagnosis reports. ``faults``
    {fault: parameters}: load-cell faults applied to the readings (:func:`apply_faults`), and
    ``sensor_faults`` the entries a correct diagnosis reports for them (``{kind, channel}``)."""

    name: str
    robot: str
    truth: dict = field(default_factory=dict)
    outliers: int = 0
    expected: list = field(default_factory=list)
    explained: bool = True
    faults: dict = field(default_factory=dict)
    sensor_faults: list = field(default_factory=list)


WORKSPACE = {  # centre, half ranges of position (m), rotation half range (rad), load ranges (N)
    "proto": dict(centre=(3.0, 0.0, 0.5), half=(0.45, 0.33, 0.28), rot=0.03, fz=(-390.0, -5.0), fxy=6.0,
                  t_centre=None, t_min=30.0),
    "tcpr8": dict(centre=(0.0, 0.0, 0.83), half=(0.2, 0.12, 0.25), rot=0.04, fz=(-40.0, 0.0), fxy=4.0,
                  t_centre=150.0, t_min=40.0),
}


def nominal_robot(kind: str):
    """The nominal description of ``proto`` (massless cables) or ``tcpr8``."""
    if kind == "proto":
        rb = load_robot(example_path("prototype_8mm.toml"))
        return eqx.tree_at(lambda r: r.mass_per_length, rb, jnp.zeros(rb.num_cables))
    if kind == "tcpr8":
        return load_robot(example_path("tcpr8.toml"))
    raise ValueError(f"unknown robot {kind!r}; allowed: 'proto', 'tcpr8'")


def default_cases(rng=None) -> list[Case]:
    """Every vocabulary effect, clean data, two effects at once (two old ones, and a
    hardware effect with an old one), an effect outside the vocabulary (a periodic length
    error) and clean data with gross outliers, on both robots (``cable_mass`` on ``proto``
    only: the TCPR-8's 0.47 mm cables weigh nothing)."""
    rng = np.random.default_rng(7) if rng is None else rng
    cases, hardware = [], []
    for kind in ("proto", "tcpr8"):
        m = 6 if kind == "proto" else 8
        soft = kind == "tcpr8"  # EA = 2.2 kN: strains of 10 %
        u = lambda lo, hi, shape=(): rng.uniform(lo, hi, shape) * rng.choice([-1, 1], shape)  # noqa: E731
        tr = {
            "clean": {},
            "anchor_offset": {"offset": u(1e-3, 4e-3, (m, 3))},
            "length_offset": {"offset": u(1e-3, 3e-3, (m,)) * (0.1 if soft else 1.0)},
            "length_drift": {"rate": u(1e-7, 3e-7, (m,)) * (0.1 if soft else 1.0)},
            "tension_sensor_bias": {"bias": u(1.0, 3.0, (m,))},
            "pose_frame_offset": {"rotation": u(5e-4, 2e-3, (3,)), "translation": u(1e-3, 3e-3, (3,))},
            "exit_friction": {"friction": 2.0},
            "nonlinear_elasticity": {"stiffening": 0.3 if not soft else -0.05},
            "platform_mass": {"mass_change": 1.5 if not soft else 0.1, "com_change": [0.01, -0.01, 0.0]},
        }
        if kind == "proto":
            tr["cable_mass"] = {"mass_per_length": 0.251}
        for name, p in tr.items():
            cases.append(Case(f"{kind}_{name}", kind, {name: p} if p else {}, 0, [name] if p else []))
        cases.append(Case(f"{kind}_two_effects", kind,
                          {"anchor_offset": tr["anchor_offset"], "tension_sensor_bias": tr["tension_sensor_bias"]},
                          0, ["anchor_offset", "tension_sensor_bias"]))
        cases.append(Case(f"{kind}_outside_vocabulary", kind,
                          {"periodic_length": {"amplitude": u(0.5e-3, 1e-3, (m,)) * (0.1 if soft else 1.0),
                                               "period": 1500.0, "phase": rng.uniform(0, 2 * np.pi, m)}},
                          0, [], explained=False))
        cases.append(Case(f"{kind}_outliers", kind, {}, 3, []))
        hardware += _hardware_cases(kind, m, tr)
    faults = [c for kind in ("proto", "tcpr8") for c in _fault_cases(kind)]
    return cases + hardware + faults  # appended, with their own random draws: the older cases keep their seeds


def _hardware_cases(kind, m, tr):
    """The cable-hardware cases (formats.md §1 v2) of one robot: 2.5 cm (proto) / 1.5 cm
    (tcpr8) swivel pulleys, winch gains off by 0.3-2 %, load cells 1.5 % high on every cable
    (proto, the issue's case) or off by 0.5-2 % per cable (tcpr8), attachment offsets of
    1-3 mm, and one hardware effect together with an old one (``tr``: the old truths)."""
    soft = kind == "tcpr8"
    rng = np.random.default_rng(70 + m)
    u = lambda lo, hi, shape=(): rng.uniform(lo, hi, shape) * rng.choice([-1, 1], shape)  # noqa: E731
    hw = {"pulley_kinematics": {"radius": 0.015 if soft else 0.025},
          "length_gain": {"gain": 1.0 + u(3e-3, 2e-2, (m,))},
          "tension_sensor_gain": {"gain": 1.0 + (u(5e-3, 2e-2, (m,)) if soft else np.full(m, 0.015))},
          "attachment_offset": {"offset": u(1e-3, 3e-3, (m, 3))}}
    cases = [Case(f"{kind}_{name}", kind, {name: p}, 0, [name]) for name, p in hw.items()]
    pair = ("tension_sensor_gain", "anchor_offset") if soft else ("pulley_kinematics", "tension_sensor_bias")
    cases.append(Case(f"{kind}_hardware_two_effects", kind, {e: (hw | tr)[e] for e in pair}, 0, list(pair)))
    return cases


def _fault_cases(kind):
    """The load-cell fault cases of one robot (nominal physics, faulty readings): one cell
    saturating at the 80th percentile of its readings, two channels exchanged, readings one
    sample late (one channel on ``proto``, every channel on ``tcpr8``), one channel rounded to
    5 σ, and every channel rounded to 1 σ (no fault: quantization at the noise level)."""
    m = 6 if kind == "proto" else 8
    rng = np.random.default_rng(90 + m)
    sigma = float(nominal_robot(kind).noise.tension)
    a, b, c, d = (int(i) + 1 for i in rng.permutation(m)[:4])
    col = lambda *js: [{"channel": f"t_{j}"} for j in js]  # noqa: E731
    late = [c] if kind == "proto" else list(range(1, m + 1))
    spec = {
        "tension_saturation": ({"channel": a, "percentile": 80.0}, [{"kind": "saturation", "channel": f"t_{a}"}]),
        "tension_channels_swapped": ({"channels": sorted([b, d])},
                                     [{"kind": "exchanged", "channel": f"t_{min(b, d)},t_{max(b, d)}"}]),
        "tension_delay": ({"channels": late, "samples": 1}, [{"kind": "delay"} | e for e in col(*late)]),
        "tension_quantization": ({"channels": [c], "step": 5.0 * sigma},
                                 [{"kind": "quantization"} | e for e in col(c)]),
        "tension_quantization_fine": ({"channels": list(range(1, m + 1)), "step": sigma}, []),
    }
    return [Case(f"{kind}_{name}", kind, {}, 0, [], True, {name.removesuffix("_fine"): p}, faults)
            for name, (p, faults) in spec.items()]


def apply_faults(ten, faults: dict) -> np.ndarray:
    """The readings ``ten`` (n, m) N (noise included, samples in time order) as faulty load
    cells give them (cables 1-based): ``tension_saturation`` {channel, percentile} (readings
    above that percentile of the channel read it), ``tension_channels_swapped`` {channels}
    (two columns exchanged), ``tension_delay`` {channels, samples} (each reading is the one of
    ``samples`` rows earlier; the first rows keep their own), ``tension_quantization``
    {channels, step} (rounded to multiples of ``step`` N)."""
    ten = np.array(ten, dtype=float)
    if "tension_saturation" in faults:
        p = faults["tension_saturation"]
        j = p["channel"] - 1
        ten[:, j] = np.minimum(ten[:, j], np.percentile(ten[:, j], p["percentile"]))
    if "tension_channels_swapped" in faults:
        i, j = (k - 1 for k in faults["tension_channels_swapped"]["channels"])
        ten[:, [i, j]] = ten[:, [j, i]]
    if "tension_delay" in faults:
        p = faults["tension_delay"]
        js, s = [k - 1 for k in p["channels"]], p["samples"]
        ten[s:, js] = ten[:-s, js].copy()
    if "tension_quantization" in faults:
        p = faults["tension_quantization"]
        js = [k - 1 for k in p["channels"]]
        ten[:, js] = np.round(ten[:, js] / p["step"]) * p["step"]
    return ten


# ---------------------------------------------------------------- true physics
def _stiffening(k):
    """The nonlinear law written out here: ``t = t_lin (1 + k t_lin / T_REF)``."""
    return jax.tree_util.Partial(lambda k, t: t * (1.0 + k * t / T_REF), k)


@eqx.filter_jit
def _settle(robot, l0, ext, pose0, law: CableLaw, stiffening: float | None):
    """True pose, exit tensions and residual wrench of one sample (``law``
    ``CableLaw.spring`` or ``CableLaw.catenary``; a ``stiffening`` coefficient: the spring
    with the nonlinear law :func:`_stiffening`): cold-start
    :func:`cstiffjax.statics.forward.forward_statics`, its residual re-evaluated
    independently (per-cable catenary solves of :func:`cstiffjax.statics.geometry.elastic_wrench`,
    or the written-out nonlinear wrench)."""
    if stiffening is not None:
        problem = StaticsProblem(robot, l0, ext, law, tension=_stiffening(stiffening))
        fs = forward_statics(problem, pose0=pose0, throw=False)
        tl = robot.EA * (statics.cable_lengths(robot, fs.pose) - l0) / l0
        W = statics.wrench(robot, fs.pose, tl * (1.0 + stiffening * tl / T_REF), ext)
    else:
        fs = forward_statics(StaticsProblem(robot, l0, ext, law), pose0=pose0, throw=False)
        W = statics.elastic_wrench(robot, fs.pose, l0, ext, law=law)
    return fs.pose, fs.tensions, jnp.where(fs.result == Status.successful, W, jnp.nan)


def settle_samples(robot, l0, ext, pose0, law: CableLaw, stiffening: float | None, name: str):
    """True poses and exit tensions of ``n`` samples, each settled by :func:`_settle`
    (``l0`` (n, m) m, ``ext`` (n, 6) N and N·m, ``pose0`` (n, 6) start poses; ``law`` and
    ``stiffening`` (None: linear cables) as there).

    **Returns:** ``(pose (n, 6), tensions (n, m) N)`` as writable numpy arrays.

    **Raises:** ``RuntimeError`` naming case ``name`` when a residual wrench exceeds
    1e-8 of the load scale (the failing samples listed) or a cable goes slack.
    """
    pose, ten, W = jax.vmap(lambda l, e, p0: _settle(robot, l, e, p0, law, stiffening))(
        jnp.asarray(l0), jnp.asarray(ext), jnp.asarray(pose0))
    scale = np.linalg.norm(np.asarray(robot.weight)) + np.linalg.norm(ext, axis=1) + 1.0
    err = np.max(np.abs(np.asarray(W)), axis=1) / scale
    if not np.all(err < 1e-8):
        raise RuntimeError(f"case {name}: true equilibrium not found for samples "
                           f"{np.flatnonzero(err >= 1e-8).tolist()} (max residual {err.max():.2e})")
    pose, ten = np.array(pose), np.array(ten)
    if np.any(ten <= 0):
        raise RuntimeError(f"case {name}: a cable went slack; change the workspace")
    return pose, ten


def _commanded_lengths(robot, pose, ext, t_centre):
    """Unstrained lengths that hold ``pose`` under ``ext`` with a centred tension
    distribution (min-norm deviation from ``t_centre`` in the null space), and the tensions."""
    S = np.asarray(statics.structure_matrix_closed_form(robot, pose))
    w = np.asarray(statics.gravity_wrench(robot, pose)) + ext
    tc = np.full(S.shape[1], 0.0 if t_centre is None else t_centre)
    t = tc - np.linalg.pinv(S) @ (S @ tc + w)
    L = np.asarray(statics.cable_lengths(robot, pose))
    EA = np.asarray(robot.EA)
    return L * EA / (EA + t), t


def _sample_inputs(robot, kind, n, rng):
    ws = WORKSPACE[kind]
    poses, exts, l0s = [], [], []
    while len(poses) < n:
        p = np.asarray(ws["centre"]) + rng.uniform(-1, 1, 3) * np.asarray(ws["half"])
        pose = np.concatenate([p, rng.uniform(-ws["rot"], ws["rot"], 3)])
        ext = np.array([*rng.uniform(-ws["fxy"], ws["fxy"], 2), rng.uniform(*ws["fz"]), 0, 0, 0])
        l0, t = _commanded_lengths(robot, pose, ext, ws["t_centre"])
        if t.min() < ws["t_min"]:
            continue
        poses.append(pose)
        exts.append(ext)
        l0s.append(l0)
    return np.array(poses), np.array(exts), np.array(l0s)


def simulate(case: Case, n: int = 90, seed: int = 0):
    """Recordings of ``case``: ``(nominal robot, columns dict)``, columns as formats.md §2."""
    rng = np.random.default_rng(seed)
    nominal = nominal_robot(case.robot)
    m = nominal.num_cables
    pose_cmd, ext, l0_cmd = _sample_inputs(nominal, case.robot, n, rng)
    time = 100.0 + np.cumsum(rng.uniform(60.0, 150.0, n))
    time -= time[0] - rng.uniform(60, 150)
    temperature = 20.5 + np.cumsum(rng.normal(0, 0.05, n))
    tr = case.truth
    true = nominal
    if "anchor_offset" in tr:
        true = eqx.tree_at(lambda r: r.anchors, true, true.anchors + np.asarray(tr["anchor_offset"]["offset"]))
    if "attachment_offset" in tr:  # platform frame
        true = eqx.tree_at(lambda r: r.attachments, true,
                           true.attachments + jnp.asarray(tr["attachment_offset"]["offset"]))
    if "pulley_kinematics" in tr:  # swivel pulleys at the anchors, axes vertical: up above the workspace
        up = np.asarray(true.anchors)[:, 2] > WORKSPACE[case.robot]["centre"][2]
        axes = np.zeros((m, 3))
        axes[:, 2] = np.where(up, 1.0, -1.0)
        true = eqx.tree_at(lambda r: (r.pulley_radius, r.pulley_axis), true,
                           (jnp.full(m, tr["pulley_kinematics"]["radius"]), jnp.asarray(axes)))
    if "platform_mass" in tr:
        p = tr["platform_mass"]
        true = eqx.tree_at(lambda r: (r.platform_mass, r.com), true,
                           (true.platform_mass + p["mass_change"], true.com + np.asarray(p["com_change"])))
    law, k = CableLaw.spring, None
    if "cable_mass" in tr:
        law = CableLaw.catenary
        true = eqx.tree_at(lambda r: r.mass_per_length, true, jnp.full(m, tr["cable_mass"]["mass_per_length"]))
    if "nonlinear_elasticity" in tr:  # the stiffening spring (the models hold it with a spring law only)
        law, k = CableLaw.spring, tr["nonlinear_elasticity"]["stiffening"]
    t_rel = time - time[0]
    l0_true = l0_cmd.copy()
    if "length_gain" in tr:  # winch: true change = gain x commanded change from the first command
        l0_true = l0_cmd[0] + np.asarray(tr["length_gain"]["gain"]) * (l0_cmd - l0_cmd[0])
    if "length_offset" in tr:
        l0_true += np.asarray(tr["length_offset"]["offset"])
    if "length_drift" in tr:
        l0_true += np.asarray(tr["length_drift"]["rate"]) * t_rel[:, None]
    if "periodic_length" in tr:
        p = tr["periodic_length"]
        l0_true += np.asarray(p["amplitude"]) * np.sin(2 * np.pi * t_rel[:, None] / p["period"] + p["phase"])
    pose, ten = settle_samples(true, l0_true, ext, pose_cmd, law, k, case.name)
    if "pose_frame_offset" in tr:  # the tracker's frame is misregistered
        p = tr["pose_frame_offset"]
        Ro = np.asarray(lie.exp(np.asarray(p["rotation"])))
        pos = pose[:, :3] @ Ro.T + np.asarray(p["translation"])
        rot = np.array([np.asarray(lie.log(Ro @ lie.exp(rv))) for rv in pose[:, 3:]])
        pose = np.concatenate([pos, rot], axis=1)
    if "tension_sensor_gain" in tr:  # load cell: reading = gain x true tension (+ bias below)
        ten = ten * np.asarray(tr["tension_sensor_gain"]["gain"])
    if "tension_sensor_bias" in tr:
        ten = ten + np.asarray(tr["tension_sensor_bias"]["bias"])
    if "exit_friction" in tr:
        direction = np.zeros_like(l0_cmd)
        direction[1:] = np.sign(np.diff(l0_cmd, axis=0))
        ten = ten - direction * tr["exit_friction"]["friction"]
    noise = nominal.noise
    pos_m = pose[:, :3] + rng.normal(0, float(noise.position), (n, 3))
    rot_m = np.array([np.asarray(lie.log(lie.exp(rng.normal(0, float(noise.rotation), 3)) @ lie.exp(rv)))
                      for rv in pose[:, 3:]])
    ten_m = ten + rng.normal(0, float(noise.tension), ten.shape)
    bad = np.sort(rng.choice(np.arange(5, n), case.outliers, replace=False)) if case.outliers else []
    for i in bad:  # gross outliers: a tracker glitch and a load-cell spike
        pos_m[i] += rng.choice([-1, 1], 3) * 3e-3 * (1e-2 if case.robot == "tcpr8" else 1)
        ten_m[i, rng.integers(m)] += 40.0
    ten_m = apply_faults(ten_m, case.faults)
    cols = schema.to_columns(m, {"time": time, "l0": l0_cmd, "wrench": ext, "pose": np.hstack([pos_m, rot_m]),
                                 "tensions": ten_m}, {"temperature": np.round(temperature, 2)})
    return nominal, cols, [int(i) + 1 for i in bad]


def case_seed(base: int, name: str) -> int:
    """The seed of the case ``name`` under the base seed ``base``: a stable hash of both
    (SHA-256, 48 bits, exact in JSON), so a case's data depend on the base seed and its name
    only, not on which other cases are generated with it nor in which order.

    **Arguments:** ``base``: the user's ``--seed``; ``name``: the case name.

    **Returns:** a non-negative integer below 2**48.
    """
    digest = hashlib.sha256(f"cstiffjax generate {int(base)} {name}".encode()).digest()
    return int.from_bytes(digest[:6], "big")


def write_case(case: Case, out_dir, n: int = 90, seed: int = 0) -> dict:
    """Write ``out_dir/robot.toml`` and ``out_dir/recordings.csv``; return the key entry."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    robot, cols, bad = simulate(case, n, seed)
    robot = _renamed(robot, case.name)
    save_robot(robot, out / "robot.toml")
    write_recordings(cols, out / "recordings.csv")
    return key_entry(case, n, seed, bad)


def key_entry(case: Case, n: int, seed: int, outliers: list[int]) -> dict:
    """The answer-key entry of a written case (``cstiffjax/io/outputs.md``, ``generate``):
    name, robot, samples ``n``, ``seed``, what a correct diagnosis reports and the
    ``outliers`` (file lines) put in."""
    return {"case": case.name, "robot": case.robot, "samples": n, "seed": seed, "expected": case.expected,
            "explained": case.explained, "outliers": outliers, "truth": _jsonable(case.truth),
            "faults": _jsonable(case.faults), "sensor_faults": case.sensor_faults}


def _renamed(robot, name):
    import dataclasses

    return dataclasses.replace(robot, name=name)


def _jsonable(x):
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    a = np.asarray(x)
    return a.item() if a.ndim == 0 else a.tolist()
