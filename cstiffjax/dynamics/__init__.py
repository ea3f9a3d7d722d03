"""Dynamics with sagging cables: mass matrix, dynamic stiffness, FRF, natural frequencies.
Imports the layers below (core .. workspace)."""
