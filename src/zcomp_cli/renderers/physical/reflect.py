"""What the object's glossy layer reflects of its surroundings (``scene.gather``).

The split-sum approximation (``gloss``) reflects the sky prefiltered toward the mirror
direction, occluded as the diffuse sky is. A path tracer's glossy object reflects what
its lobe meets: the floor it stands on (with its own shadow on it), the walls, itself
(a torus's hole), and the sky only where the lobe escapes. ``environment`` gathers a few
GGX-distributed rays per pixel (``GlossConfig.reflect_rays``) and averages, weighted by
``n.l``, the radiance each meets: the photograph's (or the synthesised floor's) at the
texel a ray meets, the object's own diffuse radiance where it meets the object, the
support's radiance beyond the frame, the prefiltered sky where it escapes. The
neighbours' rays are averaged over the object (``reflect_blur_px``).
"""

from __future__ import annotations

import numpy as np

from zcomp_cli.scene import gather
from zcomp_cli.scene.sampling import pixel_jitter


def environment(model, camera, depth, P, nv, view, rough, ys, xs, *, occluder, scene_only, images, prefiltered,
                gcfg, march) -> np.ndarray:
    """(M, 3) the radiance the GGX lobe of roughness ``rough`` (M,) reflects toward
    ``view`` (M, 3) at the object's points ``P`` (M, 3) of unit normals ``nv`` (M, 3),
    pixels (``ys``, ``xs``); ``images``: (scene radiance (H, W, 3): the photograph, the
    synthesised scene where it was re-shaded; the object's radiance (H, W, 3); the pixels
    showing the object (H, W) bool)."""
    scene_rad, obj_rad, obj_px = images
    alpha = np.maximum(rough * rough, gcfg.min_alpha)
    jit = pixel_jitter(ys, xs, salt=7)
    dirs, w = gather.ggx_directions(nv, view, alpha, int(gcfg.reflect_rays), jit)
    support = None if model.anchor is None else (model.anchor, model.up)
    seen = gather.trace(P, nv, dirs, depth, camera, cfg=march, steps=int(gcfg.reflect_steps),
                        jitter=pixel_jitter(ys, xs, salt=8), occluder_mask=scene_only, mesh=occluder,
                        support=support, walls=model.walls)
    K, M = w.shape
    L = np.zeros((K, M, 3))
    kind, ty, tx = seen.kind, seen.texel[..., 0], seen.texel[..., 1]
    ground = np.asarray(model.sky.ground, np.float64)
    obj_mean = obj_rad[obj_px].mean(0) if obj_px.any() else ground
    sky = kind == gather.SKY
    rk = np.broadcast_to(rough, (K, M))
    L[sky] = prefiltered.lookup(dirs[sky], rk[sky], ground=ground)
    at = (ty >= 0) & ((kind == gather.SCENE) | (kind == gather.SUPPORT))
    L[at] = scene_rad[ty[at], tx[at]]
    L[(kind == gather.SCENE) & (ty < 0)] = ground  # a wall beyond the frame: as lit as the support
    L[kind == gather.BEYOND] = ground
    self_ = kind == gather.OBJECT
    seen_ = self_ & (ty >= 0)
    vis = np.zeros_like(self_)
    vis[seen_] = obj_px[ty[seen_], tx[seen_]] & (np.abs(depth[ty[seen_], tx[seen_]] - seen.depth[seen_])
                                                  < march.march_thickness_rel * seen.depth[seen_])
    L[self_] = obj_mean
    L[vis] = obj_rad[ty[vis], tx[vis]]
    return (w[..., None] * L).sum(0) / np.maximum(w.sum(0), 1e-12)[:, None]


__all__ = ["environment"]
