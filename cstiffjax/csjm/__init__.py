"""The cable-driven spherical joint module (Yang et al. 2019): model and identification.
Imports the layers below."""
