"""Posterior sampling with emcee and its diagnostics."""
