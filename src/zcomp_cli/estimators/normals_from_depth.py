"""Camera-frame normals from any z-depth map by robust finite differences."""

from __future__ import annotations

import numpy as np

from zcomp_cli.camera import Camera
from zcomp_cli.conventions import valid_depth_mask
from zcomp_cli.errors import InputError

DEFAULT_DISCONTINUITY = 0.1


def _one_sided(P: np.ndarray, z: np.ndarray, axis: int):
    """Forward and backward differences of points P along ``axis`` and their |dz|
    (inf where the neighbour is missing or invalid)."""
    pad = [(0, 0)] * 3
    pad[axis] = (1, 1)
    Pp = np.pad(P, pad, constant_values=np.nan)
    zp = np.pad(z, pad[:2], constant_values=np.nan)
    sl = lambda a, b: tuple(slice(a, b) if i == axis else slice(None) for i in range(P.ndim))  # noqa: E731
    n = P.shape[axis]
    fwd = Pp[sl(2, n + 2)] - P
    bwd = P - Pp[sl(0, n)]
    jf = np.abs(zp[sl(2, n + 2)[:2]] - z)
    jb = np.abs(z - zp[sl(0, n)[:2]])
    jf = np.where(np.isfinite(jf), jf, np.inf)
    jb = np.where(np.isfinite(jb), jb, np.inf)
    return fwd, bwd, jf, jb


def normals_from_depth(depth, camera: Camera, *,
                       discontinuity_threshold: float = DEFAULT_DISCONTINUITY) -> np.ndarray:
    """Unit normals of the surface seen in a z-depth map.

    Per image axis the tangent is the one-sided difference (forward or backward) with
    the smaller depth jump, so a pixel beside a depth edge uses the neighbour on its own
    surface. Where even the smaller jump exceeds ``discontinuity_threshold * depth`` (a
    one-pixel-wide sliver) the pixel has no usable neighbour and faces the camera
    (normal = -ray direction). The normal is the cross product of the two tangents,
    oriented toward the camera.

    Args:
        depth: (H, W) z-depth in metres; invalid = 0 or non-finite.
        camera: the pinhole camera of the map.
        discontinuity_threshold: relative depth jump treated as a discontinuity (> 0).
    Returns:
        (H, W, 3) float32 camera-frame (OpenGL) unit normals; 0 where depth is invalid.
    """
    depth = np.asarray(depth)
    if depth.ndim != 2:
        raise InputError(f"normals_from_depth: depth must be (H, W), got {depth.shape}")
    if depth.shape != (camera.height, camera.width):
        raise InputError(f"normals_from_depth: depth {depth.shape} does not match the camera "
                         f"{camera.height}x{camera.width}")
    if not (np.isfinite(discontinuity_threshold) and discontinuity_threshold > 0):
        raise InputError("normals_from_depth: discontinuity_threshold must be positive")
    valid = valid_depth_mask(depth)
    z = np.where(valid, depth, np.nan).astype(np.float64)
    P = camera.pixel_rays() * z[..., None]  # NaN where invalid

    tangents = []
    ok = valid.copy()
    for axis in (1, 0):  # columns (x), then rows (y)
        fwd, bwd, jf, jb = _one_sided(P, z, axis)
        use_f = jf <= jb
        t = np.where(use_f[..., None], fwd, bwd)
        jump = np.minimum(jf, jb)
        ok &= jump <= discontinuity_threshold * np.where(valid, z, 0)
        tangents.append(t)
    with np.errstate(invalid="ignore"):
        n = np.cross(tangents[0], tangents[1])
        norm = np.linalg.norm(n, axis=-1, keepdims=True)
        good = ok & np.isfinite(norm[..., 0]) & (norm[..., 0] > 1e-20)
        n = np.where(good[..., None], n / np.where(norm > 0, norm, 1), 0.0)
        # Orient toward the camera: the normal must point against the viewing ray.
        flip = np.sum(n * P, axis=-1) > 0
    n[flip] *= -1
    # Slivers with no neighbour on their own surface: face the camera.
    sliver = valid & ~good
    if sliver.any():
        r = -camera.pixel_rays()
        r /= np.linalg.norm(r, axis=-1, keepdims=True)
        n[sliver] = r[sliver]
    n[~valid] = 0.0
    return n.astype(np.float32)
