"""cstiffjax: stiffness, cable statics and calibration of cable-driven robots in JAX.

The curated public API. Importing the package enables float64 (``jax_enable_x64``) for the
whole process and, before JAX's backend starts, a faster-compiling XLA CPU emitter
(:mod:`cstiffjax.core.config`: what, why, and how to opt out with
``CSTIFFJAX_XLA_FAST_COMPILE=0``).

The sub-packages are layers, each importing only the ones before it (``cstiffjax/README.md``):
``core -> io -> cable -> statics -> stiffness -> workspace -> dynamics -> csjm -> plots ->
runtime -> commands``. Everything not listed here is an implementation detail.
"""

from cstiffjax.cable.catenary import catenary as catenary
from cstiffjax.cable.laws import CableLaw as CableLaw
from cstiffjax.cable.laws import cable_force as cable_force
from cstiffjax.core import config as _config  # noqa: F401  (float64 first)
from cstiffjax.core import lie as lie
from cstiffjax.core.errors import DiagnosisError as DiagnosisError
from cstiffjax.core.errors import RecordingsError as RecordingsError
from cstiffjax.core.errors import RobotFileError as RobotFileError
from cstiffjax.core.errors import SolverError as SolverError
from cstiffjax.core.status import Status as Status
from cstiffjax.csjm.identify import identify as identify_csjm
from cstiffjax.csjm.model import stiffness as csjm_stiffness
from cstiffjax.dynamics.frf import frf as frf
from cstiffjax.dynamics.frf import natural_frequencies as natural_frequencies
from cstiffjax.examples import example_path as example_path
from cstiffjax.examples import list_examples as list_examples
from cstiffjax.io.recordings import Recordings as Recordings
from cstiffjax.io.recordings import load_recordings as load_recordings
from cstiffjax.io.robot import CableRobot as CableRobot
from cstiffjax.io.robot import Noise as Noise
from cstiffjax.io.robot import SphericalJointModule as SphericalJointModule
from cstiffjax.io.robot_io import load_robot as load_robot
from cstiffjax.io.robot_io import save_robot as save_robot
from cstiffjax.runtime.cache import cache_info as cache_info
from cstiffjax.runtime.cache import disable_compilation_cache as disable_cache
from cstiffjax.runtime.cache import enable_compilation_cache as enable_cache
from cstiffjax.statics.forward import StaticsProblem as StaticsProblem
from cstiffjax.statics.forward import forward_kinematics as forward_kinematics
from cstiffjax.statics.forward import forward_statics as forward_statics
from cstiffjax.statics.geometry import cable_lengths as cable_lengths
from cstiffjax.statics.geometry import gravity_wrench as gravity_wrench
from cstiffjax.statics.geometry import inverse_statics as inverse_statics
from cstiffjax.statics.geometry import structure_matrix as structure_matrix
from cstiffjax.statics.sag import pose_error as pose_error
from cstiffjax.statics.sag import sagging_inverse_statics as sagging_inverse_statics
from cstiffjax.stiffness.css import css_point as css_point
from cstiffjax.stiffness.matrix import covariant_stiffness as covariant_stiffness
from cstiffjax.stiffness.matrix import stiffness as stiffness
from cstiffjax.stiffness.matrix import stiffness_split as stiffness_split
from cstiffjax.stiffness.tension_methods import distribute_tensions as distribute_tensions
from cstiffjax.stiffness.tensions import ctfr as ctfr
from cstiffjax.stiffness.tensions import feasible_tensions as feasible_tensions
from cstiffjax.stiffness.tensions import tension_space as tension_space
from cstiffjax.workspace.interference import interference as interference
from cstiffjax.workspace.interference import interference_model as interference_model
from cstiffjax.workspace.sweep import Grid as Grid
from cstiffjax.workspace.sweep import sweep as sweep
from cstiffjax.workspace.wrench_closure import wrench_closure as wrench_closure
from cstiffjax.workspace.wrench_feasible import WrenchSet as WrenchSet
from cstiffjax.workspace.wrench_feasible import wrench_feasible as wrench_feasible

__version__ = "0.1.0"

__all__ = [
    "CableLaw",
    "CableRobot",
    "DiagnosisError",
    "Grid",
    "Noise",
    "Recordings",
    "RecordingsError",
    "RobotFileError",
    "SolverError",
    "SphericalJointModule",
    "StaticsProblem",
    "Status",
    "WrenchSet",
    "cable_force",
    "cable_lengths",
    "cache_info",
    "catenary",
    "covariant_stiffness",
    "csjm_stiffness",
    "css_point",
    "ctfr",
    "disable_cache",
    "distribute_tensions",
    "enable_cache",
    "example_path",
    "feasible_tensions",
    "forward_kinematics",
    "forward_statics",
    "frf",
    "gravity_wrench",
    "identify_csjm",
    "interference",
    "interference_model",
    "inverse_statics",
    "lie",
    "list_examples",
    "load_recordings",
    "load_robot",
    "natural_frequencies",
    "pose_error",
    "sagging_inverse_statics",
    "save_robot",
    "stiffness",
    "stiffness_split",
    "structure_matrix",
    "sweep",
    "tension_space",
    "wrench_closure",
    "wrench_feasible",
]


def __dir__() -> list[str]:
    """``dir(package)`` lists the curated API only (the layers stay importable by path)."""
    return list(__all__)
