"""ZeroComp ControlNet conditioning, built by hand (DESIGN.md section 4).

Channel order (official): depth(1), normals(3), albedo(3), shading(3), mask(1)
[, roughness(1), metallic(1)]. The 10-channel variant drops depth.

Shading encoding: the official inference divides the *gamma-2.2 encoded* image by the
linear albedo: ``s = clip(img_lin ** (1/2.2) / albedo, 1e-5, 1e3)``. zcomp receives linear
shading ``img_lin / albedo``, so we rebuild ``img_lin`` (from ``request.image`` where known
and available, else ``shading * albedo``) and reproduce that encoding exactly.
Masked pixels: shading = -1 on all three channels, mask = -1; known: mask = +1.
"""

from __future__ import annotations

import numpy as np

from zcomp_cli.conventions import camera_normals_to_openrooms
from zcomp_cli.errors import InputError

GAMMA = 2.2
SHADING_MIN, SHADING_MAX = 1e-5, 1e3
VARIANTS = (10, 11, 13)


def official_shading(image_lin: np.ndarray, albedo: np.ndarray) -> np.ndarray:
    """Official shading encoding: gamma-2.2 encoded image / linear albedo, clipped.

    image_lin, albedo: H x W x 3 float, linear. Returns H x W x 3 float32 in [1e-5, 1e3].
    Non-finite inputs map to the clip bounds (NaN -> 1e-5)."""
    img = np.clip(np.nan_to_num(np.asarray(image_lin, np.float64), nan=0.0, posinf=1e6), 0, None)
    alb = np.nan_to_num(np.asarray(albedo, np.float64), nan=0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = img ** (1.0 / GAMMA) / alb
    s = np.nan_to_num(s, nan=SHADING_MIN, posinf=SHADING_MAX, neginf=SHADING_MIN)
    return np.clip(s, SHADING_MIN, SHADING_MAX).astype(np.float32)


def _resize(x: np.ndarray, size: int, nearest: bool = False) -> np.ndarray:
    import cv2

    if x.shape[0] == size and x.shape[1] == size:
        return x
    down = x.shape[0] > size or x.shape[1] > size
    interp = cv2.INTER_NEAREST if nearest else (cv2.INTER_AREA if down else cv2.INTER_LINEAR)
    out = cv2.resize(np.ascontiguousarray(x), (size, size), interpolation=interp)
    return out.reshape(size, size, *x.shape[2:])


def build_conditioning(request, channels: int, resolution: int, box=None) -> np.ndarray:
    """One request -> C x R x R float32 conditioning (C = ``channels``).

    box: optional (x0, y0, x1, y1) crop window applied before resizing to R x R.
    Raises InputError on an unknown variant or missing roughness/metallic (13 ch)."""
    if channels not in VARIANTS:
        raise InputError(f"zerocomp: conditioning_channels={channels} not in {VARIANTS}")
    m = request.maps
    h, w = m.shape
    x0, y0, x1, y1 = box if box is not None else (0, 0, w, h)
    sl = (slice(y0, y1), slice(x0, x1))
    known = np.asarray(request.known, bool)
    if known.shape != (h, w):
        raise InputError(f"zerocomp: known mask shape {known.shape} != maps {(h, w)}")
    albedo = np.clip(np.nan_to_num(m.albedo.astype(np.float32)), 0, 1)
    img = np.asarray(request.shading, np.float32) * albedo
    if request.image is not None:
        img = np.where(known[..., None], np.asarray(request.image, np.float32), img)
    shading = official_shading(img, albedo)
    depth = np.clip(np.nan_to_num(m.depth.astype(np.float32), nan=0.0, posinf=0.0), 0, None)
    normals = camera_normals_to_openrooms(np.nan_to_num(m.normals.astype(np.float32)))

    R = resolution
    k = _resize(known[sl].astype(np.uint8), R, nearest=True).astype(bool)
    sh = _resize(shading[sl], R)
    sh[~k] = -1.0
    chans = []
    if channels != 10:
        chans.append(_resize(depth[sl], R)[..., None])
    chans += [_resize(normals[sl], R), _resize(albedo[sl], R), sh,
              np.where(k, 1.0, -1.0).astype(np.float32)[..., None]]
    if channels == 13:
        if m.roughness is None or m.metallic is None:
            raise InputError("zerocomp: this 13-channel checkpoint needs roughness and metallic "
                             "maps (from the object bundle and the scene)")
        for extra in (m.roughness, m.metallic):
            e = np.clip(np.nan_to_num(np.asarray(extra, np.float32)), 0, 1)
            chans.append(_resize(e[sl], R)[..., None])
    cond = np.concatenate(chans, axis=-1).transpose(2, 0, 1)
    assert cond.shape[0] == channels
    return np.ascontiguousarray(cond, dtype=np.float32)


def crop_box(roi, shape, margin: float) -> tuple[int, int, int, int]:
    """Square-ish window around ``roi`` grown by ``margin`` x its size on each side,
    clamped to the image of ``shape`` (h, w). roi None -> full frame."""
    h, w = shape
    if roi is None:
        return (0, 0, w, h)
    x0, y0, x1, y1 = roi
    side = max(x1 - x0, y1 - y0, 1)
    side = int(np.ceil(side * (1 + 2 * margin)))
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    side = min(side, w, h)
    bx0 = int(np.clip(round(cx - side / 2), 0, w - side))
    by0 = int(np.clip(round(cy - side / 2), 0, h - side))
    return (bx0, by0, bx0 + side, by0 + side)
