"""Depth alignment of the object on its footprint (DESIGN.md section 2, equation 2).

Fit ``bg_depth ≈ a * footprint_depth + b`` by least squares over the footprint pixels
where both depths are valid, then apply it to the object's depth. Guards, in order:

* fewer than ``min_pixels`` usable pixels -> no alignment at all (``mode="none"``);
* near-constant footprint depth (the fit of ``a`` is ill-conditioned) or a scale
  outside ``scale_range`` -> shift-only (``a = 1``, ``b`` = median difference);
* otherwise the affine fit (``mode="affine"``), with a robust re-fit on inliers.

Every fallback is recorded in ``DepthAlignment.fallback`` for the job report.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from zcomp_cli.conventions import valid_depth_mask


@dataclass(frozen=True)
class DepthAlignment:
    a: float
    b: float
    mode: str  # "affine" | "shift" | "none"
    n_pixels: int
    rmse: float
    fallback: str | None = None

    def to_dict(self) -> dict:
        return asdict(self)


def align_depth(
    bg_depth,
    footprint_depth,
    *,
    min_pixels: int = 16,
    scale_range: tuple[float, float] = (0.5, 2.0),
    min_relative_spread: float = 0.02,
) -> DepthAlignment:
    """Fit the footprint depth to the background depth.

    Args:
        bg_depth: (H, W) background z-depth in metres (0/non-finite = invalid).
        footprint_depth: (H, W) z-depth of the object's base on its support plane
            (0 outside the footprint).
        min_pixels: minimum number of pixels where both are valid.
        scale_range: accepted range of the fitted scale ``a``.
        min_relative_spread: below this (std / mean) the footprint depth is considered
            constant and only a shift is fitted.
    Returns:
        DepthAlignment(a, b, mode, n_pixels, rmse, fallback).
    """
    bg = np.asarray(bg_depth, dtype=np.float64)
    fp = np.asarray(footprint_depth, dtype=np.float64)
    if bg.shape != fp.shape or bg.ndim != 2:
        raise ValueError(f"depth maps must be (H, W) and equal, got {bg.shape} and {fp.shape}")
    sel = valid_depth_mask(bg) & valid_depth_mask(fp)
    n = int(sel.sum())
    if n < min_pixels:
        return DepthAlignment(1.0, 0.0, "none", n, float("nan"),
                              f"only {n} valid footprint pixels (< {min_pixels}): depth left unaligned")
    x = fp[sel]
    y = bg[sel]
    spread = float(np.std(x) / max(np.mean(x), 1e-9))
    fallback = None
    if spread >= min_relative_spread:
        a, b = _robust_affine(x, y)
        if np.isfinite(a) and scale_range[0] <= a <= scale_range[1]:
            r = y - (a * x + b)
            return DepthAlignment(float(a), float(b), "affine", n, float(np.sqrt(np.mean(r * r))))
        fallback = f"fitted scale {a:.3g} outside {scale_range}: shift-only alignment"
    else:
        fallback = f"footprint depth nearly constant (relative spread {spread:.3g}): shift-only alignment"
    b = float(np.median(y - x))
    r = y - (x + b)
    return DepthAlignment(1.0, b, "shift", n, float(np.sqrt(np.mean(r * r))), fallback)


def _robust_affine(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """Least squares, then one re-fit on the pixels within 2.5 MAD of the first fit
    (background depth maps have outliers: the footprint crosses a depth edge)."""
    A = np.stack([x, np.ones_like(x)], axis=1)
    coef, *_ = np.linalg.lstsq(A, y, rcond=None)
    r = y - A @ coef
    mad = np.median(np.abs(r - np.median(r))) * 1.4826
    if mad > 0:
        keep = np.abs(r - np.median(r)) <= 2.5 * mad + 1e-9
        if keep.sum() >= max(8, len(x) // 4):
            coef, *_ = np.linalg.lstsq(A[keep], y[keep], rcond=None)
    return float(coef[0]), float(coef[1])


def apply_alignment(depth, alignment: DepthAlignment) -> np.ndarray:
    """Apply ``a * depth + b`` to valid pixels; invalid pixels (and results <= 0) -> 0."""
    d = np.asarray(depth, dtype=np.float64)
    valid = valid_depth_mask(d)
    out = np.where(valid, alignment.a * np.where(valid, d, 0.0) + alignment.b, 0.0)
    out = np.where(out > 0, out, 0.0)
    return out.astype(np.float32)
