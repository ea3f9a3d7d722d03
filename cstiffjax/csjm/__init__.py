"""The cable-driven spherical joint module (seed 000): model and identification.
Imports the layers below."""
