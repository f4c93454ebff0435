"""Glossy reflections of the inserted object (GGX, split-sum).

The reflected radiance toward the camera is approximated as Karis does ("Real Shading in
Unreal Engine 4", SIGGRAPH 2013): the light prefiltered by the GGX lobe around the
mirror direction (``probe.PrefilteredProbe``), times the environment BRDF
``F0 A(roughness, n.v) + B(roughness, n.v)``, here by Karis's analytic fit ("Physically
Based Shading on Mobile", 2014).

The light prefiltered is the manifest's probe when the scene has one (its sources
included, at the fitted exposure), else the light model itself rendered into a small
equirectangular map: the sky's SH radiance, each sun a disc of its size.
"""

from __future__ import annotations

import numpy as np

from zcomp_cli import equirect
from zcomp_cli.renderers.physical import sh
from zcomp_cli.renderers.physical.lightmodel import LightModel
from zcomp_cli.worldframe import ground_frame

# Size of the map a light model is rendered into for its prefiltering.
MODEL_MAP_SIZE = (32, 64)


def env_brdf(roughness: np.ndarray, ndv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Karis's analytic environment BRDF: (A, B) (N,) for perceptual ``roughness`` and
    ``n.v`` (N,), so that the reflectance is ``F0 A + B``."""
    r = np.asarray(roughness, np.float64)
    nv = np.clip(np.asarray(ndv, np.float64), 0.0, 1.0)
    c0 = np.array([-1.0, -0.0275, -0.572, 0.022])
    c1 = np.array([1.0, 0.0425, 1.04, -0.04])
    q = r[:, None] * c0[None] + c1[None]
    a004 = np.minimum(q[:, 0] * q[:, 0], np.exp2(-9.28 * nv)) * q[:, 0] + q[:, 1]
    return a004 * -1.04 + q[:, 2], a004 * 1.04 + q[:, 3]


def model_radiance_map(model: LightModel, size=MODEL_MAP_SIZE) -> tuple[np.ndarray, np.ndarray]:
    """(equirectangular radiance (h, w, 3) of the model's sky and suns in the ``zcomp``
    convention, its ground frame (3, 3)). Lamps count as suns seen from the camera's
    distance to them (a glossy highlight's direction, not its falloff)."""
    h, w = size
    frame = ground_frame(model.up)
    d = equirect.pixel_directions(h, w, frame)
    om = equirect.solid_angles(h, w)
    L = np.maximum(sh.basis(d.reshape(-1, 3)) @ model.sky.radiance_sh, 0.0).reshape(h, w, 3)
    L = L * ((d @ model.up) > 0)[..., None]
    lights = [(s.direction, s.radius_deg, s.irradiance) for s in model.suns]
    for lp in model.lamps:
        r = float(np.linalg.norm(lp.position))
        dirn = lp.position / max(r, 1e-9)
        lights.append((dirn, float(np.degrees(np.arcsin(min(lp.radius_m / max(r, 1e-9), 0.99)))),
                       lp.intensity / max(r * r, 1e-9)))
    for dirn, radius, power in lights:
        cos = d @ dirn
        disc = cos >= np.cos(np.deg2rad(max(radius, 0.0)))
        if not disc.any():  # smaller than a texel: its nearest one
            disc = np.zeros((h, w), bool)
            disc.flat[int(np.argmax(cos))] = True
        # a light shading a facing surface with E has the radiance pi E over its disc
        L[disc] += np.pi * power[None] / max(float(om[disc].sum()), 1e-12)
    return L, frame


_CACHE: dict = {}


def prefiltered_light(model: LightModel):
    """``probe.PrefilteredProbe`` of the model's light: its probe's, else its own map's
    (cached per model object)."""
    from zcomp_cli.renderers.physical.probe import prefilter

    if model.probe is not None:
        return model.probe
    hit = _CACHE.get(id(model))
    if hit is not None and hit[0] is model:
        return hit[1]
    L, frame = model_radiance_map(model)
    pf = prefilter(L, frame, name="the fitted light")
    if len(_CACHE) > 16:
        _CACHE.clear()
    _CACHE[id(model)] = (model, pf)
    return pf


__all__ = ["env_brdf", "model_radiance_map", "prefiltered_light"]
