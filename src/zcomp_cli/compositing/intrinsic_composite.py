"""Intrinsic composite (DESIGN.md section 2, equation 1) with occlusion by nearer
background geometry."""

from __future__ import annotations

import numpy as np

from zcomp_cli.conventions import normalize, valid_depth_mask
from zcomp_cli.maps import SceneMaps


def occlusion_mask(mask, obj_depth, bg_depth, *, tolerance: float = 0.01) -> np.ndarray:
    """The object's coverage after occlusion: 0 where the background is in front.

    Args:
        mask: (H, W) object coverage in [0, 1].
        obj_depth: (H, W) aligned object z-depth (0 = none).
        bg_depth: (H, W) background z-depth (0/non-finite = unknown: never occludes).
        tolerance: relative depth margin (fraction of the object depth) so that the
            object's own support surface, which touches it, does not cut its base.
    Returns:
        (H, W) float32 coverage in [0, 1].
    """
    m = np.clip(np.nan_to_num(np.asarray(mask, dtype=np.float32)), 0.0, 1.0)
    od = np.asarray(obj_depth, dtype=np.float32)
    bd = np.asarray(bg_depth, dtype=np.float32)
    if not (m.shape == od.shape == bd.shape):
        raise ValueError(f"shapes differ: mask {m.shape}, obj {od.shape}, bg {bd.shape}")
    ov = valid_depth_mask(od)
    bv = valid_depth_mask(bd)
    with np.errstate(invalid="ignore"):
        occluded = ov & bv & (bd < od * (1.0 - tolerance))
    # Pixels of partial coverage with no object depth keep their coverage (edges).
    return np.where(occluded, 0.0, m).astype(np.float32)


def composite_intrinsics(bg: SceneMaps, obj: SceneMaps, mask) -> SceneMaps:
    """``i_comp = m * i_obj + (1 - m) * i_bg`` per map.

    Geometry (depth, normals) takes the object value where ``m > 0.5`` (blending depth
    across a silhouette would invent floating points); albedo (and roughness/metallic)
    blend with the soft coverage ``m``.

    Args:
        bg, obj: SceneMaps of the same H x W (object maps 0 outside the object).
        mask: (H, W) coverage after occlusion, in [0, 1].
    Returns:
        The composite SceneMaps (float32).
    """
    m = np.clip(np.asarray(mask, dtype=np.float32), 0.0, 1.0)
    if m.shape != bg.depth.shape or bg.depth.shape != obj.depth.shape:
        raise ValueError("background, object and mask must share H x W")
    hard = m > 0.5
    depth = np.where(hard, obj.depth, bg.depth).astype(np.float32)
    normals = np.where(hard[..., None], obj.normals, bg.normals)
    normals = normalize(normals)
    m3 = m[..., None]
    albedo = (m3 * obj.albedo + (1.0 - m3) * bg.albedo).astype(np.float32)

    def _blend1(a, b):
        if a is None and b is None:
            return None
        a = np.zeros_like(m) if a is None else a
        b = np.zeros_like(m) if b is None else b
        return (m * a + (1.0 - m) * b).astype(np.float32)

    return SceneMaps(
        depth=depth,
        normals=normals,
        albedo=albedo,
        roughness=_blend1(obj.roughness, bg.roughness),
        metallic=_blend1(obj.metallic, bg.metallic),
    )
