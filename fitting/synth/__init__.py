"""Generators of recordings with concealed effects (the blind benchmark's data)."""
