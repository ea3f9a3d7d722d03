"""Stiffness of a cable-driven spherical joint module (Yang et al. 2019) on SO(3), or its identification.

Model (default): the stiffness of the cables at --rotation with --tensions (or a uniform
--pretension), by autodiff of Yang et al. 2019 eq. (45): K = -dm/dθ in base-frame twist coordinates,
the covariant (Levi-Civita) K - ½ hat(m), and the paper's platform-frame K_D, K_L = -½ hat(τ_A)
and K = K_D + K_L (the paper prints K_L = -hat(τ_A): a wrong coefficient, see cstiffjax.csjm.model).

--identify RECORDINGS.csv: K_D = Ψ Ω⁺ from the recordings (row --reference is R0 with its load;
loads = measured tx ty tz + platform weight, platform frame), K = K_D + K_L, and the audit of
the antisymmetric part: what a conservative module must show under its load, what was
measured, and the excess (a non-conservative effect such as friction).
"""

import jax.numpy as jnp
import numpy as np

from cstiffjax.commands.common import check_outputs, finite_float, format_matrix, resolve_path, write_json
from cstiffjax.core.text import terminal
from cstiffjax.csjm import identify as ci
from cstiffjax.csjm import model as csjm
from cstiffjax.io.recordings import load_recordings
from cstiffjax.io.robot import robot_summary
from cstiffjax.io.robot_io import load_robot

NAME = "csjm"
HELP = "CSJM stiffness on SO(3) (Yang et al. 2019): model at a pose, or identification + symmetry audit"


def add_arguments(p):
    p.add_argument("robot", help="CSJM description TOML (kind = \"csjm\"), or a bundled example name (csjm.toml)")
    p.add_argument("--rotation", nargs=3, type=finite_float, default=[0.0, 0.0, 0.0], metavar=("RX", "RY", "RZ"),
                   help="pose as a rotation vector, base frame, rad (default 0 0 0)")
    p.add_argument("--tensions", nargs="+", type=finite_float, metavar="T", help="cable tensions N (one per cable)")
    p.add_argument("--pretension", type=float, default=100.0, help="uniform tension N when --tensions is absent")
    p.add_argument("--gravity", action="store_true", help="model: include the platform weight in K")
    p.add_argument("--identify", metavar="RECORDINGS", help="identify K from a CSJM recordings CSV")
    p.add_argument("--reference", type=int, default=0, help="row (0-based) of the reference pose R0 (default 0)")
    p.add_argument("--json", metavar="OUT", help="write the results as JSON")


def _print(name, M, unit="N·m/rad"):
    print(f"{name} [{unit}]:")
    print(format_matrix(M))


def _model(robot, args):
    if args.tensions is not None:
        if len(args.tensions) != robot.num_cables:
            raise ValueError(f"--tensions: got {len(args.tensions)} values, the robot has {robot.num_cables} cables")
        t = np.asarray(args.tensions)
    else:
        t = np.full(robot.num_cables, args.pretension)
    s = csjm.stiffness(robot, jnp.asarray(args.rotation), t, include_gravity=args.gravity)
    print("tensions [N]:", " ".join(f"{v:.4g}" for v in t))
    print("moment of the elements m [N·m, base frame]:", np.round(np.asarray(s.moment), 6).tolist())
    _print("K = -dm/dθ (base twist)", s.K)
    _print("covariant K - ½ hat(m)", s.covariant)
    print("applied load τ_A [N·m, platform frame]:", np.round(np.asarray(s.body_load), 6).tolist())
    _print("K_D (platform frame, Yang et al. 2019 eq. 48a)", s.K_D)
    _print("K = K_D - ½ hat(τ_A) (eq. 47, corrected coefficient)", s.covariant_body)
    vals = np.linalg.eigvalsh(np.asarray(s.covariant))
    print("eigen-stiffnesses of the covariant K [N·m/rad]:", " ".join(f"{v:.5g}" for v in vals))
    return {"rotation": args.rotation, "tensions": t, "moment": s.moment, "K": s.K, "K_covariant": s.covariant,
            "K_geometric": s.K_geometric, "K_elastic": s.K_elastic, "K_gravity": s.K_gravity,
            "body_load": s.body_load, "K_D": s.K_D, "K_L": s.K_L, "K_body": s.covariant_body,
            "eigenvalues": vals}


def _identify(robot, args):
    rec = load_recordings(resolve_path(args.identify), robot)
    ident = ci.identify_from_recordings(robot, rec, args.reference)
    audit = ci.audit_asymmetry(ident.K_D, ident.load, K_std=ident.K_D_std)
    print(f"{ident.num_measurements} measurements against reference row {args.reference}; "
          f"load ᴬτ0 = {np.round(np.asarray(ident.load), 4).tolist()} N·m (platform frame, weight included)")
    _print("K_D = Ψ Ω⁺ (eq. 49)", ident.K_D)
    _print("standard errors of K_D", ident.K_D_std)
    _print("K = K_D - ½ hat(ᴬτ0) (eq. 50, corrected coefficient)", ident.K)
    print(f"fit residual rms: {float(ident.residual_rms):.4g} N·m")
    print("antisymmetry vee(K_D - K_Dᵀ) [N·m/rad]:")
    print("  conservative module needs:", np.round(np.asarray(audit.conservative), 4).tolist())
    print("  measured:                 ", np.round(np.asarray(audit.measured), 4).tolist())
    print("  excess (non-conservative):", np.round(np.asarray(audit.excess), 4).tolist(),
          "±", np.round(np.asarray(audit.excess_std), 4).tolist())
    z = np.abs(np.asarray(audit.excess)) / np.asarray(audit.excess_std)
    if np.all(np.isfinite(z)):
        verdict = ("consistent with a conservative module (|excess| < 3 standard errors)" if np.all(z < 3) else
                   "NON-CONSERVATIVE excess (friction, hysteresis, drift, or a frame/sign convention of the data)")
        print(f"verdict: {verdict}")
    return {"recordings": args.identify, "reference": args.reference, "num_measurements": ident.num_measurements,
            "load": ident.load, "K_D": ident.K_D, "K_D_std": ident.K_D_std, "K_L": ident.K_L, "K": ident.K,
            "residual_rms": ident.residual_rms,
            "audit": {"measured": audit.measured, "conservative": audit.conservative, "excess": audit.excess,
                      "excess_std": audit.excess_std, "multiple": audit.multiple,
                      "relative_excess": audit.relative_excess}}


def run(args) -> int:
    robot_path = resolve_path(args.robot)
    check_outputs((robot_path, resolve_path(args.identify) if args.identify else None), files={"--json": args.json})
    robot = load_robot(robot_path)
    if robot.kind != "csjm":
        raise ValueError(f"{args.robot}: kind {robot.kind!r}; this command needs kind = \"csjm\"")
    print(terminal(robot_summary(robot)))
    out = {"robot": robot.name}
    out.update(_identify(robot, args) if args.identify else _model(robot, args))
    if args.json:
        write_json(args.json, out)
        print(terminal(f"wrote {args.json}"))
    return 0
