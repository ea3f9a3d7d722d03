"""Workspace sweeps and per-pose memberships: wrench-feasible, wrench-closure, interference.
Imports the layers below (core .. stiffness)."""
