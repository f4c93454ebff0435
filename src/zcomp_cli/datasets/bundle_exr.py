"""One official multi-layer bundle (``<case>_bundle0001.exr``) -> the case's background
photo, its ground-truth composite and a zcomp object bundle, read without Blender.

The layers and how each official loader reads them are described in ``lvsn.py``; the
conversions are applied here, once, and the object's normals are checked to face the
camera (a wrong frame is reported, never passed on).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from zcomp_cli.bundle import ObjectBundle
from zcomp_cli.camera import Camera
from zcomp_cli.conventions import blender_depth_to_z_depth, valid_depth_mask
from zcomp_cli.datasets.lvsn import (FOV_DEG, MIN_FACING_FRACTION, NORMAL_FRAMES, bundle_normals_to_camera,
                                     facing_fraction, group_layers, unpremultiply)
from zcomp_cli.errors import InputError

# Layers zcomp needs from a bundle; roughness and metallic only feed 13-channel models.
REQUIRED_LAYERS = ("albedo", "depth", "footprint_depth", "mask", "normals", "background", "composite")
OPTIONAL_LAYERS = ("roughness", "metallic")


@dataclass(frozen=True)
class BundleReading:
    """How one official loader reads a bundle's layers."""

    dataset: str          # the dataset key zcomp eval knows ("zerocomp-labo", "spotlight")
    loader: str           # the official file that reads it (for messages)
    value_channel: int    # the value's channel in RGBA value layers (depth, footprint...)
    normals_frame: str    # "blender-camera" (z negated) or "opengl" (as stored)
    decode_nonnegative_normals: bool  # a normals layer >= 0 everywhere is n * 0.5 + 0.5


# data/dataset_labo.py: ``src_exr['depth'][:, :, :1]``; comp_normal_to_openrooms_normal.
ZEROCOMP_READING = BundleReading("zerocomp-labo", "lvsn/ZeroComp data/dataset_labo.py", 0, "blender-camera", True)
# src/zerocomp/data/dataset_render.py: ``src_exr['depth'][:, :, 2:4]  # value, alpha``;
# normals ``n * 0.5 + 0.5 * alpha`` (signed, premultiplied).
SPOTLIGHT_READING = BundleReading("spotlight", "lvsn/SpotLight src/zerocomp/data/dataset_render.py", 2, "opengl",
                                  False)


@dataclass
class BundleCase:
    """A case read from its bundle, in zcomp's conventions."""

    background: np.ndarray    # (H, W, 3) linear
    reference: np.ndarray     # (H, W, 3) linear ground-truth composite
    bundle: ObjectBundle
    centre: np.ndarray        # (3,) the object's bounding-box centre estimate, camera frame
    base: np.ndarray          # (3,) its base point (footprint centroid), camera frame
    notes: list[str] = field(default_factory=list)
    checks: dict = field(default_factory=dict)


def _value_layer(layer: np.ndarray, channel: int) -> tuple[np.ndarray, bool]:
    """(straight value (H, W), premultiplied?) of a value layer: ``channel`` (the first
    channel when the layer has fewer), divided by the alpha channel (index 3) when the
    layer has one."""
    c = layer.shape[-1]
    value = layer[..., channel if channel < c else 0]
    if c >= 4:
        return unpremultiply(value, layer[..., 3]), True
    return np.nan_to_num(value, nan=0.0, posinf=0.0, neginf=0.0).astype(np.float32), False


def _colour_layer(layer: np.ndarray) -> np.ndarray:
    c = layer.shape[-1]
    rgb = layer[..., :3] if c >= 3 else np.repeat(layer[..., :1], 3, axis=-1)
    if c >= 4:
        return unpremultiply(rgb, layer[..., 3])
    return np.nan_to_num(rgb, nan=0.0, posinf=0.0, neginf=0.0).astype(np.float32)


def _image_layer(layer: np.ndarray, name: str, notes: list[str]) -> np.ndarray:
    """A photo layer (background, composite): linear RGB, as stored (not premultiplied:
    an opaque photograph); non-finite values -> 0, with a note."""
    rgb = layer[..., :3] if layer.shape[-1] >= 3 else np.repeat(layer[..., :1], 3, axis=-1)
    bad = ~np.isfinite(rgb)
    if bad.any():
        notes.append(f"{name}: {int(bad.any(-1).sum())} non-finite pixels set to 0")
    return np.nan_to_num(rgb, nan=0.0, posinf=0.0, neginf=0.0).astype(np.float32)


# layers named in an error at most (a file may have hundreds)
MAX_LAYERS_SHOWN = 12


def read_bundle(path, reading: BundleReading, *, fov_deg: float = FOV_DEG,
                normals_frame: str | None = None) -> BundleCase:
    """Read one official bundle.

    Args:
        path: the ``*_bundle0001.exr``.
        reading: how its official loader reads it (``ZEROCOMP_READING`` ...).
        fov_deg: the horizontal field of view of the renders (50 in both archives).
        normals_frame: override ``reading.normals_frame`` ("blender-camera" | "opengl").
    Returns:
        BundleCase. The bundle's maps are straight (un-premultiplied) values: depth and
        footprint z-depth in metres (0 = none), camera-frame unit normals, linear albedo,
        the ``mask`` layer as coverage.
    Raises:
        InputError naming the file: a missing layer (all are listed), an empty mask, no
        valid depth under the mask, or normals that face away from the camera in the
        frame the loader assumes.
    """
    from zcomp_cli.imageio import read_exr_channels

    path = Path(path)
    frame = normals_frame or reading.normals_frame
    if frame not in NORMAL_FRAMES:
        raise ValueError(f"unknown normals frame {frame!r}")
    layers = group_layers(read_exr_channels(path))
    missing = [n for n in REQUIRED_LAYERS if n not in layers]
    if missing:
        have = sorted(layers)
        shown = ", ".join(have[:MAX_LAYERS_SHOWN]) + (f" and {len(have) - MAX_LAYERS_SHOWN} more"
                                                       if len(have) > MAX_LAYERS_SHOWN else "")
        raise InputError(f"missing layer{'s' if len(missing) > 1 else ''} {', '.join(missing)} "
                         f"(the file has: {shown or 'no layers'})", where=str(path))
    h, w = layers["mask"].shape[:2]
    camera = Camera.from_fov(fov_deg, w, h)
    notes: list[str] = []

    mask = np.clip(np.nan_to_num(layers["mask"][..., 0]), 0.0, 1.0).astype(np.float32)
    if layers["mask"].shape[-1] > 1:
        notes.append(f"mask: {layers['mask'].shape[-1]} channels, the first is the coverage")
    if not (mask > 0.5).any():
        raise InputError("the mask layer is empty (no pixel > 0.5): the object is not in the frame", where=str(path))
    depth, premult = _value_layer(layers["depth"], reading.value_channel)
    depth = np.where(mask > 0, blender_depth_to_z_depth(depth), 0.0).astype(np.float32)
    if not (valid_depth_mask(depth) & (mask > 0.5)).any():
        raise InputError("the depth layer has no valid depth (> 0) under the mask", where=str(path))
    footprint, _ = _value_layer(layers["footprint_depth"], reading.value_channel)
    footprint = blender_depth_to_z_depth(footprint)
    if not valid_depth_mask(footprint).any():
        notes.append("footprint_depth is empty: zcomp's depth alignment will fall back (and say so)")
    normals = bundle_normals_to_camera(layers["normals"], frame,
                                       decode_nonnegative=reading.decode_nonnegative_normals)
    normals = np.where((mask > 0)[..., None], normals, 0.0).astype(np.float32)
    albedo = np.clip(_colour_layer(layers["albedo"]), 0.0, 1.0)
    albedo = np.where((mask > 0)[..., None], albedo, 0.0).astype(np.float32)
    extra = {}
    for name in OPTIONAL_LAYERS:
        if name in layers:
            v, _ = _value_layer(layers[name], reading.value_channel)
            extra[name] = np.clip(np.where(mask > 0, v, 0.0), 0.0, 1.0).astype(np.float32)
        else:
            notes.append(f"no {name} layer (only 13-channel models read it)")

    obj = (mask > 0.5) & valid_depth_mask(depth)
    facing = facing_fraction(normals, camera.K, obj)
    checks = {"object_normals_facing_fraction": facing, "value_layers_premultiplied": premult,
              "normals_frame": frame}
    if not np.isfinite(facing):  # ("nan%" of its pixels facing away, before)
        raise InputError("the normals layer holds no usable normal under the object's mask (NaN, infinite or "
                         "zero everywhere)", where=str(path))
    if not facing >= MIN_FACING_FRACTION:
        other = [f for f in NORMAL_FRAMES if f != frame][0]
        raise InputError(
            f"the object's normals face away from the camera at {1 - facing:.0%} of its pixels once read "
            f"as {reading.loader} reads them (frame {frame!r}): this bundle's normals are in another frame "
            f"(is it the other archive?); --bundle-normals {other} reads them as {other!r}", where=str(path))

    background = _image_layer(layers["background"], "background", notes)
    reference = _image_layer(layers["composite"], "composite", notes)
    base, up, height = object_geometry(camera, depth, mask, footprint)
    # the file's name, not its path: the bundle is a job's input (hashed by --resume) and
    # the same archive imported from another folder must give the same bundle
    meta = {"source": Path(path).name, "dataset": reading.dataset, "fov_deg": float(fov_deg),
            "object_height_m": height, "read_by": f"zcomp import ({reading.loader} conventions)"}
    bundle = ObjectBundle(depth=depth, normals=normals, albedo=albedo, mask=mask, footprint_depth=footprint,
                          camera=camera, meta=meta, **extra)
    return BundleCase(background, reference, bundle, base + up * (height / 2.0), base, notes, checks)


def object_geometry(camera: Camera, depth, mask, footprint) -> tuple[np.ndarray, np.ndarray, float]:
    """The object's base point, up direction and height, camera frame, from its depth
    and its footprint (the mesh flattened onto its support plane, which also covers the
    base the camera does not see).

    * up: the normal of a plane fitted to the footprint's points, turned toward the
      object (camera +y when the footprint has fewer than 3 points or no spread);
    * base: the footprint's centroid (the object's lowest point along up without one);
    * height: the object's extent above the base along up.

    Returns (base (3,), up (3,) unit, height >= 0) as float64.
    """
    pts = camera.unproject(np.where(mask > 0.5, depth, 0.0)).astype(np.float64)
    obj = pts[np.isfinite(pts).all(-1)]
    fp_pts = camera.unproject(footprint).astype(np.float64)
    fp = fp_pts[np.isfinite(fp_pts).all(-1)]
    up = np.array([0.0, 1.0, 0.0])
    if len(fp) >= 3:
        c = fp.mean(0)
        _, s, vt = np.linalg.svd(fp - c, full_matrices=False)
        if s[1] > 1e-6 * max(s[0], 1e-12):  # a plane, not a line of points
            up = vt[-1]
            if len(obj) and float((obj.mean(0) - c) @ up) < 0:
                up = -up
        base = c
    elif len(obj):
        base = obj[np.argmin(obj @ up)]
    else:
        base = np.zeros(3)
    height = float(max(0.0, np.max((obj - base) @ up))) if len(obj) else 0.0
    return base, up, height
