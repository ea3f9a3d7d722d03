"""Benchmarks and data generators (run as scripts: python benchmarks/NAME.py)."""
