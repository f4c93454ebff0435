"""Glossy reflections of the inserted object (GGX).

The sky's reflection toward the camera is approximated as Karis does ("Real Shading in
Unreal Engine 4", SIGGRAPH 2013): the sky prefiltered by the GGX lobe around the mirror
direction (``probe.PrefilteredProbe``), times the environment BRDF
``F0 A(roughness, n.v) + B(roughness, n.v)``, integrated from the same BRDF that reflects
the lights (his analytic fit for mobile, used before, is 0.1-0.16 below that integral
at roughness 0.3-0.8). The sky prefiltered is the manifest's probe with its
compact sources taken out, else the light model's sky rendered into a small
equirectangular map.

The suns and lamps -- the probe's compact sources among them -- are reflected each by
the GGX BRDF itself (``ggx_direct``: Trowbridge-Reitz D, height-correlated Smith G,
Schlick's Fresnel), times the light's visibility: a light the object does not see (its
shadow side, or a wall between) leaves no highlight, as in a path tracer. A light of
angular radius theta widens the lobe (Karis 2013, sphere lights: alpha + tan(theta) / 2).

The specular layer takes its share of the light from the diffuse beneath it
(``specular_albedo``): Cycles' Principled BSDF weights the layers below by one minus the
layer's directional albedo toward the viewer; without it, a rough dielectric reflects
more than it receives (a light rim at grazing angles).
"""

from __future__ import annotations

import functools

import numpy as np

from zcomp_cli import equirect
from zcomp_cli.renderers.physical import sh
from zcomp_cli.renderers.physical.lightmodel import LightModel
from zcomp_cli.renderers.physical.settings import ProbeConfig
from zcomp_cli.worldframe import ground_frame

# The constants (the model's map size, the least GGX alpha, the environment BRDF's
# table: its nodes and samples) are ``settings.ProbeConfig``'s, each with its
# provenance.
DEFAULT = ProbeConfig()


@functools.cache
def _env_lut(size: int = DEFAULT.env_lut_size, samples: int = DEFAULT.env_lut_samples,
             min_alpha: float = DEFAULT.min_alpha) -> np.ndarray:
    """(size, size, 2) the split-sum (A, B) of ``ggx_direct``'s BRDF, integrated by GGX
    importance sampling (``samples`` Hammersley points per node) as Karis 2013
    precomputes it: row roughness, column n.v, both from 0 to 1 (computed once per
    table)."""
    k = samples
    i = np.arange(k)
    u1 = (i + 0.5) / k
    bits = i.astype(np.uint32)  # van der Corput radical inverse
    bits = ((bits << 16) | (bits >> 16)) & 0xFFFFFFFF
    bits = ((bits & 0x55555555) << 1) | ((bits & 0xAAAAAAAA) >> 1)
    bits = ((bits & 0x33333333) << 2) | ((bits & 0xCCCCCCCC) >> 2)
    bits = ((bits & 0x0F0F0F0F) << 4) | ((bits & 0xF0F0F0F0) >> 4)
    bits = ((bits & 0x00FF00FF) << 8) | ((bits & 0xFF00FF00) >> 8)
    u2 = bits.astype(np.float64) / 2.0 ** 32
    nodes = np.linspace(0.0, 1.0, size)
    out = np.zeros((size, size, 2))
    for a_i, r in enumerate(nodes):
        alpha = max(r * r, min_alpha)
        # half vectors from D(h) (n.h): cos^2 = (1 - u) / (1 + (alpha^2 - 1) u)
        ch = np.sqrt((1.0 - u1) / (1.0 + (alpha * alpha - 1.0) * u1))
        sh_ = np.sqrt(np.maximum(1.0 - ch * ch, 0.0))
        phi = 2.0 * np.pi * u2
        h = np.stack([sh_ * np.cos(phi), sh_ * np.sin(phi), ch], 1)
        for v_i, nv in enumerate(nodes):
            nv = max(nv, 1e-3)
            v = np.array([np.sqrt(1.0 - nv * nv), 0.0, nv])
            vh = h @ v
            l = 2.0 * vh[:, None] * h - v
            nl = l[:, 2]
            ok = (nl > 0) & (vh > 0)
            # f (n.l) / pdf(l) = G vh / (n.h n.v), pdf(l) = D n.h / (4 v.h)
            g = np.where(ok, _smith_g(alpha, nv, np.clip(nl, 1e-6, 1.0)) * vh / np.maximum(ch * nv, 1e-12), 0.0)
            fc = (1.0 - np.clip(vh, 0.0, 1.0)) ** 5
            out[a_i, v_i] = (float(np.mean(g * (1.0 - fc))), float(np.mean(g * fc)))
    out.setflags(write=False)
    return out


def env_brdf(roughness: np.ndarray, ndv: np.ndarray,
             cfg: ProbeConfig = DEFAULT) -> tuple[np.ndarray, np.ndarray]:
    """The split-sum environment BRDF of ``ggx_direct``'s BRDF: (A, B) (N,) for
    perceptual ``roughness`` (N,) and ``n.v`` (N,) in [0, 1] (bilinear in the table of
    ``_env_lut``, ``cfg``'s), so that the directional albedo is ``F0 A + B``."""
    lut = _env_lut(cfg.env_lut_size, cfg.env_lut_samples, cfg.min_alpha)
    m = cfg.env_lut_size - 1
    r = np.clip(np.nan_to_num(np.asarray(roughness, np.float64).reshape(-1)), 0.0, 1.0) * m
    c = np.clip(np.nan_to_num(np.asarray(ndv, np.float64).reshape(-1)), 0.0, 1.0) * m
    r0 = np.minimum(np.floor(r).astype(int), m - 1)
    c0 = np.minimum(np.floor(c).astype(int), m - 1)
    fr, fc = (r - r0)[:, None], (c - c0)[:, None]
    v = ((1 - fr) * ((1 - fc) * lut[r0, c0] + fc * lut[r0, c0 + 1])
         + fr * ((1 - fc) * lut[r0 + 1, c0] + fc * lut[r0 + 1, c0 + 1]))
    return v[:, 0], v[:, 1]


def _smith_g(alpha, nv, nl):
    """Height-correlated Smith masking-shadowing of GGX (Heitz 2014)."""
    def lam(c):
        c = np.clip(c, 1e-6, 1.0)
        return 0.5 * (np.sqrt(1.0 + alpha * alpha * (1.0 - c * c) / (c * c)) - 1.0)

    return 1.0 / (1.0 + lam(nv) + lam(nl))


def specular_albedo(roughness: np.ndarray, ndv: np.ndarray, f0: np.ndarray,
                    cfg: ProbeConfig = DEFAULT) -> np.ndarray:
    """(N, C) directional albedo ``F0 A + B`` of the GGX specular layer toward the viewer,
    for perceptual ``roughness`` (N,), ``n.v`` (N,) and ``f0`` (N, C) in [0, 1]."""
    a, b = env_brdf(roughness, ndv, cfg)
    return np.clip(np.asarray(f0, np.float64) * a[:, None] + b[:, None], 0.0, 1.0)


def ggx_direct(n: np.ndarray, v: np.ndarray, l: np.ndarray, roughness: np.ndarray, f0: np.ndarray,
               tan_radius=0.0, *, cfg: ProbeConfig = DEFAULT) -> np.ndarray:
    """(N, C) ``f_spec(v, l) (n.l)``: the GGX specular BRDF times the cosine, so that a
    light bringing the irradiance ``E_perp`` to a surface facing it is reflected toward
    ``v`` with the radiance ``E_perp`` times this.

    n, v, l: (N, 3) unit normal, direction to the viewer, direction to the light;
    roughness: (N,) perceptual (alpha = roughness^2, as Blender's Principled BSDF);
    f0: (N, C) reflectance at normal incidence; tan_radius: the light's angular radius
    as a tangent (scalar or (N,)), widening the lobe; ``cfg.min_alpha`` the sharpest
    lobe. 0 where n.l <= 0 or n.v <= 0."""
    n, v, l = (np.asarray(x, np.float64).reshape(-1, 3) for x in (n, v, l))
    f0 = np.asarray(f0, np.float64)
    r = np.clip(np.nan_to_num(np.asarray(roughness, np.float64).reshape(-1)), 0.0, 1.0)
    alpha = np.maximum(r * r, cfg.min_alpha)
    a_d = np.minimum(alpha + 0.5 * np.asarray(tan_radius, np.float64), 1.0)
    nl = np.sum(n * l, 1)
    nv = np.sum(n * v, 1)
    ok = (nl > 1e-6) & (nv > 1e-6)
    h = v + l
    h = h / np.maximum(np.linalg.norm(h, axis=1, keepdims=True), 1e-12)
    nh = np.clip(np.sum(n * h, 1), 0.0, 1.0)
    vh = np.clip(np.sum(v * h, 1), 0.0, 1.0)
    a2 = a_d * a_d
    D = a2 / (np.pi * (nh * nh * (a2 - 1.0) + 1.0) ** 2)

    G = _smith_g(alpha, nv, nl)
    F = f0 + (1.0 - f0) * ((1.0 - vh) ** 5)[:, None]
    # f (n.l) = D G F / (4 n.v)
    out = (D * G / (4.0 * np.maximum(nv, 1e-6)))[:, None] * F
    return np.where(ok[:, None], out, 0.0)


def model_radiance_map(model: LightModel, size=None, cfg: ProbeConfig = DEFAULT) -> tuple[np.ndarray, np.ndarray]:
    """(equirectangular radiance (h, w, 3) of the model's sky in the ``zcomp``
    convention, its ground frame (3, 3)); its suns and lamps are reflected by
    ``ggx_direct``, each with its visibility. ``size`` (h, w); None:
    ``cfg.model_map_width`` wide, half as high."""
    h, w = (cfg.model_map_width // 2, cfg.model_map_width) if size is None else size
    frame = ground_frame(model.up)
    d = equirect.pixel_directions(h, w, frame)
    L = np.maximum(sh.basis(d.reshape(-1, 3)) @ model.sky.radiance_sh, 0.0).reshape(h, w, 3)
    L = L * ((d @ model.up) > 0)[..., None]
    return L, frame


_CACHE: dict = {}


def prefiltered_light(model: LightModel, cfg: ProbeConfig = DEFAULT):
    """``probe.PrefilteredProbe`` of the model's sky: its probe's (the compact sources
    taken out, prefiltered when the probe was read), else its own map's (cached per
    model object and config)."""
    from zcomp_cli.renderers.physical.probe import prefilter

    if model.probe is not None:
        return model.probe
    key = (id(model), cfg)
    hit = _CACHE.get(key)
    if hit is not None and hit[0] is model:
        return hit[1]
    L, frame = model_radiance_map(model, cfg=cfg)
    pf = prefilter(L, frame, name="the fitted light", cfg=cfg)
    if len(_CACHE) > 16:
        _CACHE.clear()
    _CACHE[key] = (model, pf)
    return pf


__all__ = ["env_brdf", "specular_albedo", "ggx_direct", "model_radiance_map", "prefiltered_light"]
