"""Shadow metrics: does the composite darken the same region as the reference, and as much?

Both compare each image with the background photograph it was composited into:

* darkened region: pixels more than ``threshold`` (10 %) darker than the background in
  luminance, off the object (``object_mask``), where the background is not black;
* ``shadow_iou``: intersection over union of the two darkened regions (1.0 when both
  are empty: neither casts a shadow);
* ``shadow_darkness``: mean absolute error of the ratio ``lum(image) / lum(background)``
  (clamped to [0, 1.5]) over the union of both regions (0.0 when the union is empty);
* ``shadow_bias``: the mean signed error of that ratio over the reference's region alone
  (nan when it is empty): above 0, the prediction's shadow is too pale.

Inputs: H x W x 3 linear RGB float arrays (the ratio does not depend on the encoding's
scale, and linear values keep it physical); ``object_mask`` H x W, > 0.5 on the object.
"""

from __future__ import annotations

import numpy as np

from zcomp_cli.conventions import luminance
from zcomp_cli.errors import InputError

SHADOW_THRESHOLD = 0.10
MIN_BACKGROUND_LUMINANCE = 1e-4


def _check(name, a, shape=None):
    a = np.asarray(a, np.float64)
    if a.ndim != 3 or a.shape[-1] != 3:
        raise InputError(f"{name} must be H x W x 3, got {a.shape}")
    if shape is not None and a.shape != shape:
        raise InputError(f"{name} is {a.shape[1]}x{a.shape[0]}, expected {shape[1]}x{shape[0]}")
    return np.nan_to_num(a, nan=0.0, posinf=0.0, neginf=0.0)


def shadow_ratio(image, background) -> tuple[np.ndarray, np.ndarray]:
    """(H, W) ratio lum(image) / lum(background) clamped to [0, 1.5], and the (H, W) bool
    mask where the background is bright enough for the ratio to mean something."""
    img = _check("image", image)
    bg = _check("background", background, img.shape)
    lb = luminance(bg)
    ok = lb > MIN_BACKGROUND_LUMINANCE
    r = np.where(ok, luminance(img) / np.maximum(lb, MIN_BACKGROUND_LUMINANCE), 1.0)
    return np.clip(r, 0.0, 1.5), ok


def darkened_region(image, background, object_mask=None, threshold: float = SHADOW_THRESHOLD) -> np.ndarray:
    """(H, W) bool: more than ``threshold`` darker than the background, off the object."""
    r, ok = shadow_ratio(image, background)
    reg = ok & (r < 1.0 - threshold)
    if object_mask is not None:
        om = np.asarray(object_mask, np.float64)
        if om.shape != reg.shape:
            raise InputError(f"object mask is {om.shape[1]}x{om.shape[0]}, image is {reg.shape[1]}x{reg.shape[0]}")
        reg &= ~(om > 0.5)
    return reg


def shadow_iou(pred, ref, background, object_mask=None, threshold: float = SHADOW_THRESHOLD) -> float:
    """IoU of the darkened regions of ``pred`` and ``ref`` (1.0 when both are empty)."""
    a = darkened_region(pred, background, object_mask, threshold)
    b = darkened_region(ref, background, object_mask, threshold)
    union = int((a | b).sum())
    return 1.0 if union == 0 else float((a & b).sum()) / union


def shadow_darkness(pred, ref, background, object_mask=None, threshold: float = SHADOW_THRESHOLD) -> float:
    """Mean |ratio_pred - ratio_ref| over the union of both darkened regions (0 if empty)."""
    a = darkened_region(pred, background, object_mask, threshold)
    b = darkened_region(ref, background, object_mask, threshold)
    u = a | b
    if not u.any():
        return 0.0
    rp, _ = shadow_ratio(pred, background)
    rr, _ = shadow_ratio(ref, background)
    return float(np.abs(rp - rr)[u].mean())


def shadow_bias(pred, ref, background, object_mask=None, threshold: float = SHADOW_THRESHOLD) -> float:
    """Mean ratio_pred - ratio_ref over ``ref``'s darkened region (nan if it has none):
    the sign ``shadow_darkness`` does not tell (above 0: ``pred``'s shadow too pale)."""
    b = darkened_region(ref, background, object_mask, threshold)
    if not b.any():
        return float("nan")
    return float((shadow_ratio(pred, background)[0] - shadow_ratio(ref, background)[0])[b].mean())
