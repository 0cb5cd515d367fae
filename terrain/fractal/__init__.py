"""Fractal terrain: random midpoint displacement, roughness, expansion, gap filling, synthesis."""
