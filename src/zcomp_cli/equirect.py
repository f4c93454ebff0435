"""Equirectangular (latitude-longitude) light probes: which pixel looks where.

A probe's up is gravity (DESIGN.md section 8); its directions are placed in the camera
frame through the ground frame ``(right, up, forward)`` of ``worldframe.ground_frame``.

Pixel (row i, column j) of an H x W map has its centre at ``u = (j + 0.5) / W``,
``v = (i + 0.5) / H``. Every convention puts row 0 straight up: latitude
``lat = pi/2 - v pi``. They differ in the longitude ``lon`` a column looks at, measured
on the ground from ``forward`` and increasing toward ``right``; the direction is then

    d = cos(lat) (sin(lon) right + cos(lon) forward) + sin(lat) up.

Conventions (``convention``), each with what ``rotation_deg`` means:

* ``zcomp`` (default): ``lon = (u - 0.5) 2 pi + rotation``. At rotation 0 the centre
  column looks along the camera's forward direction on the ground, and longitude grows to
  the right; ``rotation_deg`` turns the probe about up, toward the right.
* ``skylibs``: lvsn's skylibs ``world2latlong`` (``u = (1 + atan2(x, -z) / pi) / 2``,
  ``v = arccos(y) / pi``, +x right, +y up, +z toward the camera): the same formula as
  ``zcomp`` (checked on known values in the tests); kept as a name so that a probe
  made with skylibs says so.
* ``blender``: Blender's world mapping (Cycles' equirectangular lookup),
  ``u = 0.5 - atan2(d.y, d.x) / 2 pi``, ``v = 0.5 + atan2(d.z, hypot(d.x, d.y)) / pi``
  (image rows top to bottom), world +Z up, +X at the centre column. The handedness is
  ``zcomp``'s; only the yaw differs. ``rotation_deg`` is the Blender camera's heading:
  its Z rotation (``rotation_euler[2]``) for a camera whose X rotation tilts it from
  looking down, so that Z rotation 0 looks along world +Y; with a Mapping node turning
  the world by ``a`` about Z, give the camera's Z rotation minus ``a``. Then
  ``lon = (u - 0.5) 2 pi + rotation + 90 deg``. (Tested against Blender itself.)
* ``mirrored``: a probe stored left-right mirrored (longitude growing to the left, as a
  probe seen from outside its sphere): ``lon = (0.5 - u) 2 pi + rotation``.
"""

from __future__ import annotations

import math

import numpy as np

CONVENTIONS = ("zcomp", "skylibs", "blender", "mirrored")
DEFAULT_CONVENTION = "zcomp"


# An equirectangular map is twice as wide as high; this much off (a rounded size, a
# cropped row) is still read as one.
ASPECT_TOL = 0.02


def aspect_ok(width: int, height: int) -> bool:
    """Whether a ``width`` x ``height`` image has an equirectangular map's 2:1."""
    return height > 0 and abs(width / (2.0 * height) - 1.0) <= ASPECT_TOL


def _check(convention: str) -> None:
    if convention not in CONVENTIONS:
        raise ValueError(f"unknown probe convention {convention!r} (known: {', '.join(CONVENTIONS)})")


def longitude(u, convention: str = DEFAULT_CONVENTION, rotation_deg: float = 0.0):
    """Longitude (radians, from forward toward right) of horizontal image coordinate
    ``u`` in [0, 1] under ``convention`` (module docstring)."""
    _check(convention)
    u = np.asarray(u, np.float64)
    rot = math.radians(float(rotation_deg))
    if convention == "mirrored":
        return (0.5 - u) * 2 * math.pi + rot
    if convention == "blender":
        rot += math.pi / 2
    return (u - 0.5) * 2 * math.pi + rot


def pixel_directions(height: int, width: int, frame, convention: str = DEFAULT_CONVENTION,
                     rotation_deg: float = 0.0) -> np.ndarray:
    """(H, W, 3) float64 camera-frame unit directions of the probe's pixel centres.

    Args:
        height, width: the map's size.
        frame: (3, 3) rows ``right, up, forward`` (``worldframe.ground_frame``).
        convention, rotation_deg: see the module docstring.
    """
    if int(height) < 1 or int(width) < 1:
        raise ValueError(f"probe size must be positive, got {width}x{height}")
    right, up, fwd = (np.asarray(r, np.float64) for r in np.asarray(frame, np.float64))
    v = (np.arange(int(height)) + 0.5) / int(height)
    u = (np.arange(int(width)) + 0.5) / int(width)
    lat = (0.5 - v) * math.pi
    lon = longitude(u, convention, rotation_deg)
    cl = np.cos(lat)[:, None, None]
    d = (cl * (np.sin(lon)[None, :, None] * right + np.cos(lon)[None, :, None] * fwd)
         + np.sin(lat)[:, None, None] * up)
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def solid_angles(height: int, width: int) -> np.ndarray:
    """(H, W) solid angle (sr) of each pixel of an equirectangular map; sums to 4 pi."""
    v0 = np.arange(int(height)) / int(height)
    v1 = (np.arange(int(height)) + 1) / int(height)
    # exact band areas: 2 pi (sin lat0 - sin lat1) / W
    band = 2 * math.pi * (np.cos(v0 * math.pi) - np.cos(v1 * math.pi)) / int(width)
    return np.repeat(band[:, None], int(width), 1)


def direction_to_uv(direction, frame, convention: str = DEFAULT_CONVENTION,
                    rotation_deg: float = 0.0):
    """(u, v) in [0, 1) x [0, 1] of camera-frame directions (..., 3): the inverse of
    ``pixel_directions`` (rows top to bottom); floats for one direction (3,), arrays of
    the leading shape otherwise."""
    _check(convention)
    right, up, fwd = np.asarray(frame, np.float64)
    d = np.asarray(direction, np.float64)
    d = d / np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-300)
    lat = np.arcsin(np.clip(d @ up, -1.0, 1.0))
    lon = np.arctan2(d @ right, d @ fwd)
    rot = math.radians(float(rotation_deg))
    if convention == "mirrored":
        u = 0.5 - (lon - rot) / (2 * math.pi)
    else:
        if convention == "blender":
            rot += math.pi / 2
        u = 0.5 + (lon - rot) / (2 * math.pi)
    u, v = u % 1.0, 0.5 - lat / math.pi
    if d.ndim == 1:
        return float(u), float(v)
    return u, v


def bilinear_taps(u, v, height: int, width: int):
    """The four texels of an ``height`` x ``width`` map around (u, v) ((N,) each, as
    ``direction_to_uv`` gives them) and their weights: (rows y0, y1 (clamped at the
    poles), columns x0, x1 (wrapping in longitude), fx, fy (N, 1)); a texel's value
    is ``(1-fy)((1-fx) m[y0, x0] + fx m[y0, x1]) + fy((1-fx) m[y1, x0] + fx m[y1, x1])``."""
    x = np.asarray(u, np.float64) * width - 0.5
    y = np.clip(np.asarray(v, np.float64) * height - 0.5, 0, height - 1)
    x0 = np.floor(x).astype(int)
    y0 = np.floor(y).astype(int)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    return y0, np.minimum(y0 + 1, height - 1), x0 % width, (x0 + 1) % width, fx, fy


__all__ = ["CONVENTIONS", "DEFAULT_CONVENTION", "ASPECT_TOL", "aspect_ok", "longitude", "pixel_directions", "solid_angles",
           "direction_to_uv", "bilinear_taps"]
