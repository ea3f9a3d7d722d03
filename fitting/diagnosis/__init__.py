"""The mismatch diagnosis: selection, fitter, localization, checks, diagnose, discover, report."""
