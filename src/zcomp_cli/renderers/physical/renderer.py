"""PhysicalRenderer: estimated light + screen-space visibility, no weights (DESIGN.md s.5)."""

from __future__ import annotations

import time
from typing import Sequence

import numpy as np

from zcomp_cli.conventions import DEFAULT_SEED
from zcomp_cli.errors import InputError, NumericalError, UsageError
from zcomp_cli.renderers.base import Renderer, RenderOutput, RenderRequest
from zcomp_cli.renderers.physical.lighting import LightEstimate, estimate_lighting
from zcomp_cli.renderers.physical.shading import cone_directions, direct_term, shade
from zcomp_cli.renderers.physical.visibility import march_visibility

_DEFAULTS = {
    "n_light_candidates": 256,   # coarse hemisphere candidates for the light search
    "march_steps": 32,           # ray-march samples per shadow ray (synthesis)
    "estimate_march_steps": 24,  # ray-march samples per shadow ray (estimation)
    "max_resolution": 160,       # long side of the copy used for light estimation
    "cone_samples": 8,           # light directions per pixel for soft shadows
    "shadow_softness": None,     # force the light's angular radius (deg); None = fit
    "max_fit_pixels": 4000,      # pixels used by the light fit
}


def _clean(a, lo, hi):
    return np.clip(np.nan_to_num(np.asarray(a, np.float64), nan=0.0, posinf=hi, neginf=lo), lo, hi)


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
        key = (req.scene_key, seed) if req.scene_key is not None else None
        if key is not None and key in self._cache:
            return self._cache[key]
        d, n, sh, known = self._inputs(req)
        if key is not None:
            # Cached per scene, so it must depend on the scene alone: fit on every valid
            # background pixel, not on the first job's shading mask -- else a job's
            # result would depend on which job of its scene a process ran first, and
            # shards or Ray workers would give other composites than one local run.
            known = (d > 0) & np.all(np.isfinite(req.shading), axis=-1)
        est = estimate_lighting(
            d, n, sh, known, req.camera, n_candidates=int(self._s["n_light_candidates"]),
            max_resolution=int(self._s["max_resolution"]),
            march_steps=int(self._s["estimate_march_steps"]),
            max_fit_pixels=int(self._s["max_fit_pixels"]),
            cone_samples=int(self._s["cone_samples"]),
            softness_deg=self._s["shadow_softness"], seed=seed)
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
        timings["estimate"] = time.perf_counter() - t0
        radius = est.cone_deg
        K = int(self._s["cone_samples"]) if radius > 0 else 1
        dirs = cone_directions(est.direction, radius, K, seed=seed)
        images = []
        t1 = time.perf_counter()
        for req in requests:
            images.append(self._render_one(req, est, dirs))
        timings["synthesis"] = time.perf_counter() - t1
        info = {"light": est.to_info(), "fallback": est.fallback,
                "cone_samples": len(dirs), "settings": self.settings()}
        return RenderOutput(images=images, info=info, timings=timings)

    def _render_one(self, req: RenderRequest, est: LightEstimate, dirs) -> np.ndarray:
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
        ys, xs = np.nonzero(todo)
        if len(ys):
            # step 3: ambient(n) + I * mean_k max(0, n.l_k) V(p, l_k), own depth buffer
            dz = d[ys, xs]
            nv = n[ys, xs]
            nn = np.linalg.norm(nv, axis=1)
            geo = (dz > 0) & (np.abs(nn - 1) < 0.2)
            nv = np.where(geo[:, None], nv / np.maximum(nn, 1e-12)[:, None], 0.0)
            rays = np.stack([(xs + 0.5 - req.camera.cx) / req.camera.fx,
                             -(ys + 0.5 - req.camera.cy) / req.camera.fy,
                             -np.ones(len(xs))], 1)
            pts = rays * dz[:, None]
            direct = np.zeros(len(ys))
            if geo.any():
                direct[geo] = direct_term(pts[geo], nv[geo], dirs, d, req.camera, march_visibility,
                                          steps=int(self._s["march_steps"]))
            out_sh[ys, xs] = shade(nv, direct, est.ambient_sh, est.intensity)
        img = (alb * out_sh).astype(np.float32)
        if not np.all(np.isfinite(img)):
            bad = int((~np.isfinite(img)).sum())
            raise NumericalError(f"physical renderer produced {bad} non-finite values")
        return img
