"""The light scored apart from the composite: the true and the estimated light rendered on
two spheres, and the scale-invariant RMSE between the renders (issue 37, item 9).

Light-estimation papers score a light by what it does to a probe object, not by one
direction: a **diffuse** sphere (white, albedo ``DIFFUSE_ALBEDO``) shows the light's
low frequencies (where it comes from, the sun/sky split, colour), a **matte-silver**
sphere (metal, GGX, ``SILVER_ROUGHNESS``, ``SILVER_F0``) its highlights (how compact the
light is and where exactly). A composite's error mixes the light with the transport;
this scores the light alone.

The light is the ``light`` dict the physical renderer writes into each job's report
(``report["renderer"]["info"]["light"]``, ``LightModel.to_info``): ``lights`` a list of

* ``{"kind": "sun", "direction_camera": (3,), "angular_radius_deg", "irradiance_rgb": (3,)}``,
* ``{"kind": "lamp", "position_camera": (3,) metres, "intensity_rgb_at_1m": (3,),
  "radius_m", "facing_camera": (3,) or None}``,
* ``{"kind": "sky", "radiance_sh_rgb": (9, 3), "ground_radiance_rgb": (3,)}``,

plus ``up_camera`` (3,) (world up; (0, 1, 0) when missing). Strengths are zcomp's
shading units (``sh``: a surface's irradiance over pi; a sky of uniform radiance L
shades every orientation with L), so a Lambertian surface of albedo a is ``a x shading``.

**Rendering** (``render_spheres``), each sphere S x S pixels, orthographic, seen along
the camera's axis: the pixel at ``(x, y)`` in [-1, 1]^2 (x right, y up) has the camera-
frame normal ``(x, y, sqrt(1 - x^2 - y^2))`` and the view direction ``v = +z`` (toward the
camera). Directions stay in the scene's camera frame, so "a light from the right" lights
the spheres' right halves. Nothing shadows the spheres (each is alone):

* sky: ``sh.evaluate(sh.shading_coeffs(radiance_sh), n)`` clamped at 0, plus the
  ground's bounce ``ground x (1 - n.up) / 2`` (``lightmodel.Sky.shading``);
* sun: ``irradiance x max(0, n.l)``;
* lamp: a directional light toward the lamp as seen from ``center`` (the spheres stand
  there: the benchmark passes the object's base point), of irradiance
  ``intensity x profile / distance^2`` (``lightmodel.Lamp.toward``: profile 1 for a
  sphere lamp, ``4 max(0, -d.facing)`` for a panel). One direction for the whole sphere:
  the sphere is small next to the lamp's distance, and both lights are treated alike;
* the silver sphere reflects the suns and lamps through the GGX BRDF itself
  (``gloss.ggx_direct``, the light's angular radius widening the lobe), and the sky
  by the split sum (``gloss.env_brdf``: ``(F0 A + B) x L_pref(r)``, r the mirror
  direction). ``L_pref`` is the sky's SH radiance evaluated at r with each band l
  damped by ``exp(-l^2 / (2 s))``, the SH transfer of a normalised Phong lobe of
  exponent s (Ramamoorthi and Hanrahan 2002), s the reflected GGX lobe's Phong
  equivalent ``(2 / alpha^2 - 2) / 4`` (the mirror lobe is twice as wide as the
  half-vector one); clamped at 0, blended into the ground's radiance across the horizon
  over the lobe's width ``1 / sqrt(s)``. An approximation (an order-2 sky has little
  beyond the blur anyway), applied to both lights alike.

**Score** (``si_rmse``): ``min_alpha ||alpha a - b|| / ||b||`` over the sphere's pixels
and the three channels (one alpha: a colour error counts), so 0 for the same light at
any strength and 1 for a render that explains nothing of the reference (or is black).
Relative, so scores of scenes of different exposures average; linear radiance, no tone
mapping (the silver sphere's score is mostly its highlights' overlap).

Pure numpy (plus ``sh`` and ``gloss``'s GGX helpers); inputs are checked first and
raise ``InputError`` on a wrong shape or kind; non-finite numbers in a light count as
0 (a light with a non-finite direction or position is left out), so every output is
finite.
"""

from __future__ import annotations

import math

import numpy as np

from zcomp_cli.errors import InputError
from zcomp_cli.metrics.image_metrics import si_rmse as _abs_si_rmse
from zcomp_cli.scene import sh
from zcomp_cli.renderers.physical.gloss import env_brdf, ggx_direct

# Pixels across each sphere: the renders are smooth but for the silver highlights, whose
# lobe (GGX alpha 0.12, ~7 deg) spans a few pixels at 64.
SPHERE_SIZE = 64
# White diffuse sphere: the usual 0.8 grey of light-estimation papers' diffuse probes.
DIFFUSE_ALBEDO = 0.8
# Matte silver: perceptual GGX roughness (alpha = roughness^2, as Blender's Principled
# BSDF) and a grey F0 a little under polished silver's (about 0.95): a dull finish.
SILVER_ROUGHNESS = 0.35
SILVER_F0 = 0.9
# World up when a light dict does not give one: the camera's y axis (a level camera).
DEFAULT_UP = (0.0, 1.0, 0.0)
# Below this a vector's norm means "no direction" (the light is left out).
_EPS = 1e-9
# Widest lamp a sphere is lit by as a light of finite size: sin(radius) at most this
# (inside the lamp's radius its direction stops meaning anything).
_MAX_SIN_RADIUS = 0.99


def _finite(a) -> np.ndarray:
    """float64 copy of ``a`` with NaN and +-inf set to 0."""
    x = np.asarray(a, np.float64)
    return np.where(np.isfinite(x), x, 0.0)


def _vector(item: dict, key: str, where: str, shape=(3,), *, required: bool = True) -> np.ndarray | None:
    """``item[key]`` as a float64 array of ``shape`` (raw: may hold NaN); None if absent
    and not ``required``. Raises InputError on a missing key or a wrong shape."""
    if key not in item or item[key] is None:
        if required:
            raise InputError(f"missing {key!r}", where=where)
        return None
    try:
        a = np.asarray(item[key], np.float64)
    except (TypeError, ValueError) as e:
        raise InputError(f"{key!r} is not numeric ({e})", where=where) from None
    if a.shape != tuple(shape):
        raise InputError(f"{key!r} must have shape {tuple(shape)}, got {a.shape}", where=where)
    return a


def _scalar(item: dict, key: str, where: str, default: float = 0.0) -> float:
    v = item.get(key, default)
    if v is None:
        return default
    try:
        f = float(v)
    except (TypeError, ValueError):
        raise InputError(f"{key!r} must be a number, got {v!r}", where=where) from None
    return f if math.isfinite(f) else default


def _unit(a: np.ndarray | None) -> np.ndarray | None:
    """``a`` normalised, or None when absent, non-finite or (near) zero."""
    if a is None or not np.all(np.isfinite(a)):
        return None
    n = float(np.linalg.norm(a))
    return a / n if n > _EPS else None


def parse_light(light: dict, *, name: str = "light") -> dict:
    """Check a report's ``light`` dict and return it in arrays.

    Args:
        light: ``LightModel.to_info()`` (module docstring); only ``lights`` and
            ``up_camera`` are read.
        name: what to call it in errors.
    Returns:
        ``{"up": (3,) unit, "suns": [(dir (3,) unit, irradiance (3,) >= 0, tan_radius)],
        "lamps": [(position (3,), intensity (3,) >= 0, radius_m >= 0, facing (3,) unit
        or None)], "skies": [(radiance_sh (9, 3), ground (3,) >= 0)]}``, non-finite
        numbers set to 0 and lights without a finite direction or position left out.
    Raises:
        InputError: ``light`` not a dict, ``lights`` missing or not a list, an item of an
        unknown kind, a value of the wrong shape.
    """
    if not isinstance(light, dict):
        raise InputError(f"must be a dict (LightModel.to_info), got {type(light).__name__}", where=name)
    items = light.get("lights")
    if not isinstance(items, (list, tuple)):
        raise InputError("has no 'lights' list (LightModel.to_info)", where=name)
    up = _unit(_vector(light, "up_camera", name, required=False))
    out = {"up": np.asarray(DEFAULT_UP) if up is None else up, "suns": [], "lamps": [], "skies": []}
    for i, it in enumerate(items):
        where = f"{name}.lights[{i}]"
        if not isinstance(it, dict):
            raise InputError(f"must be a dict, got {type(it).__name__}", where=where)
        kind = it.get("kind")
        if kind == "sun":
            d = _unit(_vector(it, "direction_camera", where))
            e = np.maximum(_finite(_vector(it, "irradiance_rgb", where)), 0.0)
            r = min(max(_scalar(it, "angular_radius_deg", where), 0.0), 89.0)
            if d is not None:
                out["suns"].append((d, e, math.tan(math.radians(r))))
        elif kind == "lamp":
            p = _vector(it, "position_camera", where)
            e = np.maximum(_finite(_vector(it, "intensity_rgb_at_1m", where)), 0.0)
            r = max(_scalar(it, "radius_m", where), 0.0)
            f = _vector(it, "facing_camera", where, required=False)
            if np.all(np.isfinite(p)):
                out["lamps"].append((p, e, r, _unit(f)))
        elif kind == "sky":
            c = _finite(_vector(it, "radiance_sh_rgb", where, (sh.N_COEFFS, 3)))
            g = _vector(it, "ground_radiance_rgb", where, required=False)
            g = np.zeros(3) if g is None else np.maximum(_finite(g), 0.0)
            out["skies"].append((c, g))
        else:
            raise InputError(f"unknown light kind {kind!r} (known: sun, lamp, sky)", where=where)
    return out


def sphere_geometry(size: int = SPHERE_SIZE) -> tuple[np.ndarray, np.ndarray]:
    """(normals (size, size, 3) camera-frame unit vectors, 0 off the sphere; mask
    (size, size) bool, the pixels whose centre falls on the sphere). Row 0 is the top
    (+y), column 0 the left (-x); the sphere faces the camera (+z)."""
    size = int(size)
    if size < 2:
        raise InputError(f"sphere size must be at least 2 pixels, got {size}")
    c = (np.arange(size) + 0.5) / size * 2.0 - 1.0
    x, y = np.meshgrid(c, -c)
    rr = x * x + y * y
    mask = rr < 1.0
    z = np.sqrt(np.clip(1.0 - rr, 0.0, 1.0))
    n = np.stack([x, y, z], -1) * mask[..., None]
    return n, mask


def _sky_specular(coeffs: np.ndarray, ground: np.ndarray, up: np.ndarray, r: np.ndarray,
                  roughness: float) -> np.ndarray:
    """(N, 3) the sky's radiance toward mirror directions ``r`` (N, 3) prefiltered by the
    GGX lobe of perceptual ``roughness`` (module docstring: SH bands damped as by a
    Phong lobe, blended into the ground across the horizon)."""
    alpha = max(roughness * roughness, 1e-3)
    s = max((2.0 / (alpha * alpha) - 2.0) / 4.0, 1.0)
    band = np.array([0, 1, 1, 1, 2, 2, 2, 2, 2], np.float64)
    damp = np.exp(-band * band / (2.0 * s))
    L = np.maximum(sh.evaluate(coeffs * damp[:, None], r), 0.0)
    w = 1.0 / math.sqrt(s)
    above = np.clip(0.5 + 0.5 * (r @ up) / w, 0.0, 1.0)[:, None]
    return above * L + (1.0 - above) * ground[None]


def render_spheres(light: dict, center=None, *, size: int = SPHERE_SIZE) -> dict:
    """Render ``light`` on the diffuse and the matte-silver sphere (module docstring).

    Args:
        light: a report's light dict (``parse_light``).
        center: (3,) camera frame, metres: where the spheres stand, the point lamps are
            seen from (None: the camera's origin).
        size: pixels across each sphere (>= 2).
    Returns:
        ``{"diffuse": (size, size, 3), "silver": (size, size, 3), "mask": (size, size)
        bool}``: linear radiance in shading units, >= 0, finite, 0 off the sphere.
    Raises:
        InputError: a malformed light (``parse_light``), a centre that is not a finite
        (3,) vector, size < 2.
    """
    lt = parse_light(light)
    c = np.zeros(3) if center is None else np.asarray(center, np.float64)
    if c.shape != (3,) or not np.all(np.isfinite(c)):
        raise InputError(f"center must be a finite (3,) point, got {np.asarray(center).tolist()}")
    nmap, mask = sphere_geometry(size)
    n = nmap[mask]
    m = len(n)
    v = np.tile([0.0, 0.0, 1.0], (m, 1))
    ndv = np.clip(n[:, 2], 0.0, 1.0)
    r = 2.0 * ndv[:, None] * n - v
    rough = np.full(m, SILVER_ROUGHNESS)
    f0 = np.full((m, 3), SILVER_F0)
    up = lt["up"]
    shading = np.zeros((m, 3))
    spec = np.zeros((m, 3))
    a_env, b_env = env_brdf(rough, ndv, fresnel="schlick")
    for coeffs, ground in lt["skies"]:
        shading += np.maximum(sh.evaluate(sh.shading_coeffs(coeffs), n), 0.0)
        shading += np.clip(0.5 * (1.0 - n @ up), 0.0, 1.0)[:, None] * ground[None]
        spec += (SILVER_F0 * a_env + b_env)[:, None] * _sky_specular(coeffs, ground, up, r, SILVER_ROUGHNESS)
    directional = [(d, e, t) for d, e, t in lt["suns"]]
    for p, inten, rad, facing in lt["lamps"]:
        to = p - c
        dist = float(np.linalg.norm(to))
        if dist <= _EPS:
            continue  # the lamp is at the sphere's centre: no direction
        d = to / dist
        prof = 1.0 if facing is None else 4.0 * max(-float(d @ facing), 0.0)
        sin_r = min(rad / dist, _MAX_SIN_RADIUS)
        directional.append((d, inten * prof / (dist * dist), sin_r / math.sqrt(1.0 - sin_r * sin_r)))
    for d, e, tan_r in directional:
        if not np.any(e > 0):
            continue
        shading += np.maximum(n @ d, 0.0)[:, None] * e[None]
        # e is the shading of a facing surface: its irradiance over pi
        spec += np.pi * e[None] * ggx_direct(n, v, np.tile(d, (m, 1)), rough, f0, tan_r, fresnel="schlick",
                                             energy=False)
    out = {}
    for key, val in (("diffuse", DIFFUSE_ALBEDO * shading), ("silver", spec)):
        img = np.zeros((size, size, 3))
        img[mask] = val
        out[key] = np.maximum(_finite(img), 0.0)
    out["mask"] = mask
    return out


def si_rmse(a, b, mask=None) -> float:
    """Relative scale-invariant RMSE of render ``a`` against reference ``b``:
    ``min_alpha ||alpha a - b|| / ||b||`` over the pixels of ``mask`` and the channels.

    ``image_metrics.si_rmse`` (the absolute one, ``zcomp eval``'s) divided by the RMS of
    ``b``, both images first scaled to a peak of 1 (the ratio does not change; huge
    values cannot overflow). It is the sine of the angle between the two images as
    vectors, so symmetric in ``a`` and ``b``.

    Args:
        a, b: (H, W, 3) float, finite; mask: optional (H, W), > 0.5 selects a pixel.
    Returns:
        float in [0, 1]: 0 when ``a`` is ``b`` at any positive scale; 1 when ``a`` is 0
        (or orthogonal to ``b``) while ``b`` is not; when ``b`` is 0 on the mask, 0 if
        ``a`` is too, else 1 (a light where the reference has none).
    Raises:
        InputError: wrong shapes, size mismatch, non-finite values, empty mask.
    """
    from zcomp_cli.metrics.image_metrics import check_pair

    p, q, m = check_pair(a, b, mask, names=("a", "b"))
    ps, qs = (x if m is None else x[m] for x in (p, q))
    pk, qk = float(np.abs(ps).max()), float(np.abs(qs).max())
    if qk <= 0.0:
        return 0.0 if pk <= 0.0 else 1.0
    if pk <= 0.0:
        return 1.0
    p, q = p / pk, q / qk
    ref = float(np.sqrt(np.mean((q if m is None else q[m]) ** 2)))
    return float(min(max(_abs_si_rmse(p, q, m) / ref, 0.0), 1.0))


def light_sphere_error(light_est: dict, light_true: dict, *, center=None, size: int = SPHERE_SIZE) -> dict:
    """Score an estimated light against the true one on the two spheres.

    Args:
        light_est, light_true: reports' light dicts (``parse_light``), camera frame of
            the same scene.
        center: (3,) camera frame, metres, where the spheres stand (lamps are seen from
            there); None: the camera's origin.
        size: pixels across each sphere.
    Returns:
        ``{"diffuse": si-RMSE of the diffuse sphere, "silver": of the silver sphere,
        "mean": their mean}``, each in [0, 1] (``si_rmse``), finite.
    Raises:
        InputError: a malformed light, centre or size (``render_spheres``).
    """
    est = render_spheres(light_est, center, size=size)
    true = render_spheres(light_true, center, size=size)
    d = si_rmse(est["diffuse"], true["diffuse"], true["mask"])
    s = si_rmse(est["silver"], true["silver"], true["mask"])
    return {"diffuse": d, "silver": s, "mean": 0.5 * (d + s)}


__all__ = ["SPHERE_SIZE", "DIFFUSE_ALBEDO", "SILVER_ROUGHNESS", "SILVER_F0", "parse_light", "sphere_geometry",
           "render_spheres", "si_rmse", "light_sphere_error"]
