"""Small replicas of the official ZeroComp and SpotLight evaluation archives, written by
the tests in the layouts the official loaders read (docs/reproduce.md):

* ``<root>/<case>/<case>_bundle0001.exr``: one multi-layer EXR, channels
  ``<layer>.<R|G|B|A>`` (``mask.R``), the value layers RGBA premultiplied by their alpha,
  normals in each loader's frame (ZeroComp: Blender shader camera space, z forward;
  SpotLight: OpenGL camera frame);
* ZeroComp: ``<case>_bg_depth.exr``, ``_bg_normal.png`` (StableNormal: x negated),
  ``_bg_diffuse.png`` (linear values x 255), ``_bg_roughness.png`` beside the bundle;
* SpotLight: the same maps in ``WACV_bg_estimates/<case>/``, ``<case>_light_path_dto.json``
  and ``shadows/<case>/shadow_*.png``.

Each case is an analytic floor-and-wall room (``testing.floor_scene``) with a sphere
standing on the floor; the ground truth pastes the sphere with a darkened floor patch
under it. The true values are returned so that tests can check every conversion.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from zcomp_cli.imageio import write_exr
from zcomp_cli.testing import floor_scene, sphere_object_bundle

SIZE = 40
# SpotLight frames: v (right, forward, up) of Blender's "object space".
GT_LIGHT = (0.3, -0.2, 0.9)
PATH_LIGHT = (1.0, 0.0, 0.0)


@dataclass
class ReplicaCase:
    name: str
    scene: object          # testing.SyntheticScene (true background maps)
    bundle: object         # ObjectBundle (true object maps, zcomp conventions)
    background: np.ndarray
    composite: np.ndarray


def make_case(k: int, size: int = SIZE) -> tuple[object, object, np.ndarray, np.ndarray]:
    sc = floor_scene(size, size, with_wall=True, wall_distance=5.0, light_dir=(0.4 - 0.3 * k, 1.0, 0.4))
    centre = sc.world_to_camera([0.25 * k - 0.1, 0.3, -3.0])
    b = sphere_object_bundle(sc.camera, center=centre, radius=0.3, albedo=(0.7, 0.5, 0.3),
                             floor_normal=sc.up_cam, supersample=2)
    bg = sc.image.astype(np.float32)
    m = b.mask[..., None]
    shadow = np.where(b.footprint_depth[..., None] > 0, 0.55, 1.0)
    comp = (1 - m) * bg * shadow + m * b.albedo * 0.8
    return sc, b, bg, comp.astype(np.float32)


def bundle_channels(b, bg, comp, *, normals_frame: str, drop=()) -> dict[str, np.ndarray]:
    """The layers of an official bundle for object bundle ``b`` (straight values)."""
    a = b.mask.astype(np.float32)
    fa = (b.footprint_depth > 0).astype(np.float32)
    n = b.normals.copy()
    if normals_frame == "blender-camera":
        n[..., 2] *= -1.0  # zcomp -> Blender shader camera space (z forward)
    layers = {
        "albedo": np.concatenate([b.albedo * a[..., None], a[..., None]], -1),
        "roughness": np.stack([0.4 * a] * 3 + [a], -1),
        "metallic": np.stack([0.0 * a] * 3 + [a], -1),
        "depth": np.stack([b.depth * a] * 3 + [a], -1),
        "footprint_depth": np.stack([b.footprint_depth * fa] * 3 + [fa], -1),
        "normals": np.concatenate([n * a[..., None], a[..., None]], -1),
        "foreground": np.concatenate([b.albedo * 0.8 * a[..., None], a[..., None]], -1),
        "background": bg,
        "composite": comp,
    }
    out = {}
    for layer, arr in layers.items():
        if layer in drop:
            continue
        for i, ch in enumerate("RGBA"[: arr.shape[-1]]):
            out[f"{layer}.{ch}"] = arr[..., i]
    if "mask" not in drop:
        out["mask.R"] = a
    return out


def write_bundle(path: Path, channels: dict[str, np.ndarray]) -> None:
    names = list(channels)
    write_exr(path, np.stack([channels[c] for c in names], -1), channel_names=names)


def write_bg_maps(folder: Path, name: str, sc) -> None:
    """``_bg_depth.exr`` (RGB), StableNormal ``_bg_normal.png``, ``_bg_diffuse.png``,
    ``_bg_roughness.png``, as the archives store them."""
    from PIL import Image

    folder.mkdir(parents=True, exist_ok=True)
    write_exr(folder / f"{name}_bg_depth.exr", np.stack([sc.depth] * 3, -1))
    n = sc.normals * np.array([-1.0, 1.0, 1.0])  # StableNormal: x negated vs OpenRooms
    e = np.where(np.linalg.norm(sc.normals, axis=-1, keepdims=True) > 0, n * 0.5 + 0.5, 0.5)
    Image.fromarray(np.round(e * 255).astype(np.uint8)).save(folder / f"{name}_bg_normal.png")
    Image.fromarray(np.round(np.clip(sc.albedo, 0, 1) * 255).astype(np.uint8)).save(folder / f"{name}_bg_diffuse.png")
    Image.fromarray(np.full(sc.depth.shape, 102, np.uint8)).save(folder / f"{name}_bg_roughness.png")


def make_zerocomp_archive(root: Path, n: int = 2, *, broken: dict | None = None, size: int = SIZE
                          ) -> list[ReplicaCase]:
    """``root/GT_emission_envmap/<case>/...`` (as labo.zip unpacks). ``broken``: case
    index -> layers to leave out of its bundle."""
    cases = []
    for k in range(n):
        c = _write_case(root / "GT_emission_envmap", f"9C4A{k:04d}-crop_B0{k}", k, "blender-camera",
                        (broken or {}).get(k, ()), size)
        write_bg_maps(root / "GT_emission_envmap" / c.name, c.name, c.scene)
        cases.append(c)
    return cases


def _write_case(base: Path, name: str, k: int, normals_frame: str, drop=(), size: int = SIZE) -> ReplicaCase:
    sc, b, bg, comp = make_case(k % 4, size)
    (base / name).mkdir(parents=True)
    write_bundle(base / name / f"{name}_bundle0001.exr", bundle_channels(b, bg, comp, normals_frame=normals_frame,
                                                                         drop=drop))
    return ReplicaCase(name, sc, b, bg, comp)


def make_spotlight_archive(data: Path, n: int = 2) -> list[ReplicaCase]:
    """``data/rendered_2024-10-20_19-07-58_control/<case>/...``, ``data/WACV_bg_estimates/``,
    ``data/shadows/`` (SpotLight's README downloads)."""
    from PIL import Image

    cases = []
    root = data / "rendered_2024-10-20_19-07-58_control"
    for k in range(n):
        c = _write_case(root, f"AG8A{k:04d}-spot_{k}", k, "opengl")
        name, sc, folder = c.name, c.scene, root / c.name
        frames = [{"name": "0000", "blender_light_xyz_position_object_space": list(PATH_LIGHT)},
                  {"name": "gt_dir", "blender_light_xyz_position_object_space": list(GT_LIGHT)}]
        (folder / f"{name}_light_path_dto.json").write_text(json.dumps({"light_frames": frames}))
        write_bg_maps(data / "WACV_bg_estimates" / name, name, sc)
        sh = data / "shadows" / name
        sh.mkdir(parents=True)
        for f in ("0000", "gt_dir"):
            Image.fromarray(np.zeros(sc.depth.shape, np.uint8)).save(sh / f"shadow_positive_{f}.png")
        cases.append(c)
    return cases
