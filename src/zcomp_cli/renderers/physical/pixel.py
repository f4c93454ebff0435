"""The pixel as the path tracer films it: its reconstruction filter, and the object's
anti-aliased edge.

The synthesis shades one point per pixel (the intrinsic passes hold the depth and normal
seen through each pixel's centre); the ground truth (Cycles) averages every pixel over
its filter, a Blackman-Harris window of width 1.5 pixels (support +-1.5 px, sigma
0.416 px: ``TransportConfig.film_sigma_px``). A faceted mesh's flat faces, two pixels wide, came
out as vertical bands, and a thin shadow as single dark pixels.

* ``film_filter``: the shading filtered over the pixel's window as the film does, within
  each depth class (an object's shading never blurs into the floor behind it).
* ``unmix``: a pixel the object covers in part (coverage ``m``) holds the coverage-blended
  albedo (DESIGN.md section 2, equation 1) and one surface's geometry (the object's where
  ``m > 0.5``). A path tracer's pixel is ``m`` of the object's radiance plus ``1 - m`` of
  the surface behind it; shading the blended albedo with the object's light drew the
  floor's albedo lit as the object (a light fringe on a dark object), and the pixels
  under ``m = 0.5`` were the floor lit as the floor (the silhouette a staircase at that
  threshold). The albedo is split into the object's and the surface's from the pixels
  each covers wholly nearby, and each layer's shading is carried one pixel past where it
  was shaded (``extend``).
"""

from __future__ import annotations

import numpy as np

from zcomp_cli.renderers.physical.settings import TransportConfig
from zcomp_cli.renderers.physical.softshadow import classwise_blur, gaussian_blur


def film_filter(values: np.ndarray, classes: np.ndarray, valid: np.ndarray, cfg: TransportConfig) -> np.ndarray:
    """``values`` (h, w, C) filtered over the film's pixel window
    (``cfg.film_sigma_px``), within each class of ``classes`` (h, w), weighted by the
    ``valid`` pixels (written there only)."""
    return classwise_blur(values, classes, valid, 2.0 * cfg.film_sigma_px)


def _spread(values, source, radius):
    """(a normalised blur of ``values`` (h, w, C) over the ``source`` pixels alone, where
    some source pixel reaches (h, w))."""
    w = source.astype(np.float32)
    num = gaussian_blur((values * w[..., None]).astype(np.float32), radius).reshape(values.shape)
    den = gaussian_blur(w, radius)
    ok = den > 1e-4
    return num / np.maximum(den, 1e-4)[..., None], ok


def extend(values: np.ndarray, source: np.ndarray, dest: np.ndarray, cfg: TransportConfig) -> np.ndarray:
    """``values`` (h, w, C) at the ``source`` pixels, carried to the ``dest`` pixels from
    the source pixels within ``cfg.edge_reach_px``; where none reaches, the value stays."""
    filled, ok = _spread(values, source, cfg.edge_reach_px)
    out = np.array(values, np.float64)
    put = dest & ok
    out[put] = filled[put]
    return out


def split(mixed: np.ndarray, own: np.ndarray | None, m: np.ndarray, valid: np.ndarray, cfg: TransportConfig):
    """(the object's, the surface's) of a coverage-blended map ``mixed`` (h, w, C): with
    the object's ``own`` map (h, w, C; unblended, the request's ``object_maps``), the
    object's is its own where it covers the pixel and the surface's is what the blend
    leaves (``(mixed - m own) / (1 - m)``), from the pixels the object does not cover
    wholly enough to leave it measurable (``m < cfg.whole_coverage``) and else from the
    nearby pixels it covers not at all; without it, ``unmix``."""
    if own is None:
        return unmix(mixed, m, valid, cfg)
    mixed = np.asarray(mixed, np.float64)
    own = np.asarray(own, np.float64).reshape(mixed.shape)
    mm = m[..., None]
    covered = (valid & (m > 0))[..., None]
    a_o = np.where(covered, own, mixed)
    srf = valid & (m <= 0.0)
    near, ok = _spread(mixed, srf, cfg.edge_reach_px)
    rest = (mixed - mm * own) / np.maximum(1.0 - mm, 1e-6)
    a_s = np.where((m < cfg.whole_coverage)[..., None], rest, np.where(ok[..., None], near, mixed))
    lo = 0.0
    hi = max(1.0, float(mixed.max()) if mixed.size else 1.0)
    return a_o, np.where(covered, np.clip(a_s, lo, hi), mixed)


def unmix(mixed: np.ndarray, m: np.ndarray, valid: np.ndarray, cfg: TransportConfig):
    """(the object's, the surface's) of a coverage-blended map ``mixed`` (h, w, C), ``m``
    (h, w) the coverage, over the ``valid`` pixels: each layer estimated from the nearby
    pixels it covers wholly (``m >= cfg.whole_coverage``, ``m == 0``; within
    ``cfg.edge_reach_px``), the residual of the pixel's own blend shared by both, so that
    ``m a_o + (1 - m) a_s`` is the pixel's value again. Where no whole pixel of a layer
    reaches, that layer is the pixel's own value."""
    mixed = np.asarray(mixed, np.float64)
    obj = valid & (m >= cfg.whole_coverage)
    srf = valid & (m <= 0.0)
    a_o, ok_o = _spread(mixed, obj, cfg.edge_reach_px)
    a_s, ok_s = _spread(mixed, srf, cfg.edge_reach_px)
    a_o = np.where(ok_o[..., None], a_o, mixed)
    a_s = np.where(ok_s[..., None], a_s, mixed)
    edge = (valid & (m > 0.0) & (m < cfg.whole_coverage))[..., None]
    mm = m[..., None]
    delta = mixed - (mm * a_o + (1.0 - mm) * a_s)
    return (np.where(edge, np.clip(a_o + delta, 0.0, 1.0), mixed),
            np.where(edge, np.clip(a_s + delta, 0.0, 1.0), mixed))


__all__ = ["film_filter", "extend", "split", "unmix"]
