"""An HDR light probe as a scene's light: its compact bright sources as lights (each
with its measured direction, size and power), the rest as a sky (and, for a glossy
reflection, ``residual``: the map without its sources, which the physical renderer
prefilters where an object reads it).

Frames: the probe's up is gravity (``worldframe``), its columns are placed by its
convention and rotation (``equirect``). Only the upper hemisphere lights the scene: below
the horizon the support stands (its bounce is the sky's ``ground``, measured on the
photograph, ``lightmodel.Sky``).

**Light sources.** A source is found at the probe's brightest texel above the horizon.
Its region is the texels connected to it that are brighter than the geometric mean of
the peak and the sky's median (halfway between the two in log luminance: the same split
at any exposure). Its power is its texels' radiance above the sky's median times their
solid angle; its direction the power-weighted mean; its angular radius that of a uniform
disc of the same second moment (``R = sqrt(2) x`` the RMS angle from its direction), at
least half a texel. Sources are taken brightest first while each still brings at least
``ProbeConfig.min_source_share`` of the probe's irradiance on the support (a shadow that
faint is under the contrast the eye sees on a uniform surface, Weber's 2 %), up to
``ProbeConfig.max_sources``. The rest -- the probe with each source's texels set to the sky's median
-- is the sky, in order-2 spherical harmonics (``sh``).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from zcomp_cli import equirect
from zcomp_cli.conventions import REC601
from zcomp_cli.scene import sh
from zcomp_cli.scene.config import ProbeConfig



@dataclass(frozen=True)
class ProbeSource:
    """A compact bright source of a probe: ``direction`` (3,) camera frame, ``radius_deg``,
    ``power`` (3,) RGB irradiance it brings to a surface facing it (probe units)."""

    direction: np.ndarray
    radius_deg: float
    power: np.ndarray


@dataclass(frozen=True)
class ProbeLights:
    """A probe split into its ``sources`` (ProbeSource, brightest first) and its sky
    (``sky_radiance_sh`` (9, 3), upper hemisphere, probe units); ``name`` for reports;
    ``residual`` (H, W, 3) the map with each source's texels set to the sky's level,
    placed by ``frame``, ``convention`` and ``rotation_deg`` (what a glossy reflection
    looks up: the sources are reflected each as a light); ``sky_map`` (h, w, 3) the sky
    (the residual above the horizon, 0 below) at ``ProbeConfig.sky_width``, what the SH
    is projected from and what ``sky_radiance_at`` reads."""

    sources: tuple
    sky_radiance_sh: np.ndarray
    name: str
    residual: np.ndarray
    frame: np.ndarray
    convention: str
    rotation_deg: float
    sky_map: np.ndarray

    def sky_radiance_at(self, directions: np.ndarray) -> np.ndarray:
        """(..., 3) the sky's radiance (probe units) toward camera-frame unit
        ``directions`` (..., 3): ``sky_map`` bilinear (``equirect.bilinear_taps``), 0
        below the horizon. What weighs the sky's directions where its visibility is
        measured (``skyvis.weighted_visibility``): a sky brightest low behind a wall is
        hidden by it as much as it is bright there, which an order-2 SH, spread over the
        hemisphere, does not tell."""
        d = np.asarray(directions, np.float64)
        m = self.sky_map
        u, v = equirect.direction_to_uv(d.reshape(-1, 3), self.frame, self.convention, self.rotation_deg)
        y0, y1, x0, x1, fx, fy = equirect.bilinear_taps(u, v, *m.shape[:2])
        out = (1 - fy) * ((1 - fx) * m[y0, x0] + fx * m[y0, x1]) + fy * ((1 - fx) * m[y1, x0] + fx * m[y1, x1])
        return out.reshape(d.shape[:-1] + (3,))


def read_probe(path, cfg: ProbeConfig | None = None) -> np.ndarray:
    """(H, W, 3) float64 linear radiance of an equirectangular probe file, non-finite
    and negative values set to 0, at most ``cfg.max_width`` wide (area-averaged) and
    2:1 (resampled when the file is not: ``aspect_ok``). Raises
    ``InputError`` naming the file when nothing in it emits light."""
    cfg = ProbeConfig() if cfg is None else cfg
    from zcomp_cli.errors import InputError
    from zcomp_cli.imageio import read_image

    img = np.asarray(read_image(path), np.float32)
    if img.ndim == 2:
        img = img[..., None]
    img = img[..., :3] if img.shape[-1] >= 3 else np.repeat(img[..., :1], 3, -1)
    img = np.maximum(np.nan_to_num(img, nan=0.0, posinf=0.0, neginf=0.0), 0.0)
    h, w = img.shape[:2]
    mw = cfg.max_width
    if w > mw or not equirect.aspect_ok(w, h):
        # at most max_width wide and 2:1 (the manifest refuses another aspect; a map
        # handed over otherwise is resampled, so every step is bounded by max_width)
        img = area_resize(img, mw).astype(np.float32)
    if not float(img.max()) > 0:
        raise InputError(f"{path}: the light probe holds no light (every pixel is 0, negative or not finite)")
    return img.astype(np.float64)


def area_resize(img: np.ndarray, width: int) -> np.ndarray:
    """The map at most ``width`` wide and exactly twice as wide as high (area-averaged
    down, bilinear up): every later step's size is bounded by ``width``, whatever shape
    came in (a 10 x 2000 map made the prefilter's dense matrix 20 000 x 20 000)."""
    import cv2

    h, w = img.shape[:2]
    if w <= width and w == 2 * h:
        return img
    W = max(2, min(int(width), w) // 2 * 2)
    H = W // 2
    interp = cv2.INTER_AREA if (W <= w and H <= h) else cv2.INTER_LINEAR
    return cv2.resize(img.astype(np.float32), (W, H), interpolation=interp).astype(np.float64)


def split_probe(img: np.ndarray, frame, *, convention: str = equirect.DEFAULT_CONVENTION,
                rotation_deg: float = 0.0, name: str = "probe", cfg: ProbeConfig | None = None) -> ProbeLights:
    """Split an equirectangular radiance map (H, W, 3) into sources and sky (module
    docstring); ``frame`` is the ground frame (``worldframe.ground_frame``)."""
    cfg = ProbeConfig() if cfg is None else cfg
    from scipy import ndimage

    img = np.asarray(img, np.float64)
    H, W = img.shape[:2]
    frame = np.asarray(frame, np.float64)
    up = frame[1]
    dirs = equirect.pixel_directions(H, W, frame, convention, rotation_deg)
    omega = equirect.solid_angles(H, W)
    lum = img @ REC601.astype(np.float64)
    above = (dirs @ up) > 0
    if not above.any():
        above = np.ones_like(above)
    sky_level = float(np.median(lum[above]))
    sky_rgb = np.median(img[above], axis=0)
    cos_up = np.maximum(dirs @ up, 0.0)
    floor_total = float((lum * omega * cos_up).sum())
    work = img.copy()
    wl = lum.copy()
    sources = []
    for _ in range(cfg.max_sources):
        cand = np.where(above, wl, -np.inf)
        k = int(np.argmax(cand))
        py, px = divmod(k, W)
        peak = float(wl[py, px])
        if not (peak > sky_level) or not np.isfinite(peak):
            break
        thr = math.sqrt(peak * max(sky_level, peak * 1e-12))
        # roll so the peak sits mid-map: a source across the seam stays one region
        shift = W // 2 - px
        bright = np.roll(wl >= thr, shift, axis=1) & np.roll(above, shift, axis=1)
        lab, _ = ndimage.label(bright)
        region = np.roll(lab == lab[py, W // 2], -shift, axis=1)
        excess = np.maximum(work[region] - sky_rgb[None], 0.0)
        p_rgb = (excess * omega[region][:, None]).sum(0)
        p_lum = float(p_rgb @ REC601)
        if not p_lum > 0:
            break
        wts = excess @ REC601 * omega[region]
        dvec = (dirs[region] * wts[:, None]).sum(0)
        dvec /= max(float(np.linalg.norm(dvec)), 1e-12)
        ang = np.arccos(np.clip(dirs[region] @ dvec, -1.0, 1.0))
        rms = math.sqrt(float((wts * ang ** 2).sum() / max(wts.sum(), 1e-12)))
        half_texel = 0.5 * math.pi / H
        radius = math.degrees(max(math.sqrt(2.0) * rms, half_texel))
        share = p_lum * max(float(dvec @ up), 0.0) / max(floor_total, 1e-12)
        if share < cfg.min_source_share:
            break
        sources.append(ProbeSource(direction=dvec, radius_deg=radius, power=p_rgb))
        work[region] = np.minimum(work[region], sky_rgb[None])
        wl[region] = work[region] @ REC601
    # the sky: the rest, above the horizon, in SH (from a smaller copy: smooth anyway)
    small = area_resize(np.where(above[..., None], work, 0.0), cfg.sky_width)
    h, w = small.shape[:2]
    d_s = equirect.pixel_directions(h, w, frame, convention, rotation_deg)
    om_s = equirect.solid_angles(h, w)
    m = (d_s @ up) > 0
    sky_sh = sh.project(d_s[m], small[m], om_s[m])
    work.setflags(write=False)
    small = np.where(m[..., None], small, 0.0)
    small.setflags(write=False)
    return ProbeLights(sources=tuple(sources), sky_radiance_sh=sky_sh, name=name, residual=work, frame=frame,
                       convention=convention, rotation_deg=float(rotation_deg), sky_map=small)


def load_probe(path, frame, *, convention: str = equirect.DEFAULT_CONVENTION,
               rotation_deg: float = 0.0, cfg: ProbeConfig | None = None) -> ProbeLights:
    """``split_probe`` of the probe file ``path``."""
    cfg = ProbeConfig() if cfg is None else cfg
    return split_probe(read_probe(path, cfg), frame, convention=convention, rotation_deg=rotation_deg,
                       name=Path(path).name, cfg=cfg)


_WARNED: set = set()


def probe_radiance(params, frame, cfg: ProbeConfig | None = None) -> tuple[np.ndarray, str, float]:
    """A given probe's radiance (``lightparams.ProbeParams``): (image (H, W, 3) float64,
    its convention, its rotation). A probe file is read (``read_probe``); a mirror-ball
    photograph is unwrapped in ``frame`` (``chromeball``: zcomp's convention, rotation 0)."""
    cfg = ProbeConfig() if cfg is None else cfg
    if not params.is_ball:
        return read_probe(params.hdr, cfg), params.convention, float(params.rotation_deg)
    from zcomp_cli import chromeball
    from zcomp_cli.errors import InputError

    img, info = chromeball.ball_probe(params.hdr, params.ball_center, params.ball_radius, frame,
                                      reflectance=float(params.reflectance or chromeball.CHROME_REFLECTANCE),
                                      max_width=cfg.max_width)
    if params.hdr not in _WARNED:  # once per ball photograph and process, not per job
        _WARNED.add(params.hdr)
        for w in info.warnings():
            logging.getLogger(__name__).warning("%s: %s", Path(params.hdr).name, w)
    if not float(img.max()) > 0:
        raise InputError(f"{params.hdr}: the chrome ball holds no light (every pixel is 0, negative or not finite)")
    return img, equirect.DEFAULT_CONVENTION, 0.0


# split probes kept in this process (the light stage splits a scene's probe once; the
# glossy prefilter and a path tracer's world read it again): a few scenes' worth
_SPLIT: dict = {}
KEEP_SPLIT = 2


def load_given_probe(params, frame, cfg: ProbeConfig | None = None) -> ProbeLights:
    """``split_probe`` of a given probe (``probe_radiance``), kept per file content,
    parameters, frame and config for the process's next asks."""
    cfg = ProbeConfig() if cfg is None else cfg
    import os

    f = np.asarray(frame, np.float64)
    try:
        st = os.stat(params.hdr)
        stamp = (st.st_size, st.st_mtime_ns)
    except OSError:
        stamp = None
    key = (repr(params.to_dict()), f.tobytes(), cfg, stamp)
    hit = _SPLIT.get(key)
    if hit is not None:
        return hit
    img, convention, rotation = probe_radiance(params, f, cfg)
    out = split_probe(img, f, convention=convention, rotation_deg=rotation, name=Path(params.hdr).name, cfg=cfg)
    while len(_SPLIT) >= KEEP_SPLIT:
        _SPLIT.pop(next(iter(_SPLIT)))
    _SPLIT[key] = out
    return out


__all__ = ["ProbeSource", "ProbeLights", "read_probe", "split_probe", "load_probe", "probe_radiance", "area_resize",
           "load_given_probe"]
