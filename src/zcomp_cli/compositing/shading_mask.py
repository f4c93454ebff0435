"""Shading mask (DESIGN.md section 2, equation 3).

A background pixel is masked (its shading becomes unknown to the renderer) when its 3D
point lies within ``d = λ * (max_y - min_y)`` of the nearest object point, ``y`` being
the vertical extent of the object's 3D points. Object pixels are masked too. Pixels
directly above the object (in its image columns, above its top-most pixel) are never
masked: the object cannot shade them, and masking them would erase the background.

Speed: instead of all-pairs distances, background points are first tested against the
object's 3D bounding box grown by ``d`` (a cheap vectorised test), and only the
survivors are queried in a k-d tree of the object points.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from zcomp_cli.camera import Camera
from zcomp_cli.conventions import valid_depth_mask


@dataclass
class ShadingMaskResult:
    mask: np.ndarray  # (H, W) bool, True = shading unknown
    radius_m: float
    object_extent_m: float
    candidates: int  # background pixels tested against the k-d tree


def shading_mask(
    bg_depth,
    obj_depth,
    obj_mask,
    camera: Camera,
    *,
    radius_scale: float = 1.0,
    up=(0.0, 1.0, 0.0),
    max_object_points: int = 20000,
) -> ShadingMaskResult:
    """Compute the shading mask s.

    Args:
        bg_depth: (H, W) background z-depth (metres, 0 invalid). Invalid pixels are
            masked only if they are object pixels.
        obj_depth: (H, W) aligned object z-depth (0 outside the object).
        obj_mask: (H, W) object coverage after occlusion in [0, 1]; > 0 counts as object.
        camera: the view's intrinsics.
        radius_scale: λ (1.0 in the paper).
        up: direction of "vertical" in the camera frame for the extent (camera y by
            default, as in the paper).
        max_object_points: object points are subsampled to at most this many for the
            k-d tree (the object surface is smooth at that density).
    Returns:
        ShadingMaskResult with the boolean mask.
    """
    from scipy.spatial import cKDTree

    bg_depth = np.asarray(bg_depth, dtype=np.float32)
    obj_depth = np.asarray(obj_depth, dtype=np.float32)
    om = np.asarray(obj_mask, dtype=np.float32)
    h, w = bg_depth.shape
    if obj_depth.shape != (h, w) or om.shape != (h, w) or (camera.height, camera.width) != (h, w):
        raise ValueError("bg_depth, obj_depth, obj_mask and camera must share H x W")
    if not np.isfinite(radius_scale) or radius_scale < 0:
        raise ValueError(f"radius_scale must be >= 0, got {radius_scale}")

    is_obj = np.nan_to_num(om) > 0
    out = is_obj.copy()
    obj_valid = is_obj & valid_depth_mask(obj_depth)
    if not obj_valid.any():
        return ShadingMaskResult(out, 0.0, 0.0, 0)

    obj_pts = camera.unproject(np.where(obj_valid, obj_depth, 0.0))[obj_valid].astype(np.float64)
    up = np.asarray(up, dtype=np.float64)
    up = up / max(np.linalg.norm(up), 1e-12)
    heights = obj_pts @ up
    extent = float(heights.max() - heights.min())
    d = radius_scale * extent
    if len(obj_pts) > max_object_points:
        step = int(np.ceil(len(obj_pts) / max_object_points))
        obj_pts_tree = obj_pts[::step]
    else:
        obj_pts_tree = obj_pts

    if d > 0:
        bg_valid = valid_depth_mask(bg_depth) & ~is_obj
        lo = obj_pts.min(axis=0) - d
        hi = obj_pts.max(axis=0) + d
        pts = camera.unproject(np.where(bg_valid, bg_depth, 0.0)).astype(np.float64)
        with np.errstate(invalid="ignore"):
            near_box = bg_valid & np.all((pts >= lo) & (pts <= hi), axis=-1)
        cand = np.flatnonzero(near_box)
        if cand.size:
            tree = cKDTree(obj_pts_tree)
            dist, _ = tree.query(pts.reshape(-1, 3)[cand], k=1, distance_upper_bound=d)
            # Subsampling can only overestimate distances, by at most the sampling gap.
            hit = cand[np.isfinite(dist) & (dist <= d)]
            out.reshape(-1)[hit] = True
    else:
        cand = np.array([], dtype=np.int64)

    # Never mask pixels above the object's top-most pixel in each of its columns.
    cols = np.flatnonzero(is_obj.any(axis=0))
    if cols.size:
        top = np.argmax(is_obj[:, cols], axis=0)  # first object row per column
        rows = np.arange(h)[:, None]
        above = rows < top[None, :]
        sub = out[:, cols]
        sub[above] = False
        out[:, cols] = sub
    return ShadingMaskResult(out, float(d), extent, int(cand.size))
