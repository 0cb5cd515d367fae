"""A labelled run on disk: per-frame label files, COCO JSON and the camera table.

The layout (``docs/labels.md`` describes every field)::

    RUN_DIR/labels/
      rims_NNNNNN.json        the frame's crater rims and instance table (render.labels)
      instances_NNNNNN.png    16-bit instance numbers (0: none)
      semantic_NNNNNN.png     8-bit classes: 0 sky, 1 terrain, 2 rock, 3 shadowed
      hazard_NNNNNN.png       8-bit: 0 unsafe, 1 safe, 255 unknown (with a lander)
      flow_NNNNNN.tif         float32 (du, dv) pixels to frame NNNNNN + 1 (NaN: no surface)
      occlusion_NNNNNN.png    8-bit: 1 where the pixel's point is hidden or gone in the next
      coco.json               COCO instances: craters (with their rim ellipses) and rocks
      cameras.csv             one row per frame: pose, intrinsics, sun

Every file is written atomically; the COCO file and the camera table are rewritten from the
per-frame files and ``truth.json`` when a run finishes (:func:`write_exports`), so a resumed
run's exports cover every frame.
"""

from __future__ import annotations

import csv
import io
import json
import math
from pathlib import Path

import numpy as np

from render.labels import FrameLabels
from terrain.core.outputs import atomic_path
from terrain.io import write_float_tiff, write_png

__all__ = ["CAMERA_COLUMNS", "COCO_CATEGORIES", "write_exports", "write_flow",
           "write_frame_labels"]

#: COCO categories of a labelled run.
COCO_CATEGORIES = ({"id": 1, "name": "crater", "supercategory": "terrain"},
                   {"id": 2, "name": "rock", "supercategory": "terrain"})
_CATEGORY = {"crater": 1, "rock": 2}
#: Columns of ``cameras.csv``: frame, time (s), image file, camera centre (m, world), attitude
#: quaternion R_WC (w, x, y, z), image size and pinhole (pixels), unit sun direction (world).
CAMERA_COLUMNS = ("index", "time", "image", "x", "y", "z", "qw", "qx", "qy", "qz", "width",
                  "height", "fx", "fy", "cx", "cy", "sun_x", "sun_y", "sun_z")
#: Vertices of the polygon a crater annotation without visible pixels gets from its ellipse.
ELLIPSE_VERTICES = 36


def write_frame_labels(folder: str | Path, index: int, labels: FrameLabels,
                       prefix: str = "labels/") -> dict:
    """Write one frame's labels (all but the flow) under ``folder``.

    Parameters
    ----------
    folder : str or pathlib.Path
        The run directory (files go to its ``labels/``), or any folder with ``prefix`` "".
    index : int
        The frame.
    labels : render.labels.FrameLabels
        What :meth:`render.labels.Labeller.label` gave.
    prefix : str
        Prepended to each file name (relative to ``folder``).

    Returns
    -------
    dict
        The files written, relative to ``folder``, by kind (the truth entry's ``labels``).
    """
    folder = Path(folder)
    (folder / prefix).mkdir(parents=True, exist_ok=True)
    names = {"rims": f"{prefix}rims_{index:06d}.json"}
    with atomic_path(folder / names["rims"]) as tmp:
        tmp.write_text(json.dumps(labels.as_dict(), indent=1), encoding="utf-8")
    for kind, image in (("instances", labels.instance_mask), ("semantic", labels.semantic),
                        ("hazard", labels.hazard)):
        if image is not None:
            names[kind] = f"{prefix}{kind}_{index:06d}.png"
            write_png(image, folder / names[kind])
    return names


def write_flow(folder: str | Path, index: int, labels: FrameLabels,
               prefix: str = "labels/") -> dict:
    """Write a frame's flow and occlusion mask (:meth:`render.labels.Labeller.add_flow`).

    Parameters
    ----------
    folder : str or pathlib.Path
        As :func:`write_frame_labels`.
    index : int
        The frame (its flow runs to frame ``index + 1``).
    labels : render.labels.FrameLabels
        With ``flow`` and ``occluded`` filled in.
    prefix : str
        As :func:`write_frame_labels`.

    Returns
    -------
    dict
        ``{"flow": .., "occlusion": ..}`` relative to ``folder``.
    """
    folder = Path(folder)
    (folder / prefix).mkdir(parents=True, exist_ok=True)
    assert labels.flow is not None and labels.occluded is not None
    names = {"flow": f"{prefix}flow_{index:06d}.tif",
             "occlusion": f"{prefix}occlusion_{index:06d}.png"}
    write_float_tiff(labels.flow, folder / names["flow"],
                     tags={"UNITS": "pixel", "BANDS": "du,dv", "TO_FRAME": str(index + 1)})
    write_png(labels.occluded.astype(np.uint8), folder / names["occlusion"])
    return names


def _ellipse_polygon(e: dict) -> list[float]:
    (u, v), (a, b), ang = e["centre"], e["axes"], math.radians(e["angle_deg"])
    t = np.linspace(0.0, 2 * math.pi, ELLIPSE_VERTICES, endpoint=False)
    x = u + a * np.cos(t) * math.cos(ang) - b * np.sin(t) * math.sin(ang)
    y = v + a * np.cos(t) * math.sin(ang) + b * np.sin(t) * math.cos(ang)
    return np.stack([x, y], axis=1).reshape(-1).round(3).tolist()


def coco_frame(image_id: int, file_name: str, width: int, height: int, rims: dict,
               mask: np.ndarray | None, first_id: int) -> tuple[dict, list[dict]]:
    """Give one frame's COCO image record and annotations.

    Parameters
    ----------
    image_id : int
        The COCO image id.
    file_name : str
        The image file, relative to the run directory.
    width, height : int
        Image size.
    rims : dict
        The frame's rims JSON (``craters`` and ``instances``).
    mask : (h, w) uint16, optional
        The frame's instance mask.
    first_id : int
        The first annotation id to use.

    Returns
    -------
    image : dict
    annotations : list of dict
        Craters (category 1) with ``ellipse``, ``conic`` and visibility, and rocks
        (category 2); segmentation as RLE from the instance mask, or the rim ellipse's
        polygon for a crater with no visible pixel; ``catalog_id`` is the catalogue's id.
    """
    from pycocotools import mask as cocomask

    image = {"id": image_id, "file_name": file_name, "width": width, "height": height}
    anns: list[dict] = []
    rock_rows = [r for r in rims.get("instances", []) if r["kind"] == "rock"]

    def add(category, rle_or_poly, extra):
        if isinstance(rle_or_poly, dict):
            area = float(cocomask.area(rle_or_poly))
            bbox = [float(v) for v in cocomask.toBbox(rle_or_poly)]
            rle_or_poly = dict(rle_or_poly, counts=rle_or_poly["counts"].decode("ascii"))
        else:
            xs, ys = rle_or_poly[0][0::2], rle_or_poly[0][1::2]
            bbox = [min(xs), min(ys), max(xs) - min(xs), max(ys) - min(ys)]
            area = 0.0
        anns.append(dict(id=first_id + len(anns), image_id=image_id, category_id=category,
                         segmentation=rle_or_poly, area=area, bbox=bbox, iscrowd=0, **extra))

    def rle(n):
        assert mask is not None
        return cocomask.encode(np.asfortranarray((mask == n).astype(np.uint8)))

    for r in rims.get("craters", []):
        extra = {"catalog_id": r["id"], "ellipse": r["ellipse"], "conic": r["conic"],
                 "in_frame": r["in_frame"], "occluded": r["occluded"], "lit": r["lit"]}
        n = r.get("instance", 0)
        add(1, rle(n) if (n and mask is not None) else [_ellipse_polygon(r["ellipse"])], extra)
    for r in rock_rows:
        if mask is not None:
            add(2, rle(r["instance"]), {"catalog_id": r["id"]})
    return image, anns


def write_exports(run_dir: str | Path) -> dict:
    """Write a labelled run's ``labels/coco.json`` and ``labels/cameras.csv`` from its frames.

    Parameters
    ----------
    run_dir : str or pathlib.Path
        A run directory whose truth entries list their label files.

    Returns
    -------
    dict
        ``{"coco": .., "cameras": .., "annotations": n}`` (paths relative to ``run_dir``).
    """
    import cv2

    run_dir = Path(run_dir)
    frames = json.loads((run_dir / "truth.json").read_text(encoding="utf-8"))
    images: list[dict] = []
    anns: list[dict] = []
    buf = io.StringIO()
    out = csv.writer(buf, lineterminator="\n")
    out.writerow(CAMERA_COLUMNS)
    for f in frames:
        k, cam = f["intrinsics"], f["camera"]
        out.writerow([f["index"], repr(float(f["time"])), f.get("image") or "",
                      *(repr(float(v)) for v in cam["position"]),
                      *(repr(float(v)) for v in cam["attitude"]), k["width"], k["height"],
                      *(repr(float(k[n])) for n in ("fx", "fy", "cx", "cy")),
                      *(repr(float(v)) for v in f["sun"]["direction"])])
        lab = f.get("labels") or {}
        if "rims" not in lab:
            continue
        rims = json.loads((run_dir / lab["rims"]).read_text(encoding="utf-8"))
        mask = None
        if "instances" in lab:
            mask = cv2.imread(str(run_dir / lab["instances"]), cv2.IMREAD_UNCHANGED)
        image, a = coco_frame(int(f["index"]) + 1, f.get("image") or "", k["width"],
                              k["height"], rims, mask, len(anns) + 1)
        image["frame"] = int(f["index"])
        images.append(image)
        anns.extend(a)
    coco = {"info": {"description": "craterscape labelled run", "version": "1.0"},
            "images": images, "annotations": anns, "categories": list(COCO_CATEGORIES)}
    (run_dir / "labels").mkdir(exist_ok=True)
    with atomic_path(run_dir / "labels/coco.json") as tmp:
        tmp.write_text(json.dumps(coco), encoding="utf-8")
    with atomic_path(run_dir / "labels/cameras.csv") as tmp:
        tmp.write_text(buf.getvalue(), encoding="utf-8")
    return {"coco": "labels/coco.json", "cameras": "labels/cameras.csv",
            "annotations": len(anns)}
