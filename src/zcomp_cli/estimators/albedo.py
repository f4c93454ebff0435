"""Weight-free albedo: a classical colour-Retinex intrinsic decomposition.

Assumptions (Land & McCann's Retinex, with Funt et al.'s colour test): reflectance is
piecewise constant, so it changes in sharp steps; illumination (shading) is smooth and
grey. In log space the image is ``log I = log A + log S``. Each image gradient of log
luminance is attributed to the albedo if it is large (``|grad| > lum_threshold``) or if
the chromaticity changes across it (``|grad chroma| > chroma_threshold``: grey light
cannot change colour); every other gradient is shading. The albedo gradients are
integrated back by a least-squares Poisson solve (DCT, Neumann boundary), shading is
``log L - log A_lum`` lightly smoothed, and the colour albedo is ``image / shading``, so
chromaticity is preserved exactly.

Colour: Retinex's grey shading would put the plate's whole colour cast into the albedo,
and the light fitted to ``image / albedo`` would come out white however warm the plate
(an object rendered under it keeps its own colour where every surface of the photograph
carries the cast). The shading instead takes the plate's white balance, one colour
``c`` for the frame read off the photograph by colour constancy
(``estimators.white_balance.plate_illuminant``, the form and order in
``PLATE_WHITE_BALANCE``), and the albedo is ``image / (grey shading * c)``.

Scale: an intrinsic decomposition is defined up to a global factor. We choose it so that
the 95th percentile of albedo luminance is 0.8 (bright paint/paper, not a mirror): this
keeps most albedos in [0, 1] without letting a few specular pixels set the scale.
"""

from __future__ import annotations

import numpy as np

from zcomp_cli.conventions import luminance
from zcomp_cli.errors import InputError
from zcomp_cli.estimators.white_balance import plate_illuminant

_EPS = 1e-4
# The plate's white balance: shades of grey, the Minkowski norm of order p of the pixels
# (Finlayson & Trezzi 2004). Fitted by benchmarks/fit_plate_white_balance.py on the
# development seeds 1618, 8191, 2719, 3301 and 4441 (112 generated cases whose true shading
# is known; docs/plate_white_balance.json): the lowest mean angle to the true light colour,
# 5.10 degrees at p = 2 (p = 1 ties: 5.10; grey, Retinex alone, 5.87; p = 6, 5.88; the
# grey-edge forms 8.4-8.9).
PLATE_WHITE_BALANCE = {"p": 2.0, "edges": False}
# The estimate's version, in its cache key and in the key of every scene whose albedo it
# gives: bumped whenever the estimate changes, so no cache or resumed job keeps an old one
# (2: the shading takes the plate's white balance).
RETINEX_VERSION = "retinex/2"


def _poisson_dct(gx: np.ndarray, gy: np.ndarray) -> np.ndarray:
    """Least-squares integration of a gradient field (forward differences, Neumann
    boundary) by a DCT-II Poisson solve. Returns the field with zero mean."""
    from scipy.fft import dctn, idctn

    h, w = gx.shape
    div = np.zeros((h, w))
    div[:, :-1] += gx[:, :-1]
    div[:, 1:] -= gx[:, :-1]
    div[:-1, :] += gy[:-1, :]
    div[1:, :] -= gy[:-1, :]
    # The Neumann Laplacian's eigenvalues in the DCT-II basis.
    lx = 2 * np.cos(np.pi * np.arange(w) / w) - 2
    ly = 2 * np.cos(np.pi * np.arange(h) / h) - 2
    denom = ly[:, None] + lx[None, :]
    f = dctn(-div, type=2, norm="ortho")
    denom[0, 0] = 1.0
    f = f / -denom
    f[0, 0] = 0.0
    return idctn(f, type=2, norm="ortho")


def retinex_albedo(image_lin, *, lum_threshold: float = 0.12, chroma_threshold: float = 0.03,
                   shading_smooth_px: float = 1.0, percentile: float = 95.0,
                   percentile_value: float = 0.8,
                   white_balance: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Split a linear image into albedo and shading of one colour, the plate's.

    Args:
        image_lin: (H, W, 3) linear RGB, >= 0 (any scale; HDR allowed). Non-finite
            pixels are treated as black.
        lum_threshold: log-luminance step (per pixel) above which an edge is albedo.
        chroma_threshold: chromaticity step above which an edge is albedo.
        shading_smooth_px: Gaussian sigma (pixels) applied to the log shading.
        percentile, percentile_value: the global scale puts this percentile of albedo
            luminance at this value.
        white_balance: the shading takes the plate's colour (``PLATE_WHITE_BALANCE``);
            False: grey shading, every colour in the albedo (Retinex alone).
    Returns:
        albedo: (H, W, 3) float32 linear in [0, 1].
        shading: (H, W, 3) float32, grey luminance times the plate's colour (unit
            luminance), ``image / albedo`` where albedo > 0 and unclipped, > 0.
    """
    from scipy.ndimage import gaussian_filter

    img = np.asarray(image_lin, dtype=np.float64)
    if img.ndim != 3 or img.shape[2] != 3 or min(img.shape[:2]) < 2:
        raise InputError(f"retinex_albedo: expected an (H, W, 3) image, got {img.shape}")
    if not (0 < percentile <= 100 and 0 < percentile_value <= 1):
        raise InputError("retinex_albedo: percentile in (0, 100] and percentile_value in (0, 1]")
    img = np.clip(np.nan_to_num(img, nan=0.0, posinf=0.0, neginf=0.0), 0.0, None)
    lum = luminance(img)
    peak = float(lum.max())
    if peak <= 0:
        # A black image: nothing to decompose; mid-grey albedo, zero-light shading.
        albedo = np.full(img.shape, 0.5, np.float32)
        return albedo, np.full(img.shape, _EPS, np.float32)
    # Work relative to the peak so that the eps floor means the same at any exposure.
    img = img / peak
    lum = lum / peak
    eps = 1e-3
    L = np.log(lum + eps)
    chroma = (img + eps / 3) / (img.sum(-1, keepdims=True) + eps)

    gx = np.zeros_like(L)
    gy = np.zeros_like(L)
    gx[:, :-1] = L[:, 1:] - L[:, :-1]
    gy[:-1, :] = L[1:, :] - L[:-1, :]
    cx = np.zeros_like(L)
    cy = np.zeros_like(L)
    cx[:, :-1] = np.abs(chroma[:, 1:] - chroma[:, :-1]).sum(-1)
    cy[:-1, :] = np.abs(chroma[1:, :] - chroma[:-1, :]).sum(-1)
    ax = np.where((np.abs(gx) > lum_threshold) | (cx > chroma_threshold), gx, 0.0)
    ay = np.where((np.abs(gy) > lum_threshold) | (cy > chroma_threshold), gy, 0.0)
    log_a = _poisson_dct(ax, ay)
    log_s = L - log_a
    if shading_smooth_px > 0:
        log_s = gaussian_filter(log_s, shading_smooth_px, mode="nearest")
    shading_grey = np.exp(log_s)
    colour = plate_illuminant(img, **PLATE_WHITE_BALANCE) if white_balance else np.ones(3)
    # A channel the plate holds no light in (its norm 0): its albedo reads 0, not 0 / 0.
    colour = np.maximum(colour, _EPS)
    albedo = img / (shading_grey[..., None] * colour)
    albedo, scale = scale_albedo(albedo, percentile, percentile_value)
    # Shading so that image = albedo * shading in the original units.
    shading = (shading_grey * peak / scale)[..., None] * colour
    # (within float32: an image of 3e38 overflowed the cast below)
    shading = np.clip(shading, _EPS, min(1e3 * max(peak, 1.0), float(np.finfo(np.float32).max)))
    return albedo.astype(np.float32), shading.astype(np.float32)


def scale_albedo(albedo, percentile: float = 95.0, value: float = 0.8) -> tuple[np.ndarray, float]:
    """Fix the global scale an intrinsic decomposition leaves open: the ``percentile``
    of albedo luminance goes to ``value``; the result is clipped to [0, 1].

    Args:
        albedo: (H, W, 3) linear albedo up to scale (non-negative, finite).
    Returns:
        (scaled albedo, float32 in [0, 1]; the factor applied).
    """
    a = np.asarray(albedo, np.float64)
    ref = float(np.percentile(luminance(a), percentile))
    scale = value / ref if ref > 1e-12 else 1.0
    return np.clip(a * scale, 0.0, 1.0).astype(np.float32), scale


def scale_invariant_error(estimate, reference, mask=None) -> float:
    """Relative squared error after the best global scale:
    ``min_s ||s * est - ref||^2 / ||ref||^2`` over ``mask`` (0 = perfect, 1 = as bad as 0)."""
    e = np.asarray(estimate, np.float64)
    r = np.asarray(reference, np.float64)
    if e.shape != r.shape:
        raise InputError(f"scale_invariant_error: shapes differ {e.shape} vs {r.shape}")
    if mask is not None:
        m = np.asarray(mask, bool)
        e, r = e[m], r[m]
    e, r = e.ravel(), r.ravel()
    den = float(r @ r)
    if den <= 0:
        raise InputError("scale_invariant_error: the reference is all zero")
    ee = float(e @ e)
    s = float(e @ r) / ee if ee > 0 else 0.0
    return float(np.sum((s * e - r) ** 2) / den)
