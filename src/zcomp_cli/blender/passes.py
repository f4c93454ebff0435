"""Blender render passes -> zcomp intrinsics, as tested numpy functions.

Blender writes its view-layer passes to a multilayer EXR, one part per pass, channels
named ``<ViewLayer>.<Pass>.<Channel>`` (``ViewLayer.Depth.Z``, ``ViewLayer.Normal.X``,
``ViewLayer.albedo.R``...). Conversions done here, never in node graphs:

* Z pass: z-depth with 1e10 on empty pixels -> 0 (``conventions.blender_depth_to_z_depth``);
* Normal pass: world space -> camera frame (``conventions.world_to_camera_normals``);
  zcomp's Blender camera sits at the origin with identity rotation, so this is the
  identity rotation, but going through the function keeps the contract in one place;
* film passes (alpha, AOVs) are averages over the pixel filter, i.e. premultiplied by
  coverage at silhouettes: divide by alpha (``unpremultiply``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from zcomp_cli.conventions import blender_depth_to_z_depth, normalize, world_to_camera_normals
from zcomp_cli.errors import InputError, RenderError

__all__ = [
    "read_multilayer_exr",
    "get_pass",
    "unpremultiply",
    "geometry_maps",
    "appearance_maps",
    "footprint_depth",
    "paste_window",
]


def read_multilayer_exr(path) -> dict[str, np.ndarray]:
    """Read every channel of every part of a (multi-part, multilayer) EXR.

    Returns ``{"Pass.Channel": (H, W) float32}``, the view-layer prefix dropped
    (``ViewLayer.Depth.Z`` -> ``Depth.Z``). Raises InputError if the file is unreadable.
    """
    import OpenImageIO as oiio

    path = Path(path)
    if not path.is_file():
        raise InputError("render output not found", where=str(path))
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise InputError(f"cannot read EXR: {oiio.geterror()}", where=str(path))
    out: dict[str, np.ndarray] = {}
    try:
        sub = 0
        while inp.seek_subimage(sub, 0):
            spec = inp.spec()
            data = inp.read_image(sub, 0, 0, spec.nchannels, oiio.FLOAT)
            if data is None:
                raise InputError(f"cannot decode part {sub}: {inp.geterror()}", where=str(path))
            data = np.asarray(data, dtype=np.float32).reshape(spec.height, spec.width, spec.nchannels)
            for i, name in enumerate(spec.channelnames):
                parts = name.split(".")
                key = ".".join(parts[-2:]) if len(parts) >= 2 else name
                out[key] = data[..., i]
            sub += 1
    finally:
        inp.close()
    return out


def get_pass(channels: dict[str, np.ndarray], name: str, comps: str) -> np.ndarray:
    """Stack channels ``name.c`` for c in ``comps`` -> (H, W) or (H, W, len(comps))."""
    missing = [f"{name}.{c}" for c in comps if f"{name}.{c}" not in channels]
    if missing:
        raise RenderError(f"render output lacks channels {missing} (has {sorted(channels)})")
    arrs = [channels[f"{name}.{c}"] for c in comps]
    return arrs[0] if len(arrs) == 1 else np.stack(arrs, axis=-1)


def unpremultiply(values, alpha, *, eps: float = 1e-4) -> np.ndarray:
    """Divide a premultiplied film pass by its coverage.

    Args:
        values: (H, W) or (H, W, C) premultiplied pass.
        alpha: (H, W) coverage in [0, 1].
        eps: below this coverage the pixel is empty: the result is 0 there.
    Returns:
        float32 of ``values``' shape; non-finite inputs become 0.
    """
    v = np.nan_to_num(np.asarray(values, dtype=np.float32), nan=0.0, posinf=0.0, neginf=0.0)
    a = np.nan_to_num(np.asarray(alpha, dtype=np.float32), nan=0.0)
    if a.shape != v.shape[:2]:
        raise ValueError(f"alpha shape {a.shape} does not match values {v.shape}")
    a = a[..., None] if v.ndim == 3 else a
    out = np.where(a > eps, v / np.maximum(a, eps), 0.0)
    return out.astype(np.float32)


def geometry_maps(channels: dict[str, np.ndarray], cam_to_world=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Depth, normals and hit mask from the 1-sample geometry render.

    Returns:
        depth (H, W) z-depth in metres, 0 where no surface is hit at the pixel centre;
        normals (H, W, 3) camera-frame unit normals, 0 where depth is 0;
        hit (H, W) bool.
    """
    alpha = get_pass(channels, "Combined", "A")
    z = blender_depth_to_z_depth(get_pass(channels, "Depth", "Z"))
    # With one sample through the pixel centre, alpha is 0 or 1; require both a hit and
    # a valid depth so that a stray empty sample never yields depth 1e10 or 0 mixes.
    hit = (np.nan_to_num(alpha) > 0.5) & (z > 0)
    n_world = get_pass(channels, "Normal", "XYZ")
    M = np.eye(4) if cam_to_world is None else np.asarray(cam_to_world, dtype=np.float64)
    n_cam = world_to_camera_normals(n_world, M)
    # Renormalise: any residual filtering at the silhouette shortens the vectors.
    n_cam = normalize(n_cam)
    depth = np.where(hit, z, 0.0).astype(np.float32)
    normals = np.where(hit[..., None], n_cam, 0.0).astype(np.float32)
    return depth, normals, hit


def appearance_maps(channels: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Mask and un-premultiplied material maps from the anti-aliased render.

    Returns ``{"mask": (H, W) in [0, 1], "albedo": (H, W, 3) linear in [0, 1],
    "roughness": (H, W), "metallic": (H, W)}`` (the last two only when rendered).
    """
    alpha = np.clip(np.nan_to_num(get_pass(channels, "Combined", "A"), nan=0.0), 0.0, 1.0)
    out = {"mask": alpha.astype(np.float32)}
    out["albedo"] = np.clip(unpremultiply(get_pass(channels, "albedo", "RGB"), alpha), 0.0, 1.0)
    for name in ("roughness", "metallic"):
        key = next((k for k in channels if k.startswith(f"{name}.")), None)
        if key is not None:
            out[name] = np.clip(unpremultiply(channels[key], alpha), 0.0, 1.0)
    return out


def footprint_depth(channels: dict[str, np.ndarray]) -> np.ndarray:
    """Footprint z-depth (H, W) from the flattened-mesh render; 0 outside it. Needs only
    the alpha and Z passes (the same hit rule as ``geometry_maps``)."""
    alpha = get_pass(channels, "Combined", "A")
    z = blender_depth_to_z_depth(get_pass(channels, "Depth", "Z"))
    hit = (np.nan_to_num(alpha) > 0.5) & (z > 0)
    return np.where(hit, z, 0.0).astype(np.float32)


def paste_window(values, box, width: int, height: int) -> np.ndarray:
    """Put a map rendered in a pixel window back into a full frame of zeros.

    Args:
        values: (h, w) or (h, w, C) map of the window.
        box: ``[x0, x1, y0, y1]`` pixels (top-left origin, ends exclusive), or None when
            ``values`` already covers the frame.
        width, height: the full frame.
    Returns:
        (height, width[, C]) array of ``values``' dtype, zero outside the window (zero is
        "no surface" for every map: depth, normals, coverage, albedo).
    Raises:
        RenderError when the window's size does not match ``values``.
    """
    v = np.asarray(values)
    if box is None:
        if v.shape[:2] != (height, width):
            raise RenderError(f"render is {v.shape[1]}x{v.shape[0]}, expected {width}x{height}")
        return v
    x0, x1, y0, y1 = (int(b) for b in box)
    if not (0 <= x0 < x1 <= width and 0 <= y0 < y1 <= height) or v.shape[:2] != (y1 - y0, x1 - x0):
        raise RenderError(f"border render is {v.shape[1]}x{v.shape[0]}, expected window {box} "
                          f"of a {width}x{height} frame")
    out = np.zeros((height, width) + v.shape[2:], dtype=v.dtype)
    out[y0:y1, x0:x1] = v
    return out
