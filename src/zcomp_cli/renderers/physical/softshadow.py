"""One smooth shadow per light, and the contact shadow (ambient occlusion).

A light of angular radius ``a`` seen from a receiver whose ray meets its occluder after
``t`` metres casts a penumbra of half-width ``t * tan(a)``. Instead of averaging a few
hard shadows from discrete cone directions (which shows as overlapping copies), the
shadow is computed ONCE for the central direction, with the distance to the occluder,
and then filtered per pixel with the penumbra width that distance implies (the idea of
percentage-closer soft shadows, in screen space):

1. hard visibility ``V`` and occluder distance ``t`` per pixel of a window (one march,
   sample offsets decorrelated per pixel so that no step pattern survives);
2. blocker search: the mean occluder distance of the shadowed pixels around each pixel;
3. penumbra radius in pixels ``r = t_blocker * tan(a) * f / z``;
4. ``V`` blurred with Gaussians of geometrically growing radii (normalised, separately
   on the object and on the rest so that one never bleeds into the other) and, per
   pixel, interpolated between the two levels around ``r``: continuous in ``r``, so the
   penumbra is smooth and free of bands.

The sky's visibility (``scene.skyvis``) is blurred with the same normalised filter.
"""

from __future__ import annotations

import numpy as np

from zcomp_cli.renderers.physical.settings import TransportConfig



def blur_reach(radius: float) -> int:
    """Pixels from its centre that ``gaussian_blur`` of ``radius`` reads (half the kernel)."""
    return int(np.ceil(3 * radius / 2.0)) if radius > 0 else 0


def gaussian_blur(img: np.ndarray, radius: float) -> np.ndarray:
    """Gaussian blur of an (H, W[, C]) float32 image, sigma ``radius / 2`` pixels, the
    border replicated; ``radius <= 0`` returns it unchanged."""
    import cv2

    if radius <= 0:
        return img
    k = 2 * blur_reach(radius) + 1
    return cv2.GaussianBlur(img, (k, k), radius / 2.0, borderType=cv2.BORDER_REPLICATE)


def _reached(den: np.ndarray):
    """(where a blurred weight ``den`` reaches, the weight to divide by): below 1e-4 no
    weight counts as reaching (a normalised blur keeps the value there), and the
    divisor is floored at it."""
    return den > 1e-4, np.maximum(den, 1e-4)


def normalized_blur(values: np.ndarray, weight: np.ndarray, radius: float) -> np.ndarray:
    """Gaussian blur of ``values`` (H, W) or (H, W, C) (the channels blurred together,
    each as alone) over the pixels where ``weight`` (H, W) > 0, normalised by
    the blurred weight; where no weight reaches, the value itself."""
    if radius <= 0:
        return values
    w = weight.astype(np.float32)
    v = np.asarray(values)
    wv = w if v.ndim == 2 else w[..., None]
    num = gaussian_blur((v * wv).astype(np.float32), radius)
    den = gaussian_blur(w, radius)
    if v.ndim == 3:
        den = den[..., None]
    ok, den = _reached(den)
    return np.where(ok, num / den, v).astype(np.float64)


def classwise_blur(values: np.ndarray, classes: np.ndarray, valid: np.ndarray, radius: float,
                   fill: np.ndarray | None = None) -> np.ndarray:
    """``normalized_blur`` separately within each class label (e.g. object / scene),
    weighted by the ``valid`` pixels; written to the valid pixels, and also to the
    ``fill`` pixels of the same class (their own value does not count). ``values``:
    (H, W) or (H, W, C), the channels in one pass (any number)."""
    out = values.astype(np.float64)
    if radius <= 0:
        return out
    H, W = values.shape[:2]
    dest = valid if fill is None else (valid | fill)
    reach = blur_reach(radius)
    # (float32 once for every class: the weights are 0 or 1, so weighting after the
    # cast is the same as before it; each class's quotient is formed at its own pixels)
    v32 = values.astype(np.float32)
    for c in np.unique(classes[dest]):
        in_c = classes == c
        m = dest & in_c
        ys, xs = np.flatnonzero(m.any(1)), np.flatnonzero(m.any(0))
        # each class over the box its pixels' kernels read (a small object's class
        # needs a small crop): the same result as over the whole frame
        sl = (slice(max(0, ys[0] - reach), min(H, ys[-1] + 1 + reach)),
              slice(max(0, xs[0] - reach), min(W, xs[-1] + 1 + reach)))
        w = (valid[sl] & in_c[sl]).astype(np.float32)
        num = gaussian_blur(v32[sl] * (w if v32.ndim == 2 else w[..., None]), radius)
        den = gaussian_blur(w, radius)
        # the class's pixels that some weight reaches (elsewhere the value stays)
        ok, den = _reached(den)
        put = dest[sl] & in_c[sl] & ok
        if num.ndim == 3:
            den, put = den[..., None], put[..., None]
        np.divide(num, den, out=num)
        np.copyto(out[sl], num, where=put)
    return out


def penumbra_filter(vis: np.ndarray, t_hit: np.ndarray, z: np.ndarray, classes: np.ndarray,
                    valid: np.ndarray, focal_px: float, tan_radius: float,
                    box: tuple[int, int, int, int] | None = None, cfg: TransportConfig | None = None) -> np.ndarray:
    """Smooth a hard shadow into the penumbra a light of angular radius ``atan(tan_radius)``
    casts.

    Args:
        vis: (H, W) hard visibility in {0, 1} of the central light direction.
        t_hit: (H, W) distance (m) to the occluder along the light ray (inf where lit).
        z: (H, W) positive z-depth of each pixel (m).
        classes: (H, W) int labels; the blur never mixes labels (object vs scene).
        valid: (H, W) bool, pixels with geometry.
        focal_px: focal length in pixels; tan_radius: tan of the light's angular radius,
            a number or (H, W) per pixel (a lamp: its radius over its distance).
        box: (y0, x0, y1, x1), the pixels whose result is needed (None: all). Each blur
            then reads only the context its kernel reaches around the box: the result
            there is the same as on the whole frame, for a fraction of the work when the
            frame carries a wide margin for the widest penumbra.
        cfg: the blur levels (``penumbra_levels_px``) and the blocker search's radius.
    Returns:
        (H, W) float64 visibility in [0, 1], or (y1 - y0, x1 - x0) with ``box``.
    """
    cfg = TransportConfig() if cfg is None else cfg
    H, W = vis.shape
    y0, x0, y1, x1 = (0, 0, H, W) if box is None else (max(0, int(box[0])), max(0, int(box[1])),
                                                        min(H, int(box[2])), min(W, int(box[3])))

    def around(reach):  # the box grown by ``reach`` pixels, inside the frame
        return (slice(max(0, y0 - reach), min(H, y1 + reach)), slice(max(0, x0 - reach), min(W, x1 + reach)))

    def inner(sl):  # the box inside a crop ``sl``
        return (slice(y0 - sl[0].start, y1 - sl[0].start), slice(x0 - sl[1].start, x1 - sl[1].start))

    vis = np.where(valid, vis, 1.0).astype(np.float64)
    tan_b = np.asarray(tan_radius, np.float64)
    if tan_b.ndim == 2:
        tan_b = tan_b[y0:y1, x0:x1]
    if not np.any(tan_b > 0) or not (vis < 1).any():
        return vis[y0:y1, x0:x1]
    # 2. blocker search: mean occluder distance of the shadowed pixels nearby
    search = cfg.blocker_search_px
    sl = around(blur_reach(search))
    v_c, ok_c, t_c = vis[sl], valid[sl], t_hit[sl]
    shadowed = ok_c & (v_c < 0.5) & np.isfinite(t_c)
    # the occluder distance's mean over the shadowed pixels, and the shadowed share of
    # the valid ones: two normalised blurs sharing one (the shadowed pixels' blur)
    ins = inner(sl)
    g_s = gaussian_blur(shadowed.astype(np.float32), search)[ins]
    g_t = gaussian_blur(np.where(shadowed, t_c, 0.0).astype(np.float32), search)[ins]
    g_v = gaussian_blur(ok_c.astype(np.float32), search)[ins]
    ok_s, d_s = _reached(g_s)
    ok_v, d_v = _reached(g_v)
    tb = np.where(ok_s, g_t / d_s, np.where(shadowed[ins], t_c[ins], 0.0))
    has = np.where(ok_v, g_s / d_v, shadowed[ins]) > 1e-3
    # 3. penumbra half-width in pixels
    ok_b = valid[y0:y1, x0:x1]
    r = np.where(has & ok_b, tb * np.maximum(tan_b, 0.0) * focal_px / np.maximum(z[y0:y1, x0:x1], 1e-6), 0.0)
    r = np.clip(np.nan_to_num(r), 0.0, cfg.max_penumbra_px)
    # 4. interpolate between blur levels (linear in log2(1 + r): continuous, monotone)
    # only the levels up to the widest penumbra present, each over the context it reads
    levels_px = cfg.penumbra_levels_px
    n_lv = max(2, int(np.searchsorted(levels_px, r.max())) + 1)
    radii = levels_px[:n_lv]
    lv = np.log2(1.0 + np.asarray(radii))
    pos = np.interp(np.log2(1.0 + r), lv, np.arange(len(lv)))
    i0 = np.clip(np.floor(pos).astype(int), 0, len(lv) - 2)
    f = pos - i0
    # (1 - f) level i0 + f level i0 + 1, each level blurred only over the box of the
    # pixels that take it (the wide levels only near the wide penumbrae), plus the
    # context its kernel reads: the same values as over the whole box
    out = np.zeros(r.shape)
    for k, rad in enumerate(radii):
        lo, hi = i0 == k, (i0 == k - 1) & (f > 0)
        take = lo | hi
        if not take.any():
            continue
        rows, cols = np.flatnonzero(take.any(1)), np.flatnonzero(take.any(0))
        ty0, tx0, ty1, tx1 = y0 + rows[0], x0 + cols[0], y0 + rows[-1] + 1, x0 + cols[-1] + 1
        reach = blur_reach(rad)
        sl = (slice(max(0, ty0 - reach), min(H, ty1 + reach)), slice(max(0, tx0 - reach), min(W, tx1 + reach)))
        L = classwise_blur(vis[sl], classes[sl], valid[sl], rad)[ty0 - sl[0].start:ty1 - sl[0].start,
                                                                   tx0 - sl[1].start:tx1 - sl[1].start]
        tb_ = (slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1))
        o, fb = out[tb_], f[tb_]
        m = lo[tb_]
        o[m] += (1 - fb[m]) * L[m]
        m = hi[tb_]
        o[m] += fb[m] * L[m]
    return np.clip(out, 0.0, 1.0)


__all__ = ["blur_reach", "gaussian_blur", "normalized_blur", "classwise_blur", "penumbra_filter"]
