"""Runtime services: the persistent compilation cache and serialized programs.
Imports core only; the commands and ``fitting`` use it."""
