"""Data in and out: the robot and recordings Modules and the TOML/CSV contracts (``formats.md``).
Imports only :mod:`cstiffjax.core`."""
