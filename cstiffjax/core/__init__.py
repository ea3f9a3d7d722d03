"""Core: process configuration (float64, XLA flags), host arrays, errors, the ``Status`` result codes,
SO(3) helpers and progress bars. Imports nothing else of cstiffjax."""
