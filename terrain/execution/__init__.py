"""Chunked execution on Dask: synthesis, craters, expansion and filling chunk by chunk."""
