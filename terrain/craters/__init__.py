"""Craters: the profile kernels, degradation, roughness overlays, populations and catalogues."""
