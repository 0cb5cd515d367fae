"""What the render tests render: a small cratered layer stack and a descent over it."""

from __future__ import annotations

from pathlib import Path


def cratered_stack(folder: Path) -> Path:
    """Write a three-layer stack (65 px of 100 m, layers of 33 px, craters from 1 m) there."""
    from terrain.craters.population import Population
    from terrain.fractal.synthetic import synthesize_tile
    from terrain.stack.build import build_stack
    from terrain.stack.store import write_stack

    base = synthesize_tile(65, resolution=100.0, relief=500.0, seed=3).tile
    stack = build_stack(base, (3250.0, 3250.0), levels=2, layer_size=33, seed=4,
                        population=Population(dmin=1.0, dmax=3000.0, density=5e4))
    return write_stack(stack, folder)


def descent_scenario(stack_dir: Path, name: str, *, frames: int = 3) -> str:
    """Return the TOML of a 64 x 48 descent from 1500 m to 100 m over ``stack_dir``."""
    return f"""
name = "{name}"
seed = 5
[scene]
type = "terrain"
stack = "{stack_dir}"
[sun]
azimuth = 100.0
elevation = 15.0
[camera]
width = 64
height = 48
fov = 50.0
[sensor]
bits = 16
exposure = 4.0
gain = 10.0
read_noise = 2.0
[render]
shadow_size = 512
[trajectory]
type = "descent"
frames = {frames}
duration = 4.0
start_altitude = 1500.0
end_altitude = 100.0
ground_track = [300.0, 100.0]
"""
