"""Stiffness by autodiff, the pose-minor kernel, the constant stiffness space and tension
distribution. Imports core, io, cable and statics."""
