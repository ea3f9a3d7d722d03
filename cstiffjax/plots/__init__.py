"""Figures (matplotlib only). Nothing below imports this layer."""
