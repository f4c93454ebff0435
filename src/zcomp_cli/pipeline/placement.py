"""``placement: {pixel: [x, y], yaw_deg, height}`` -> a camera-frame ``Pose``.

The object's base goes on the background surface seen at the pixel, upright along the
background normal there (mesh +Y aligned with the normal), turned by ``yaw_deg`` about
that up axis."""

from __future__ import annotations

import numpy as np

from zcomp_cli.camera import Camera
from zcomp_cli.conventions import valid_depth_mask
from zcomp_cli.errors import GeometryError
from zcomp_cli.pipeline.manifest import Placement
from zcomp_cli.pose import Pose, euler_deg_to_matrix, rotation_aligning


def pose_from_placement(placement: Placement, depth, normals, camera: Camera, *, window: int = 2) -> Pose:
    """Place the object's base point at the surface seen at ``placement.pixel``.

    Args:
        depth: (H, W) background z-depth (0 invalid); normals: (H, W, 3) camera frame.
        window: half-size of the neighbourhood averaged for a robust normal (and used
            to find a valid depth if the exact pixel has none).
    Raises:
        GeometryError if no valid depth/normal is near the pixel.
    """
    x, y = placement.pixel
    col, row = int(np.floor(x)), int(np.floor(y))
    h, w = depth.shape
    if not (0 <= col < w and 0 <= row < h):
        raise GeometryError(f"placement pixel {[x, y]} is outside the {w}x{h} image")
    r0, r1 = max(0, row - window), min(h, row + window + 1)
    c0, c1 = max(0, col - window), min(w, col + window + 1)
    d = depth[r0:r1, c0:c1]
    n = normals[r0:r1, c0:c1].reshape(-1, 3)
    valid = valid_depth_mask(d).reshape(-1) & (np.linalg.norm(n, axis=-1) > 0.5)
    if not valid.any():
        raise GeometryError(f"no valid background depth/normal near placement pixel {[x, y]}")
    if valid_depth_mask(depth[row, col]) and np.linalg.norm(normals[row, col]) > 0.5:
        z = float(depth[row, col])
    else:
        z = float(np.median(d.reshape(-1)[valid]))
    # Base point: the ray through the exact (sub-pixel) position at that depth.
    px = camera.ray(x, y) * z
    up = n[valid].mean(axis=0)
    up /= max(np.linalg.norm(up), 1e-12)
    if not np.all(np.isfinite(up)) or np.linalg.norm(up) < 0.5:
        raise GeometryError(f"degenerate background normal at placement pixel {[x, y]}")
    R = rotation_aligning([0.0, 1.0, 0.0], up) @ euler_deg_to_matrix(0.0, placement.yaw_deg, 0.0)
    return Pose(position=tuple(px.tolist()), rotation=R, scale=placement.scale, height=placement.height)
