"""Calibration: one Levenberg-Marquardt, parameters, measurement models, least squares."""
