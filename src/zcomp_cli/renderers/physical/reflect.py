"""What the object's glossy layer reflects of its surroundings (``scene.gather``).

The split-sum approximation (``gloss``) reflects the sky prefiltered toward the mirror
direction, occluded as the diffuse sky is. A path tracer's glossy object reflects what
its lobe meets: the floor it stands on (with its own shadow on it), the walls, itself
(a torus's hole), and the sky only where the lobe escapes. ``environment`` gathers a few
GGX-distributed rays per pixel (``GlossConfig.reflect_rays``) and averages the radiance
each meets, weighted by the BRDF over the rays' density with its Fresnel term
(``lobe_weights``; the split sum's n.l took a grazing lobe's light 5-22 % too low where
the sky is brighter on its grazing side): the photograph's (or the synthesised floor's)
at the texel a ray meets, the object's own diffuse radiance where it meets the object,
the support's beyond the frame (what it reflects of the light, measured where the frame
shows it, times the light's shading at the point the ray meets:
``LightModel.open_shading``, a lamp's falling off with its distance), and where it
escapes the prefiltered sky at the ray's own direction, filtered to its share of the
lobe (filtered importance sampling). The neighbours' rays are averaged over the object
(``reflect_blur_px``).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from zcomp_cli.scene import gather
from zcomp_cli.scene.sampling import pixel_jitter


class Surroundings(NamedTuple):
    """What the object's rays read where they meet something: ``scene`` (H, W, 3) the
    scene's radiance (the photograph, the synthesised scene where it was re-shaded);
    ``own`` (H, W, 3) the object's radiance; ``shown`` (H, W) bool the pixels showing the
    object; ``support`` (3,) what the support reflects of the light
    (``support_reflectance``) or None (not measured: the support beyond the frame is as
    bright as the sky's ``ground``)."""

    scene: np.ndarray
    own: np.ndarray
    shown: np.ndarray
    support: np.ndarray | None = None


def support_reflectance(points: np.ndarray, normals: np.ndarray, image: np.ndarray, valid: np.ndarray,
                        model, trim: float) -> np.ndarray | None:
    """(3,) what the support reflects of the light, linear RGB: the mean, over its pixels
    (``depthmesh.support_mask``) among ``valid`` (H, W), of the photograph ``image``
    (H, W, 3) over the shading ``model`` (a ``LightModel``) gives them with nothing
    hiding its lights (``LightModel.open_shading``), at camera-frame ``points`` (H, W, 3)
    of unit ``normals`` (H, W, 3). Its albedo (with its specular layer) times the share
    of the light the scene lets reach it (walls hiding the sky, shadows), as the frame
    shows them: a support point beyond the frame reflects this much of the light there.
    The mean, not the median: a ray bundle gathers a checkered floor's mean, and the
    median of a two-tone checker is one of its tones (0.6 of the mean on a development
    case, docs/calibration-record.md); trimmed by ``trim`` at either end
    (``TransportConfig.support_trim``), so that a glint of the sun toward the camera (an
    HDR photograph's floor pixels 1000 times the rest) does not light the floor beyond
    the frame, while a checker's two tones keep their mean (against the plain mean the
    object moved by -0.03 to +0.07 dB on three seeds). None where fewer than 3 pixels
    show the support or the light leaves them dark."""
    from zcomp_cli.scene.depthmesh import support_mask

    img = np.asarray(image, np.float64)[..., :3]
    ok = np.asarray(valid, bool) & np.all(np.isfinite(img), -1) & np.all(np.isfinite(points), -1) \
        & np.all(np.isfinite(normals), -1)
    sup, _ = support_mask(np.nan_to_num(points), np.nan_to_num(normals), ok, model.up)
    if sup.sum() < 3:
        return None
    E = model.open_shading(points[sup], model.up)
    lit = E.mean(1) > 1e-6 * max(float(E.mean(1).max()), 1e-30)
    if lit.sum() < 3:
        return None
    r = np.clip(img[sup][lit], 0.0, None) / E[lit]
    # the trimmed mean as scipy.stats.trim_mean takes it (int(trim n) off either end),
    # without the 0.6 s its import adds to a job's process
    cut = int(float(trim) * len(r))
    if cut > 0:
        r = np.partition(r, (cut, len(r) - cut - 1), axis=0)[cut:len(r) - cut]
    return r.mean(0)


def environment(model, camera, depth, P, nv, view, rough, ys, xs, *, occluder, scene_only, images, prefiltered,
                gcfg, march, layers=None) -> np.ndarray:
    """(M, 3) the radiance the GGX lobe of roughness ``rough`` (M,) reflects toward
    ``view`` (M, 3) at the object's points ``P`` (M, 3) of unit normals ``nv`` (M, 3),
    pixels (``ys``, ``xs``); ``images``: what the rays read (``Surroundings``);
    ``layers``: (metallic (M,), base colour (M, 3)), whose Fresnel weighs the lobe (None:
    a dielectric)."""
    alpha = np.maximum(rough * rough, gcfg.min_alpha)
    k = int(gcfg.reflect_rays)
    dirs, nl = gather.ggx_directions(nv, view, alpha, k, pixel_jitter(ys, xs, salt=7))
    L, sky = _met(model, camera, depth, P, nv, dirs, ys, xs, int(gcfg.reflect_steps), occluder, scene_only, images,
                  march)
    w, g, vh, nh = lobe_weights(nv, view, dirs, alpha, nl, layers)
    # the rays that escape see the sky: each its prefiltered radiance at its own direction,
    # over the share of the lobe the ray stands for (filtered importance sampling,
    # Krivanek and Colbert 2008: the solid angle 1 / (k pdf), as the roughness whose
    # prefilter lobe, about 4 pi alpha^2, covers it; at most the surface's own), over
    # that lookup's share above the horizon
    a = alpha[None]
    D = a * a / (np.pi * (nh * nh * (a * a - 1.0) + 1.0) ** 2)
    omega = 4.0 * vh / np.maximum(k * D * nh, 1e-12)
    rho = np.minimum(np.sqrt(np.sqrt(omega / (4.0 * np.pi))), np.broadcast_to(rough[None], omega.shape))
    esc = sky & (g > 0)
    L_sky = np.zeros(L.shape)
    if esc.any():
        d_e, r_e = dirs[esc], rho[esc]
        got = prefiltered.lookup(d_e, r_e)
        share = 1.0 - prefiltered.lookup(d_e, r_e, ground=np.ones(3))[:, :1] + got[:, :1]
        L_sky[esc] = got / np.maximum(share, 0.05)
    return (w * np.where(esc[..., None], L_sky, L)).sum(0) / np.maximum(w.sum(0), 1e-12)


def lobe_weights(nv, view, dirs, alpha, nl, layers=None):
    """The weights of GGX-sampled rays (``gather.ggx_directions``: directions ``dirs``
    (k, M, 3), their ``nl`` (k, M) n.l, 0 below the surface) that make their weighted
    mean radiance the light the layer reflects over its albedo, ``int L f (n.l) / int f
    (n.l)``, at unit normals ``nv`` (M, 3), toward ``view`` (M, 3), GGX ``alpha`` (M,):
    f (n.l) over the rays' density D(h) n.h / (4 v.h), G F v.h / (n.h n.v) (n.v is one
    per point and drops out). Not the n.l of Karis's prefilter, which assumes n = v:
    at grazing the Fresnel term leans the lobe toward its grazing side (a cylinder's cap
    at n.v = 0.2 under a forest reflected 20 % too little of its sky). F per layer, as
    Cycles' Principled: the dielectric's exact curve weighted 1 - metallic, the metal's
    Schlick curve from its base colour; ``layers``: (metallic (M,), base colour (M, 3)),
    None a dielectric. Returns ((k, M, 3) weights, (k, M) G v.h / n.h, (k, M) v.h,
    (k, M) n.h)."""
    from zcomp_cli.renderers.physical.gloss import fresnel_shape, principled_layers, smith_g

    h = dirs + view[None]
    h /= np.maximum(np.linalg.norm(h, axis=2, keepdims=True), 1e-12)
    vh = np.clip(np.sum(h * view[None], 2), 1e-6, 1.0)
    nh = np.clip(np.sum(h * nv[None], 2), 1e-6, 1.0)
    ndv = np.clip(np.sum(nv * view, 1), 1e-6, 1.0)
    g = np.where(nl > 0, smith_g(np.asarray(alpha)[None], ndv[None], np.clip(nl, 1e-6, 1.0)) * vh / nh, 0.0)
    met, base = (np.zeros(vh.shape[1]), None) if layers is None else layers
    F = sum(w[None, :, None] * (f0[None] + (1.0 - f0[None]) * fresnel_shape(vh, kind)[..., None])
            for w, f0, kind in principled_layers(met, base))
    return g[..., None] * np.broadcast_to(F, vh.shape + (3,)), g, vh, nh


def bounce(model, camera, depth, P, nv, ys, xs, *, occluder, scene_only, images, k: int, steps: int,
           march) -> np.ndarray:
    """(M, 3) the shading (irradiance over pi) the object's points ``P`` (M, 3) of unit
    normals ``nv`` (M, 3) receive from what is not sky: ``k`` cosine-distributed rays per
    point (turned per pixel), each bringing the radiance of what it meets (``_met``: the
    floor, a wall, the object itself; ``images``: ``Surroundings``); the rays that escape
    bring nothing here (the sky's irradiance is counted with its visibility)."""
    from zcomp_cli.scene.skyvis import hemisphere_directions

    dirs = np.stack(hemisphere_directions(nv, pixel_jitter(ys, xs, salt=9), int(k)))
    L, _ = _met(model, camera, depth, P, nv, dirs, ys, xs, int(steps), occluder, scene_only, images, march)
    return L.mean(0)


def _met(model, camera, depth, P, nv, dirs, ys, xs, steps, occluder, scene_only, images, march):
    """((k, M, 3) the radiance each ray ``dirs`` (k, M, 3) meets first, 0 where it escapes
    to the sky; (k, M) bool, it escapes): the photograph's (or the synthesised scene's) at
    the texel or support point it meets in the frame; the support's beyond it, what it
    reflects (``Surroundings.support``) of the light's shading at that point (without
    that measure, and on a wall beyond the frame, the support's radiance the light fit
    measured: ``Sky.ground``); the object's own radiance where it meets the object and
    that point shows in the frame, else the object's mean."""
    scene_rad, obj_rad, obj_px, reflects = images
    support = None if model.anchor is None else (model.anchor, model.up)
    seen = gather.trace(P, nv, dirs, depth, camera, cfg=march, steps=steps, jitter=pixel_jitter(ys, xs, salt=8),
                        occluder_mask=scene_only, mesh=occluder, support=support, walls=model.walls)
    kind, ty, tx = seen.kind, seen.texel[..., 0], seen.texel[..., 1]
    L = np.zeros(kind.shape + (3,))
    ground = np.asarray(model.sky.ground, np.float64)
    at = (ty >= 0) & ((kind == gather.SCENE) | (kind == gather.SUPPORT))
    L[at] = scene_rad[ty[at], tx[at]]
    L[((kind == gather.SCENE) & (ty < 0)) | (kind == gather.BEYOND)] = ground
    beyond = kind == gather.BEYOND
    if reflects is not None and beyond.any():
        met = np.broadcast_to(P, dirs.shape)[beyond] + dirs[beyond] * seen.distance[beyond][:, None]
        L[beyond] = np.asarray(reflects, np.float64)[None] * model.open_shading(met, support[1])
    self_ = kind == gather.OBJECT
    shown = np.zeros_like(self_)
    s = self_ & (ty >= 0)
    shown[s] = obj_px[ty[s], tx[s]] & (np.abs(depth[ty[s], tx[s]] - seen.depth[s])
                                       < march.march_thickness_rel * seen.depth[s])
    L[self_] = obj_rad[obj_px].mean(0) if obj_px.any() else ground
    L[shown] = obj_rad[ty[shown], tx[shown]]
    return L, kind == gather.SKY


__all__ = ["Surroundings", "support_reflectance", "environment", "bounce", "lobe_weights"]
