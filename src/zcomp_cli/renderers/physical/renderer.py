"""PhysicalRenderer: estimated light + screen-space visibility, no weights (DESIGN.md s.5)."""

from __future__ import annotations

import time
from typing import Sequence

import numpy as np

from zcomp_cli.conventions import DEFAULT_SEED
from zcomp_cli.errors import InputError, NumericalError, UsageError
from zcomp_cli.renderers.base import Renderer, RenderOutput, RenderRequest
from zcomp_cli.renderers.physical.lighting import LightEstimate, estimate_lighting
from zcomp_cli.renderers.physical.shading import sh_basis
from zcomp_cli.renderers.physical.softshadow import (AO_BLUR_PX, AO_BOUNCE, MAX_PENUMBRA_PX, WINDOW_MARGIN_PX,
                                                     ambient_occlusion,
                                                     classwise_blur, penumbra_filter, pixel_jitter)
from zcomp_cli.renderers.physical.visibility import march_visibility

_DEFAULTS = {
    "n_light_candidates": 128,   # coarse hemisphere candidates for the light search
    "march_steps": 32,           # ray-march samples per shadow ray (synthesis)
    "estimate_march_steps": 16,  # ray-march samples per shadow ray (estimation)
    "max_resolution": 160,       # long side of the copy used for light estimation
    "cone_samples": 8,           # light directions per pixel for soft shadows
    "shadow_softness": None,     # force the light's angular radius (deg); None = KEY_SOFTNESS_DEG
    "max_fit_pixels": 2000,      # pixels used by the light fit
}


def _clean(a, lo, hi):
    # one copy (np.array), then nan_to_num and the clip in place on it
    out = np.nan_to_num(np.array(a, np.float64), copy=False, nan=0.0, posinf=hi, neginf=lo)
    return np.clip(out, lo, hi, out=out)


class PhysicalRenderer(Renderer):
    """Embedded renderer. Settings (all optional): see ``_DEFAULTS``; unknown -> UsageError."""

    name = "physical"

    def __init__(self, **settings):
        unknown = set(settings) - set(_DEFAULTS)
        if unknown:
            raise UsageError(f"unknown physical renderer setting(s): {', '.join(sorted(unknown))}; "
                             f"known: {', '.join(_DEFAULTS)}")
        self._s = {**_DEFAULTS, **settings}
        from zcomp_cli.limits import shorten

        for k in ("n_light_candidates", "march_steps", "estimate_march_steps", "max_resolution",
                  "cone_samples", "max_fit_pixels"):
            v = self._s[k]
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not 1 <= v <= 1_000_000:
                raise UsageError(f"physical renderer setting {k}: expected an integer in [1, 1000000], "
                                 f"got {shorten(v)}")
        sv = self._s["shadow_softness"]
        if sv is not None and (isinstance(sv, bool) or not isinstance(sv, (int, float))
                               or not (0 <= float(sv) <= 60)):
            raise UsageError(f"physical renderer setting shadow_softness: expected degrees in [0, 60], "
                             f"got {shorten(sv)}")
        self._cache: dict = {}

    def settings(self) -> dict:
        return {"name": self.name, **self._s}

    # step 1: light (cached per scene and seed)
    def estimate(self, req: RenderRequest, seed: int = DEFAULT_SEED) -> LightEstimate:
        """The scene's light: the manifest's known light (``req.light``), else estimated."""
        light = getattr(req, "light", None)
        key = ((req.scene_key, seed, repr(sorted(light.items())) if light else None)
               if req.scene_key is not None else None)
        if key is not None and key in self._cache:
            return self._cache[key]
        d, n, sh, known = self._inputs(req)
        albedo = _clean(req.maps.albedo, 0.0, 1.0)  # darkness is read within an albedo
        if key is not None:
            # Cached per scene, so it must depend on the scene alone: fit on every valid
            # background pixel, not on the first job's shading mask -- else a job's
            # result would depend on which job of its scene a process ran first, and
            # shards or Ray workers would give other composites than one local run.
            known = (d > 0) & np.all(np.isfinite(req.shading), axis=-1)
        if light:
            from zcomp_cli.renderers.physical.known_light import light_from_spec

            est = light_from_spec(light, d, n, sh, known, req.camera,
                                  max_resolution=int(self._s["max_resolution"]),
                                  march_steps=int(self._s["estimate_march_steps"]),
                                  albedo=albedo)
            if key is not None:
                self._cache[key] = est
            return est
        est = estimate_lighting(
            d, n, sh, known, req.camera, n_candidates=int(self._s["n_light_candidates"]),
            max_resolution=int(self._s["max_resolution"]),
            march_steps=int(self._s["estimate_march_steps"]),
            max_fit_pixels=int(self._s["max_fit_pixels"]),
            cone_samples=int(self._s["cone_samples"]),
            softness_deg=self._s["shadow_softness"], seed=seed, albedo=albedo)
        if key is not None:
            self._cache[key] = est
        return est

    @staticmethod
    def _inputs(req: RenderRequest):
        H, W = req.camera.height, req.camera.width
        m = req.maps
        shapes = {"depth": (m.depth, (H, W)), "normals": (m.normals, (H, W, 3)),
                  "albedo": (m.albedo, (H, W, 3)), "shading": (req.shading, (H, W, 3)),
                  "known": (req.known, (H, W))}
        for name, (a, want) in shapes.items():
            if np.shape(a) != want:
                raise InputError(f"physical renderer: {name} has shape {np.shape(a)}, expected {want}")
        d = _clean(m.depth, 0.0, 1e6)
        n = _clean(m.normals, -1.0, 1.0)
        sh = _clean(req.shading, 0.0, 1e6)
        return d, n, sh, np.asarray(req.known, bool)

    def render(self, requests: Sequence[RenderRequest], *, seed: int = DEFAULT_SEED) -> RenderOutput:
        if not requests:
            raise UsageError("physical renderer needs at least one request")
        timings = {"estimate": 0.0, "synthesis": 0.0}
        t0 = time.perf_counter()
        est = self.estimate(requests[0], seed)
        if est.lamp_position is not None:
            # step 1a: a lamp near the scene, seen from this job's object (the estimate
            # is the scene's, aimed at its support's centre)
            est = _aimed_at_object(est, requests)
        timings["estimate"] = time.perf_counter() - t0
        grown = None
        if not est.fallback and est.source == "manifest":
            # step 1b: where the object's shadow falls for this light, beyond the mask.
            # Only for a known light: an estimated direction is too often wrong (median
            # 46 deg off on the fresh benchmark, seed 9001) and a wrong shadow drawn at full
            # length cost more than the cut one (two cases -2 and -5 dB there)
            t1 = time.perf_counter()
            reach = np.zeros(np.shape(requests[0].known), bool)
            for req in requests:
                reach |= self._shadow_reach(req, est)
            unknown = np.zeros_like(reach)
            for req in requests:
                unknown |= ~np.asarray(req.known, bool)
            if (reach & ~unknown).any():
                grown = unknown | reach
                requests = [_grown_request(req, reach) for req in requests]
            timings["shadow_reach"] = time.perf_counter() - t1
        images = []
        t1 = time.perf_counter()
        for req in requests:
            images.append(self._render_one(req, est))
        timings["synthesis"] = time.perf_counter() - t1
        shadow = ("contact shadow only (ambient occlusion): no cast shadow pins the light direction"
                  if est.fallback else "one soft shadow per light, penumbra from the occluder distance")
        info = {"light": est.to_info(), "fallback": est.fallback, "shadow": shadow,
                "settings": self.settings()}
        return RenderOutput(images=images, info=info, timings=timings, shading_mask=grown)

    def _shadow_reach(self, req: RenderRequest, est: LightEstimate) -> np.ndarray:
        """(H, W) bool: known pixels in the shadow of what the request's shading mask
        holds (the inserted object), grown by the widest penumbra. The shading mask is
        a ball around the object; under a low sun its shadow runs past it, and a shadow
        cut at the mask's edge is a visible straight end."""
        d, n, _, known = self._inputs(req)
        H, W = d.shape
        occ = ~known & (d > 0)
        out = np.zeros((H, W), bool)
        if not occ.any():
            return out
        st = 2 if H * W > FULL_RES_PIXELS else 1
        geo = (d > 0) & (np.abs(np.linalg.norm(n, axis=-1) - 1) < 0.2)
        gy, gx, Pg, Ng, ok = _grid_points(d, n, geo, req.camera, (0, 0, H, W), st)
        import cv2

        for l, _, cone in _lights(est):
            cand = known[gy, gx] & ok & ((Ng @ l) > 0.02)
            if not cand.any():
                continue
            ys, xs, P, N = gy[cand], gx[cand], Pg[cand], Ng[cand]
            v, t = march_visibility(P, N, l, d, req.camera, steps=int(self._s["march_steps"]), nearest=True,
                                    return_distance=True, occluder_mask=occ)
            if req.occluder is not None:
                from zcomp_cli.renderers.physical.meshshadow import mesh_shadow

                vm, tm = mesh_shadow(req.occluder, P, N, l)
                v, t = np.minimum(v, vm), np.minimum(t, tm)
            hit = v < 0.5
            if not hit.any():
                continue
            # the widest penumbra among them (t tan a f / z), then the compositor's blur
            tan_a = np.tan(np.deg2rad(min(cone, 89.0)))
            pen = float(np.max(t[hit] * tan_a * req.camera.fx / np.maximum(d[ys[hit], xs[hit]], 1e-6)))
            r = int(np.ceil(min(pen, MAX_PENUMBRA_PX) + st + 2))
            one = np.zeros((H, W), np.uint8)
            one[ys[hit], xs[hit]] = 1
            k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
            out |= cv2.dilate(one, k) > 0
        return out & known & (d > 0)

    def _render_one(self, req: RenderRequest, est: LightEstimate) -> np.ndarray:
        # step 2: known pixels reproduce albedo * known shading exactly
        d, n, sh, known = self._inputs(req)
        alb = _clean(req.maps.albedo, 0.0, 1e6)
        H, W = d.shape
        out_sh = sh.copy()
        unknown = ~known
        x0, y0, x1, y1 = (0, 0, W, H) if req.roi is None else req.roi
        x0, y0 = max(0, int(x0)), max(0, int(y0))
        x1, y1 = min(W, int(x1)), min(H, int(y1))
        todo = np.zeros((H, W), bool)
        todo[y0:y1, x0:x1] = True
        todo &= unknown
        # unknown pixels outside roi: a flat ambient guess, finite but unused
        amb0 = np.maximum(est.ambient_sh[0], 0)
        out_sh[unknown & ~todo] = amb0
        if todo.any():
            alb_mean = alb[(d > 0)].mean(0) if (d > 0).any() else np.zeros(3)
            out_sh[todo] = self._synthesise(d, n, todo, req.camera, est, alb_mean,
                                            getattr(req, "occluder", None))
        img = (alb * out_sh).astype(np.float32)
        if not np.all(np.isfinite(img)):
            bad = int((~np.isfinite(img)).sum())
            raise NumericalError(f"physical renderer produced {bad} non-finite values")
        return img

    def _synthesise(self, d, n, todo, camera, est: LightEstimate, albedo_mean=(0.0, 0.0, 0.0),
                    occluder=None) -> np.ndarray:
        """Shading of the ``todo`` pixels: ambient(n) * AO + I * max(0, n.l) * V_soft, where
        V_soft is one filtered shadow (``softshadow``); with an unconstrained direction
        the light is spread over the sky: (ambient(n) + I * max(0, n.l)) * AO."""
        H, W = d.shape
        ys, xs = np.nonzero(todo)
        geo_all = (d > 0) & (np.abs(np.linalg.norm(n, axis=-1) - 1) < 0.2)

        def window(margin, even=False):
            wy0, wx0 = max(0, ys.min() - margin), max(0, xs.min() - margin)
            if even:  # strided grids line up globally (ROI-independent results)
                a = 2 if even is True else int(even)
                wy0, wx0 = wy0 - wy0 % a, wx0 - wx0 % a
            return wy0, wx0, min(H, ys.max() + 1 + margin), min(W, xs.max() + 1 + margin)

        def points(wy0, wx0, wy1, wx1, step=1):
            return _grid_points(d, n, geo_all, camera, (wy0, wx0, wy1, wx1), step)

        # ambient occlusion on a stride-2 grid around the todo pixels, then filtered
        # (stride 4 on large frames: ambient occlusion is smooth)
        ao_st = 4 if H * W > FULL_RES_PIXELS else 2
        ay0, ax0, ay1, ax1 = window(int(3 * max(AO_BLUR_PX, 1.5 * ao_st)) + 4, even=ao_st)
        gy, gx, P, N, ok = points(ay0, ax0, ay1, ax1, ao_st)
        ao_c = np.ones(gy.shape)
        scene_only = None
        if occluder is not None:
            # the real mesh is the object's occluder; the depth's shell only the scene's
            # (``mesh_silhouette``): one silhouette for every light and the sky
            from zcomp_cli.renderers.physical.meshshadow import mesh_silhouette

            scene_only = ~mesh_silhouette(occluder, camera, (H, W))
        occ_c = dist_c = None
        if ok.any():
            ao_c[ok] = ambient_occlusion(P[ok], N[ok], gy[ok], gx[ok], d, camera, occluder_mask=scene_only)
            if occluder is not None:
                # the sky the object hides, from its mesh (``mesh_occlusion``): smooth,
                # unlimited in range, and no solid slab behind its visible shell
                from zcomp_cli.renderers.physical.meshshadow import mesh_discs, mesh_occlusion

                occ_c, dist_c = np.zeros(gy.shape), np.zeros(gy.shape)
                # (the exact near field for the scene's points by the object, not the
                # object's own: ``refine``)
                occ_c[ok], dist_c[ok] = mesh_occlusion(mesh_discs(occluder), P[ok], N[ok], mesh=occluder,
                                                       refine=scene_only[gy[ok], gx[ok]], return_distance=True)
        h_, w_ = ay1 - ay0, ax1 - ax0
        up2 = lambda a: np.repeat(np.repeat(a, ao_st, 0), ao_st, 1)[:h_, :w_]
        okf = geo_all[ay0:ay1, ax0:ax1]
        cls = _depth_classes(d[ay0:ay1, ax0:ax1])
        # a 2x2 block straddling a silhouette must not lend the object's value to the
        # floor (a light rim): only pixels of their anchor's class vouch for it; the
        # normalised blur fills the others from their own class
        same = up2(ok) & (up2(cls[::ao_st, ::ao_st]) == cls)
        rad = max(AO_BLUR_PX, 1.5 * ao_st)
        ao = classwise_blur(up2(ao_c), cls, okf & same, rad, fill=okf)
        if occ_c is not None:
            occ = classwise_blur(up2(occ_c), cls, okf & same, rad, fill=okf)
            dist = up2(dist_c)
            # The sky occlusion reaches past the shading mask (a sphere still hides a
            # quarter of the sky one radius past its side); cut at the mask's edge it
            # drew an ellipse. It fades out over the outer MESH_AO_FADE of the mask's
            # radius, the farthest of its pixels from the mesh (in metres: the mask is
            # a ball around the object, squeezed on screen below it), after the blur.
            # Any other mask (an API caller's) ends it within 2 blur radii of its edge.
            tw = todo[ay0:ay1, ax0:ax1] & okf & np.isfinite(dist)
            R = float(dist[tw].max()) if tw.any() else 0.0
            if R > 0:  # (a mesh without area has no elements: nothing hidden)
                import cv2

                t = np.clip((R - dist) / max(MESH_AO_FADE * R, 1e-9), 0.0, 1.0)
                px = cv2.distanceTransform(np.pad(todo[ay0:ay1, ax0:ax1], 1).astype(np.uint8),
                                           cv2.DIST_L2, 5)[1:-1, 1:-1]
                u = np.clip(px / (2.0 * rad), 0.0, 1.0)
                ao = ao * (1.0 - occ * t * t * (3.0 - 2.0 * t) * u * u * (3.0 - 2.0 * u))
        # occluded directions still see light bounced off the occluders
        rho = float(np.clip(np.mean(albedo_mean), 0.0, 0.9))
        ao = ao + (1.0 - ao) * rho * AO_BOUNCE
        ao_t = ao[ys - ay0, xs - ax0]

        nv = n[ys, xs].astype(np.float64)
        nv = nv / np.maximum(np.linalg.norm(nv, axis=1, keepdims=True), 1e-12)
        geo = geo_all[ys, xs]
        nv[~geo] = 0.0
        amb = np.maximum(sh_basis(nv) @ est.ambient_sh, 0.0)
        if est.fallback:
            ndl = np.maximum(0.0, nv @ est.direction)
            return (amb + ndl[:, None] * np.asarray(est.intensity)[None, :]) * ao_t[:, None]
        # each light's shadow: one march, then the penumbra filter
        out = amb * ao_t[:, None]
        for l, inten, cone in _lights(est):
            v_t = self._soft_visibility(d, n, geo_all, camera, l, cone, window(WINDOW_MARGIN_PX, even=(
                H * W > FULL_RES_PIXELS)), ys, xs, occluder, scene_only)
            out = out + (np.maximum(0.0, nv @ l) * v_t)[:, None] * np.asarray(inten)[None, :]
        return out

    def _soft_visibility(self, d, n, geo_all, camera, l, cone_deg, box, ys, xs, occluder,
                         scene_only=None) -> np.ndarray:
        """Filtered visibility of the light ``l`` at pixels (ys, xs), marched over the
        window ``box``; ``scene_only``: (H, W) bool, the texels that occlude in the march
        (None: all), the ``occluder`` mesh shadowing for the rest. Above FULL_RES_PIXELS
        the march runs on a stride-2 grid (the filter smooths it anyway): a quarter of
        the rays, the synthesis budget at 512x512."""
        H, W = d.shape
        st = 2 if H * W > FULL_RES_PIXELS else 1
        wy0, wx0, wy1, wx1 = box
        gy, gx, P, N, ok = _grid_points(d, n, geo_all, camera, box, st)
        lit = ok & ((N @ l) > 0)
        vis = np.zeros(gy.shape)
        t_hit = np.full(gy.shape, np.inf)
        if lit.any():
            v, t = march_visibility(P[lit], N[lit], l, d, camera,
                                    steps=int(self._s["march_steps"]),
                                    jitter=pixel_jitter(gy[lit], gx[lit]), return_distance=True,
                                    nearest=True, occluder_mask=scene_only)
            if occluder is not None:
                from zcomp_cli.renderers.physical.meshshadow import mesh_shadow

                vm, tm = mesh_shadow(occluder, P[lit], N[lit], l)
                v, t = np.minimum(v, vm), np.minimum(t, tm)
            vis[lit], t_hit[lit] = v, t
        vis = np.where(ok & ~lit, 1.0, vis)  # facing away: n.l = 0 does the shading
        ok_full = geo_all[wy0:wy1, wx0:wx1]
        cls_w = _depth_classes(d[wy0:wy1, wx0:wx1])  # the stride-2 blur's and the penumbra's
        if st == 2:
            h_, w_ = wy1 - wy0, wx1 - wx0
            up2 = lambda a: np.repeat(np.repeat(a, 2, 0), 2, 1)[:h_, :w_]
            same = up2(ok) & (up2(cls_w[::2, ::2]) == cls_w)
            vis = classwise_blur(up2(vis), cls_w, ok_full & same, 1.0, fill=ok_full)
            t_hit = up2(t_hit)
            ok = ok_full
        tan_a = np.tan(np.deg2rad(min(cone_deg, 89.0)))
        # filtered only over the box of the pixels asked for (the window's margin is
        # context for the blurs)
        by0, bx0 = int(ys.min()) - wy0, int(xs.min()) - wx0
        vs = penumbra_filter(vis, t_hit, d[wy0:wy1, wx0:wx1], cls_w,
                             ok, camera.fx, tan_a, box=(by0, bx0, int(ys.max()) + 1 - wy0, int(xs.max()) + 1 - wx0))
        return vs[ys - wy0 - by0, xs - wx0 - bx0]


# Outer share of the shading mask's radius over which the object's sky occlusion fades
# out (``_synthesise``).
MESH_AO_FADE = 0.35


# A lamp's light aimed at an object changes its strength by (distance to the support's
# centre / distance to the object)^2, within these bounds (a lamp fitted right over the
# object must not flood it).
LAMP_GAIN_RANGE = (0.25, 4.0)


def _object_centre(requests: Sequence[RenderRequest]) -> np.ndarray | None:
    """(3,) camera-frame centre of the inserted object: its posed mesh's bounding box,
    else the mean of its visible points (where the last request's depth is nearer than
    the first's: the composite over the background); None when neither exists."""
    for req in requests:
        if req.occluder is not None and len(req.occluder.vertices):
            v = np.asarray(req.occluder.vertices, np.float64)
            v = v[np.all(np.isfinite(v), 1)]
            if len(v):
                return 0.5 * (v.min(0) + v.max(0))
    d0 = _clean(requests[0].maps.depth, 0.0, 1e6)
    d1 = _clean(requests[-1].maps.depth, 0.0, 1e6)
    m = ~np.asarray(requests[-1].known, bool) & (d1 > 0) & ((d0 <= 0) | (d1 < d0 * (1 - 1e-3)))
    if not m.any():
        return None
    return requests[-1].camera.unproject(d1)[m].astype(np.float64).mean(0)


def _aimed_at_object(est: LightEstimate, requests: Sequence[RenderRequest]) -> LightEstimate:
    """The estimate with its lamp's direction and strength as the object sees them."""
    import dataclasses

    c = _object_centre(requests)
    lamp = np.asarray(est.lamp_position, np.float64)
    if c is None or not np.all(np.isfinite(c)):
        return est
    v = lamp - c
    dist = float(np.linalg.norm(v))
    if dist <= 1e-9:
        return est
    d0 = float(np.linalg.norm(lamp - np.asarray(est.lamp_aim, np.float64)))
    gain = float(np.clip((d0 / dist) ** 2, *LAMP_GAIN_RANGE))
    return dataclasses.replace(
        est, direction=v / dist, intensity=np.asarray(est.intensity) * gain,
        direction_source=f"{est.direction_source}; aimed at the object at {np.round(c, 2).tolist()} "
                         f"(strength x{gain:.2f})")


def _lights(est: LightEstimate):
    """(direction, intensity (3,), angular radius in degrees) of each of the estimate's
    directional lights, the first one first."""
    return [(np.asarray(x.direction, np.float64), x.intensity, x.cone_deg) for x in (est, *est.extra_lights)]


def _grid_points(d, n, valid, camera, box, step=1):
    """Pixels of ``box = (y0, x0, y1, x1)`` on a ``step`` grid: (gy, gx, camera-frame points,
    unit normals (0 where not ``valid``), valid)."""
    wy0, wx0, wy1, wx1 = box
    gy, gx = np.mgrid[wy0:wy1:step, wx0:wx1:step]
    nv = n[gy, gx].astype(np.float64)
    ok = valid[gy, gx]
    nv = np.where(ok[..., None], nv / np.maximum(np.linalg.norm(nv, axis=-1, keepdims=True), 1e-12), 0.0)
    return gy, gx, camera.ray(gx + 0.5, gy + 0.5) * d[gy, gx][..., None], nv, ok


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


# Frames larger than this march the direct shadow on a stride-2 grid.
FULL_RES_PIXELS = 256 * 256


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
