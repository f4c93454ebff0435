"""A mirror-ball photograph as a light probe (issue 38): ``light: {type: chrome_ball}``.

The ball is photographed from the camera's position, with the scene camera's
orientation, and seen small enough to be read orthographically (a long lens, or a ball
far from the camera compared with its radius: the view ray is the camera's forward
direction ``i = (0, 0, -1)`` over the whole ball). A ball pixel at ``(x, y)`` with
``r`` pixels of radius sees the mirror normal ``n = ((x - cx) / r, -(y - cy) / r,
sqrt(1 - ...))`` (camera frame: x right, y up, z toward the viewer) and reflects the
direction ``d = i - 2 (i . n) n``. Inverting it, the direction ``d`` is seen where
``n = (d - i) / |d - i|``; every direction but ``i`` itself has one such point.

What the ball cannot tell, stated in ``BallInfo``:

* **its reflectance**: a mirror ball reflects a share of the light (polished chromium
  about 0.6 at normal incidence; it grows toward grazing, by Fresnel, which is not
  undone); the radiance read is divided by ``reflectance``;
* **the blind spot behind the ball**: the directions within ``blind_deg`` of the
  camera's forward direction are all seen in the ball's outermost ring of pixels, less
  than one pixel wide: nothing there can be read. ``blind_deg = 180 - 2 asin(1 - 1/r)``
  (the direction seen one pixel inside the rim). They are filled with the mean of the
  ring around the spot, the same in every direction;
* **the camera and the photographer**, seen at the ball's centre (directions toward
  the camera), are left as they are;
* **a clipped sun**: an 8- or 16-bit photograph clips the sun's disc; its radiance,
  hence the shadow's strength, is too low (``clipped`` is the share of the ball's pixels
  at the format's maximum).

Pure functions on arrays; reading the file is ``read_ball``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from zcomp_cli import equirect

# Polished chromium's specular reflectance at normal incidence across the visible
# (physical: handbook values 0.55-0.65 from 400 to 700 nm); a steel ball is about the
# same. Given as ``reflectance`` when the ball's is known.
CHROME_REFLECTANCE = 0.6
# An 8/16-bit value this close to the format's maximum is taken as clipped (physical:
# one code value of an 8-bit file is 1/255 = 0.004).
CLIP_LEVEL = 1.0 - 1.0 / 255.0
# Probe width per ball pixel of radius: the ball's equator ring of 2 pi r pixels covers
# 360 deg twice over the front and back halves' longitudes (sampling: a probe wider than
# about 4 r texels reads the same pixel in neighbouring texels).
WIDTH_PER_RADIUS = 4
MIN_WIDTH = 64


@dataclass(frozen=True)
class BallInfo:
    """What the unwrap could and could not read: the ball's radius in pixels, its
    ``reflectance``, the blind spot's half-angle (degrees, about the camera's forward
    direction), the share of clipped ball pixels, whether the photograph is HDR."""

    radius_px: float
    reflectance: float
    blind_deg: float
    clipped: float
    hdr: bool

    def warnings(self) -> list[str]:
        out = []
        if not self.hdr:
            out.append("the chrome ball photograph is 8/16-bit (LDR): the sun and bright lamps are clipped, so "
                       "their shadows come out too faint; shoot an HDR bracket (EXR/HDR) for the light's strength")
        elif self.clipped > 0:
            out.append(f"{100 * self.clipped:.1f}% of the ball's pixels are at the file's maximum: clipped")
        out.append(f"the {self.blind_deg:.0f} deg behind the ball (around the camera's forward direction) are "
                   "not seen in a mirror ball: filled with the light around them")
        return out

    def to_dict(self) -> dict:
        return {"radius_px": self.radius_px, "reflectance": self.reflectance, "blind_deg": self.blind_deg,
                "clipped": self.clipped, "hdr": self.hdr}


def blind_degrees(radius_px: float) -> float:
    """Half-angle (degrees) about the camera's forward direction that a ball of
    ``radius_px`` pixels cannot show: the directions reflected in its last pixel ring
    (module docstring). 180 for a ball under one pixel."""
    r = float(radius_px)
    if not r > 1.0:
        return 180.0
    return 180.0 - 2.0 * math.degrees(math.asin(1.0 - 1.0 / r))


def check_ball(width: int, height: int, center, radius) -> str | None:
    """Why a ball of ``center`` (x, y) and ``radius`` (pixels) cannot be read from a
    ``width`` x ``height`` photograph, else None."""
    cx, cy = (float(v) for v in center)
    r = float(radius)
    if not (math.isfinite(cx) and math.isfinite(cy) and math.isfinite(r)):
        return f"centre {center!r} and radius {radius!r} must be finite"
    if r < 2.0:
        return f"radius {r:g} px is under 2 pixels: nothing can be read from the ball"
    if cx - r < -0.5 or cy - r < -0.5 or cx + r > width + 0.5 or cy + r > height + 0.5:
        return (f"the ball (centre [{cx:g}, {cy:g}], radius {r:g} px) reaches outside the {width}x{height} "
                "photograph")
    return None


def unwrap(image: np.ndarray, center, radius: float, frame, *, width: int | None = None,
           reflectance: float = CHROME_REFLECTANCE, hdr: bool = True,
           max_width: int = 2048) -> tuple[np.ndarray, BallInfo]:
    """An equirectangular probe of a mirror-ball photograph.

    Args:
        image: (H, W, 3) linear RGB of the photograph (rows from the top).
        center: (x, y) of the ball's centre, pixels (x right, y down; pixel centres at
            ``+0.5``, as zcomp's placements).
        radius: the ball's radius, pixels.
        frame: (3, 3) ground frame rows ``right, up, forward`` in the camera frame
            (``worldframe.ground_frame``).
        width: the probe's width (height half); default ``WIDTH_PER_RADIUS x radius``
            within [``MIN_WIDTH``, ``max_width``].
        reflectance: the ball's, in (0, 1]; the radiance read is divided by it.
        hdr: whether ``image`` is HDR (float); an LDR one has its clipped pixels counted.
    Returns:
        ((width/2, width, 3) float64 radiance in zcomp's convention at rotation 0 in
        ``frame``, ``BallInfo``).
    """
    import cv2

    img = np.asarray(image, np.float32)
    if img.ndim != 3 or img.shape[-1] < 3:
        raise ValueError(f"expected an (H, W, 3) image, got shape {img.shape}")
    img = np.ascontiguousarray(np.maximum(np.nan_to_num(img[..., :3], nan=0.0, posinf=0.0, neginf=0.0), 0.0))
    H, W = img.shape[:2]
    why = check_ball(W, H, center, radius)
    if why:
        raise ValueError(why)
    if not 0.0 < float(reflectance) <= 1.0:
        raise ValueError(f"reflectance must be in (0, 1], got {reflectance!r}")
    cx, cy, r = float(center[0]), float(center[1]), float(radius)
    if width is None:
        width = int(np.clip(WIDTH_PER_RADIUS * r, MIN_WIDTH, max_width))
    width = max(2, int(width) // 2 * 2)
    h = width // 2
    d = equirect.pixel_directions(h, width, frame).reshape(-1, 3)
    i = np.array([0.0, 0.0, -1.0])
    n = d - i
    norm = np.linalg.norm(n, axis=-1, keepdims=True)
    n = n / np.maximum(norm, 1e-12)
    # pixel coordinates (cv2.remap samples at integer pixel centres: subtract 0.5)
    mx = (cx + r * n[:, 0] - 0.5).astype(np.float32)
    my = (cy - r * n[:, 1] - 0.5).astype(np.float32)
    out = cv2.remap(img, mx.reshape(h, width), my.reshape(h, width), cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_REPLICATE).reshape(-1, 3).astype(np.float64)
    blind = blind_degrees(r)
    behind = d @ i
    cos_blind = math.cos(math.radians(blind))
    spot = behind > cos_blind
    if spot.any() and (~spot).any():
        # the ring just outside the spot, one blind-spot width wide at most
        ring = ~spot & (behind > math.cos(math.radians(min(180.0, 2.0 * blind))))
        fill = out[ring].mean(0) if ring.any() else out[~spot].mean(0)
        out[spot] = fill
    clipped = 0.0
    if not hdr:  # the share of the ball's own pixels at the format's maximum
        yy, xx = np.mgrid[0:H, 0:W]
        on_ball = (xx + 0.5 - cx) ** 2 + (yy + 0.5 - cy) ** 2 <= r * r
        if on_ball.any():
            clipped = float((img[on_ball].max(-1) >= _linear(CLIP_LEVEL)).mean())
    info = BallInfo(radius_px=r, reflectance=float(reflectance), blind_deg=float(blind), clipped=clipped,
                    hdr=bool(hdr))
    return (out / float(reflectance)).reshape(h, width, 3), info


def _linear(v: float) -> float:
    """sRGB code value (0-1) -> linear (read_image decodes LDR files this way)."""
    return v / 12.92 if v <= 0.04045 else ((v + 0.055) / 1.055) ** 2.4


def read_ball(path) -> tuple[np.ndarray, bool]:
    """(linear (H, W, 3) float32 image, whether the file is HDR: float pixels, whatever
    its name says -- a 32-bit float TIFF is) of a ball photograph."""
    from zcomp_cli.imageio import read_image_hdr

    return read_image_hdr(path)


def ball_probe(path, center, radius, frame, *, reflectance: float = CHROME_REFLECTANCE,
               max_width: int = 2048) -> tuple[np.ndarray, BallInfo]:
    """``unwrap`` of the ball photograph at ``path``."""
    img, hdr = read_ball(path)
    return unwrap(img, center, radius, frame, reflectance=reflectance, hdr=hdr, max_width=max_width)


__all__ = ["BallInfo", "CHROME_REFLECTANCE", "blind_degrees", "check_ball", "unwrap", "read_ball", "ball_probe"]
