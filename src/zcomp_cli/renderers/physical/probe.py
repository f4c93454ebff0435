"""An HDR light probe as the renderer's light: its compact bright sources as lights (each
with its measured direction, size and power), the rest as a sky, and a prefiltered copy
for the sky's glossy reflection.

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
from zcomp_cli.renderers.physical import sh
from zcomp_cli.renderers.physical.settings import ProbeConfig

# The constants (the sources taken at most and their least share, the widths the probe
# is read, projected and prefiltered at, the prefilter's roughness levels) are
# ``settings.ProbeConfig``'s, each with its provenance.
DEFAULT = ProbeConfig()


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
    (``sky_radiance_sh`` (9, 3), upper hemisphere, probe units); ``name`` for reports."""

    sources: tuple
    sky_radiance_sh: np.ndarray
    name: str
    gloss: "PrefilteredProbe"


@dataclass(frozen=True)
class PrefilteredProbe:
    """The radiance above the horizon (without the compact sources, which are lights of
    their own) blurred by GGX lobes of several
    roughness levels: ``maps`` (levels, h, w, 4) equirectangular in the probe's
    convention, RGB and the lobe's share above the horizon (below it the support is
    seen: ``lookup``'s ``ground``); ``frame``/``convention``/``rotation_deg`` to look
    them up; ``scale`` multiplies the radiance (the exposure the fit finds)."""

    maps: np.ndarray
    roughness: tuple
    frame: np.ndarray
    convention: str
    rotation_deg: float
    scale: float = 1.0
    name: str = ""

    def __str__(self) -> str:
        return f"prefiltered {self.name} ({self.maps.shape[2]}x{self.maps.shape[1]}, {len(self.roughness)} levels)"

    def scaled(self, k: float) -> "PrefilteredProbe":
        import dataclasses

        return dataclasses.replace(self, scale=float(self.scale * k))

    def lookup(self, directions: np.ndarray, roughness: np.ndarray, ground=None) -> np.ndarray:
        """(N, 3) prefiltered radiance toward unit ``directions`` (N, 3) for perceptual
        ``roughness`` (N,) in [0, 1] (bilinear in direction, linear between levels);
        ``ground`` (3,): the support's radiance, for the lobe's share below the horizon."""
        d = np.asarray(directions, np.float64).reshape(-1, 3)
        _, h, w, _ = self.maps.shape
        u, v = equirect.direction_to_uv(d, self.frame, self.convention, self.rotation_deg)
        x = u * w - 0.5
        y = np.clip(v * h - 0.5, 0, h - 1)
        x0 = np.floor(x).astype(int)
        y0 = np.floor(y).astype(int)
        fx, fy = (x - x0)[:, None], (y - y0)[:, None]
        y1 = np.minimum(y0 + 1, h - 1)
        x0w, x1w = x0 % w, (x0 + 1) % w
        r = np.clip(np.asarray(roughness, np.float64).reshape(-1), self.roughness[0], self.roughness[-1])
        lv = np.interp(r, self.roughness, np.arange(len(self.roughness)))
        l0 = np.clip(np.floor(lv).astype(int), 0, len(self.roughness) - 2)
        fl = (lv - l0)[:, None]

        def at(level):
            m = self.maps
            return ((1 - fy) * ((1 - fx) * m[level, y0, x0w] + fx * m[level, y0, x1w])
                    + fy * ((1 - fx) * m[level, y1, x0w] + fx * m[level, y1, x1w]))

        v = (1 - fl) * at(l0) + fl * at(l0 + 1)
        out = self.scale * v[:, :3]
        if ground is not None:
            out = out + np.clip(1.0 - v[:, 3:4], 0.0, 1.0) * np.asarray(ground, np.float64)[None]
        return out


def read_probe(path, cfg: ProbeConfig = DEFAULT) -> np.ndarray:
    """(H, W, 3) float64 linear radiance of an equirectangular probe file, non-finite
    and negative values set to 0, at most ``cfg.max_width`` wide (area-averaged) and
    2:1 (resampled when the file is not: ``aspect_ok``). Raises
    ``InputError`` naming the file when nothing in it emits light."""
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
        img = _area_resize(img, mw).astype(np.float32)
    if not float(img.max()) > 0:
        raise InputError(f"{path}: the light probe holds no light (every pixel is 0, negative or not finite)")
    return img.astype(np.float64)


def _area_resize(img: np.ndarray, width: int) -> np.ndarray:
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
                rotation_deg: float = 0.0, name: str = "probe", cfg: ProbeConfig = DEFAULT) -> ProbeLights:
    """Split an equirectangular radiance map (H, W, 3) into sources and sky (module
    docstring); ``frame`` is the ground frame (``worldframe.ground_frame``)."""
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
    small = _area_resize(np.where(above[..., None], work, 0.0), cfg.sky_width)
    h, w = small.shape[:2]
    d_s = equirect.pixel_directions(h, w, frame, convention, rotation_deg)
    om_s = equirect.solid_angles(h, w)
    m = (d_s @ up) > 0
    sky_sh = sh.project(d_s[m], small[m], om_s[m])
    # the sky's reflection: the sources are reflected each with its own visibility
    # (``gloss.ggx_direct``), so the prefiltered copy holds the rest
    gloss = prefilter(work, frame, convention=convention, rotation_deg=rotation_deg, name=name, cfg=cfg)
    return ProbeLights(sources=tuple(sources), sky_radiance_sh=sky_sh, name=name, gloss=gloss)


def _ggx_alpha(roughness):
    r = np.asarray(roughness, np.float64)
    return np.maximum(r * r, 1e-4)


def prefilter(img: np.ndarray, frame, *, convention: str = equirect.DEFAULT_CONVENTION,
              rotation_deg: float = 0.0, name: str = "probe", cfg: ProbeConfig = DEFAULT) -> PrefilteredProbe:
    """The probe (H, W, 3) convolved with GGX lobes of ``cfg.gloss_roughness`` around each
    reflection direction (the split-sum approximation of Karis 2013: the lobe with
    n = v = r), on a ``cfg.gloss_width``-wide copy; energy-preserving (each lobe's
    weights sum to 1)."""
    small = _area_resize(np.asarray(img, np.float64), cfg.gloss_width)
    h, w = small.shape[:2]
    frame = np.asarray(frame, np.float64)
    d = equirect.pixel_directions(h, w, frame, convention, rotation_deg).reshape(-1, 3)
    om = equirect.solid_angles(h, w).reshape(-1)
    above = (d @ frame[1] > 0).astype(np.float64)[:, None]
    L = np.concatenate([small.reshape(-1, 3) * above, above], 1)
    cos = np.clip(d @ d.T, -1.0, 1.0)  # (out, in)
    maps = []
    for r in cfg.gloss_roughness:
        a2 = float(_ggx_alpha(r)) ** 2
        # GGX D(h) with h halfway between r and l, weighted by n.l (n = r), as a
        # function of cos(r, l): cos(theta_h) = sqrt((1 + cos) / 2)
        ch2 = np.clip((1.0 + cos) / 2.0, 0.0, 1.0)
        D = a2 / (math.pi * (ch2 * (a2 - 1.0) + 1.0) ** 2)
        wgt = D * np.maximum(cos, 0.0) * om[None]
        wgt /= np.maximum(wgt.sum(1, keepdims=True), 1e-30)
        maps.append((wgt @ L).reshape(h, w, 4))
    return PrefilteredProbe(maps=np.stack(maps), roughness=cfg.gloss_roughness, frame=frame,
                            convention=convention, rotation_deg=float(rotation_deg), name=name)


def load_probe(path, frame, *, convention: str = equirect.DEFAULT_CONVENTION,
               rotation_deg: float = 0.0, cfg: ProbeConfig = DEFAULT) -> ProbeLights:
    """``split_probe`` of the probe file ``path``."""
    return split_probe(read_probe(path, cfg), frame, convention=convention, rotation_deg=rotation_deg,
                       name=Path(path).name, cfg=cfg)


_WARNED: set = set()


def probe_radiance(params, frame, cfg: ProbeConfig = DEFAULT) -> tuple[np.ndarray, str, float]:
    """A given probe's radiance (``lightparams.ProbeParams``): (image (H, W, 3) float64,
    its convention, its rotation). A probe file is read (``read_probe``); a mirror-ball
    photograph is unwrapped in ``frame`` (``chromeball``: zcomp's convention, rotation 0)."""
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


def load_given_probe(params, frame, cfg: ProbeConfig = DEFAULT) -> ProbeLights:
    """``split_probe`` of a given probe (``probe_radiance``)."""
    img, convention, rotation = probe_radiance(params, frame, cfg)
    return split_probe(img, frame, convention=convention, rotation_deg=rotation, name=Path(params.hdr).name,
                       cfg=cfg)


__all__ = ["ProbeSource", "ProbeLights", "PrefilteredProbe", "read_probe", "split_probe", "prefilter",
           "load_probe", "probe_radiance", "load_given_probe"]
