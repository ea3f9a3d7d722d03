"""fitting: calibration and posterior checks of cstiffjax models (imports cstiffjax, never the reverse).

- :func:`calibrate` (CDPR parameters from recordings), :func:`calibrate_model` (any
  ``(params, inputs) -> predictions``), :func:`calibrate_csjm_stiffness` (seed 000 eq. 45)
  -> :class:`Fit`; core :func:`solve_least_squares` -> :class:`LSResult`.
- :func:`sample_posterior` (emcee) -> :class:`Posterior`; :func:`posterior_predictive_check`.
- :mod:`fitting.parameters`, :mod:`fitting.models`, :mod:`fitting.plots`; the forward
  statics of the fits, the sampler and the diagnosis is
  :func:`cstiffjax.equilibrium.forward_statics` (warm start).
"""

import cstiffjax  # noqa: F401  (float64)

from .least_squares import (
    Fit,
    LSResult,
    calibrate,
    calibrate_csjm_stiffness,
    calibrate_model,
    identifiability,
    solve_least_squares,
)
from .models import cdpr_residuals, predict_cdpr, residual_channels, synthetic_recordings
from .parameters import CDPR_PARAMETERS, ParameterSpec, apply_to_robot, cdpr_spec
from .posterior import ChainTooShortError, Posterior, posterior_predictive_check, sample_posterior

__all__ = [
    "CDPR_PARAMETERS",
    "ChainTooShortError",
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
    "identifiability",
    "posterior_predictive_check",
    "predict_cdpr",
    "residual_channels",
    "sample_posterior",
    "solve_least_squares",
    "synthetic_recordings",
]
