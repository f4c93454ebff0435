"""FLIP (Andersson et al. 2020) through NVIDIA's ``flip-evaluator``, validated first.

``flip_evaluator.evaluate`` calls ``sys.exit`` on bad arguments and silently misreads
arrays that are not H x W x 3 float32 C-contiguous, so every input is checked and
converted here before the call.
"""

from __future__ import annotations

import numpy as np

from zcomp_cli.errors import InputError

MODES = ("LDR", "HDR")


def _prepare(img, mode: str, name: str) -> np.ndarray:
    a = np.asarray(img)
    if a.ndim != 3 or a.shape[-1] != 3:
        raise InputError(f"FLIP needs an H x W x 3 image, got shape {a.shape}", where=name)
    if not np.issubdtype(a.dtype, np.floating) and not np.issubdtype(a.dtype, np.integer):
        raise InputError(f"FLIP needs a numeric image, got dtype {a.dtype}", where=name)
    a = a.astype(np.float32)
    if not np.isfinite(a).all():
        raise InputError("non-finite values (NaN/Inf)", where=name)
    if mode == "LDR":
        # Tolerate float rounding at the ends of the range, nothing more.
        if a.min() < -1e-4 or a.max() > 1.0 + 1e-4:
            raise InputError(
                f"LDR FLIP expects sRGB-encoded values in [0, 1], got [{a.min():.4g}, {a.max():.4g}]",
                where=name,
            )
        a = np.clip(a, 0.0, 1.0)
    elif a.min() < 0.0:
        raise InputError(f"HDR FLIP expects non-negative linear values, min {a.min():.4g}", where=name)
    return np.ascontiguousarray(a, dtype=np.float32)


def flip_error_map(pred, ref, *, mode: str = "LDR") -> np.ndarray:
    """Per-pixel FLIP error, H x W float32 in [0, 1] (0 = identical).

    Args:
        pred, ref: H x W x 3. LDR: sRGB-encoded in [0, 1]. HDR: linear RGB >= 0.
        mode: "LDR" or "HDR".
    """
    import flip_evaluator

    if mode not in MODES:
        raise InputError(f"FLIP mode must be one of {MODES}, got {mode!r}")
    p = _prepare(pred, mode, "pred")
    r = _prepare(ref, mode, "ref")
    if p.shape != r.shape:
        raise InputError(f"size mismatch: pred {p.shape}, ref {r.shape}")
    if min(p.shape[:2]) < 2:
        raise InputError(f"FLIP needs images of at least 2x2, got {p.shape[1]}x{p.shape[0]}")
    emap, _mean, _params = flip_evaluator.evaluate(r, p, mode, applyMagma=False)
    emap = np.asarray(emap, dtype=np.float32)
    return emap[..., 0] if emap.ndim == 3 else emap


def flip(pred, ref, mask=None, *, mode: str = "LDR") -> float:
    """Mean FLIP error (lower is better, 0 for identical images), optionally over a mask
    (H x W, > 0.5 selects)."""
    emap = flip_error_map(pred, ref, mode=mode)
    if mask is None:
        return float(emap.mean())
    m = np.asarray(mask)
    if m.ndim == 3 and m.shape[-1] == 1:
        m = m[..., 0]
    if m.shape != emap.shape:
        raise InputError(f"mask is {m.shape}, images are {emap.shape}", where="mask")
    sel = np.nan_to_num(m.astype(np.float64)) > 0.5
    if not sel.any():
        raise InputError("mask selects no pixel", where="mask")
    return float(emap[sel].mean())
