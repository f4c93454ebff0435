"""World up for a scene (DESIGN.md section 8): from the camera's pitch and roll when the
manifest gives them, else read off the scene's support plane.

The support plane is the most common upward orientation of the known geometry: the
normals are binned on a sphere of directions (``FrameConfig.support_bins``), only bins
within ``max_tilt_deg`` of the camera's +y vote (a wall facing the camera is no support),
and up is the mean of the normals within ``support_deg`` of the winning bin. Without such
normals, the camera's +y (a level camera).
"""

from __future__ import annotations

import numpy as np

from zcomp_cli.conventions import unit_normal_mask
from zcomp_cli.scene.config import FrameConfig
from zcomp_cli.scene.lightparams import Origin
from zcomp_cli.scene.sampling import fibonacci_sphere
from zcomp_cli.worldframe import up_from_pitch_roll



def support_up(normals: np.ndarray, cfg: FrameConfig | None = None) -> np.ndarray | None:
    """(3,) the support's normal from unit ``normals`` (N, 3), or None when no normal
    lies within ``cfg.max_tilt_deg`` of the camera's +y."""
    cfg = FrameConfig() if cfg is None else cfg
    n = np.asarray(normals, np.float64).reshape(-1, 3)
    n = n[np.all(np.isfinite(n), 1)]
    n = n[unit_normal_mask(n)]
    cam_up = np.array([0.0, 1.0, 0.0])
    n = n[n @ cam_up > np.cos(np.deg2rad(cfg.max_tilt_deg))]
    if len(n) < cfg.min_support_normals:
        return None
    bins = fibonacci_sphere(cfg.support_bins)
    bins = bins[bins @ cam_up > np.cos(np.deg2rad(cfg.max_tilt_deg + cfg.support_deg))]
    near = n @ bins.T > np.cos(np.deg2rad(cfg.support_deg))
    best = bins[int(near.sum(0).argmax())]
    dom = n[n @ best > np.cos(np.deg2rad(cfg.support_deg))].mean(0)
    return dom / max(float(np.linalg.norm(dom)), 1e-12)


def scene_up(context: dict | None, normals: np.ndarray, valid: np.ndarray,
             cfg: FrameConfig | None = None) -> tuple[np.ndarray, Origin]:
    """(world up (3,), where it came from) for a scene: ``context`` the manifest's
    scene light context (``pitch_deg``/``roll_deg`` when given), else the support plane
    of the ``valid`` (H, W) pixels' ``normals`` (H, W, 3), else the camera's +y."""
    cfg = FrameConfig() if cfg is None else cfg
    ctx = context or {}
    if ctx.get("pitch_deg") is not None:
        return up_from_pitch_roll(float(ctx["pitch_deg"]), float(ctx.get("roll_deg") or 0.0)), Origin.MANIFEST
    sel = np.asarray(normals)[np.asarray(valid, bool)]
    if len(sel) > 20000:  # a deterministic stride subsample is plenty for a vote
        sel = sel[np.linspace(0, len(sel) - 1, 20000).astype(np.int64)]
    up = support_up(sel, cfg)
    if up is None:
        return np.array([0.0, 1.0, 0.0]), Origin.DEFAULT
    return up, Origin.SUPPORT


__all__ = ["support_up", "scene_up"]
