"""Evaluation protocols and regions of ``zcomp eval``.

Protocols (how images are encoded before the pixel metrics):

* ``zcomp``: sRGB-encoded [0, 1] (the exact curve), or linear with ``--linear``;
* ``paper``: the ZeroComp paper's protocol: images in the official display encoding,
  ``clip(x, 0, 1) ** (1 / 2.2)`` (the official loaders' ``gamma_correction``; the
  official script saves its composites so encoded), and the paper's metrics: PSNR, RMSE,
  si-RMSE, SSIM, MAE, LPIPS (AlexNet, on 256 x 256 resizes in [-1, 1]) and FLIP (LDR, on
  the encoded images). si-RMSE is ``min_a RMSE(a * pred, ref)`` with one scale for all
  pixels and channels (closed form ``a = <pred, ref> / <pred, pred>``), MAE the mean
  absolute difference over pixels and channels, both on the encoded [0, 1] values. It is
  the default when every reference was written by ``zcomp import``.

Regions:

* ``full``: the whole image;
* ``object-crop``: the object's bounding box (coverage > 0.5 in ``object_mask.png``
  beside the reference) grown by 25 % of its width on the left and the right and 25 % of
  its height above and below, "while ensuring to avoid going over the image's bounds"
  (the ZeroComp supplementary material's object crop, Sec. 2),
  rounded outward to whole pixels and clipped to the image. LPIPS resizes the crop to
  256 x 256 like any image.
"""

from __future__ import annotations

import math

import numpy as np

from zcomp_cli.errors import InputError

PROTOCOLS = ("zcomp", "paper")
REGIONS = ("full", "object-crop")
OBJECT_CROP_GROW = 0.25
OBJECT_MASK_THRESHOLD = 0.5
# The columns of the ZeroComp supplementary material's tables (Tab. 1 uses "the same metrics").
PAPER_METRICS = ("psnr", "rmse", "si-rmse", "ssim", "mae", "lpips", "flip")
ENCODINGS = {"zcomp": "srgb", "paper": "gamma2.2"}


def encode(img_lin, encoding: str) -> np.ndarray:
    """Linear H x W x 3 -> [0, 1] display values: ``srgb`` (exact curve) or ``gamma2.2``
    (the official ``clip(x, 0, 1) ** (1 / 2.2)``)."""
    from zcomp_cli.conventions import gamma_encode, linear_to_srgb

    if encoding == "srgb":
        return linear_to_srgb(img_lin)
    if encoding == "gamma2.2":
        return gamma_encode(img_lin)
    raise ValueError(f"unknown encoding {encoding!r}")


def object_crop_box(mask, grow: float = OBJECT_CROP_GROW,
                    threshold: float = OBJECT_MASK_THRESHOLD) -> tuple[int, int, int, int]:
    """The object crop ``(x0, y0, x1, y1)`` (half-open pixel box) of a coverage mask.

    Args:
        mask: (H, W) coverage in [0, 1]; the object is where it is > ``threshold``.
        grow: fraction of the box's width (height) added on each side.
    Returns:
        The grown box rounded outward and clipped to the image. A mask covering columns
        10..19 and rows 20..29 of a 64 x 64 image -> (7, 17, 23, 33).
    Raises:
        InputError when the mask selects no pixel.
    """
    m = np.nan_to_num(np.asarray(mask, np.float64)) > threshold
    if m.ndim != 2 or not m.any():
        raise InputError("the object mask selects no pixel: no object crop")
    rows, cols = np.flatnonzero(m.any(1)), np.flatnonzero(m.any(0))
    x0, x1 = int(cols[0]), int(cols[-1]) + 1
    y0, y1 = int(rows[0]), int(rows[-1]) + 1
    gw, gh = grow * (x1 - x0), grow * (y1 - y0)
    h, w = m.shape
    return (max(0, math.floor(x0 - gw)), max(0, math.floor(y0 - gh)),
            min(w, math.ceil(x1 + gw)), min(h, math.ceil(y1 + gh)))


def crop(arr, box):
    """``arr[y0:y1, x0:x1]`` (None stays None)."""
    if arr is None:
        return None
    x0, y0, x1, y1 = box
    return arr[y0:y1, x0:x1]
