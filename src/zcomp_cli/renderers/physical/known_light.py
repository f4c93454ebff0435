"""A known light from the manifest (``pipeline/lightspec.py``) as the renderer's light
model: nothing is estimated but the overall level, read off the photograph.

The direction is given in the camera frame, or as azimuth/elevation relative to the
support plane (the dominant surface of the known geometry) and the image axes: azimuth
0 is the image's right, 90 away from the camera, elevation above the plane. The strength
is direct / ambient irradiance on a surface facing the light, so the shadow level is
``1 / (1 + strength * cos)`` of the lit level on the support (cos: light vs its normal).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from zcomp_cli.camera import Camera
from zcomp_cli.conventions import REC601
from zcomp_cli.renderers.physical.lighting import ExtraLight, LightEstimate, _downsample, dominant_normal, fibonacci_sphere
from zcomp_cli.renderers.physical.visibility import march_visibility


# Where a manifest light's radius came from, when it gives ``angular_radius_deg``.
MANIFEST_RADIUS_SOURCE = "manifest: angular_radius_deg"


def direction_from_angles(azimuth_deg: float, elevation_deg: float, up: np.ndarray) -> np.ndarray:
    """Camera-frame unit vector toward a light at ``azimuth_deg`` (0 = image right, 90 =
    away from the camera, in the support plane of normal ``up``) and ``elevation_deg``
    above that plane."""
    up = np.asarray(up, np.float64) / np.linalg.norm(up)
    ex = np.array([1.0, 0.0, 0.0]) - up * up[0]
    ex /= np.linalg.norm(ex)
    ey = np.cross(up, ex)  # in the plane, 90 deg from ex: away from the camera (-z) for up ~ +y
    if ey[2] > 0:
        ey = -ey
    a, e = np.deg2rad(azimuth_deg), np.deg2rad(elevation_deg)
    d = np.cos(e) * (np.cos(a) * ex + np.sin(a) * ey) + np.sin(e) * up
    return d / np.linalg.norm(d)


# The probe's brightest pixels covering this solid angle are its "sun"; the rest is sky.
SUN_SOLID_ANGLE_SR = 0.02  # ~ a disc of 4.6 deg radius


def probe_lights(hdr: np.ndarray, rotation_deg: float = 0.0, up=(0.0, 1.0, 0.0)):
    """Split an equirectangular probe (H, W, 3 linear; +Y up, centre column toward the
    camera's -z, turned by ``rotation_deg`` about +Y) into a sun and a sky.

    Returns:
        (sun direction (3,), sun irradiance on a surface facing it (3,), sky irradiance
        order-1 coefficients (4, 3): E(n) ~ c0 + c . n, sun angular radius in degrees).
    """
    import cv2

    img = np.nan_to_num(np.asarray(hdr, np.float64), nan=0.0, posinf=0.0)
    img = np.maximum(img, 0.0)
    img = cv2.resize(img.astype(np.float32), (128, 64), interpolation=cv2.INTER_AREA).astype(np.float64)
    h, w = img.shape[:2]
    v, u = np.mgrid[0:h, 0:w]
    lat = (0.5 - (v + 0.5) / h) * np.pi
    lon = ((u + 0.5) / w - 0.5) * 2 * np.pi + np.deg2rad(rotation_deg)
    dirs = np.stack([np.sin(lon) * np.cos(lat), np.sin(lat), -np.cos(lon) * np.cos(lat)], -1).reshape(-1, 3)
    d_omega = ((2 * np.pi / w) * (np.pi / h) * np.cos(lat)).reshape(-1)
    L = img.reshape(-1, 3)
    power = (L @ np.array([0.299, 0.587, 0.114])) * d_omega
    order = np.argsort(-(L @ np.array([0.299, 0.587, 0.114])))
    area = np.cumsum(d_omega[order])
    sun = np.zeros(len(L), bool)
    sun[order[: max(1, int(np.searchsorted(area, SUN_SOLID_ANGLE_SR)) + 1)]] = True
    sdir = (dirs[sun] * power[sun, None]).sum(0)
    sdir = sdir / max(np.linalg.norm(sdir), 1e-12)
    e_sun = (L[sun] * d_omega[sun, None]).sum(0)
    # sky irradiance for a set of normals, fitted by c0 + c . n
    ns = fibonacci_sphere(64)
    sky = ~sun
    E = np.maximum(ns @ dirs[sky].T, 0.0) @ (L[sky] * d_omega[sky, None])  # (64, 3)
    X = np.concatenate([np.ones((len(ns), 1)), ns], 1)
    coef, *_ = np.linalg.lstsq(X, E, rcond=None)
    radius = float(np.degrees(np.sqrt(d_omega[sun].sum() / np.pi)))
    return sdir, e_sun, coef, radius


def light_from_spec(spec: dict, depth, normals, shading, known, camera: Camera, *,
                    max_resolution: int = 160, march_steps: int = 16, albedo=None) -> LightEstimate:
    """LightEstimate of a manifest light; the ambient level is the lit level of the
    support (its known pixels the light reaches) over ``1 + strength * cos``.
    ``albedo`` (H, W, 3) serves ``strength: auto`` (``estimate_lighting``)."""
    d, n, sh, k, cam = _downsample(depth, normals, shading, known, camera, max_resolution)
    nn = np.linalg.norm(n, axis=-1)
    valid = k & (d > 0) & (np.abs(nn - 1) < 0.2) & np.all(np.isfinite(sh), -1) & np.all(sh > 0, -1)
    idx = np.flatnonzero(valid.ravel())
    if len(idx) > 4000:
        idx = idx[np.linspace(0, len(idx) - 1, 4000).astype(np.int64)]
    N = n.reshape(-1, 3)[idx].astype(np.float64)
    N /= np.maximum(np.linalg.norm(N, axis=1, keepdims=True), 1e-12)
    S = sh.reshape(-1, 3)[idx].astype(np.float64)
    P = cam.unproject(d).reshape(-1, 3)[idx].astype(np.float64)
    up = dominant_normal(N)
    if spec.get("type") == "probe":
        return _probe_estimate(spec, N, S, P, up, d, cam, march_steps)
    specs = spec["lights"] if spec.get("type") == "lights" else [spec]
    dirs, hows = zip(*(_spec_direction(x, up) for x in specs))
    radii = [x.get("angular_radius_deg") for x in specs]
    if specs[0].get("strength") == "auto":
        # directions known, the rest measured from the photo as for estimated ones
        from zcomp_cli.renderers.physical.lighting import estimate_lighting

        est = estimate_lighting(depth, normals, shading, known, camera, max_resolution=max_resolution,
                                march_steps=march_steps, direction=np.stack(dirs), albedo=albedo,
                                softness_deg=None if radii[0] is None else float(radii[0]))
        est.source = "manifest"
        if radii[0] is not None:
            est.softness_source = MANIFEST_RADIUS_SOURCE
        est.direction_source = f"manifest: {hows[0]}"
        # read from a shadow, or only fitted to the shading (a bare floor: the regression
        # then splits the light from the ambient as it can, which the report must say)
        est.share_source = (f"not measured (no shadow of the light in the photo): {est.share_source}"
                            if est.share_source.startswith("fit") else f"measured ({est.share_source})")
        est.extra_lights = tuple(
            dataclasses.replace(x, direction_source=f"manifest: {how}",
                                softness_deg=x.softness_deg if r is None else float(r))
            for x, how, r in zip(est.extra_lights, hows[1:], radii[1:]))
        return est
    strengths = [float(x.get("strength", 2.0)) for x in specs]
    coss = [float(max(l @ up, 0.05)) for l in dirs]
    on = N @ up > np.cos(np.deg2rad(15))
    lit = on.copy()
    for l in dirs:  # the support where every light reaches
        if len(P):
            lit &= (march_visibility(P, N, l, d, cam, steps=march_steps) > 0.5) & (N @ l > 0)
    pick = lit if lit.sum() >= 15 else (on if on.sum() >= 15 else np.ones(len(S), bool))
    level = np.median(S[pick], 0) if len(S) else np.full(3, 0.5)
    total = 1.0 + sum(s_ * c for s_, c in zip(strengths, coss))
    amb = level / total
    sh_c = np.zeros((4, 3))
    sh_c[0] = amb
    radius = lambda r: 1.0 if r is None else float(r)
    extras = tuple(ExtraLight(l, s_ * amb, radius(r), float((total - s_ * c) / total), f"manifest: {how}",
                              "manifest strength")
                   for l, s_, c, r, how in zip(dirs[1:], strengths[1:], coss[1:], radii[1:], hows[1:]))
    return LightEstimate(dirs[0], strengths[0] * amb, sh_c, float(1.0 / total), radius(radii[0]),
                         float("nan"), float("nan"), 0.0, None, 0.0, "manifest strength", "manifest",
                         0.0, f"manifest: {hows[0]}", extra_lights=extras,
                         softness_source=(MANIFEST_RADIUS_SOURCE if radii[0] is not None
                                          else "manifest default: 1 deg"))


def _spec_direction(spec: dict, up: np.ndarray):
    """(camera-frame unit direction toward the light, how it was given) of a
    directional light spec."""
    if spec.get("direction") is not None:
        l = np.asarray(spec["direction"], np.float64)
        return l / np.linalg.norm(l), "direction (camera frame)"
    l = direction_from_angles(spec["azimuth_deg"], spec["elevation_deg"], up)
    return l, f"azimuth {spec['azimuth_deg']:g} deg, elevation {spec['elevation_deg']:g} deg"


def _probe_estimate(spec, N, S, P, up, d, cam, march_steps) -> LightEstimate:
    """A probe's sun + sky, scaled so the lit support matches the photograph."""
    from zcomp_cli.imageio import read_image
    from zcomp_cli.renderers.physical.shading import sh_basis

    hdr = read_image(spec["hdr"])
    l, e_sun, sky, radius = probe_lights(hdr, float(spec.get("rotation_deg", 0.0)))
    cos = float(max(l @ up, 0.0))
    on = N @ up > np.cos(np.deg2rad(15))
    lit = on.copy()
    if len(P) and cos > 0:
        lit &= (march_visibility(P, N, l, d, cam, steps=march_steps) > 0.5)
    pick = lit if lit.sum() >= 15 else (on if on.sum() >= 15 else np.ones(len(S), bool))
    level = np.median(S[pick], 0) if len(S) else np.full(3, 0.5)
    model_up = (sh_basis(up[None]) @ sky)[0] + e_sun * cos
    scale = level / np.maximum(model_up, 1e-9)
    sky_s = sky * scale[None]
    amb_up = float(np.maximum(sh_basis(up[None]) @ sky_s, 0).mean())
    share = amb_up / max(amb_up + float((e_sun * scale).mean()) * cos, 1e-12)
    name = Path(spec["hdr"]).name
    return LightEstimate(l, e_sun * scale, sky_s, float(share), radius, float("nan"), float("nan"), 0.0,
                         None, 0.0, "manifest probe", "manifest",
                         0.0, f"manifest: probe {name}, rotation {float(spec.get('rotation_deg', 0.0)):g} deg",
                         softness_source=f"manifest: probe {name}, its brightest area")


__all__ = ["light_from_spec", "direction_from_angles", "dominant_normal", "REC601"]
