"""ZeroComp ControlNet conditioning, built by hand (DESIGN.md section 4).

Channel order (official): depth(1), normals(3), albedo(3), shading(3), mask(1)
[, roughness(1), metallic(1)]. The 10-channel variant drops depth.

* depth: raw metres, clamped >= 0;
* normals: ``n * 0.5 + 0.5`` of zcomp's OpenGL camera-frame normals, no axis flip
  (``conventions.camera_normals_to_conditioning``): a camera-facing surface is blue ~ 1;
* albedo: linear [0, 1];
* shading (official *inference* encoding): ``clip(img_lin, 0, 1) ** (1/2.2) / albedo``,
  clamped to [1e-5, 1e3], and 1e-5 wherever albedo <= 1e-5. zcomp's request holds linear
  shading ``img_lin / albedo``; ``img_lin`` is rebuilt from ``request.image`` where known
  and available, else ``shading * albedo``. The OpenRooms *training* loader instead feeds
  linear / linear (``linear_shading``; ``shading="linear"``);
* masked pixels: shading = -1 on all three channels, mask = -1; known: mask = +1.

Geometry: the model sees a **square** window of the frame (``square_window``), resized
isotropically to ``resolution``; a non-square frame is never squashed. The window may
extend past the frame only when the job's region is longer than the frame's short side;
the padding repeats the edge maps and is marked unknown (mask -1).
"""

from __future__ import annotations

import numpy as np

from zcomp_cli.conventions import (
    CONDITIONING_VARIANTS,
    GAMMA,
    SHADING_EPS,
    SHADING_MAX,
    camera_normals_to_conditioning,
)
from zcomp_cli.errors import InputError, UsageError

# The official training loaders (data/dataset_openrooms.py) use 1e-6 for both bounds.
TRAIN_SHADING_EPS = 1e-6
VARIANTS = tuple(CONDITIONING_VARIANTS)
WINDOWS = ("auto", "center", "roi")
SHADING_ENCODINGS = ("inference", "linear")


def official_shading(image_lin: np.ndarray, albedo: np.ndarray) -> np.ndarray:
    """Official inference shading: ``clip(img, 0, 1) ** (1/2.2) / albedo``.

    Args:
        image_lin: H x W x 3 linear image (HDR allowed: it is clipped to [0, 1] first,
            as the official inference does before gamma-encoding).
        albedo: H x W x 3 linear albedo.
    Returns:
        H x W x 3 float32 in [1e-5, 1e3]; exactly 1e-5 where albedo <= 1e-5 (no spike).
        NaN image -> 0, +Inf image -> 1, non-finite albedo -> 0.
    """
    img = np.clip(np.nan_to_num(np.asarray(image_lin, np.float64), nan=0.0, posinf=1.0,
                                neginf=0.0), 0.0, 1.0)
    alb = np.nan_to_num(np.asarray(albedo, np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    return _ratio(img ** (1.0 / GAMMA), alb, SHADING_EPS)


def linear_shading(image_lin: np.ndarray, albedo: np.ndarray,
                   eps: float = TRAIN_SHADING_EPS) -> np.ndarray:
    """OpenRooms training-loader shading: ``clip(img, 0, 1) / albedo`` (both linear),
    ``eps`` where albedo <= eps, clamped to [eps, 1e3]. H x W x 3 float32."""
    img = np.clip(np.nan_to_num(np.asarray(image_lin, np.float64), nan=0.0, posinf=1.0,
                                neginf=0.0), 0.0, 1.0)
    alb = np.nan_to_num(np.asarray(albedo, np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    return _ratio(img, alb, eps)


def _ratio(num: np.ndarray, alb: np.ndarray, eps: float) -> np.ndarray:
    num, alb = np.broadcast_arrays(num, alb)
    ok = alb > eps
    s = np.full(num.shape, eps, np.float64)
    s[ok] = num[ok] / alb[ok]
    return np.clip(s, eps, SHADING_MAX).astype(np.float32)


# ----------------------------------------------------------------------------- windows


def _place(centre: float, side: int, dim: int) -> int:
    """Start of a ``side``-long window centred on ``centre``, kept inside ``[0, dim)``
    when it fits; a window longer than ``dim`` is centred on the frame instead."""
    if side <= dim:
        return int(np.clip(round(centre - side / 2), 0, dim - side))
    return -((side - dim) // 2)


def square_window(roi, shape, mode: str = "auto", margin: float = 0.5) -> tuple[int, int, int, int]:
    """Square window ``(x0, y0, x1, y1)`` (half-open, may extend past the frame) that the
    model sees, isotropically resized to its resolution.

    Args:
        roi: ``(x0, y0, x1, y1)`` region the job needs, or None (whole frame).
        shape: frame (h, w).
        mode: ``auto`` (default): a short-side square (the official scale: short side ->
            model resolution) holding the roi, centred on it; with no roi it is the official
            centre crop. ``center``: the official centre crop, whatever the roi.
            ``roi``: a square around the roi grown by ``margin`` x its size on each side
            (more model pixels on the object), at most the short side.
        margin: context for ``roi`` mode.
    A window is longer than the short side only when the roi is (then it is padded).
    """
    if mode not in WINDOWS:
        raise UsageError(f"zerocomp: window must be one of {WINDOWS}, got {mode!r}")
    h, w = (int(v) for v in shape)
    short = min(h, w)
    if roi is None or mode == "center":
        x0, y0 = _place(w / 2, short, w), _place(h / 2, short, h)
        return (x0, y0, x0 + short, y0 + short)
    rx0, ry0, rx1, ry1 = (int(v) for v in roi)
    need = max(rx1 - rx0, ry1 - ry0, 1)
    if mode == "roi":
        side = min(int(np.ceil(need * (1 + 2 * margin))), short)
    else:
        side = short
    side = max(side, need)
    x0 = _place((rx0 + rx1) / 2, side, w)
    y0 = _place((ry0 + ry1) / 2, side, h)
    return (x0, y0, x0 + side, y0 + side)


def crop_box(roi, shape, margin: float) -> tuple[int, int, int, int]:
    """The ``roi`` window mode (kept for callers of the old name)."""
    return square_window(roi, shape, "roi", margin)


def take_window(x: np.ndarray, box) -> np.ndarray:
    """``x[y0:y1, x0:x1]`` where the box may reach past the frame: edge values repeat."""
    h, w = x.shape[:2]
    x0, y0, x1, y1 = box
    pad = [(max(0, -y0), max(0, y1 - h)), (max(0, -x0), max(0, x1 - w))] + [(0, 0)] * (x.ndim - 2)
    inner = x[max(0, y0):min(h, y1), max(0, x0):min(w, x1)]
    if any(p != (0, 0) for p in pad):
        inner = np.pad(inner, pad, mode="edge")
    return inner


def in_frame(box, shape) -> np.ndarray:
    """Bool (side x side) mask of the window pixels that lie inside the frame."""
    h, w = shape
    x0, y0, x1, y1 = box
    ys = np.arange(y0, y1)
    xs = np.arange(x0, x1)
    return ((ys >= 0) & (ys < h))[:, None] & ((xs >= 0) & (xs < w))[None, :]


def resize_square(x: np.ndarray, size: int, nearest: bool = False) -> np.ndarray:
    """Resize a square (S x S [x C]) array to size x size: area when shrinking
    (antialiased, like the official bilinear+antialias), bilinear when growing."""
    import cv2

    if x.shape[0] != x.shape[1]:
        raise ValueError(f"resize_square expects a square array, got {x.shape}")
    if x.shape[0] == size:
        return x
    interp = cv2.INTER_NEAREST if nearest else (cv2.INTER_AREA if x.shape[0] > size else cv2.INTER_LINEAR)
    out = cv2.resize(np.ascontiguousarray(x), (size, size), interpolation=interp)
    return out.reshape(size, size, *x.shape[2:])


# ----------------------------------------------------------------------------- conditioning


def build_conditioning(request, channels: int, resolution: int, box=None, *,
                       shading: str = "inference") -> np.ndarray:
    """One request -> C x R x R float32 conditioning (C = ``channels``, R = ``resolution``).

    Args:
        request: a RenderRequest (maps, linear shading, known mask, optional image).
        box: square window (``square_window``); None = the official centre crop.
        shading: ``inference`` (official inference encoding) or ``linear`` (OpenRooms
            training loader: linear image / linear albedo).
    Raises InputError on an unknown variant, a non-square box or missing roughness/metallic.
    """
    if channels not in VARIANTS:
        raise InputError(f"zerocomp: conditioning_channels={channels} not in {VARIANTS}")
    if shading not in SHADING_ENCODINGS:
        raise UsageError(f"zerocomp: shading encoding must be one of {SHADING_ENCODINGS}")
    m = request.maps
    h, w = m.shape
    box = square_window(None, (h, w)) if box is None else tuple(int(v) for v in box)
    if box[2] - box[0] != box[3] - box[1] or box[2] <= box[0]:
        raise InputError(f"zerocomp: window {box} is not a non-empty square (never squash)")
    known = np.asarray(request.known, bool)
    if known.shape != (h, w):
        raise InputError(f"zerocomp: known mask shape {known.shape} != maps {(h, w)}")
    albedo = np.clip(np.nan_to_num(m.albedo.astype(np.float32)), 0, 1)
    img = np.nan_to_num(np.asarray(request.shading, np.float32), nan=0.0, posinf=0.0) * albedo
    if request.image is not None:
        img = np.where(known[..., None], np.asarray(request.image, np.float32), img)
    enc = official_shading(img, albedo) if shading == "inference" else linear_shading(img, albedo)
    depth = np.clip(np.nan_to_num(m.depth.astype(np.float32), nan=0.0, posinf=0.0), 0, None)
    normals = camera_normals_to_conditioning(
        np.nan_to_num(m.normals.astype(np.float32), nan=0.0, posinf=0.0, neginf=0.0))

    R = resolution

    def win(x, nearest=False):
        return resize_square(take_window(x, box), R, nearest=nearest)

    # padding past the frame border repeats the edge maps but its shading is unknown
    k = take_window(known, box) & in_frame(box, (h, w))
    k = resize_square(k.astype(np.uint8), R, nearest=True).astype(bool)
    sh = win(enc)
    sh[~k] = -1.0
    chans = []
    if channels != 10:
        chans.append(win(depth)[..., None])
    chans += [win(normals), win(albedo), sh, np.where(k, 1.0, -1.0).astype(np.float32)[..., None]]
    if channels == 13:
        if m.roughness is None or m.metallic is None:
            raise InputError("zerocomp: this 13-channel checkpoint needs roughness and metallic "
                             "maps (from the object bundle and the scene)")
        for extra in (m.roughness, m.metallic):
            e = np.clip(np.nan_to_num(np.asarray(extra, np.float32)), 0, 1)
            chans.append(win(e)[..., None])
    cond = np.concatenate(chans, axis=-1).transpose(2, 0, 1)
    assert cond.shape[0] == channels
    return np.ascontiguousarray(cond, dtype=np.float32)

