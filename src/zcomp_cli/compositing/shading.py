"""Shading from an image and its albedo (DESIGN.md section 3)."""

from __future__ import annotations

import numpy as np

from zcomp_cli.conventions import SHADING_EPS, SHADING_MAX


def shading_from_image(image_lin, albedo, *, eps: float = SHADING_EPS, max_value: float = SHADING_MAX):
    """``image / max(albedo, eps)`` clamped to ``[eps, max_value]``.

    Args:
        image_lin: (H, W, 3) linear RGB, any non-negative range (HDR allowed).
        albedo: (H, W, 3) linear albedo in [0, 1].
    Returns:
        (H, W, 3) float32 shading. Non-finite inputs give ``eps`` (treated as unknown
        darkness rather than propagating NaN).
    """
    img = np.asarray(image_lin, dtype=np.float32)
    alb = np.asarray(albedo, dtype=np.float32)
    if img.shape != alb.shape or img.ndim != 3 or img.shape[-1] != 3:
        raise ValueError(f"image and albedo must both be (H, W, 3), got {img.shape} and {alb.shape}")
    img = np.nan_to_num(img, nan=0.0, posinf=max_value, neginf=0.0)
    alb = np.nan_to_num(alb, nan=0.0, posinf=1.0, neginf=0.0)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):  # (3e38 / eps: inf, clipped below)
        s = img / np.maximum(alb, eps)
    return np.clip(np.nan_to_num(s, nan=eps), eps, max_value).astype(np.float32)
