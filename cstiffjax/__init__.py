"""cstiffjax: stiffness, cable statics and calibration of cable-driven robots in JAX.

The curated public API. Importing the package enables float64 (``jax_enable_x64``) for the
whole process and, before JAX's backend starts, a faster-compiling XLA CPU emitter
(:mod:`cstiffjax.core.config`: what, why, and how to opt out with
``CSTIFFJAX_XLA_FAST_COMPILE=0``). The names below are imported on first use (``cstiffjax.stiffness``
imports the stiffness layer, and JAX, then): ``import cstiffjax`` itself imports no JAX, so the
command line answers ``--version`` and ``--help`` at once.

The sub-packages are layers, each importing only the ones before it (``cstiffjax/README.md``):
``core -> io -> cable -> statics -> stiffness -> workspace -> dynamics -> csjm -> plots ->
runtime -> commands``. Everything not listed here is an implementation detail.
"""

import importlib

from cstiffjax import stiffness as _stiffness_layer  # noqa: F401  (imports nothing; see below)
from cstiffjax.core import config as _config  # noqa: F401  (float64 first: before JAX is imported)

del stiffness  # noqa: F821  (the sub-package's name, set by its import: ``cstiffjax.stiffness`` is the function)

_API = {  # name -> (module, attribute; None: the module itself): imported on first use
    "CableLaw": ("cstiffjax.cable.laws", "CableLaw"),
    "CableRobot": ("cstiffjax.io.robot", "CableRobot"),
    "DiagnosisError": ("cstiffjax.core.errors", "DiagnosisError"),
    "Grid": ("cstiffjax.workspace.sweep", "Grid"),
    "Noise": ("cstiffjax.io.robot", "Noise"),
    "Recordings": ("cstiffjax.io.recordings", "Recordings"),
    "RecordingsError": ("cstiffjax.core.errors", "RecordingsError"),
    "RobotFileError": ("cstiffjax.core.errors", "RobotFileError"),
    "SolverError": ("cstiffjax.core.errors", "SolverError"),
    "SphericalJointModule": ("cstiffjax.io.robot", "SphericalJointModule"),
    "StaticsProblem": ("cstiffjax.statics.forward", "StaticsProblem"),
    "Status": ("cstiffjax.core.status", "Status"),
    "WrenchSet": ("cstiffjax.workspace.wrench_feasible", "WrenchSet"),
    "cable_force": ("cstiffjax.cable.laws", "cable_force"),
    "cable_lengths": ("cstiffjax.statics.geometry", "cable_lengths"),
    "cache_info": ("cstiffjax.runtime.cache", "cache_info"),
    "catenary": ("cstiffjax.cable.catenary", "catenary"),
    "covariant_stiffness": ("cstiffjax.stiffness.matrix", "covariant_stiffness"),
    "csjm_stiffness": ("cstiffjax.csjm.model", "stiffness"),
    "css_point": ("cstiffjax.stiffness.css", "css_point"),
    "ctfr": ("cstiffjax.stiffness.tensions", "ctfr"),
    "disable_cache": ("cstiffjax.runtime.cache", "disable_compilation_cache"),
    "distribute_tensions": ("cstiffjax.stiffness.tension_methods", "distribute_tensions"),
    "enable_cache": ("cstiffjax.runtime.cache", "enable_compilation_cache"),
    "example_path": ("cstiffjax.examples", "example_path"),
    "feasible_tensions": ("cstiffjax.stiffness.tensions", "feasible_tensions"),
    "forward_kinematics": ("cstiffjax.statics.forward", "forward_kinematics"),
    "forward_statics": ("cstiffjax.statics.forward", "forward_statics"),
    "frf": ("cstiffjax.dynamics.frf", "frf"),
    "gravity_wrench": ("cstiffjax.statics.geometry", "gravity_wrench"),
    "identify_csjm": ("cstiffjax.csjm.identify", "identify"),
    "interference": ("cstiffjax.workspace.interference", "interference"),
    "interference_model": ("cstiffjax.workspace.interference", "interference_model"),
    "inverse_statics": ("cstiffjax.statics.geometry", "inverse_statics"),
    "lie": ("cstiffjax.core.lie", None),
    "list_examples": ("cstiffjax.examples", "list_examples"),
    "load_recordings": ("cstiffjax.io.recordings", "load_recordings"),
    "load_robot": ("cstiffjax.io.robot_io", "load_robot"),
    "natural_frequencies": ("cstiffjax.dynamics.frf", "natural_frequencies"),
    "pose_error": ("cstiffjax.statics.sag", "pose_error"),
    "sagging_inverse_statics": ("cstiffjax.statics.sag", "sagging_inverse_statics"),
    "save_robot": ("cstiffjax.io.robot_io", "save_robot"),
    "stiffness": ("cstiffjax.stiffness.matrix", "stiffness"),
    "stiffness_split": ("cstiffjax.stiffness.matrix", "stiffness_split"),
    "structure_matrix": ("cstiffjax.statics.geometry", "structure_matrix"),
    "sweep": ("cstiffjax.workspace.sweep", "sweep"),
    "tension_space": ("cstiffjax.stiffness.tensions", "tension_space"),
    "wrench_closure": ("cstiffjax.workspace.wrench_closure", "wrench_closure"),
    "wrench_feasible": ("cstiffjax.workspace.wrench_feasible", "wrench_feasible"),
}

__version__ = "0.1.0"

__all__ = sorted(_API)  # the curated names, one list


def __dir__() -> list[str]:
    """``dir(package)`` lists the curated API only (the layers stay importable by path)."""
    return list(__all__)


def __getattr__(name: str):
    """The curated name ``name``, imported from its module on first use (then kept)."""
    try:
        module, attribute = _API[name]
    except KeyError:
        raise AttributeError(f"module 'cstiffjax' has no attribute {name!r}") from None
    value = importlib.import_module(module)
    value = value if attribute is None else getattr(value, attribute)
    globals()[name] = value
    return value
