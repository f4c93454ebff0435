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
    alpha = np.maximum(rough * rough, gcfg.min_alpha)
    dirs, w = gather.ggx_directions(nv, view, alpha, int(gcfg.reflect_rays), pixel_jitter(ys, xs, salt=7))
    L, sky = _met(model, camera, depth, P, nv, dirs, ys, xs, int(gcfg.reflect_steps), occluder, scene_only, images,
                  march)
    # the rays that escape see the sky: its prefiltered radiance toward the mirror
    # direction over the lobe's share above the horizon (one smooth lookup, not the few
    # rays' own: the split sum's, occluded by what the rays met)
    r = 2.0 * np.sum(nv * view, 1)[:, None] * nv - view
    up_share = 1.0 - prefiltered.lookup(r, rough, ground=np.ones(3))[:, :1] + prefiltered.lookup(r, rough)[:, :1]
    L_sky = prefiltered.lookup(r, rough) / np.maximum(up_share, 0.05)
    W = np.maximum(w.sum(0), 1e-12)
    return ((w[..., None] * L).sum(0) + (w * sky).sum(0)[:, None] * L_sky) / W[:, None]


def bounce(model, camera, depth, P, nv, ys, xs, *, occluder, scene_only, images, k: int, steps: int,
           march) -> np.ndarray:
    """(M, 3) the shading (irradiance over pi) the object's points ``P`` (M, 3) of unit
    normals ``nv`` (M, 3) receive from what is not sky: ``k`` cosine-distributed rays per
    point (turned per pixel), each bringing the radiance of what it meets (``_met``: the
    floor, a wall, the object itself); the rays that escape bring nothing here (the sky's
    irradiance is counted with its visibility)."""
    from zcomp_cli.scene.skyvis import hemisphere_directions

    dirs = np.stack(hemisphere_directions(nv, pixel_jitter(ys, xs, salt=9), int(k)))
    L, _ = _met(model, camera, depth, P, nv, dirs, ys, xs, int(steps), occluder, scene_only, images, march)
    return L.mean(0)


def _met(model, camera, depth, P, nv, dirs, ys, xs, steps, occluder, scene_only, images, march):
    """((k, M, 3) the radiance each ray ``dirs`` (k, M, 3) meets first, 0 where it escapes
    to the sky; (k, M) bool, it escapes): the photograph's (or the synthesised scene's) at
    the texel or support point it meets in the frame, the support's beyond it or a wall
    beyond the frame as lit as the support, the object's own radiance where it meets the
    object and that point shows in the frame, else the object's mean."""
    scene_rad, obj_rad, obj_px = images
    support = None if model.anchor is None else (model.anchor, model.up)
    seen = gather.trace(P, nv, dirs, depth, camera, cfg=march, steps=steps, jitter=pixel_jitter(ys, xs, salt=8),
                        occluder_mask=scene_only, mesh=occluder, support=support, walls=model.walls)
    kind, ty, tx = seen.kind, seen.texel[..., 0], seen.texel[..., 1]
    L = np.zeros(kind.shape + (3,))
    ground = np.asarray(model.sky.ground, np.float64)
    at = (ty >= 0) & ((kind == gather.SCENE) | (kind == gather.SUPPORT))
    L[at] = scene_rad[ty[at], tx[at]]
    L[((kind == gather.SCENE) & (ty < 0)) | (kind == gather.BEYOND)] = ground
    self_ = kind == gather.OBJECT
    shown = np.zeros_like(self_)
    s = self_ & (ty >= 0)
    shown[s] = obj_px[ty[s], tx[s]] & (np.abs(depth[ty[s], tx[s]] - seen.depth[s])
                                       < march.march_thickness_rel * seen.depth[s])
    L[self_] = obj_rad[obj_px].mean(0) if obj_px.any() else ground
    L[shown] = obj_rad[ty[shown], tx[shown]]
    return L, kind == gather.SKY


__all__ = ["environment", "bounce"]
