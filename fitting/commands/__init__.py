"""Sub-commands of the ``cstiffjax`` CLI that need ``fitting`` (registered with the CLI)."""
