"""Plumbing every stage uses; imports no other terrain module.

Errors, keyed randomness, memory checks, progress, metadata keys, TOML, atomic outputs, the DEM
tile, bodies and the Zarr store.
"""
