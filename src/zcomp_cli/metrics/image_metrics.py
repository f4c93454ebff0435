"""Pixel metrics on H x W x 3 float arrays (pure numpy; SSIM through scikit-image).

Colour space: whatever the caller passes. ``zcomp eval`` passes sRGB-encoded images in
[0, 1] (the convention of the paper's tables) or linear RGB with ``--linear``. Every
metric uses ``data_range = 1``. An optional ``mask`` (H x W, bool or float > 0.5)
restricts the score to a region; it must select at least one pixel.
"""

from __future__ import annotations

import numpy as np

from zcomp_cli.errors import InputError

_SSIM_WIN = 7  # scikit-image's default window for Gaussian-free SSIM


def check_pair(pred, ref, mask=None, *, names: tuple[str, str] = ("pred", "ref")):
    """Validate a pair of images (and mask) and return them as float64 arrays.

    Args:
        pred, ref: H x W x 3 arrays, any float/int dtype, finite values.
        mask: optional H x W array; nonzero / > 0.5 selects a pixel.
    Returns:
        (pred, ref, mask) with mask a bool H x W array or None.
    Raises:
        InputError: wrong shapes, size mismatch, non-finite values, empty mask.
    """
    p = np.asarray(pred, dtype=np.float64)
    r = np.asarray(ref, dtype=np.float64)
    for arr, name in ((p, names[0]), (r, names[1])):
        if arr.ndim != 3 or arr.shape[-1] != 3:
            raise InputError(f"expected an H x W x 3 image, got shape {arr.shape}", where=name)
        if arr.shape[0] < 1 or arr.shape[1] < 1:
            raise InputError("empty image", where=name)
        if not np.isfinite(arr).all():
            n = int((~np.isfinite(arr)).sum())
            raise InputError(f"{n} non-finite values (NaN/Inf)", where=name)
    if p.shape != r.shape:
        raise InputError(
            f"size mismatch: {names[0]} is {p.shape[1]}x{p.shape[0]}, "
            f"{names[1]} is {r.shape[1]}x{r.shape[0]}"
        )
    m = None
    if mask is not None:
        m = np.asarray(mask)
        if m.ndim == 3 and m.shape[-1] == 1:
            m = m[..., 0]
        if m.shape != p.shape[:2]:
            raise InputError(f"mask is {m.shape}, images are {p.shape[:2]}", where="mask")
        m = np.nan_to_num(m.astype(np.float64)) > 0.5
        if not m.any():
            raise InputError("mask selects no pixel", where="mask")
    return p, r, m


def _select(x: np.ndarray, m):
    return x if m is None else x[m]


def mae(pred, ref, mask=None) -> float:
    """Mean absolute error over pixels and channels (0 for identical images)."""
    p, r, m = check_pair(pred, ref, mask)
    return float(np.mean(np.abs(_select(p - r, m))))


def mse(pred, ref, mask=None) -> float:
    """Mean squared error over pixels and channels."""
    p, r, m = check_pair(pred, ref, mask)
    return float(np.mean(_select(p - r, m) ** 2))


def rmse(pred, ref, mask=None) -> float:
    """Root mean squared error over pixels and channels."""
    return float(np.sqrt(mse(pred, ref, mask)))


def psnr(pred, ref, mask=None, *, data_range: float = 1.0) -> float:
    """Peak signal-to-noise ratio in dB: ``10 log10(data_range^2 / MSE)``.

    Returns ``inf`` for identical images (MSE == 0); the JSON writer stores it as the
    string "inf".
    """
    e = mse(pred, ref, mask)
    if e <= 0.0:
        return float("inf")
    return float(10.0 * np.log10(data_range**2 / e))


def si_rmse(pred, ref, mask=None) -> float:
    """Scale-invariant RMSE: ``min_alpha RMSE(alpha * pred, ref)``.

    Closed form ``alpha = <pred, ref> / <pred, pred>`` (one scalar for all channels).
    When ``pred`` is (near) zero everywhere the best alpha is undefined: alpha = 0 is
    used, so the result is RMSE(0, ref) (finite, never a division by zero).
    """
    p, r, m = check_pair(pred, ref, mask)
    p, r = _select(p, m).ravel(), _select(r, m).ravel()
    den = float(np.dot(p, p))
    alpha = float(np.dot(p, r)) / den if den > 1e-20 else 0.0
    return float(np.sqrt(np.mean((alpha * p - r) ** 2)))


def ssim(pred, ref, mask=None) -> float:
    """Structural similarity, as ``skimage.metrics.structural_similarity(pred, ref,
    channel_axis=-1, data_range=1)`` (7x7 uniform window, border of 3 pixels excluded).

    With a mask, the SSIM map is averaged over the masked pixels of the same interior
    region. Images must be at least 7x7.
    """
    from skimage.metrics import structural_similarity

    p, r, m = check_pair(pred, ref, mask)
    if min(p.shape[:2]) < _SSIM_WIN:
        raise InputError(
            f"SSIM needs images of at least {_SSIM_WIN}x{_SSIM_WIN}, got {p.shape[1]}x{p.shape[0]}"
        )
    if m is None:
        return float(structural_similarity(p, r, channel_axis=-1, data_range=1.0))
    _, smap = structural_similarity(p, r, channel_axis=-1, data_range=1.0, full=True)
    pad = (_SSIM_WIN - 1) // 2
    inner = np.zeros_like(m)
    inner[pad:-pad, pad:-pad] = True
    sel = m & inner
    if not sel.any():
        raise InputError("mask selects no pixel away from the SSIM border", where="mask")
    return float(smap.mean(axis=-1)[sel].mean())
