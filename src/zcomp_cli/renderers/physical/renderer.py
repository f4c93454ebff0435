"""PhysicalRenderer: screen-space transport of the scene's fitted light, no weights
(DESIGN.md sections 5 and 8).

Steps of ``render``:

1. the scene's light: the request's fitted light (``RenderRequest.fitted_light``, the
   light stage's: ``zcomp_cli.light``), or, for a caller who gave none, the same stage
   run here (kept per scene for the renderer's life);
2. for a light the manifest gives, where the object's shadow falls beyond the shading
   mask (``scene.shadowreach``: the mask is grown along it);
3. each request: known pixels reproduce albedo x shading exactly; the others are
   synthesised with the light model's transport (``scene.lightmodel``): the sky through
   its visibility (screen-space occlusion, and the object's mesh), the support's bounce,
   each sun and lamp with its soft shadow, the scene's albedo offset, and on the object
   its glossy reflection where the bundle has roughness and metallic maps.

With ``--debug`` (``RenderRequest.debug``), a job whose light's fit read the photograph's shadows
also returns the evidence the fit read, at the job's resolution, as
``RenderOutput.debug_maps`` (``light.evidence_maps``: the soft cast-shadow mask, its
confidence, the support's shadow ratio, the casters and the support).
"""

from __future__ import annotations

import time
from typing import Sequence

import numpy as np

from zcomp_cli.conventions import DEFAULT_SEED
from zcomp_cli.errors import NumericalError, UsageError
from zcomp_cli.light.stage import FittedLight, SceneLight, clean
from zcomp_cli.renderers.base import Renderer, RenderOutput, RenderRequest
from zcomp_cli.renderers.lighting import request_light, request_reach
from zcomp_cli.renderers.physical.settings import PhysicalSettings
from zcomp_cli.renderers.physical.softshadow import blur_reach, classwise_blur, penumbra_filter
from zcomp_cli.scene.depthmesh import has_geometry
from zcomp_cli.scene.lightmodel import LightModel, ShadowKind, disc_shading
from zcomp_cli.scene.march import grid_points, march_visibility
from zcomp_cli.scene.sampling import disc_samples, length, pixel_jitter
from zcomp_cli.scene.skyvis import sky_samples, weighted_visibility
from zcomp_cli.threads import compute_threads


class PhysicalRenderer(Renderer):
    """Embedded renderer. Settings: ``settings.PhysicalSettings`` (all optional);
    unknown names or bad values raise UsageError."""

    name = "physical"
    uses_light = True

    def __init__(self, **settings):
        self._settings = PhysicalSettings.from_kwargs(**settings)
        # the light stage for a caller who gives no fitted light (memory only)
        self._lights = SceneLight(self._settings.light)

    def settings(self) -> dict:
        return {"name": self.name, **self._settings.as_dict()}

    def light_config(self):
        return self._settings.light

    # step 1: the light
    def fitted_light(self, req: RenderRequest, seed: int = DEFAULT_SEED) -> FittedLight:
        """The scene's fitted light (``request_light``)."""
        return request_light(req, self._lights, seed)

    def light(self, req: RenderRequest, seed: int = DEFAULT_SEED) -> LightModel:
        """The scene's light model (``fitted_light``'s)."""
        return self.fitted_light(req, seed).model

    @staticmethod
    def _inputs(req: RenderRequest):
        m = req.maps
        d = clean(m.depth, 0.0, 1e6)
        n = clean(m.normals, -1.0, 1.0)
        sh = clean(req.shading, 0.0, 1e6)
        return d, n, sh, np.asarray(req.known, bool)

    def render(self, requests: Sequence[RenderRequest], *, seed: int = DEFAULT_SEED) -> RenderOutput:
        if not requests:
            raise UsageError("physical renderer needs at least one request")
        timings = {"estimate": 0.0, "synthesis": 0.0}
        t0 = time.perf_counter()
        fitted = self.fitted_light(requests[0], seed)
        model, evidence = fitted.model, fitted.evidence
        timings["estimate"] = time.perf_counter() - t0
        t1 = time.perf_counter()
        # step 2: where a given light's shadow falls beyond the mask
        grown, reach = request_reach(requests, model, self._settings.light)
        if grown is not None:
            requests = [_grown_request(req, reach) for req in requests]
        timings["shadow_reach"] = time.perf_counter() - t1
        t1 = time.perf_counter()
        from zcomp_cli.renderers.physical.gloss import BUILT

        built = len(BUILT)
        images, layers = zip(*[self._render_one(req, model) for req in requests])
        timings["synthesis"] = time.perf_counter() - t1
        if len(BUILT) > built:  # (the job's ledger: a glossy prefilter built, not reused)
            timings["prefilter_built"] = float(sum(BUILT[built:]))
        light = model.to_info()
        info = {"light": light, "fallback": light["fallback"], "shadow": str(model.shadows),
                "settings": self.settings()}
        debug_maps = {}
        if evidence is not None and any(getattr(r, "debug", False) for r in requests):
            # the light's evidence at the job's resolution (``evidence_maps``)
            debug_maps = evidence.maps(np.shape(requests[0].known))
        return RenderOutput(images=list(images), info=info, timings=timings, shading_mask=grown, debug_maps=debug_maps,
                            object_layers=list(layers))

    def _render_one(self, req: RenderRequest, model: LightModel) -> np.ndarray:
        # step 3: known pixels reproduce albedo * known shading exactly
        d, n, sh, known = self._inputs(req)
        alb = clean(req.maps.albedo, 0.0, 1e6)
        H, W = d.shape
        out_sh = sh.copy()
        unknown = ~known
        x0, y0, x1, y1 = (0, 0, W, H) if req.roi is None else req.roi
        x0, y0 = max(0, int(x0)), max(0, int(y0))
        x1, y1 = min(W, int(x1)), min(H, int(y1))
        todo = np.zeros((H, W), bool)
        todo[y0:y1, x0:x1] = True
        todo &= unknown
        # unknown pixels outside roi: a flat sky guess, finite but unused
        out_sh[unknown & ~todo] = model.sky.shading(model.up[None])[0]
        if todo.any():
            cov = getattr(req, "coverage", None)
            cov = np.zeros((H, W)) if cov is None else np.clip(np.nan_to_num(np.asarray(cov, np.float64)), 0, 1)
            pos = d > 0
            # (per channel: three contiguous gathers, a third of one (N, 3) gather's time)
            alb_mean = np.array([alb[..., c][pos].mean() for c in range(3)]) if pos.any() else np.zeros(3)
            whole = pos & (cov > 0.5)
            obj_mean = np.array([alb[..., c][whole].mean() for c in range(3)]) if whole.any() else None
            # shaded a little past the region asked for: the film filter and the edge's
            # layers read their neighbours, so a region of interest gets the values the
            # whole frame would
            import cv2

            r = int(np.ceil(3 * self._settings.transport.film_sigma_px + self._settings.transport.edge_reach_px))
            todo_c = cv2.dilate(todo.astype(np.uint8), np.ones((2 * r + 1,) * 2, np.uint8)) > 0
            todo_c &= unknown
            radiance, own = self._synthesise(d, n, todo_c, req.camera, model, alb_mean, req.occluder, unknown,
                                             alb, cov, req.maps.roughness, req.maps.metallic,
                                             alb * out_sh if req.image is None else req.image, req.object_maps,
                                             obj_mean)
        img = alb * out_sh
        layer = None
        if todo.any():
            keep = todo[todo_c]
            img[todo] = radiance[keep]
            if own is not None:
                layer = img.copy()
                layer[todo] = own[keep]
                layer = layer.astype(np.float32)
        img = img.astype(np.float32)
        if not np.all(np.isfinite(img)):
            bad = int((~np.isfinite(img)).sum())
            raise NumericalError(f"physical renderer produced {bad} non-finite values")
        if layer is not None and not np.all(np.isfinite(layer)):
            raise NumericalError("physical renderer produced non-finite values in the object's layer")
        return img, layer

    def _sky_visibility(self, d, n, todo, camera, occluder, geo_all, albedo_mean, model: LightModel, unknown=None):
        """(the share of ``model``'s sky the scene leaves the todo pixels (M, 3) (its
        radiance weighs the directions: a given probe's map, else its SH; its walls
        occlude), the share of what it leaves that the object's mesh hides (M, 3), the
        scene-only occluder mask or None): the scene's screen-space occlusion on a
        stride-2 grid (4 on large frames), each direction weighted by the sky's radiance
        there (``weighted_visibility``'s sums, pooled by a class-aware blur before they
        are divided: a share from a pixel's few directions, where one bright direction
        decides it, is biased toward 1); the object's mesh occlusion at every pixel
        (``_object_sky``)."""
        radiance_sh, walls = model.sky.radiance_sh, model.walls
        cfg = self._settings.transport
        H, W = d.shape
        ys, xs = np.nonzero(todo)
        ao_st = 4 if H * W > cfg.full_res_pixels else 2
        ay0, ax0, ay1, ax1 = _window(ys, xs, H, W, int(3 * max(cfg.sky_blur_px, 1.5 * ao_st)) + 4, even=ao_st)
        gy, gx, P, N, ok = grid_points(d, n, geo_all, camera, (ay0, ax0, ay1, ax1), ao_st)
        rad = max(cfg.sky_blur_px, 1.5 * ao_st)
        # only the grid points a todo pixel's blur reads (its kernel's reach, plus a
        # block: a pixel takes its block's anchor) are computed; the window's wider
        # margin only keeps the blur's border away from them
        import cv2

        grow = blur_reach(rad) + ao_st
        need = cv2.dilate(todo[ay0:ay1, ax0:ax1].astype(np.uint8), np.ones((2 * grow + 1,) * 2, np.uint8)) > 0
        ok &= need[::ao_st, ::ao_st]
        # the sky's sums sum L V and sum L (3 + 3), pooled by the blur before they are divided
        ao_c = np.ones(gy.shape + (6,))
        scene_only = None
        if occluder is not None:
            # the real mesh is the object's occluder; the depth's shell only the scene's
            # (``mesh_silhouette``): one silhouette for every light and the sky
            from zcomp_cli.scene.objectshadow import mesh_silhouette

            scene_only = ~mesh_silhouette(occluder, camera, (H, W))
        if ok.any():
            smp = sky_samples(P[ok], N[ok], gy[ok], gx[ok], d, camera, cfg=self._settings.light.march,
                              occluder_mask=scene_only, walls=walls)
            ao_c[ok] = weighted_visibility(*smp, sky_radiance_of(model, radiance_sh), sums=True)
        h_, w_ = ay1 - ay0, ax1 - ax0
        up2 = lambda a: np.repeat(np.repeat(a, ao_st, 0), ao_st, 1)[:h_, :w_]
        okf = geo_all[ay0:ay1, ax0:ax1]
        cls = _depth_classes(d[ay0:ay1, ax0:ax1])
        # a block straddling a silhouette must not lend the object's value to the floor
        # (a light rim): only pixels of their anchor's class vouch for it; the
        # normalised blur fills the others from their own class
        same = up2(ok) & (up2(cls[::ao_st, ::ao_st]) == cls)
        both = classwise_blur(up2(ao_c), cls, okf & same, rad, fill=okf)[ys - ay0, xs - ax0]
        num, den = both[:, :3], both[:, 3:]
        ao = np.where(den > 1e-12, num / np.maximum(den, 1e-300), 1.0)
        hid = np.zeros_like(ao)
        if occluder is not None:
            hid = self._object_sky(d, n, todo, camera, occluder, model, ys, xs, rad,
                                   todo if unknown is None else unknown)
        return ao, hid, scene_only

    def _object_sky(self, d, n, todo, camera, occluder, model, ys, xs, blur_px, unknown):
        """(M, 3) the share of the sky's irradiance the object's mesh hides from the todo
        pixels (ys, xs), every pixel its own (``meshrays.sky_occlusion``: rays drawn where
        the sky is bright; a contact's darkness within a pixel of the silhouette, where a
        grid and a blur spread it), faded out toward the mask's edge.

        The sky occlusion reaches past the shading mask (a sphere still hides a quarter of
        the sky one radius past its side); cut at the mask's edge it drew an ellipse. It
        fades out over the outer ``mesh_ao_fade`` of the mask's radius, the farthest of
        its pixels from the mesh (in metres: the mask is a ball around the object,
        squeezed on screen below it); any other mask (an API caller's) ends it within
        two blur radii (``blur_px``) of its edge, past the film filter's reach."""
        import cv2
        from scipy.spatial import cKDTree

        from zcomp_cli.scene.meshrays import sky_occlusion
        from zcomp_cli.scene.objectshadow import area_triangles, sample_triangles

        cfg = self._settings.transport
        P = camera.ray(xs + 0.5, ys + 0.5) * d[ys, xs][:, None]
        N = n[ys, xs].astype(np.float64)
        N = N / np.maximum(length(N), 1e-12)[:, None]
        occ = sky_occlusion(occluder, P, N, sky_pool_of(model, self._settings.gloss, cfg), cfg.sky_rays,
                            pixel_jitter(ys, xs, salt=5), cfg.mesh_ray_bias_rel * np.maximum(-P[:, 2], 1e-6))
        tri, _, area, _ = area_triangles(occluder)
        if not len(tri):
            return occ
        cen = sample_triangles(tri, area / area.sum(), cfg.mesh_fade_samples)[1]
        tree = cKDTree(cen)
        # the mask's radius: its farthest pixel from the mesh, whatever region is shaded
        uy, ux = np.nonzero(unknown)
        workers = compute_threads()
        R = (float(tree.query(camera.ray(ux + 0.5, uy + 0.5) * d[uy, ux][:, None], workers=workers)[0].max())
             if len(uy) else 0.0)
        if not R > 0:
            return occ
        # (the fade only where the mesh hides some sky: elsewhere it multiplies 0)
        dist = np.zeros(len(P))
        some = np.flatnonzero(occ.any(1))
        dist[some] = tree.query(P[some], workers=workers)[0]
        t = np.clip((R - dist) / max(cfg.mesh_ao_fade * R, 1e-9), 0.0, 1.0)
        px = cv2.distanceTransform(np.pad(unknown, 1).astype(np.uint8), cv2.DIST_L2, 5)[1:-1, 1:-1][ys, xs]
        # (from the film filter's reach inside the edge: it reads its neighbours)
        u = np.clip((px - 1.0 - 2.0 * cfg.film_sigma_px) / (2.0 * blur_px), 0.0, 1.0)
        return occ * (t * t * (3.0 - 2.0 * t) * u * u * (3.0 - 2.0 * u))[:, None]

    def _parts(self, d, n, todo, camera, model: LightModel, albedo_mean, occluder, unknown=None, object_albedo=None):
        """The two parts of the diffuse shading of the ``todo`` pixels: (sky and the
        ground's bounce (M, 3), the suns' and lamps' (M, 3), the sky's visible share
        with the occluders' bounce (M, 3), unit normals (M, 3), each sun and lamp as
        (light, directions (M, 3), facing shading (M, 3), visibility (M,)), the texels
        that occlude as the scene's (H, W) bool or None, the sky's visible share alone
        (M, 3)). The sky the scene hides still brings the light its occluders bounce at
        the scene's mean albedo (``albedo_mean`` (3,)), the sky the object's mesh hides at
        ``object_albedo`` (3,), the object's (None: the scene's)."""
        H, W = d.shape
        ys, xs = np.nonzero(todo)
        geo_all = has_geometry(d, n)
        ao, hid, scene_only = self._sky_visibility(d, n, todo, camera, occluder, geo_all, albedo_mean, model, unknown)
        seen = ao * (1.0 - hid)
        nv = n[ys, xs].astype(np.float64)
        nv = nv / np.maximum(length(nv), 1e-12)[:, None]
        nv[~geo_all[ys, xs]] = 0.0
        from zcomp_cli.scene import sh as shm
        from zcomp_cli.scene.lightmodel import ground_view

        sky = np.maximum(shm.evaluate(shm.shading_coeffs(model.sky.radiance_sh), nv), 0.0)
        # occluded directions still see light bounced off the occluders (the object's
        # own rays bring it there: ``_object_layer`` reads ``seen``)
        # (the scene's occluders at the scene's mean albedo, the object at its own: a dark
        # vase's contact is dark)
        bounce_of = lambda a: float(np.clip(np.mean(a), 0.0, 0.9)) * self._settings.transport.sky_bounce
        rb = bounce_of(albedo_mean)
        vis_sky = seen + (1.0 - ao) * rb + ao * hid * bounce_of(albedo_mean if object_albedo is None else object_albedo)
        ambient = sky * vis_sky + ground_view(nv, model.up)[:, None] * model.sky.ground[None]
        direct = np.zeros_like(ambient)
        lit = []
        if model.shadows is ShadowKind.CAST:
            cfg = self._settings.transport
            box = _window(ys, xs, H, W, cfg.window_margin_px, even=(H * W > cfg.full_res_pixels))
            P = camera.ray(xs + 0.5, ys + 0.5) * d[ys, xs][:, None]
            fade = (_edge_fade(todo if unknown is None else unknown, ys, xs, cfg.edge_fade_px, cfg.mesh_ao_fade)
                    if model.source != "manifest" else None)
            for light in (*model.suns, *model.lamps):
                L, _, E = light.toward(P)
                v_t = self._soft_visibility(d, n, geo_all, camera, light, box, ys, xs, occluder, scene_only,
                                            model.walls)
                if fade is not None:
                    # an estimated light's shadow is not grown past the shading mask: it
                    # fades out at the mask's edge instead of stopping in a seam
                    v_t = 1.0 - (1.0 - v_t) * fade
                # the light over its disc: a broad one still shines past the terminator
                # (the disc's samples only where a point's horizon cuts it: ``disc_shading``)
                direct += v_t[:, None] * disc_shading(
                    light, P, nv, lambda i, light=light: _disc_points(light, P[i], ys[i], xs[i], cfg.light_samples,
                                                                      salt=3)[0])
                lit.append((light, L, E, v_t))
        return ambient, direct, vis_sky, nv, lit, scene_only, seen

    def _synthesise(self, d, n, todo, camera, model: LightModel, albedo_mean, occluder, unknown, albedo, coverage,
                    roughness=None, metallic=None, image=None, own=None, object_albedo=None):
        """((M, 3) radiance of the ``todo`` pixels under ``model``, (M, 3) the object's own
        or None) (module docstring, step 3): the diffuse shading filtered as the film does
        (``pixel.film_filter``) times the albedo (the scene's with its offset); where the
        object covers a pixel, its own albedo, diffuse and glossy layers apart, and the
        radiance there the surface's behind it where the object covers it in part
        (``pixel.split``: the two albedos), the object's where wholly."""
        from zcomp_cli.renderers.physical.pixel import extend, film_filter, split
        from zcomp_cli.renderers.physical.reflect import support_reflectance

        cfg = self._settings.transport
        ys, xs = np.nonzero(todo)
        ambient, direct, vis_sky, nv, lit, scene_only, seen = self._parts(d, n, todo, camera, model, albedo_mean,
                                                                          occluder, unknown, object_albedo)
        y0, x0, y1, x1 = _window(ys, xs, *d.shape, int(np.ceil(cfg.edge_reach_px)) + 2)
        ly, lx = ys - y0, xs - x0
        t = np.zeros((y1 - y0, x1 - x0), bool)
        t[ly, lx] = True

        def img(v):  # (M, C) at the todo pixels -> the window (h, w, C)
            o = np.zeros(t.shape + (v.shape[1],))
            o[ly, lx] = v
            return o

        cov = np.where(t, coverage[y0:y1, x0:x1], 0.0)
        obj = t & (cov > 0.5)  # the pixels whose geometry is the object's
        cls = _depth_classes(d[y0:y1, x0:x1]) * 2 + obj
        S = film_filter(img(ambient + direct), cls, t, cfg)
        a = np.clip(albedo[y0:y1, x0:x1], 0.0, None)
        yy, xx = np.mgrid[y0:y1, x0:x1]
        P_w = camera.ray(xx.ravel() + 0.5, yy.ravel() + 0.5) * d[y0:y1, x0:x1].reshape(-1, 1)
        N_w = n[y0:y1, x0:x1].reshape(-1, 3)

        def scene(alb, sh):  # the scene's specular layer: its image is E (albedo + offset), brighter toward grazing
            off = model.albedo_offset(P_w, N_w, alb).reshape(alb.shape)
            return (alb + np.where(alb > 1e-3, off, 0.0)) * sh

        rad = scene(a, S)
        if (cov > 0).any():
            edge = t & (cov > 0) & (cov < cfg.whole_coverage)
            crop = lambda m_: None if m_ is None else np.asarray(m_, np.float64)[y0:y1, x0:x1]
            a_o, a_s = split(a, crop(None if own is None else own.albedo), cov, t, cfg)
            win = (y0, x0, y1, x1, t, cls, obj)
            # what the support reflects of the light where the frame shows it (its known
            # pixels the object does not cover): a ray meeting it beyond the frame reads
            # that much of the light there
            background = (d > 0) & (coverage <= 0) & (True if unknown is None else ~unknown)
            sup = None if image is None else support_reflectance(
                camera.unproject(d.astype(np.float32)).astype(np.float64), n, image, background, model,
                cfg.support_trim)
            O = self._object_layer(d, camera, model, occluder, scene_only, albedo_mean, roughness, metallic, image,
                                   win, (ys, xs, nv, vis_sky, lit, ambient, direct, seen), S, rad, a_o, cov, own,
                                   support=sup)
            # each layer carried past where it was shaded, to the pixels it covers in part
            O = extend(O, obj, edge & ~obj, cfg)
            F = extend(scene(a_s, S), t & ~obj, edge & obj, cfg)
            # the surface where the object covers a pixel in part (its shadow ratio is the
            # surface's), the object where it covers it wholly; the object apart
            rad = np.where(edge[..., None], F, np.where((cov > 0)[..., None], O, rad))
            return rad[ly, lx], O[ly, lx]
        return rad[ly, lx], None

    def _object_layer(self, d, camera, model, occluder, scene_only, albedo_mean, roughness, metallic, image, win,
                      parts, S, rad, a_o, cov, own=None, support=None):
        """(h, w, 3) the object's radiance over the window ``win`` (y0, x0, y1, x1, the todo
        pixels, the classes, the object's pixels) at its pixels: its albedo ``a_o`` times
        its diffuse shading -- the scene's and its own bounce gathered along rays
        (``reflect.bounce``) instead of the support's radiance below the horizon and the
        occluders' bounce as a share of the scene's albedo -- times what its glossy layer
        leaves, plus the glossy layer (``_glossy``, reflecting what its lobe meets:
        ``reflect.environment``); ``support`` (3,) what the support reflects of the
        light or None (``reflect.Surroundings``)."""
        from zcomp_cli.renderers.physical.pixel import film_filter, split
        from zcomp_cli.renderers.physical.reflect import Surroundings, bounce
        from zcomp_cli.scene import sh as shm

        cfg, pc = self._settings.transport, self._settings.gloss
        y0, x0, y1, x1, t, cls, obj = win
        ys, xs, nv, vis_sky, lit, ambient, direct, seen = parts
        ly, lx = ys - y0, xs - x0
        sel = obj[ly, lx]
        photo = np.nan_to_num(np.array(image, np.float64)[..., :3])
        photo[y0:y1, x0:x1][t & ~obj] = rad[t & ~obj]
        own_rad = np.zeros(d.shape + (3,))
        own_rad[y0:y1, x0:x1][obj] = (a_o * S)[obj]
        images = Surroundings(photo, own_rad, _pasted(np.zeros(d.shape), obj, (y0, x0)) > 0, support)
        if cfg.bounce_rays > 0 and sel.any():
            P = camera.ray(xs[sel] + 0.5, ys[sel] + 0.5) * d[ys[sel], xs[sel]][:, None]
            got = bounce(model, camera, d, P, nv[sel], ys[sel], xs[sel], occluder=occluder, scene_only=scene_only,
                         images=images, k=cfg.bounce_rays, steps=self._settings.light.march.sky_steps,
                         march=self._settings.light.march)
            # the sky's visible share without the occluders' bounce, which the rays bring;
            # a given probe's sky from its map's own directions (``meshrays.pool_shading``)
            if model.probe is not None:
                from zcomp_cli.scene.meshrays import pool_shading

                sky = pool_shading(sky_pool_of(model, self._settings.gloss, cfg), model.sky.radiance_sh, nv[sel])
            else:
                sky = np.maximum(shm.evaluate(shm.shading_coeffs(model.sky.radiance_sh), nv[sel]), 0.0)
            from zcomp_cli.renderers.physical.softshadow import classwise_blur

            # (the neighbours' rays averaged: each pixel's are turned apart)
            gi = np.zeros(t.shape + (3,))
            gi[ly[sel], lx[sel]] = got
            got = classwise_blur(gi, cls, obj, cfg.bounce_blur_px)[ly[sel], lx[sel]] if cfg.bounce_blur_px > 0 else got
            raw = np.zeros(t.shape + (3,))
            raw[ly[sel], lx[sel]] = sky * seen[sel] + got + direct[sel]
            S = np.where(obj[..., None], film_filter(raw, cls, obj, cfg), S)
            own_rad[y0:y1, x0:x1][obj] = (a_o * S)[obj]
        G, keep = np.zeros_like(S), np.ones(t.shape + (1,))
        if roughness is not None and sel.any():
            full = lambda w_, m: _pasted(m, w_, (y0, x0))

            def layer(mixed, which):  # the object's own roughness or metallic
                o = None if own is None or getattr(own, which) is None else np.asarray(getattr(own, which))
                return full(split(np.asarray(mixed)[y0:y1, x0:x1, None], None if o is None else o[y0:y1, x0:x1, None],
                                  cov, t, cfg)[0][..., 0], mixed)

            rough = layer(roughness, "roughness")
            met = None if metallic is None else layer(metallic, "metallic")
            sub = [(li, Ld[sel], E[sel], v[sel]) for li, Ld, E, v in lit]
            env = None
            base = full(a_o, np.zeros(d.shape + (3,)))
            if pc.reflect_rays > 0:
                env = self._environment(model, camera, d, nv[sel], ys[sel], xs[sel], rough, met, base, occluder,
                                        scene_only, images, cls, obj, (y0, x0))
            gl, kp = self._glossy(model, camera, d, nv[sel], ys[sel], xs[sel], np.ones(int(sel.sum())), base, rough,
                                  met, vis_sky[sel], sub, env=env)
            both = np.zeros(t.shape + (4,))
            both[ly[sel], lx[sel]] = np.concatenate([gl, kp[:, None]], 1)
            both = film_filter(both, cls, obj, cfg)
            G, keep = both[..., :3], np.where(obj[..., None], both[..., 3:], 1.0)
        return a_o * S * keep + G

    def _glossy(self, model, camera, d, nv, ys, xs, cov, albedo, roughness, metallic, vis_sky, lit=(), env=None):
        """((M, 3) the object's glossy reflection, (M,) the diffuse layer's weight beneath
        it) (``gloss`` module docstring): the prefiltered sky toward the mirror direction
        times the split-sum environment BRDF, occluded by the sky's visibility, plus
        each sun and lamp of ``lit`` (``_parts``) through the GGX BRDF, summed over points
        of its disc (``gloss.ggx_light``, ``GlossConfig.highlight_samples``), times its own
        visibility; a dielectric's exact Fresnel (F0 0.04), a metal's Schlick curve from its
        albedo, weighted by ``metallic``, with multiple scattering's energy. The diffuse
        beneath keeps what the specular layer does not reflect (a metal none). ``env``
        (M, 3): the radiance the lobe meets, gathered (``reflect``), instead of the
        occluded prefiltered sky."""
        from zcomp_cli.renderers.physical.gloss import ggx_light, prefiltered_light, principled_layers, specular_albedo

        pc = self._settings.gloss
        P = camera.ray(xs + 0.5, ys + 0.5) * d[ys, xs][:, None]
        v = -P / np.maximum(np.linalg.norm(P, axis=1, keepdims=True), 1e-12)
        ndv = np.clip(np.sum(nv * v, 1), 1e-4, 1.0)
        r = 2.0 * ndv[:, None] * nv - v
        rough = np.clip(np.nan_to_num(np.asarray(roughness, np.float64)[ys, xs]), 0.0, 1.0)
        met = np.zeros(len(ys)) if metallic is None else np.clip(np.nan_to_num(np.asarray(metallic)[ys, xs]), 0, 1)
        layers = principled_layers(met, albedo[ys, xs])
        if env is None:
            pf = prefiltered_light(model, pc)
            L_sky = pf.lookup(r, rough)
            # the lobe's share below the horizon sees the support, which the sky's
            # occluders do not hide
            env = vis_sky.mean(1, keepdims=True) * L_sky + pf.lookup(r, rough, ground=model.sky.ground) - L_sky
        albedos = [specular_albedo(rough, ndv, f0, pc, fresnel=kind) for _, f0, kind in layers]
        out = env * sum(w[:, None] * a for (w, _, _), a in zip(layers, albedos))
        for light, _, _, v_t in lit:
            # each sun and lamp as points of its disc (``ggx_light``); the shading is a
            # facing surface's: its irradiance over pi
            off, tan = _disc_points(light, P, ys, xs, pc.highlight_samples, salt=2)
            dirs, _, shade = light.disc(P, off)
            out = out + v_t[:, None] * ggx_light(nv, v, rough, layers, dirs, shade, tan / np.sqrt(len(off)), cfg=pc)
        # Cycles' Principled layering: the diffuse gets one minus the dielectric
        # layer's directional albedo toward the viewer
        keep = (1.0 - met) * (1.0 - albedos[0][:, 0])
        return cov[:, None] * out, keep

    def _environment(self, model, camera, d, nv, ys, xs, roughness, metallic, albedo, occluder, scene_only, images,
                     cls, obj, corner):
        """(M, 3) the surroundings the object's glossy lobe reflects at pixels (ys, xs)
        (``reflect.environment``; ``metallic`` (H, W) or None and the base colour
        ``albedo`` (H, W, 3) give its layers' Fresnel), averaged over the neighbours'
        rays within the object
        (``GlossConfig.reflect_blur_px``; ``cls``/``obj`` the window's classes and object
        pixels, its ``corner`` (y0, x0))."""
        from zcomp_cli.renderers.physical.gloss import prefiltered_light
        from zcomp_cli.renderers.physical.reflect import environment
        from zcomp_cli.renderers.physical.softshadow import classwise_blur

        pc = self._settings.gloss
        P = camera.ray(xs + 0.5, ys + 0.5) * d[ys, xs][:, None]
        v = -P / np.maximum(np.linalg.norm(P, axis=1, keepdims=True), 1e-12)
        rough = np.clip(np.nan_to_num(np.asarray(roughness, np.float64)[ys, xs]), 0.0, 1.0)
        met = np.zeros(len(ys)) if metallic is None else np.clip(np.nan_to_num(np.asarray(metallic)[ys, xs]), 0, 1)
        env = environment(model, camera, d, P, nv, v, rough, ys, xs, occluder=occluder, scene_only=scene_only,
                          images=images, prefiltered=prefiltered_light(model, pc), gcfg=pc,
                          march=self._settings.light.march, layers=(met, np.clip(albedo[ys, xs], 0, 1)))
        y0, x0 = corner
        img = np.zeros(obj.shape + (3,))
        img[ys - y0, xs - x0] = env
        img = classwise_blur(img, cls, obj, pc.reflect_blur_px)
        return img[ys - y0, xs - x0]

    def _soft_visibility(self, d, n, geo_all, camera, light, box, ys, xs, occluder,
                         scene_only=None, walls=()) -> np.ndarray:
        """Filtered visibility of ``light`` (a model's ``Sun`` or ``Lamp``) at pixels (ys, xs),
        marched over the window ``box``; ``scene_only``: (H, W) bool, the texels that
        occlude in the march (None: all), the ``occluder`` mesh shadowing for the rest.
        Above ``transport.full_res_pixels`` the march runs on a stride-2 grid (the filter
        smooths it anyway): a quarter of the rays."""
        cfg = self._settings.transport
        H, W = d.shape
        st = 2 if H * W > cfg.full_res_pixels else 1
        wy0, wx0, wy1, wx1 = box
        march = self._settings.light.march
        gy, gx, P, N, ok = grid_points(d, n, geo_all, camera, box, st)
        L, dist, _ = light.toward(P.reshape(-1, 3))
        L, dist = L.reshape(P.shape), dist.reshape(gy.shape)
        lit = ok & (np.sum(N * L, -1) > 0)
        vis = np.zeros(gy.shape)
        t_hit = np.full(gy.shape, np.inf)
        if lit.any():
            v, t = march_visibility(P[lit], N[lit], L[lit], d, camera, cfg=march,
                                    steps=int(self._settings.march_steps),
                                    jitter=pixel_jitter(gy[lit], gx[lit]), return_distance=True,
                                    nearest=True, occluder_mask=scene_only, max_distance=dist[lit], walls=walls)
            vis[lit], t_hit[lit] = v, t
        vis = np.where(ok & ~lit, 1.0, vis)  # facing away: n.l = 0 does the shading
        ok_full = geo_all[wy0:wy1, wx0:wx1]
        cls_w = _depth_classes(d[wy0:wy1, wx0:wx1])  # the stride-2 blur's and the penumbra's
        h_, w_ = wy1 - wy0, wx1 - wx0
        if st == 2:
            up2 = lambda a: np.repeat(np.repeat(a, 2, 0), 2, 1)[:h_, :w_]
            same = up2(ok) & (up2(cls_w[::2, ::2]) == cls_w)
            vis = classwise_blur(up2(vis), cls_w, ok_full & same, 1.0, fill=ok_full)
            t_hit = up2(t_hit)
        if light.varies:  # a lamp's angular size at each pixel of the window
            yy, xx = np.mgrid[wy0:wy1, wx0:wx1]
            Pw = camera.ray(xx + 0.5, yy + 0.5) * d[yy, xx][..., None]
            tan_a = light.tan_radius(Pw.reshape(-1, 3)).reshape(yy.shape)
        else:
            tan_a = float(light.tan_radius(None))
        ok = ok_full
        # filtered only over the box of the pixels asked for (the window's margin is
        # context for the blurs)
        by0, bx0 = int(ys.min()) - wy0, int(xs.min()) - wx0
        vs = penumbra_filter(vis, t_hit, d[wy0:wy1, wx0:wx1], cls_w, ok, camera.fx, tan_a,
                             box=(by0, bx0, int(ys.max()) + 1 - wy0, int(xs.max()) + 1 - wx0), cfg=cfg)
        vs = vs[ys - wy0 - by0, xs - wx0 - bx0]
        if occluder is not None:
            # the object's own shadow, its light sampled over its disc by rays on the
            # mesh (``meshrays.light_visibility``): a wide lamp's umbra and penumbra as
            # they are, every pixel its own (no grid, no shadow map's steps)
            from zcomp_cli.scene.meshrays import light_visibility

            Pp = camera.ray(xs + 0.5, ys + 0.5) * d[ys, xs][:, None]
            Np = n[ys, xs].astype(np.float64)
            Np = Np / np.maximum(length(Np), 1e-12)[:, None]
            vs = vs * light_visibility(occluder, Pp, Np, light, cfg.light_samples, pixel_jitter(ys, xs, salt=3),
                                       cfg.mesh_ray_bias_rel * np.maximum(-Pp[:, 2], 1e-6))
        return vs


def _disc_points(light, P: np.ndarray, ys, xs, k: int, salt: int):
    """((k, M, 2) points of the unit disc for ``light`` (``Sun.disc``, ``Lamp.disc``) at
    the points ``P`` (M, 3) of pixels (ys, xs), turned per pixel (``pixel_jitter`` with
    ``salt``), or its centre alone (1, M, 2) where ``k`` is 1 or the light has no size;
    its angular radius's tangent, scalar or (M,))."""
    tan = np.asarray(light.tan_radius(P) if light.varies else light.tan_radius(None), np.float64)
    if int(k) <= 1 or np.max(tan) <= 0:
        return np.zeros((1, len(ys), 2)), tan
    return disc_samples(int(k), pixel_jitter(ys, xs, salt=salt)), tan


def _edge_fade(region: np.ndarray, ys, xs, width_px: float, share: float) -> np.ndarray:
    """(M,) in [0, 1] at pixels (ys, xs) of ``region`` (H, W) bool (the shading mask, the
    whole frame's: the same with or without a region of interest): 0 on its edge,
    rising smoothly to 1 at ``width_px`` inside it (``TransportConfig.edge_fade_px``) or
    at the outer ``share`` of the region's radius (the deepest pixel's distance to its
    edge; ``TransportConfig.mesh_ao_fade``, as the object's sky occlusion fades),
    whichever is wider: a soft light's shadow reaches past the mask, and cut over a few
    pixels it drew the mask's ellipse."""
    import cv2

    dt = cv2.distanceTransform(np.pad(region, 1).astype(np.uint8), cv2.DIST_L2, 5)[1:-1, 1:-1]
    width = max(float(width_px), share * float(dt.max()) if dt.size else 0.0, 1e-9)
    u = np.clip(dt[ys, xs] / width, 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)



def _window(ys, xs, H, W, margin, even=False):
    """(y0, x0, y1, x1): the box of the pixels grown by ``margin``; ``even``: its corner
    on a grid of that stride (True: 2), so strided grids line up globally (results do
    not depend on the region)."""
    wy0, wx0 = max(0, int(ys.min()) - margin), max(0, int(xs.min()) - margin)
    if even:
        a = 2 if even is True else int(even)
        wy0, wx0 = wy0 - wy0 % a, wx0 - wx0 % a
    return wy0, wx0, min(H, int(ys.max()) + 1 + margin), min(W, int(xs.max()) + 1 + margin)


_POOLS: dict = {}


def sky_radiance_of(model: LightModel, radiance_sh: np.ndarray):
    """What weighs the sky's directions where its visibility is measured
    (``skyvis.weighted_visibility``): a given probe's map
    (``probe.ProbeLights.sky_radiance_at``, the split the light stage made), else the
    model's SH sky ``radiance_sh`` (9, 3), as the light fit weighs them."""
    ref = model.probe
    if ref is None:
        return radiance_sh
    from zcomp_cli.knobs import from_mapping
    from zcomp_cli.scene.config import ProbeConfig
    from zcomp_cli.scene.probe import load_given_probe

    return load_given_probe(ref.params, ref.frame, cfg=from_mapping(ProbeConfig, ref.cfg, "probe")).sky_radiance_at


def sky_pool_of(model: LightModel, gcfg, cfg) -> tuple:
    """``meshrays.sky_pool`` of the model's sky: its probe's map without the compact
    sources (the glossy prefilter's), else its SH sky drawn into a map
    (``gloss.model_radiance_map``); ``cfg.sky_pool`` directions, kept per sky."""
    from zcomp_cli import equirect
    from zcomp_cli.renderers.physical.gloss import model_radiance_map
    from zcomp_cli.scene.meshrays import sky_pool
    from zcomp_cli.scene.probe import area_resize

    ref = model.probe
    key = (("probe", repr(ref.params.to_dict()), ref.frame.tobytes(), repr(sorted(ref.cfg.items())))
           if ref is not None else ("sky", model.sky.radiance_sh.tobytes(), model.up.tobytes()), cfg.sky_pool, gcfg)
    hit = _POOLS.get(key)
    if hit is None:
        if ref is not None:
            from zcomp_cli.knobs import from_mapping
            from zcomp_cli.scene.config import ProbeConfig
            from zcomp_cli.scene.probe import load_given_probe

            sp = load_given_probe(ref.params, ref.frame, cfg=from_mapping(ProbeConfig, ref.cfg, "probe"))
            img = area_resize(sp.residual, gcfg.model_map_width * 4)
            dirs = equirect.pixel_directions(*img.shape[:2], sp.frame, sp.convention, sp.rotation_deg)
        else:
            img, frame = model_radiance_map(model, cfg=gcfg)
            dirs = equirect.pixel_directions(*img.shape[:2], frame)
        hit = sky_pool(img, dirs, equirect.solid_angles(*img.shape[:2]), model.up, cfg.sky_pool)
        while len(_POOLS) >= 8:
            _POOLS.pop(next(iter(_POOLS)))
        _POOLS[key] = hit
    return hit


def _pasted(frame: np.ndarray, window: np.ndarray, corner) -> np.ndarray:
    """A copy of ``frame`` with ``window`` pasted at ``corner`` (y0, x0)."""
    out = np.array(frame, np.float64)
    y0, x0 = corner
    out[y0:y0 + window.shape[0], x0:x0 + window.shape[1]] = window
    return out


def _grown_request(req: RenderRequest, reach: np.ndarray) -> RenderRequest:
    """The request with ``reach`` re-shaded too: unknown, and inside the roi."""
    import dataclasses

    known = np.asarray(req.known, bool) & ~reach
    roi = req.roi
    if roi is not None:
        rows, cols = np.flatnonzero(reach.any(1)), np.flatnonzero(reach.any(0))
        x0, y0, x1, y1 = roi
        roi = (min(x0, int(cols[0])), min(y0, int(rows[0])), max(x1, int(cols[-1]) + 1), max(y1, int(rows[-1]) + 1))
    return dataclasses.replace(req, known=known, roi=roi)


def _depth_classes(depth: np.ndarray, rel_jump: float = 0.1) -> np.ndarray:
    """Label the connected pieces of a depth map separated by depth discontinuities
    (relative jump > ``rel_jump``; grazing surfaces step by a few % per pixel): an inserted object and the floor behind it get
    different labels, so shadow filters never blur one into the other."""
    import cv2

    d = depth.astype(np.float32)
    jump = np.zeros(d.shape, bool)
    dx = np.abs(np.diff(d, axis=1)) > rel_jump * np.maximum(d[:, 1:], d[:, :-1])
    dy = np.abs(np.diff(d, axis=0)) > rel_jump * np.maximum(d[1:], d[:-1])
    jump[:, 1:] |= dx
    jump[1:] |= dy
    _, lab = cv2.connectedComponents((~jump & (d > 0)).astype(np.uint8), connectivity=4)
    return lab
