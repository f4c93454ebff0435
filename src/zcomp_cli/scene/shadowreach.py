"""Where a given light's shadow of the inserted object falls beyond the shading mask.

The shading mask is a ball around the object; under a low sun its shadow runs past it,
and a shadow cut at the mask's edge is a visible straight end. For a light the
manifest gives (an estimated one's shadow is faded at the mask's edge instead: a wrong
shadow drawn at full length costs more than a cut one), the known pixels in the shadow
of what the mask holds -- marched through the depth map toward each sun and lamp
(``march``), and through the object's mesh (``objectshadow``) -- grown by the widest
penumbra, are re-shaded too. Every renderer that draws the light re-shades the same
pixels (``RenderOutput.shading_mask``), so the compositor's ratio covers them.
"""

from __future__ import annotations

import numpy as np

from zcomp_cli.scene.config import MarchConfig, ReachConfig
from zcomp_cli.scene.depthmesh import has_geometry
from zcomp_cli.scene.march import grid_points, march_visibility
from zcomp_cli.scene.objectshadow import light_shadow


def pass_reach(depth, normals, known, camera, occluder, model, *, march: MarchConfig, cfg: ReachConfig) -> np.ndarray:
    """(H, W) bool: the known pixels in the shadow of what one pass's shading mask holds
    (its unknown pixels of valid depth), grown by the widest penumbra (module
    docstring). ``depth`` (H, W) and ``normals`` (H, W, 3) finite; ``occluder`` the
    object's posed mesh or None; ``model`` the ``LightModel``."""
    import cv2

    d, n = np.asarray(depth, np.float64), np.asarray(normals, np.float64)
    known = np.asarray(known, bool)
    H, W = d.shape
    occ = ~known & (d > 0)
    out = np.zeros((H, W), bool)
    if not occ.any():
        return out
    st = 2 if H * W > cfg.full_res_pixels else 1
    gy, gx, Pg, Ng, ok = grid_points(d, n, has_geometry(d, n), camera, (0, 0, H, W), st)
    for light in (*model.suns, *model.lamps):
        L, dist, _ = light.toward(Pg.reshape(-1, 3))
        L, dist = L.reshape(Pg.shape), dist.reshape(gy.shape)
        cand = known[gy, gx] & ok & (np.sum(Ng * L, -1) > 0.02)
        if not cand.any():
            continue
        ys, xs, P, N = gy[cand], gx[cand], Pg[cand], Ng[cand]
        v, t = march_visibility(P, N, L[cand], d, camera, cfg=march, steps=int(cfg.march_steps), nearest=True,
                                return_distance=True, occluder_mask=occ, max_distance=dist[cand], walls=model.walls)
        if occluder is not None:
            vm, tm = light_shadow(occluder, P, N, light, bias_rel=march.march_bias_rel, cfg=cfg.object_shadow)
            v, t = np.minimum(v, vm), np.minimum(t, tm)
        hit = v < 0.5
        if not hit.any():
            continue
        # the widest penumbra among them (t tan a f / z), then the compositor's blur
        tan_a = light.tan_radius(P[hit])
        pen = float(np.max(t[hit] * tan_a * camera.fx / np.maximum(d[ys[hit], xs[hit]], 1e-6)))
        r = int(np.ceil(min(pen, cfg.max_penumbra_px) + st + 2))
        one = np.zeros((H, W), np.uint8)
        one[ys[hit], xs[hit]] = 1
        k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
        out |= cv2.dilate(one, k) > 0
    return out & known & (d > 0)


def shadow_reach(passes, camera, model, *, march: MarchConfig, cfg: ReachConfig):
    """(grown, reach) over a job's passes -- each ``(depth, normals, known, occluder)``
    -- under ``model``: ``reach`` the known pixels their object's shadow falls on
    (``pass_reach``), ``grown`` the passes' unknown pixels with it; (None, None) where
    it falls inside the mask."""
    reach = None
    unknown = None
    for depth, normals, known, occluder in passes:
        r = pass_reach(depth, normals, known, camera, occluder, model, march=march, cfg=cfg)
        reach = r if reach is None else reach | r
        u = ~np.asarray(known, bool)
        unknown = u if unknown is None else unknown | u
    if reach is None or not (reach & ~unknown).any():
        return None, None
    return unknown | reach, reach


__all__ = ["shadow_reach", "pass_reach"]
