"""Run ``zcomp_cli/blender/scripts/render_scene.py`` and turn its raw passes into zcomp maps.

Blender runs in a subprocess through ``zcomp_cli.blender.runner``; every conversion of
its passes (1e10 depth, world-space normals) happens here with tested numpy functions
from ``zcomp_cli.conventions``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from zcomp_cli.conventions import blender_depth_to_z_depth, normalize, world_to_camera_normals
from zcomp_cli.errors import RenderError

SCRIPT = "render_scene.py"


@dataclass
class SceneMaps:
    """One rendered scene in zcomp's conventions.

    Attributes:
        image: (H, W, 3) float32 linear radiance (Cycles Combined, unexposed).
        albedo: (H, W, 3) float32 linear base colour (albedo AOV; 0 on the sky).
        depth: (H, W) float32 z-depth in metres, 0 where the pixel centre sees no surface.
        normals: (H, W, 3) float32 camera-frame unit normals, 0 where depth is 0.
    """

    image: np.ndarray
    albedo: np.ndarray
    depth: np.ndarray
    normals: np.ndarray


def _channels(path: Path) -> dict[str, np.ndarray]:
    from zcomp_cli.blender.passes import read_multilayer_exr

    return read_multilayer_exr(path)


def _get(ch: dict, name: str, comps: str) -> np.ndarray:
    keys = [f"{name}.{c}" for c in comps]
    missing = [k for k in keys if k not in ch]
    if missing:
        raise RenderError(f"render output lacks channels {missing} (has {sorted(ch)})")
    arrs = [ch[k] for k in keys]
    return arrs[0] if len(arrs) == 1 else np.stack(arrs, axis=-1)


def maps_from_passes(beauty: dict, geometry: dict) -> SceneMaps:
    """Convert the raw channels of ``beauty.exr`` and ``geometry.exr``.

    The camera is the identity, so world-space normals are camera-frame normals; going
    through ``world_to_camera_normals`` keeps that contract in one place.
    """
    image = np.nan_to_num(_get(beauty, "Combined", "RGB"), nan=0.0, posinf=0.0, neginf=0.0)
    # The albedo AOV is the Principled base colour (as the object intrinsics define
    # it); Blender's Diffuse Color pass ("DiffCol" before 5.0) is the fallback.
    if "albedo.R" in beauty:
        diff_name = "albedo"
    else:
        diff_name = "Diffuse Color" if "Diffuse Color.R" in beauty else "DiffCol"
    albedo = np.clip(np.nan_to_num(_get(beauty, diff_name, "RGB"), nan=0.0), 0.0, 1.0)
    depth = blender_depth_to_z_depth(_get(geometry, "Depth", "Z"))
    n = normalize(world_to_camera_normals(_get(geometry, "Normal", "XYZ"), np.eye(4)))
    valid = depth > 0
    normals = np.where(valid[..., None], n, 0.0)
    return SceneMaps(image.astype(np.float32), albedo.astype(np.float32),
                     depth.astype(np.float32), normals.astype(np.float32))


def render_scenes(items: list[dict], *, threads: int = 0, on_event: Callable[[dict], None] | None = None,
                  log_path=None) -> dict[str, SceneMaps]:
    """Render every item (see the job format in ``zcomp_cli/blender/scripts/render_scene.py``) in
    one Blender process and return its maps by item id.

    Raises:
        RenderError: naming every item that failed and Blender's log file.
    """
    from zcomp_cli.blender.runner import run_blender_batch

    res = run_blender_batch(SCRIPT, items, common={"threads": int(threads)}, on_event=on_event,
                            log_path=log_path)
    failed = {k: v.get("error", "?") for k, v in res.results.items() if v.get("event") != "done"}
    if failed:
        lines = "; ".join(f"{k}: {v}" for k, v in sorted(failed.items()))
        raise RenderError(f"Blender scene render failed for {len(failed)} item(s): {lines} (log: {res.log_path})")
    out = {}
    for it in items:
        files = res.results[str(it["id"])]["files"]
        out[str(it["id"])] = maps_from_passes(_channels(Path(files["beauty"])), _channels(Path(files["geometry"])))
    return out
