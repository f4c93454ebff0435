"""Shadow-opacity compositor (DESIGN.md section 2, equations 4-5).

    R  = clamp((lum(f(i_comp)) + ε) / (lum(f(i_bg)) + ε), 0, 1)   inside s, 1 outside
    w  = blur(s)            (15 x 15 Gaussian, σ = 1.5, reflect padding as torchvision)
    R' = 1 - w * (1 - R)    (= w R + (1 - w), written so that R' is exactly 1 where w = 0)
    C  = mean(x_bg) / mean(f(i_bg)) per channel, over pixels off the object (guarded)
    x  = (1 - m) * R' * x_bg + m * C * f(i_comp)

Every pixel where ``w == 0`` and ``m == 0`` is bit-identical to the background.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from zcomp_cli.conventions import REC601, luminance

RATIO_EPS = 1e-4
BLUR_SIZE = 15
BLUR_SIGMA = 1.5
BALANCE_RANGE = (0.25, 4.0)


def _finite(x, name):
    x = np.asarray(x, dtype=np.float64)
    if not np.all(np.isfinite(x)):
        raise ValueError(f"{name} has non-finite values")
    return x


def shadow_ratio(f_comp, f_bg, mask, *, eps: float = RATIO_EPS) -> np.ndarray:
    """Shadow opacity R (equation 4) on Rec.601 luma.

    Args:
        f_comp, f_bg: (H, W, 3) renderer outputs, linear RGB (finite, >= 0).
        mask: (H, W) bool shading mask s.
        eps: added to numerator and denominator (a black background gives R = 1).
    Returns:
        (H, W) float32 R in [0, 1], exactly 1 outside the mask.
    """
    fc = _finite(f_comp, "f_comp")
    fb = _finite(f_bg, "f_bg")
    s = np.asarray(mask, dtype=bool)
    if fc.shape != fb.shape or fc.shape[:2] != s.shape:
        raise ValueError(f"shape mismatch: {fc.shape}, {fb.shape}, mask {s.shape}")
    lc = np.maximum(luminance(fc, REC601.astype(np.float64)), 0.0)
    lb = np.maximum(luminance(fb, REC601.astype(np.float64)), 0.0)
    R = np.clip((lc + eps) / (lb + eps), 0.0, 1.0)
    return np.where(s, R, 1.0).astype(np.float32)


def gaussian_kernel1d(size: int = BLUR_SIZE, sigma: float = BLUR_SIGMA) -> np.ndarray:
    r = size // 2
    x = np.arange(-r, r + 1, dtype=np.float64)
    k = np.exp(-0.5 * (x / sigma) ** 2)
    return k / k.sum()


def blur_weight(mask, *, size: int = BLUR_SIZE, sigma: float = BLUR_SIGMA) -> np.ndarray:
    """w = blur(s): the shading mask as {0, 1} blurred with a ``size`` x ``size``
    Gaussian, padded by reflection as the official compositor's torchvision
    ``GaussianBlur`` does (``torch.nn.functional.pad(mode="reflect")``: the edge pixel is
    not repeated, numpy's ``reflect`` = scipy's ``mirror``; scipy's own ``reflect`` is
    numpy's ``symmetric`` and would differ). A mask touching the frame border therefore
    keeps its full weight there instead of fading over the last ``size // 2`` pixels.
    Still exactly 0 farther than ``size // 2`` pixels from s (reflection only reads pixels
    within that distance). Returns (H, W) float32 in [0, 1]."""
    from scipy.ndimage import convolve1d

    s = np.asarray(mask, dtype=np.float64)
    k = gaussian_kernel1d(size, sigma)
    w = convolve1d(convolve1d(s, k, axis=0, mode="mirror"), k, axis=1, mode="mirror")
    # Convolution of zeros is exactly zero, but float noise near 0 is cleaned anyway.
    w[w < 1e-7] = 0.0
    return np.clip(w, 0.0, 1.0).astype(np.float32)


def colour_balance(x_bg, f_bg, region, *, clamp=BALANCE_RANGE) -> tuple[np.ndarray, str | None]:
    """Per-channel ``mean(x_bg) / mean(f(i_bg))`` over ``region`` (pixels off the object
    where the renderer output is meaningful). Returns (C (3,), fallback note or None).
    Falls back to 1 per channel when the region is empty or a mean is ~0."""
    xb = np.asarray(x_bg, dtype=np.float64)
    fb = np.asarray(f_bg, dtype=np.float64)
    reg = np.asarray(region, dtype=bool) & np.all(np.isfinite(xb), -1) & np.all(np.isfinite(fb), -1)
    if reg.sum() == 0:
        return np.ones(3), "no off-object pixels: colour balance = 1"
    mx = xb[reg].mean(axis=0)
    mf = fb[reg].mean(axis=0)
    C = np.ones(3)
    note = None
    for c in range(3):
        if mf[c] > 1e-8 and mx[c] > 1e-8:
            C[c] = mx[c] / mf[c]
        else:
            note = "near-zero channel mean: colour balance = 1 on that channel"
    lo, hi = clamp
    if np.any((C < lo) | (C > hi)):
        note = f"colour balance {np.round(C, 3).tolist()} clamped to [{lo}, {hi}]"
    return np.clip(C, lo, hi), note


@dataclass
class CompositeResult:
    image: np.ndarray  # (H, W, 3) linear composite
    ratio: np.ndarray  # R
    ratio_blurred: np.ndarray  # R'
    weight: np.ndarray  # w = blur(s)
    balance: np.ndarray  # C
    notes: list = field(default_factory=list)


def composite(x_bg, f_bg, f_comp, shading_mask, obj_mask, *, balance_region=None, f_object=None) -> CompositeResult:
    """The final composite (equations 4-5).

    Args:
        x_bg: (H, W, 3) linear background photograph (HDR allowed).
        f_bg, f_comp: (H, W, 3) renderer outputs (linear) for background and composite.
        shading_mask: (H, W) bool s.
        obj_mask: (H, W) object coverage m in [0, 1] (after occlusion).
        balance_region: (H, W) bool where C is measured; default: off-object pixels.
        f_object: optional (H, W, 3), the object's own radiance where ``obj_mask`` > 0
            (``RenderOutput.object_layers``): the object term is ``m C f_object`` and
            ``f_comp`` there is the surface behind it; None: ``f_comp`` is both.
    Returns:
        CompositeResult; ``image`` is float32 and finite for finite inputs.
    """
    xb = np.asarray(x_bg, dtype=np.float32)
    m = np.clip(np.nan_to_num(np.asarray(obj_mask, dtype=np.float32)), 0.0, 1.0)
    s = np.asarray(shading_mask, dtype=bool)
    R = shadow_ratio(f_comp, f_bg, s)
    w = blur_weight(s)
    Rb = (1.0 - w * (1.0 - R)).astype(np.float32)
    region = (m == 0) if balance_region is None else (np.asarray(balance_region, bool) & (m == 0))
    C, note = colour_balance(xb, f_bg, region)
    notes = [note] if note else []
    fc = np.asarray(f_comp if f_object is None else f_object, dtype=np.float32)
    obj_term = m[..., None] * (fc * C.astype(np.float32)[None, None, :])
    bg_term = (1.0 - m)[..., None] * Rb[..., None] * xb
    out = np.where((m > 0)[..., None], bg_term + obj_term, Rb[..., None] * xb)
    out = keep_untouched(out, xb, w, m)
    return CompositeResult(out, R, Rb, w, C, notes)


def keep_untouched(image, photo, weight, obj_mask) -> np.ndarray:
    """``image`` with ``photo`` bit for bit outside the blurred mask (``weight`` 0) and
    the object (``obj_mask`` 0): float32. ``photo`` is ``x_bg``, or the photograph as read
    where it has negative pixels (``Scene.photo``, which ``x_bg`` holds at 0)."""
    m = np.clip(np.nan_to_num(np.asarray(obj_mask, dtype=np.float32)), 0.0, 1.0)
    untouched = (np.asarray(weight) == 0) & (m == 0)
    return np.where(untouched[..., None], np.asarray(photo, dtype=np.float32), image).astype(np.float32)
