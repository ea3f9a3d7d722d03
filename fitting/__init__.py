"""fitting: calibration, posterior checks and mismatch diagnosis of cstiffjax models.

The curated public API. ``fitting`` imports :mod:`cstiffjax`, never the reverse. Its
sub-packages are layers, each importing only the ones before it (``fitting/README.md``):
``calibration -> posterior -> effects -> diagnosis -> synth -> plots -> commands``.
"""

import cstiffjax  # noqa: F401  (float64 first)
from cstiffjax.runtime import programs as _programs

_programs.cover("fitting")  # serialized programs' keys hash this package's sources too

from fitting.calibration.least_squares import Fit as Fit  # noqa: E402
from fitting.calibration.least_squares import LSResult as LSResult  # noqa: E402
from fitting.calibration.least_squares import calibrate as calibrate  # noqa: E402
from fitting.calibration.least_squares import calibrate_csjm_stiffness as calibrate_csjm_stiffness  # noqa: E402
from fitting.calibration.least_squares import calibrate_model as calibrate_model  # noqa: E402
from fitting.calibration.least_squares import identifiability as identifiability  # noqa: E402
from fitting.calibration.least_squares import solve_least_squares as solve_least_squares  # noqa: E402
from fitting.calibration.models import cdpr_residuals as cdpr_residuals  # noqa: E402
from fitting.calibration.models import predict_cdpr as predict_cdpr  # noqa: E402
from fitting.calibration.models import residual_channels as residual_channels  # noqa: E402
from fitting.calibration.models import synthetic_recordings as synthetic_recordings  # noqa: E402
from fitting.calibration.parameters import CDPR_PARAMETERS as CDPR_PARAMETERS  # noqa: E402
from fitting.calibration.parameters import ParameterSpec as ParameterSpec  # noqa: E402
from fitting.calibration.parameters import apply_to_robot as apply_to_robot  # noqa: E402
from fitting.calibration.parameters import cdpr_spec as cdpr_spec  # noqa: E402
from fitting.diagnosis.diagnose import Diagnosis as Diagnosis  # noqa: E402
from fitting.diagnosis.diagnose import diagnose as diagnose  # noqa: E402
from fitting.diagnosis.report import write_report as write_report  # noqa: E402
from fitting.effects import EFFECTS as EFFECTS  # noqa: E402
from fitting.posterior.sampler import ChainTooShortError as ChainTooShortError  # noqa: E402
from fitting.posterior.sampler import Posterior as Posterior  # noqa: E402
from fitting.posterior.sampler import posterior_predictive_check as posterior_predictive_check  # noqa: E402
from fitting.posterior.sampler import sample_posterior as sample_posterior  # noqa: E402
from fitting.synth.generate import default_cases as default_cases  # noqa: E402
from fitting.synth.generate import write_case as write_case  # noqa: E402

__all__ = [
    "CDPR_PARAMETERS",
    "EFFECTS",
    "ChainTooShortError",
    "Diagnosis",
    "Fit",
    "LSResult",
    "ParameterSpec",
    "Posterior",
    "apply_to_robot",
    "calibrate",
    "calibrate_csjm_stiffness",
    "calibrate_model",
    "cdpr_residuals",
    "cdpr_spec",
    "default_cases",
    "diagnose",
    "identifiability",
    "posterior_predictive_check",
    "predict_cdpr",
    "residual_channels",
    "sample_posterior",
    "solve_least_squares",
    "synthetic_recordings",
    "write_case",
    "write_report",
]


def __dir__() -> list[str]:
    """``dir(package)`` lists the curated API only (the layers stay importable by path)."""
    return list(__all__)
