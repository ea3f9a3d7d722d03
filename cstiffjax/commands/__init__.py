"""Sub-commands of the ``cstiffjax`` CLI (one module each)."""
