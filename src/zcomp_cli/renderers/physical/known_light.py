"""A known light from the manifest (``pipeline/lightspec.py``) as the renderer's light
model: nothing is estimated but the overall level, read off the photograph.

The direction is given in the camera frame, or as azimuth/elevation relative to the
support plane (the dominant surface of the known geometry) and the image axes: azimuth
0 is the image's right, 90 away from the camera, elevation above the plane. The strength
is direct / ambient irradiance on a surface facing the light, so the shadow level is
``1 / (1 + strength * cos)`` of the lit level on the support (cos: light vs its normal).
"""

from __future__ import annotations

import numpy as np

from zcomp_cli.camera import Camera
from zcomp_cli.conventions import REC601
from zcomp_cli.renderers.physical.lighting import LightEstimate, _downsample, fibonacci_sphere
from zcomp_cli.renderers.physical.visibility import march_visibility


def dominant_normal(normals: np.ndarray) -> np.ndarray:
    """The most common orientation of (N, 3) unit normals, as the support's normal; the
    camera's +y when none is within 60 deg of it."""
    up = np.array([0.0, 1.0, 0.0])
    if len(normals) < 3:
        return up
    bins = fibonacci_sphere(200)
    votes = (normals @ bins.T > np.cos(np.deg2rad(15))).sum(0)
    dom = normals[normals @ bins[votes.argmax()] > np.cos(np.deg2rad(15))].mean(0)
    dom /= max(np.linalg.norm(dom), 1e-12)
    return dom if dom @ up > 0.5 else up


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


def light_from_spec(spec: dict, depth, normals, shading, known, camera: Camera, *,
                    max_resolution: int = 160, march_steps: int = 16) -> LightEstimate:
    """LightEstimate of a manifest light; the ambient level is the lit level of the
    support (its known pixels the light reaches) over ``1 + strength * cos``."""
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
    if spec.get("direction") is not None:
        l = np.asarray(spec["direction"], np.float64)
        l /= np.linalg.norm(l)
        how = "direction (camera frame)"
    else:
        l = direction_from_angles(spec["azimuth_deg"], spec["elevation_deg"], up)
        how = f"azimuth {spec['azimuth_deg']:g} deg, elevation {spec['elevation_deg']:g} deg"
    strength = float(spec.get("strength", 2.0))
    cos = float(max(l @ up, 0.05))
    on = N @ up > np.cos(np.deg2rad(15))
    lit = on.copy()
    if len(P):
        lit &= (march_visibility(P, N, l, d, cam, steps=march_steps) > 0.5) & (N @ l > 0)
    pick = lit if lit.sum() >= 15 else (on if on.sum() >= 15 else np.ones(len(S), bool))
    level = np.median(S[pick], 0) if len(S) else np.full(3, 0.5)
    amb = level / (1.0 + strength * cos)
    sh_c = np.zeros((4, 3))
    sh_c[0] = amb
    share = 1.0 / (1.0 + strength * cos)
    est = LightEstimate(l, strength * amb, sh_c, float(share), float(spec.get("angular_radius_deg", 1.0)),
                        float("nan"), float("nan"), 0.0, None, 0.0, "manifest strength", "manifest",
                        0.0, f"manifest: {how}")
    return est


__all__ = ["light_from_spec", "direction_from_angles", "dominant_normal", "REC601"]
