"""The GGX specular layer of a Principled BSDF, as Cycles draws it: Fresnel, the split-sum
environment BRDF and the energy of multiple scattering (the material physics the light's
fit and the renderers share: the scene's own surfaces have a specular layer too).

A dielectric's reflectance is the exact unpolarised Fresnel of its IOR
(``DIELECTRIC_IOR``, the Principled BSDF's 1.5: F0 = 0.04), which Blender 4+ uses (its
"generalized Schlick" with a negative exponent: the real Fresnel curve rescaled between F0
and 1). A metal keeps Schlick's curve from its base colour. Both are scaled for the light
that scatters more than once between the microfacets (``multiscatter``, Kulla and Conty
2017; Cycles' ``microfacet_ggx_preserve_energy``). ``specular_albedo`` is the layer's
directional albedo toward the viewer, ``(F0 A + B) x multiscatter`` (Karis 2013's split
sum, integrated from the BRDF itself): what Cycles' Principled BSDF takes from the layers
beneath it, and what the layer reflects of a uniform surround. The tables' sizes are a
``BrdfTable`` (``scene.config``); the physical renderer's ``GlossConfig`` carries the same
three fields, user-tunable, and is passed as it is.
"""

from __future__ import annotations

import functools

import numpy as np

from zcomp_cli.scene.config import BrdfTable
from zcomp_cli.scene.sampling import dot, length

# Blender's Principled BSDF's default IOR (a dielectric's reflectance at normal
# incidence ((n - 1) / (n + 1))^2 = 0.04, what its "Specular IOR Level" 0.5 keeps)
DIELECTRIC_IOR = 1.5
DIELECTRIC_F0 = ((DIELECTRIC_IOR - 1.0) / (DIELECTRIC_IOR + 1.0)) ** 2
FRESNELS = ("dielectric", "schlick")


def fresnel_dielectric(cos_i: np.ndarray, eta: float) -> np.ndarray:
    """(N,) the unpolarised Fresnel reflectance of a smooth interface of relative index
    ``eta`` (> 1, from outside) at incidence cosines ``cos_i`` (N,) in [0, 1]."""
    c = np.clip(np.asarray(cos_i, np.float64), 0.0, 1.0)
    g = np.sqrt(eta * eta - 1.0 + c * c)
    a = (g - c) / (g + c)
    b = (c * (g + c) - 1.0) / (c * (g - c) + 1.0)
    return 0.5 * a * a * (1.0 + b * b)


def fresnel_shape(cos_i: np.ndarray, fresnel: str) -> np.ndarray:
    """(N,) w in [0, 1] with the reflectance ``F = f0 + (1 - f0) w`` at the cosines
    ``cos_i`` (N,): Schlick's ``(1 - c)^5``, or the dielectric's exact curve rescaled
    between its F0 and 1 (Cycles' generalized Schlick of exponent -IOR)."""
    c = np.clip(np.asarray(cos_i, np.float64), 0.0, 1.0)
    if fresnel == "schlick":
        return (1.0 - c) ** 5
    if fresnel == "dielectric":
        return np.clip((fresnel_dielectric(c, DIELECTRIC_IOR) - DIELECTRIC_F0) / (1.0 - DIELECTRIC_F0), 0.0, 1.0)
    raise ValueError(f"fresnel must be one of {FRESNELS}, got {fresnel!r}")


@functools.cache
def _env_lut(size: int, samples: int, min_alpha: float, fresnel: str = "schlick") -> np.ndarray:
    """(size, size, 2) the split-sum (A, B) of ``ggx_direct``'s single-scattering BRDF
    with the ``fresnel`` curve, integrated by GGX importance sampling (``samples``
    Hammersley points per node) as Karis 2013 precomputes it: row roughness, column
    n.v, both from 0 to 1 (computed once per table). A + B is the albedo with F = 1."""
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
            g = np.where(ok, smith_g(alpha, nv, np.clip(nl, 1e-6, 1.0)) * vh / np.maximum(ch * nv, 1e-12), 0.0)
            fc = fresnel_shape(vh, fresnel)
            out[a_i, v_i] = (float(np.mean(g * (1.0 - fc))), float(np.mean(g * fc)))
    out.setflags(write=False)
    return out


def _bilinear(lut: np.ndarray, roughness, ndv) -> np.ndarray:
    """(N, C) the table ``lut`` (size, size, C) (row roughness, column n.v, both 0..1)
    at ``roughness`` (N,) or one for all (a scalar: its row found once) and ``ndv``
    (N,), bilinear."""
    m = lut.shape[0] - 1
    c = np.clip(np.nan_to_num(np.asarray(ndv, np.float64).reshape(-1)), 0.0, 1.0) * m
    c0 = np.minimum(np.floor(c).astype(int), m - 1)
    fc = (c - c0)[:, None]
    if np.ndim(roughness) == 0:
        r = float(np.clip(np.nan_to_num(np.float64(roughness)), 0.0, 1.0)) * m
        r0 = min(int(np.floor(r)), m - 1)
        fr = r - r0
    else:
        r = np.clip(np.nan_to_num(np.asarray(roughness, np.float64).reshape(-1)), 0.0, 1.0) * m
        r0 = np.minimum(np.floor(r).astype(int), m - 1)
        fr = (r - r0)[:, None]
    return ((1 - fr) * ((1 - fc) * lut[r0, c0] + fc * lut[r0, c0 + 1])
            + fr * ((1 - fc) * lut[r0 + 1, c0] + fc * lut[r0 + 1, c0 + 1]))


def env_brdf(roughness: np.ndarray, ndv: np.ndarray,
             cfg: BrdfTable | None = None, *, fresnel: str = "schlick") -> tuple[np.ndarray, np.ndarray]:
    """The split-sum environment BRDF of ``ggx_direct``'s single-scattering BRDF: (A, B)
    (N,) for perceptual ``roughness`` (N,) and ``n.v`` (N,) in [0, 1] (bilinear in the
    table of ``_env_lut``, ``cfg``'s) and the ``fresnel`` curve, so that the directional
    albedo of one scattering is ``F0 A + B``."""
    cfg = BrdfTable() if cfg is None else cfg
    v = _bilinear(_env_lut(cfg.env_lut_size, cfg.env_lut_samples, cfg.min_alpha, fresnel), roughness, ndv)
    return v[:, 0], v[:, 1]


@functools.cache
def _energy_lut(size: int, samples: int, min_alpha: float) -> np.ndarray:
    """(size, size, 2) per roughness row and n.v column: the single-scattering albedo
    with F = 1, E(mu), and its cosine-weighted mean over the hemisphere, E_avg = 2 int
    E(mu) mu dmu (the same in every column)."""
    lut = _env_lut(size, samples, min_alpha)
    E = np.clip(lut[..., 0] + lut[..., 1], 1e-4, 1.0)
    mu = np.linspace(0.0, 1.0, size)
    e_avg = np.clip(2.0 * np.trapz(E * mu[None], mu, axis=1), 1e-4, 1.0)
    out = np.stack([E, np.repeat(e_avg[:, None], size, 1)], -1)
    out.setflags(write=False)
    return out


@functools.cache
def _shape_average(fresnel: str) -> float:
    """The cosine-weighted hemispherical mean of ``fresnel_shape``: 2 int w(mu) mu dmu
    (1/21 for Schlick's)."""
    mu = np.linspace(0.0, 1.0, 4097)
    return float(2.0 * np.trapz(fresnel_shape(mu, fresnel) * mu, mu))


def multiscatter(roughness: np.ndarray, ndv: np.ndarray, f0: np.ndarray, cfg: BrdfTable | None = None, *,
                 fresnel: str) -> np.ndarray:
    """(N, C) the factor that restores to the single-scattering GGX layer the light that
    scatters more than once between its microfacets (module docstring), for perceptual
    ``roughness`` (N,), ``ndv`` (N,) and ``f0`` (N, C) of the ``fresnel`` curve: 1 for a
    smooth surface, up to ~1.1 for a rough dielectric."""
    cfg = BrdfTable() if cfg is None else cfg
    e = _bilinear(_energy_lut(cfg.env_lut_size, cfg.env_lut_samples, cfg.min_alpha), roughness, ndv)
    E, e_avg = e[:, :1], e[:, 1:]
    f0 = np.clip(np.asarray(f0, np.float64), 0.0, 1.0)
    f_avg = f0 + (1.0 - f0) * _shape_average(fresnel)
    f_ms = f_avg * e_avg / (1.0 - f_avg * (1.0 - e_avg))
    return 1.0 + f_ms * (1.0 - E) / E


def smith_g(alpha, nv, nl):
    """Height-correlated Smith masking-shadowing of GGX (Heitz 2014)."""
    def lam(c):
        c = np.clip(c, 1e-6, 1.0)
        return 0.5 * (np.sqrt(1.0 + alpha * alpha * (1.0 - c * c) / (c * c)) - 1.0)

    return 1.0 / (1.0 + lam(nv) + lam(nl))


def specular_albedo(roughness: np.ndarray, ndv: np.ndarray, f0: np.ndarray,
                    cfg: BrdfTable | None = None, *, fresnel: str) -> np.ndarray:
    """(N, C) directional albedo ``(F0 A + B) x multiscatter`` of the GGX specular layer
    toward the viewer, for perceptual ``roughness`` (N,) (or a scalar, one for all), ``n.v``
    (N,) and ``f0`` (N, C)
    in [0, 1] of the ``fresnel`` curve ("dielectric": f0 is the dielectric's 0.04)."""
    cfg = BrdfTable() if cfg is None else cfg
    a, b = env_brdf(roughness, ndv, cfg, fresnel=fresnel)
    f0 = np.asarray(f0, np.float64)
    return np.clip((f0 * a[:, None] + b[:, None]) * multiscatter(roughness, ndv, f0, cfg, fresnel=fresnel), 0.0, 1.0)


def dielectric_offset(ndv, roughness: float, albedo, cfg: BrdfTable | None = None) -> np.ndarray:
    """(N, 3) what a dielectric's specular layer adds to its albedo, seen at ``ndv`` (N,)
    (n.v in [0, 1]) with perceptual ``roughness`` (a scalar in [0, 1]) over ``albedo``
    (N, 3) linear in [0, 1]: ``R (1 - albedo)``, R the layer's directional albedo toward the
    viewer (``specular_albedo``, the dielectric's F0 0.04).

    Why: Cycles' Principled BSDF weights the diffuse beneath its specular layer by 1 - R,
    and under a surround of uniform radiance the layer reflects R of it, so a surface of
    base colour ``a`` lit with the irradiance E shows ``E ((1 - R) a + R) = E (a + R (1 -
    a))``: its image over its albedo is brighter on dark albedos and toward grazing views
    (R is 0.02-0.04 facing the camera; at n.v = 0.05, 0.08 at roughness 0.9 and 0.5 at 0.2)."""
    mu = np.clip(np.nan_to_num(np.asarray(ndv, np.float64).reshape(-1)), 0.0, 1.0)
    a = np.clip(np.nan_to_num(np.asarray(albedo, np.float64).reshape(len(mu), -1)), 0.0, 1.0)
    r = float(np.clip(np.nan_to_num(roughness), 0.0, 1.0))
    R = specular_albedo(r, mu, np.full((len(mu), 1), DIELECTRIC_F0), cfg, fresnel="dielectric")
    return R * (1.0 - a)


def camera_offset(points, normals, roughness: float, albedo, cfg: BrdfTable | None = None) -> np.ndarray:
    """(N, C) ``dielectric_offset`` of surfaces at ``points`` (N, 3; the camera frame, the
    camera at the origin) of unit ``normals`` (N, 3) and ``albedo`` (N, C), seen from the
    camera; zeros where ``roughness`` is NaN (no specular layer)."""
    p = np.asarray(points, np.float64).reshape(-1, 3)
    a = np.asarray(albedo, np.float64).reshape(len(p), -1)
    if not np.isfinite(roughness):
        return np.zeros_like(a)
    n = np.asarray(normals, np.float64).reshape(-1, 3)
    ndv = -dot(n, p) / np.maximum(length(p), 1e-12)
    return dielectric_offset(ndv, roughness, a, cfg)


__all__ = ["dielectric_offset", "camera_offset", "DIELECTRIC_IOR", "DIELECTRIC_F0", "FRESNELS", "fresnel_dielectric",
           "fresnel_shape", "env_brdf", "multiscatter", "specular_albedo", "smith_g"]
