"""Glossy reflections of the inserted object (GGX).

The sky's reflection toward the camera is approximated as Karis does ("Real Shading in
Unreal Engine 4", SIGGRAPH 2013): the sky prefiltered by the GGX lobe around the mirror
direction (``PrefilteredProbe``, ``prefilter``), times the environment BRDF
``F0 A(roughness, n.v) + B(roughness, n.v)``, integrated from the same BRDF that reflects
the lights (his analytic fit for mobile, used before, is 0.1-0.16 below that integral
at roughness 0.3-0.8). The sky prefiltered is the manifest's probe with its
compact sources taken out, else the light model's sky rendered into a small
equirectangular map.

The suns and lamps -- the probe's compact sources among them -- are reflected each by
the GGX BRDF itself (``ggx_direct``: Trowbridge-Reitz D, height-correlated Smith G),
times the light's visibility: a light the object does not see (its shadow side, or a
wall between) leaves no highlight, as in a path tracer. A light of angular radius theta
widens the lobe (Karis 2013, sphere lights: alpha + tan(theta) / 2).

**Fresnel and the energy of multiple scattering, as Cycles' Principled BSDF.** A
dielectric's reflectance is the exact unpolarised Fresnel of its IOR (``DIELECTRIC_IOR``,
the Principled BSDF's 1.5: F0 = 0.04), which Blender 4+ uses (its "generalized Schlick"
with a negative exponent: the real Fresnel curve rescaled between F0 and 1); Schlick's
approximation is 10-25 % below it at n.h = 0.4-0.8 (``fresnel="dielectric"``). A metal
keeps Schlick's curve from its base colour (Cycles' F82 tint with a white tint is close
to it; ``fresnel="schlick"``). Both are scaled for the light that scatters more than
once between the microfacets (``multiscatter``, Kulla and Conty 2017, "Revisiting
physically based shading at Imageworks"; Cycles' ``microfacet_ggx_preserve_energy``):
``1 + F_ms (1 - E(mu)) / E(mu)``, E the single-scattering albedo with F = 1 toward the
viewer, ``F_ms = F_avg E_avg / (1 - F_avg (1 - E_avg))``. Measured against Cycles 5.0
(a black Principled sphere under a white world, ``benchmarks/gloss_albedo_vs_cycles.py``):
Schlick and single scattering were 10-26 % below it at n.v 0.3-0.85.

The specular layer takes its share of the light from the diffuse beneath it
(``specular_albedo``): Cycles' Principled BSDF weights the layers below by one minus the
layer's directional albedo toward the viewer; without it, a rough dielectric reflects
more than it receives (a light rim at grazing angles).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from zcomp_cli import equirect
from zcomp_cli.renderers.physical.settings import GlossConfig
from zcomp_cli.scene.brdf import (DIELECTRIC_F0, DIELECTRIC_IOR, FRESNELS, env_brdf, fresnel_dielectric,  # noqa: F401
                                  fresnel_shape, multiscatter, smith_g, specular_albedo)
from zcomp_cli.scene import sh
from zcomp_cli.scene.probe import area_resize
from zcomp_cli.scene.lightmodel import LightModel
from zcomp_cli.worldframe import ground_frame


@dataclass(frozen=True)
class PrefilteredProbe:
    """The radiance above the horizon (without the compact sources, which are lights of
    their own) blurred by GGX lobes of several
    roughness levels: ``maps`` (levels, h, w, 4) equirectangular in the probe's
    convention, RGB and the lobe's share above the horizon (below it the support is
    seen: ``lookup``'s ``ground``); ``frame``/``convention``/``rotation_deg`` to look
    them up; ``scale`` multiplies the radiance (the exposure the fit finds)."""

    maps: np.ndarray
    roughness: tuple
    frame: np.ndarray
    convention: str
    rotation_deg: float
    scale: float = 1.0
    name: str = ""

    def __str__(self) -> str:
        return f"prefiltered {self.name} ({self.maps.shape[2]}x{self.maps.shape[1]}, {len(self.roughness)} levels)"

    def scaled(self, k: float) -> "PrefilteredProbe":
        import dataclasses

        return dataclasses.replace(self, scale=float(self.scale * k))

    def lookup(self, directions: np.ndarray, roughness: np.ndarray, ground=None) -> np.ndarray:
        """(N, 3) prefiltered radiance toward unit ``directions`` (N, 3) for perceptual
        ``roughness`` (N,) in [0, 1] (bilinear in direction, linear between levels);
        ``ground`` (3,): the support's radiance, for the lobe's share below the horizon."""
        d = np.asarray(directions, np.float64).reshape(-1, 3)
        _, h, w, _ = self.maps.shape
        u, v = equirect.direction_to_uv(d, self.frame, self.convention, self.rotation_deg)
        y0, y1, x0w, x1w, fx, fy = equirect.bilinear_taps(u, v, h, w)
        r = np.clip(np.asarray(roughness, np.float64).reshape(-1), self.roughness[0], self.roughness[-1])
        lv = np.interp(r, self.roughness, np.arange(len(self.roughness)))
        l0 = np.clip(np.floor(lv).astype(int), 0, len(self.roughness) - 2)
        fl = (lv - l0)[:, None]

        def at(level):
            m = self.maps
            return ((1 - fy) * ((1 - fx) * m[level, y0, x0w] + fx * m[level, y0, x1w])
                    + fy * ((1 - fx) * m[level, y1, x0w] + fx * m[level, y1, x1w]))

        v = (1 - fl) * at(l0) + fl * at(l0 + 1)
        out = self.scale * v[:, :3]
        if ground is not None:
            out = out + np.clip(1.0 - v[:, 3:4], 0.0, 1.0) * np.asarray(ground, np.float64)[None]
        return out


def _ggx_alpha(roughness):
    r = np.asarray(roughness, np.float64)
    return np.maximum(r * r, 1e-4)


def prefilter(img: np.ndarray, frame, *, convention: str = equirect.DEFAULT_CONVENTION,
              rotation_deg: float = 0.0, name: str = "probe", cfg: GlossConfig) -> PrefilteredProbe:
    """The probe (H, W, 3) convolved with GGX lobes of ``cfg.gloss_roughness`` around each
    reflection direction (the split-sum approximation of Karis 2013: the lobe with
    n = v = r), on a ``cfg.gloss_width``-wide copy; energy-preserving (each lobe's
    weights sum to 1)."""
    small = area_resize(np.asarray(img, np.float64), cfg.gloss_width)
    h, w = small.shape[:2]
    frame = np.asarray(frame, np.float64)
    d = equirect.pixel_directions(h, w, frame, convention, rotation_deg).reshape(-1, 3)
    om = equirect.solid_angles(h, w).reshape(-1)
    above = (d @ frame[1] > 0).astype(np.float64)[:, None]
    L = np.concatenate([small.reshape(-1, 3) * above, above], 1)
    cos = np.clip(d @ d.T, -1.0, 1.0)  # (out, in)
    maps = []
    for r in cfg.gloss_roughness:
        a2 = float(_ggx_alpha(r)) ** 2
        # GGX D(h) with h halfway between r and l, weighted by n.l (n = r), as a
        # function of cos(r, l): cos(theta_h) = sqrt((1 + cos) / 2)
        ch2 = np.clip((1.0 + cos) / 2.0, 0.0, 1.0)
        D = a2 / (math.pi * (ch2 * (a2 - 1.0) + 1.0) ** 2)
        wgt = D * np.maximum(cos, 0.0) * om[None]
        wgt /= np.maximum(wgt.sum(1, keepdims=True), 1e-30)
        maps.append((wgt @ L).reshape(h, w, 4))
    return PrefilteredProbe(maps=np.stack(maps), roughness=cfg.gloss_roughness, frame=frame,
                            convention=convention, rotation_deg=float(rotation_deg), name=name)


def principled_layers(metallic: np.ndarray, base: np.ndarray | None) -> list[tuple[np.ndarray, np.ndarray, str]]:
    """Cycles' Principled BSDF's specular layers at N points, as (weight (N,), f0 (N, C),
    ``fresnel``) each: the dielectric (its exact Fresnel, F0 0.04) weighted 1 -
    ``metallic`` (N,) in [0, 1], and where any point is metallic the metal (Schlick's curve
    from the ``base`` colour (N, 3), clipped to [0, 1]) weighted ``metallic``."""
    met = np.asarray(metallic, np.float64).reshape(-1)
    layers = [(1.0 - met, np.full((len(met), 1), DIELECTRIC_F0), "dielectric")]
    if np.any(met > 0):
        layers.append((met, np.clip(np.asarray(base, np.float64), 0, 1), "schlick"))
    return layers


def ggx_direct(n: np.ndarray, v: np.ndarray, l: np.ndarray, roughness: np.ndarray, f0: np.ndarray,
               tan_radius=0.0, *, fresnel: str, cfg: GlossConfig | None = None,
               energy: bool = True) -> np.ndarray:
    """(N, C) ``f_spec(v, l) (n.l)``: the GGX specular BRDF times the cosine, so that a
    light bringing the irradiance ``E_perp`` to a surface facing it is reflected toward
    ``v`` with the radiance ``E_perp`` times this.

    n, v, l: (N, 3) unit normal, direction to the viewer, direction to the light;
    roughness: (N,) perceptual (alpha = roughness^2, as Blender's Principled BSDF);
    f0: (N, C) reflectance at normal incidence; tan_radius: the light's angular radius
    as a tangent (scalar or (N,)), widening the lobe; ``fresnel`` the reflectance's
    curve (``fresnel_shape``); ``energy``: times ``multiscatter`` (False: the single
    scattering alone, reciprocal); ``cfg.min_alpha`` the sharpest lobe. 0 where
    n.l <= 0 or n.v <= 0."""
    cfg = GlossConfig() if cfg is None else cfg
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

    G = smith_g(alpha, nv, nl)
    F = f0 + (1.0 - f0) * fresnel_shape(vh, fresnel)[:, None]
    # f (n.l) = D G F / (4 n.v)
    out = (D * G / (4.0 * np.maximum(nv, 1e-6)))[:, None] * F
    if energy:
        out = out * multiscatter(r, np.clip(nv, 0.0, 1.0), np.broadcast_to(f0, out.shape), cfg, fresnel=fresnel)
    return np.where(ok[:, None], out, 0.0)


def ggx_light(n: np.ndarray, v: np.ndarray, roughness: np.ndarray, layers, directions: np.ndarray,
              shading: np.ndarray, tan_radius=0.0, *, cfg: GlossConfig | None = None) -> np.ndarray:
    """(N, C) the radiance a sun or lamp reflects toward ``v`` off the specular
    ``layers`` (``principled_layers``: (weight (N,), f0 (N, C), fresnel) each), the light
    given as k samples of its disc (``Sun.disc``, ``Lamp.disc``): ``directions`` (k, N, 3)
    unit, toward each, ``shading`` (k, N, 3) a facing surface's shading were the whole
    light there. pi times the mean over the samples of each one's shading times
    ``ggx_direct`` toward it, its lobe widened by ``tan_radius`` (scalar or (N,)): the
    angular radius of a sample's share of the disc. One sample at the disc's centre
    with its whole radius is the widened-lobe approximation (Karis 2013), which puts a
    broad light's highlight where its centre's mirror image falls; its samples put it
    where the disc's does (a panel seen edge-on, a sun's disc half below the horizon).

    n, v: (N, 3) unit normal and direction to the viewer; roughness (N,) perceptual."""
    d = np.asarray(directions, np.float64)
    k, N = d.shape[:2]
    E = np.broadcast_to(np.asarray(shading, np.float64), d.shape).reshape(k * N, 3)
    rep = lambda a: np.broadcast_to(np.asarray(a, np.float64), (k,) + np.shape(a)).reshape((k * N,) + np.shape(a)[1:])
    tan = np.broadcast_to(np.asarray(tan_radius, np.float64), (N,))
    out = sum(rep(w)[:, None] * ggx_direct(rep(n), rep(v), d.reshape(-1, 3), rep(roughness), rep(f0), rep(tan),
                                           fresnel=kind, cfg=cfg)
              for w, f0, kind in layers)
    return np.pi * (E * out).reshape(k, N, -1).mean(0)


def model_radiance_map(model: LightModel, size=None, cfg: GlossConfig | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(equirectangular radiance (h, w, 3) of the model's sky in the ``zcomp``
    convention, its ground frame (3, 3)); its suns and lamps are reflected by
    ``ggx_direct``, each with its visibility. ``size`` (h, w); None:
    ``cfg.model_map_width`` wide, half as high."""
    cfg = GlossConfig() if cfg is None else cfg
    h, w = (cfg.model_map_width // 2, cfg.model_map_width) if size is None else size
    frame = ground_frame(model.up)
    d = equirect.pixel_directions(h, w, frame)
    L = np.maximum(sh.basis(d.reshape(-1, 3)) @ model.sky.radiance_sh, 0.0).reshape(h, w, 3)
    L = L * ((d @ model.up) > 0)[..., None]
    return L, frame


_CACHE: dict = {}
# prefiltered skies kept in this process (the sky of a scene's light, read by each of its
# jobs' glossy objects): a few scenes' worth
KEEP_PREFILTERED = 16
# the seconds of each prefilter built in this process, in order (a job's ledger reads
# whether its render built one: issue 49)
BUILT: list = []


def prefiltered_light(model: LightModel, cfg: GlossConfig) -> PrefilteredProbe:
    """``PrefilteredProbe`` of the model's sky, built when an object first reads it and
    kept for the process (per light and config): its probe's (``ProbeRef``: the map with
    its compact sources taken out, ``scene.probe.load_given_probe``, split with the
    config it was split with), else the model's own sky's map."""
    from zcomp_cli.knobs import from_mapping
    from zcomp_cli.scene.config import ProbeConfig

    ref = model.probe
    if ref is not None:
        key = ("probe", repr(ref.params.to_dict()), ref.frame.tobytes(), repr(sorted(ref.cfg.items())), cfg)
    else:
        key = ("sky", model.sky.radiance_sh.tobytes(), model.up.tobytes(), cfg)
    pf = _CACHE.get(key)
    if pf is None:
        import time

        t0 = time.perf_counter()
        if ref is not None:
            from zcomp_cli.scene.probe import load_given_probe

            split = load_given_probe(ref.params, ref.frame, cfg=from_mapping(ProbeConfig, ref.cfg, "probe"))
            pf = prefilter(split.residual, split.frame, convention=split.convention, rotation_deg=split.rotation_deg,
                           name=split.name, cfg=cfg)
        else:
            L, frame = model_radiance_map(model, cfg=cfg)
            pf = prefilter(L, frame, name="the fitted light", cfg=cfg)
        while len(_CACHE) >= KEEP_PREFILTERED:
            _CACHE.pop(next(iter(_CACHE)))
        _CACHE[key] = pf
        BUILT.append(time.perf_counter() - t0)
    return pf if ref is None else pf.scaled(ref.scale)


__all__ = ["env_brdf", "specular_albedo", "ggx_direct", "ggx_light", "multiscatter", "fresnel_dielectric",
           "fresnel_shape", "principled_layers", "DIELECTRIC_F0", "DIELECTRIC_IOR", "FRESNELS", "model_radiance_map",
           "prefiltered_light", "prefilter", "PrefilteredProbe"]
