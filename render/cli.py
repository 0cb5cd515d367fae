"""The ``craterscape render`` commands: a sequence into a run directory, or one frame."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import click

from terrain.cli.tools import ImageSizeType, progress_bar
from terrain.core.errors import InvalidParameterError

__all__ = ["render"]


def _largest_image_side() -> int:
    """Return the largest image side a scenario may ask for (imported when an option is read)."""
    from render.scenario import MAX_IMAGE_SIDE

    return MAX_IMAGE_SIDE


RESOLUTION = ImageSizeType(_largest_image_side)


@click.group()
def render() -> None:
    """Camera images, LIDAR range and ground truth along trajectories."""


@render.command()
@click.argument("scenario_file", type=click.Path(dir_okay=False, path_type=Path))
@click.option("-o", "--output", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="Run directory (new or empty; with --resume, an interrupted run).")
@click.option("--frames", type=click.IntRange(1, 100000), default=None,
              help="Override the scenario's frame count.")
@click.option("--resolution", type=RESOLUTION, default=None,
              help="Override the image size (field of view kept).")
@click.option("--resume", is_flag=True, help="Continue an interrupted run in the same folder.")
@click.option("--labels", is_flag=True,
              help="Write image-space labels (docs/labels.md), default settings unless the "
                   "scenario has a [labels] table.")
def sequence(scenario_file: Path, output: Path, frames: int | None,
             resolution: tuple[int, int] | None, resume: bool, labels: bool) -> None:
    """Render every frame of a scenario: frames/, range/, normals/, truth.json, manifest."""
    from render.context import keep_current
    from render.scenario import load_scenario
    from render.sequence import run_sequence

    scenario = _with_labels(load_scenario(scenario_file).with_overrides(frames, resolution),
                            labels)
    with keep_current(), progress_bar("render", "frame",
                                      total=scenario.trajectory.frames) as progress:
        manifest = run_sequence(scenario, output, resume=resume, progress=progress)
    click.echo(f"wrote {manifest['frames_written']} frames to {output} "
               f"({manifest['render_seconds']:.1f} s)", err=True)


@render.command()
@click.argument("scenario_file", type=click.Path(dir_okay=False, path_type=Path))
@click.argument("dispersions_file", type=click.Path(dir_okay=False, path_type=Path))
@click.option("-o", "--output", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="Campaign folder (new or empty; with --resume, an interrupted campaign).")
@click.option("--workers", type=click.IntRange(1, 4096), default=None,
              help="Render on a local pool of N worker processes.")
@click.option("--scheduler", default=None, metavar="ADDRESS",
              help="Render on the Dask cluster at ADDRESS (tcp://HOST:PORT).")
@click.option("--resume", is_flag=True, help="Skip the cases an interrupted campaign finished.")
def campaign(scenario_file: Path, dispersions_file: Path, output: Path, workers: int | None,
             scheduler: str | None, resume: bool) -> None:
    """Render a scenario once per case of DISPERSIONS_FILE (CSV or TOML; docs/campaigns.md).

    Writes OUT/cases/NNNNNN.toml (each case's scenario), OUT/cases/NNNNNN/ (its run
    directory), OUT/summary.csv and OUT/campaign.json.
    """
    from render.dispersions import read_dispersions
    from render.montecarlo import run_campaign

    total = len(read_dispersions(dispersions_file).cases)
    with progress_bar("campaign", "case", total=total) as progress:
        record = run_campaign(scenario_file, dispersions_file, output, workers=workers,
                              scheduler=scheduler, resume=resume, progress=progress)
    click.echo(f"rendered {record['cases_rendered']} of {record['cases']} cases into {output} "
               f"({record['seconds']:.1f} s, {record['workers']} worker(s))", err=True)


@render.command()
@click.argument("scenario_file", type=click.Path(dir_okay=False, path_type=Path))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False, path_type=Path),
              help="Image file (PNG); range, normals and truth go beside it.")
@click.option("--index", type=int, default=None, help="Trajectory frame to render (default 0).")
@click.option("--resolution", type=RESOLUTION, default=None, help="Override the image size.")
@click.option("--labels", is_flag=True,
              help="Write image-space labels into OUT_labels/ (docs/labels.md).")
def frame(scenario_file: Path, output: Path, index: int | None,
          resolution: tuple[int, int] | None, labels: bool) -> None:
    """Render one view of a scenario.

    Writes OUT.png, OUT_range.tif, OUT_normals.tif, OUT_truth.json (and OUT_radiance.tif
    where [output] radiance is on; OUT_labels/ with labels, its flow to the next trajectory
    frame where there is one; OUT_radar.npz and OUT_lidar.npz where the scenario has [radar]
    and [lidar] tables: the run files of docs/sensors.md for this one frame; OUT_bodies.png
    for a binary scene).
    """
    from dataclasses import replace

    from render.context import keep_current
    from render.renderer import Renderer
    from render.scenario import load_scenario
    from render.sequence import check_frame_memory, load_scene, render_sample
    from terrain.core.outputs import atomic_path, check_output_path, transaction
    from terrain.io import write_float_tiff, write_png

    if output.suffix.lower() != ".png":
        raise InvalidParameterError(f"frame output must be a .png file; got '{output}'")
    stem = output.with_suffix("")
    companions = {"range": Path(f"{stem}_range.tif"), "normals": Path(f"{stem}_normals.tif"),
                  "radiance": Path(f"{stem}_radiance.tif"), "truth": Path(f"{stem}_truth.json"),
                  "radar": Path(f"{stem}_radar.npz"), "lidar": Path(f"{stem}_lidar.npz"),
                  "body_ids": Path(f"{stem}_bodies.png")}
    for p in (output, *companions.values()):
        check_output_path(p, [scenario_file])
    scenario = _with_labels(load_scenario(scenario_file).with_overrides(None, resolution),
                            labels)
    check_frame_memory(scenario)
    scene = load_scene(scenario)
    samples = scenario.samples(scene)
    index = 0 if index is None else index
    if not 0 <= index < len(samples):
        raise InvalidParameterError(f"--index must lie in [0, {len(samples) - 1}]; got {index}")
    with keep_current():
        renderer = Renderer()
        image, fr, truth = render_sample(renderer, scene, scenario, samples[index], index,
                                         samples)
    ids = fr.body_ids if scenario.outputs.get("body_ids", True) else None
    stale = [companions[k] for k in ("range", "normals", "radiance")
             if not scenario.outputs.get(k)] + ([companions["body_ids"]] if ids is None else [])
    stale += [companions[k] for k, on in (("radar", bool(scenario.radar)),
                                          ("lidar", scenario.lidar is not None)) if not on]
    with transaction(stale=stale, folders=[output.parent]):  # image and truth as one set
        write_png(image, output, inputs=[scenario_file])
        if scenario.outputs["range"]:
            write_float_tiff(fr.range, companions["range"], tags={"UNITS": "metre"})
        if scenario.outputs["normals"]:
            write_float_tiff(fr.normals, companions["normals"], tags={"FRAME": "world"})
        if scenario.outputs.get("radiance"):
            lighting = scenario.lighting_at(samples[index].time, scene)
            write_float_tiff(lighting.radiance(fr.radiance), companions["radiance"],
                             tags={"UNITS": "W m-2 sr-1 nm-1"})
        if scenario.labels is not None:
            with keep_current():
                truth = replace(truth, labels=_frame_labels(renderer, scenario, scene, samples,
                                                            index, fr, truth, output))
        if ids is not None:
            write_png(ids, companions["body_ids"], inputs=[scenario_file])
        with atomic_path(companions["truth"]) as tmp:
            tmp.write_text(json.dumps(truth.as_dict(), indent=2), encoding="utf-8")
        if scenario.radar or scenario.lidar is not None:
            from render.instruments import record_lidar, record_radar

            with keep_current():
                if scenario.radar:
                    record_radar(renderer, scene, scenario.radar, scenario.lighting,
                                 scenario.options, samples, companions["radar"],
                                 frames=[index], scenario=scenario.name, seed=scenario.seed)
                if scenario.lidar is not None:
                    record_lidar(renderer, scene, scenario.lidar, scenario.lighting,
                                 scenario.options, samples, companions["lidar"],
                                 frames=[index], seed=scenario.seed, scenario=scenario.name)
    click.echo(f"wrote {output} (frame {index}, {fr.drawn.get('triangles', 0)} triangles)",
               err=True)


def _with_labels(scenario, labels: bool):
    """Return the scenario, with default labels switched on by ``--labels`` where it has none."""
    from dataclasses import replace

    from render.labels import LabelSpec

    if labels and scenario.labels is None:
        return replace(scenario, labels=LabelSpec())
    return scenario


def _frame_labels(renderer, scenario, scene, samples, index, fr, truth, output: Path) -> dict:
    """Write ``render frame``'s labels beside its image (flow: to the next sample, if any)."""
    from render.dataset import write_flow, write_frame_labels
    from render.labels import Labeller

    spec = scenario.labels
    labeller = Labeller(scene, spec)
    lab = labeller.label(fr, truth.pose, truth.intrinsics, scenario.lighting)
    prefix = f"{output.with_suffix('').name}_labels/"
    names = write_frame_labels(output.parent, index, lab, prefix)
    if spec.flow and index + 1 < len(samples):
        from render.renderer import View

        nxt = samples[index + 1]
        scene.set_body_rotation(nxt.body_rotation)
        nfr = renderer.render(scene, View(nxt.pose, scenario.intrinsics, nxt.time),
                                scenario.lighting, scenario.options)
        labeller.add_flow(lab, fr.range, truth.pose, truth.body_rotation, nfr.range, nxt.pose,
                          nxt.body_rotation, truth.intrinsics)
        names.update(write_flow(output.parent, index, lab, prefix))
    return names


@render.command()
@click.argument("scenario_file", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--host", default="127.0.0.1", show_default=True,
              help="Address to listen on; anything but loopback needs --token.")
@click.option("--port", type=click.IntRange(0, 65535), default=10363, show_default=True,
              help="TCP port (0: a free one, printed on stderr).")
@click.option("--token", envvar="CRATERSCAPE_TOKEN", default=None,
              help="Shared secret every client must send first (env CRATERSCAPE_TOKEN).")
@click.option("--idle-timeout", type=click.FloatRange(min=0, min_open=True), default=300.0,
              show_default=True, help="Close a client sending nothing but PING this long (s).")
@click.option("--read-timeout", type=click.FloatRange(min=0, min_open=True), default=10.0,
              show_default=True, help="Close a client whose message stalls this long (s).")
@click.option("--max-clients", type=click.IntRange(1, 1024), default=32, show_default=True,
              help="Clients connected at once.")
def serve(scenario_file: Path, host: str, port: int, token: str | None, idle_timeout: float,
          read_timeout: float, max_clients: int) -> None:
    """Serve a scenario's scene over TCP until SIGINT/SIGTERM (protocol: docs/protocol.md)."""
    from render.context import keep_current
    from render.scenario import load_scenario
    from render.server import RenderServer

    scenario = load_scenario(scenario_file)
    server = RenderServer(scenario, host, port, token=token, idle_timeout=idle_timeout,
                          read_timeout=read_timeout, max_clients=max_clients)
    server.bind()
    with keep_current():
        server.load()
        bound_host, bound_port = server.address
        click.echo(f"craterscape: serving {scenario.name} ({server.scene.kind}) on "
                   f"{bound_host}:{bound_port}", err=True)
        sys.stderr.flush()
        server.serve()
    click.echo(f"craterscape: server stopped after {server.requests} requests", err=True)
