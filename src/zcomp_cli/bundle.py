"""The object intrinsics bundle (DESIGN.md section 3): a folder with

``depth.exr`` (z-depth, metres, 0 = empty), ``normals.exr`` (camera frame, OpenGL, unit),
``albedo.exr`` (linear RGB), ``mask.exr`` (anti-aliased coverage in [0, 1]),
``footprint_depth.exr`` (z-depth of the object's base projected on its support plane,
0 outside the footprint), optional ``roughness.exr`` / ``metallic.exr``, and ``meta.json``
(K, resolution, pose, object height in metres, mesh hash, Blender version).

``meta.json`` is written last: a bundle without it is incomplete (a crash mid-write),
which is how the cache and ``--resume`` tell finished work from unfinished.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from zcomp_cli.camera import Camera
from zcomp_cli.errors import InputError
from zcomp_cli.safe_read import read_json_file

BUNDLE_MAPS = ("depth", "normals", "albedo", "mask", "footprint_depth")
OPTIONAL_MAPS = ("roughness", "metallic")
_CHANNELS = {"depth": 1, "normals": 3, "albedo": 3, "mask": 1, "footprint_depth": 1,
             "roughness": 1, "metallic": 1}


@dataclass
class ObjectBundle:
    """An object's intrinsic maps for one pose and camera (all H x W, float32)."""

    depth: np.ndarray
    normals: np.ndarray
    albedo: np.ndarray
    mask: np.ndarray
    footprint_depth: np.ndarray
    camera: Camera
    meta: dict = field(default_factory=dict)
    roughness: np.ndarray | None = None
    metallic: np.ndarray | None = None

    def __post_init__(self):
        h, w = self.camera.height, self.camera.width
        for name in BUNDLE_MAPS + OPTIONAL_MAPS:
            arr = getattr(self, name)
            if arr is None:
                continue
            arr = np.asarray(arr, dtype=np.float32)
            c = _CHANNELS[name]
            want = (h, w) if c == 1 else (h, w, c)
            if arr.shape != want:
                raise InputError(f"bundle map {name!r} has shape {arr.shape}, expected {want}")
            setattr(self, name, arr)

    @property
    def height_m(self) -> float | None:
        v = self.meta.get("object_height_m")
        return float(v) if v is not None else None

    @staticmethod
    def is_complete(folder) -> bool:
        folder = Path(folder)
        return (folder / "meta.json").is_file() and all(
            (folder / f"{m}.exr").is_file() for m in BUNDLE_MAPS
        )

    @classmethod
    def load(cls, folder) -> "ObjectBundle":
        from zcomp_cli.imageio import read_map

        folder = Path(folder)
        meta_path = folder / "meta.json"
        if not meta_path.is_file():
            raise InputError("not an object bundle (no meta.json)", where=str(folder))
        try:
            meta = read_json_file(meta_path)
        except (OSError, ValueError) as exc:
            raise InputError(f"invalid meta.json: {exc}", where=str(meta_path)) from exc
        try:
            camera = Camera(np.asarray(meta["K"], dtype=np.float64), *meta["resolution"])
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"meta.json lacks a valid K/resolution: {exc}", where=str(meta_path)) from exc
        maps = {}
        for name in BUNDLE_MAPS:
            p = folder / f"{name}.exr"
            if not p.is_file():
                raise InputError(f"bundle is missing {p.name}", where=str(folder))
            maps[name] = read_map(p, channels=_CHANNELS[name])
        for name in OPTIONAL_MAPS:
            p = folder / f"{name}.exr"
            maps[name] = read_map(p, channels=1) if p.is_file() else None
        return cls(camera=camera, meta=meta, **maps)

    def save(self, folder) -> None:
        from zcomp_cli.imageio import write_exr, write_json_atomic

        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        for name in BUNDLE_MAPS + OPTIONAL_MAPS:
            arr = getattr(self, name)
            if arr is not None:
                write_exr(folder / f"{name}.exr", arr)
        meta = dict(self.meta)
        meta["K"] = self.camera.K.tolist()
        meta["resolution"] = [self.camera.width, self.camera.height]
        write_json_atomic(folder / "meta.json", meta)
