"""The plate's white balance: the colour of the light a photograph was taken under,
times its camera's white balance, read off the photograph alone.

An intrinsic decomposition leaves the light's colour open: ``image = albedo * shading``
holds for any colour ``c`` moved from one factor to the other. Retinex takes the shading
grey, so every colour cast of the plate (a tungsten-lit room photographed with a daylight
white balance) lands in the albedo, the light fitted to ``image / albedo`` comes out
white, and an object rendered under it keeps its own colour where the photograph's
surfaces all carry the cast. What a composite needs is the product the plate shows: the
light's colour as the camera recorded it.

The estimate is the Minkowski-norm family of colour constancy (Finlayson & Trezzi,
"Shades of grey and colour constancy", 2004): the illuminant is
``(mean_pixels I_c^p)^(1/p)`` per channel, grey-world at ``p = 1`` and the brightest
surface (white patch) as ``p -> inf``; or the same norm of the image's gradients
(van de Weijer et al., "Edge-based colour constancy", 2007: the grey-edge hypothesis,
that the average reflectance *difference* is achromatic). Which form and which ``p``
zcomp uses is fitted on generated scenes whose true shading is known
(``benchmarks/fit_plate_white_balance.py``; the chosen values are ``PLATE_WHITE_BALANCE``
in ``estimators/albedo.py``).
"""

from __future__ import annotations

import math

import numpy as np

from zcomp_cli.conventions import luminance
from zcomp_cli.errors import InputError

__all__ = ["plate_illuminant", "angular_error_deg"]


def plate_illuminant(image_lin, *, p: float, edges: bool = False, valid=None) -> np.ndarray:
    """The colour of a photograph's light by a Minkowski norm of its pixels or edges.

    Args:
        image_lin: (H, W, 3) linear RGB, any scale (HDR allowed). Non-finite and negative
            values are ignored (not counted).
        p: the norm's order, ``>= 1``; ``math.inf`` for the per-channel maximum.
        edges: the norm of the per-channel gradient magnitudes (grey-edge) instead of the
            pixels (shades of grey).
        valid: optional (H, W) bool, the pixels to count (e.g. not the sky).
    Returns:
        (3,) float64, the illuminant's RGB with unit luminance (Rec. 709 weights); grey
        ``(1, 1, 1)`` where the image holds no light to read (all black, or nothing valid).
    """
    img = np.asarray(image_lin, np.float64)
    if img.ndim != 3 or img.shape[2] != 3:
        raise InputError(f"plate_illuminant: expected an (H, W, 3) image, got {img.shape}")
    if not (isinstance(p, (int, float)) and (p >= 1 or p == math.inf)) or math.isnan(p):
        raise InputError(f"plate_illuminant: p must be >= 1 (or inf), got {p!r}")
    ok = np.isfinite(img).all(-1) & (img >= 0).all(-1)
    if valid is not None:
        v = np.asarray(valid, bool)
        if v.shape != img.shape[:2]:
            raise InputError(f"plate_illuminant: valid {v.shape} does not match the image {img.shape[:2]}")
        ok &= v
    img = np.where(ok[..., None], img, 0.0)
    if edges:
        gy, gx = np.gradient(img, axis=(0, 1))
        x = np.hypot(gx, gy)
        # a gradient is read only where both of its neighbours were counted
        ok = ok & np.roll(ok, 1, 0) & np.roll(ok, -1, 0) & np.roll(ok, 1, 1) & np.roll(ok, -1, 1)
    else:
        x = img
    x = x[ok]
    if x.size == 0:
        return np.ones(3)
    peak = float(x.max())
    if not (peak > 0 and math.isfinite(peak)):
        return np.ones(3)
    x = x / peak  # the norm of values in [0, 1]: x^p neither overflows nor underflows to 0 at once
    c = x.max(0) if p == math.inf else np.mean(x ** p, axis=0) ** (1.0 / p)
    lum = float(luminance(c[None, :])[0])
    if not (lum > 0 and math.isfinite(lum)):
        return np.ones(3)
    return c / lum


def angular_error_deg(a, b) -> float:
    """The angle (degrees) between two RGB colours, the colour constancy literature's
    error: independent of the colours' brightness. ``a``, ``b``: (3,) non-negative."""
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    if a.shape != (3,) or b.shape != (3,):
        raise InputError(f"angular_error_deg: expected two (3,) colours, got {a.shape} and {b.shape}")
    na, nb = float(np.linalg.norm(a)), float(np.linalg.norm(b))
    if not (na > 0 and nb > 0):
        raise InputError("angular_error_deg: a colour is black")
    return math.degrees(math.acos(max(-1.0, min(1.0, float(a @ b) / (na * nb)))))
