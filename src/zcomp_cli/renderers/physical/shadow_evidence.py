"""Cast shadows the photograph shows on its support, tied to what casts them (DESIGN.md
section 8, "The light from the shadows").

On the support (``depthmesh``: the plane the scene stands on), the known shading is the
light that reaches each point: a cast shadow is a region darker than its lit
surroundings on the same surface. Dividing the shading by the **lit level** -- a smooth
upper envelope of the support's shading, fitted on the pixels not yet called dark and
refitted (``LIT_ITERS``) -- leaves the **ratio** ``r = shading / lit level``: about 1
where the light reaches, the shadowed/lit ratio in an umbra (the sky's share of the
light there, Madsen and Nielsen's measurement), in between across a penumbra. Dividing by
the albedo (the caller's shading) keeps texture out of it.

A dark region counts as a cast shadow only where it can be tied to a caster: its pixels
next to (within ``ATTACH_REL`` of the frame) an occluder of the depth mesh that stands on
the support (has a base). Dark regions tied to nothing (the shadow of something outside
the frame, an albedo error) are left out of the evidence: ``weight`` is 0 there, 1 on
the lit support and on tied dark regions.

``ShadowEvidence`` is a soft mask with a confidence, on the working copy's pixel grid
(the debug outputs show it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# Iterations of the lit level (fit, call the pixels below it dark, refit without them).
LIT_ITERS = 4
# Darker than the lit level by this many noise scales (and at least by Weber's 2 %
# contrast, the least a viewer sees): a dark pixel.
DARK_SIGMAS = 3.0
WEBER = 0.02
# A dark region is tied to a caster within this share of the frame's long side of it.
ATTACH_REL = 1.0 / 60.0
# The band of pixels along the support's outline and the albedo's edges whose ratio is
# not read (the erosion and the edge's dilation, a pixel each).
UNREAD_PX = 2
# A tied shadow lies within this many times its caster's height of it (along the
# ground): the shadow of a light at least atan(1/4) = 14 deg above the horizon.
REACH_HEIGHTS = 4.0
# Points of a caster its ground distance is measured to (a stride of them).
MAX_REACH_POINTS = 2000
# An albedo whose log spreads less than this over the support is one albedo.
ALBEDO_SPREAD = 0.02
# A change of the albedo's log this large between neighbours (per pixel) is an edge.
ALBEDO_EDGE = 0.05
# Pixels of a dark region fewer than this share of the support are noise.
MIN_REGION_REL = 1e-3


@dataclass(frozen=True)
class ShadowEvidence:
    """On the (h, w) working grid: ``ratio`` shading over the lit level (1 where lit;
    nan off the support), ``dark`` the pixels called dark, ``tied`` the dark pixels of
    regions tied to a caster, ``weight`` the confidence each pixel counts with (0 on
    untied dark regions and off the support), ``sigma`` the ratio's noise scale on the
    lit support, ``lit_level`` (h, w), ``reach`` the support's pixels within reach of a
    caster's shadow (``within_reach``), ``shading`` (h, w) the luminance read, ``basis``
    (h, w, P) the lit level's (``lit_basis``)."""

    ratio: np.ndarray
    dark: np.ndarray
    tied: np.ndarray
    weight: np.ndarray
    sigma: float
    lit_level: np.ndarray
    reach: np.ndarray
    shading: np.ndarray
    basis: np.ndarray

    @property
    def shown(self) -> bool:
        """Whether any tied cast shadow is seen."""
        return bool(self.tied.any())

    @property
    def soft_mask(self) -> np.ndarray:
        """(h, w) in [0, 1]: how much of the light each tied dark pixel misses, relative
        to the typical umbra (the debug map)."""
        out = np.zeros(self.ratio.shape)
        if not self.tied.any():
            return out
        umbra = float(np.nanpercentile(self.ratio[self.tied], 10))
        depth = max(1.0 - umbra, 1e-6)
        out[self.tied] = np.clip((1.0 - self.ratio[self.tied]) / depth, 0.0, 1.0)
        return out


def lit_basis(points, up, ok, albedo=None) -> np.ndarray:
    """(h, w, P) the lit level's basis: the quadratic monomials of the pixels' ground
    coordinates (along the ground's right and forward axes, centred and scaled by their
    spread on ``ok``), and, with ``albedo`` (h, w), its log and the log's square (a
    surface's apparent shading depends on its albedo: its specular layer adds a share
    that does not scale with it, more at grazing angles), where it varies."""
    from zcomp_cli.worldframe import ground_frame

    right, _, fwd = ground_frame(np.asarray(up, np.float64))
    u, v = points @ right, points @ fwd
    su, sv = u[ok], v[ok]
    u = (u - su.mean()) / max(float(su.std()), 1e-9)
    v = (v - sv.mean()) / max(float(sv.std()), 1e-9)
    cols = [np.ones_like(u), u, v, u * u, u * v, v * v]
    if albedo is not None:
        la = np.log(np.maximum(np.nan_to_num(np.asarray(albedo, np.float64)), 1e-4))
        sa = la[ok]
        if len(sa) and float(sa.std()) > ALBEDO_SPREAD:
            la = (la - sa.mean()) / float(sa.std())
            cols += [la, la * la]
    return np.stack(cols, -1)


def _normalized_blur(values, weight, radius):
    import cv2

    k = 2 * int(math.ceil(1.5 * radius)) + 1
    num = cv2.GaussianBlur((values * weight).astype(np.float32), (k, k), radius / 2.0, borderType=cv2.BORDER_REPLICATE)
    den = cv2.GaussianBlur(weight.astype(np.float32), (k, k), radius / 2.0, borderType=cv2.BORDER_REPLICATE)
    return np.where(den > 1e-3, num / np.maximum(den, 1e-6), np.nan)


def within_reach(points: np.ndarray, casters: np.ndarray, up, support: np.ndarray,
                 labels: np.ndarray | None = None) -> np.ndarray:
    """(h, w) bool: the support's pixels whose distance along the ground from a caster is
    at most REACH_HEIGHTS times that caster's height above the support: where its shadow
    can fall under a light at least ``atan(1 / REACH_HEIGHTS)`` above the horizon.
    ``labels``: the casters' components (each with its own height; None: one)."""
    from scipy.spatial import cKDTree

    from zcomp_cli.worldframe import ground_frame

    out = np.zeros(support.shape, bool)
    if not casters.any() or not support.any():
        return out
    up = np.asarray(up, np.float64)
    right, _, fwd = ground_frame(up)
    h0 = float(np.median(points[support] @ up))
    S = points[support]
    Sg = np.stack([S @ right, S @ fwd], 1)
    lab = np.where(casters, 1, 0) if labels is None else np.where(casters, labels, 0)
    hit = np.zeros(len(S), bool)
    for k in np.unique(lab[lab > 0]):
        C = points[lab == k]
        if len(C) > MAX_REACH_POINTS:  # a stride of its points: the ground distance to within a pixel or two
            C = C[np.linspace(0, len(C) - 1, MAX_REACH_POINTS).astype(np.int64)]
        height = float(np.max(C @ up) - h0)
        if height <= 0:
            continue
        tree = cKDTree(np.stack([C @ right, C @ fwd], 1))
        dist, _ = tree.query(Sg, k=1, distance_upper_bound=REACH_HEIGHTS * height)
        hit |= np.isfinite(dist)
    out[support] = hit
    return out


def shadow_evidence(shading: np.ndarray, support: np.ndarray, casters: np.ndarray, points: np.ndarray, up,
                    known: np.ndarray | None = None, albedo: np.ndarray | None = None,
                    labels: np.ndarray | None = None) -> ShadowEvidence:
    """The support's cast-shadow evidence (module docstring).

    Args:
        shading: (h, w) luminance of image / albedo (linear, any exposure).
        support: (h, w) bool, the support's pixels; casters: (h, w) bool, the pixels of
            the objects standing on it (``depthmesh.DepthMesh.casters``).
        known: (h, w) bool, the pixels whose shading is known (default: finite > 0).
        points: (h, w, 3) the pixels' camera-frame points; up: (3,) world up.
        labels: (h, w) int, the occluders' components (each caster's reach its own).
        albedo: (h, w) luminance of the albedo: where it changes from pixel to pixel the
            image and the albedo map rarely line up (an anti-aliased edge over a sampled
            one), and the ratio there tells nothing (weight 0).
    """
    import cv2

    s = np.asarray(shading, np.float64)
    ok = np.asarray(support, bool) & np.isfinite(s) & (s > 0)
    if known is not None:
        ok &= np.asarray(known, bool)
    # the support's outline: a working pixel there averages the support with what
    # borders it (a wall's darker corner, a box's side), which is no shadow
    ok &= cv2.erode(np.asarray(support, np.uint8), np.ones((3, 3), np.uint8), borderType=cv2.BORDER_REPLICATE) > 0
    if albedo is not None:
        la = np.log(np.maximum(np.nan_to_num(np.asarray(albedo, np.float64)), 1e-4))
        grad = np.maximum(np.abs(cv2.Sobel(la, cv2.CV_64F, 1, 0, ksize=3)), np.abs(cv2.Sobel(la, cv2.CV_64F, 0, 1, ksize=3))) / 4
        ok &= cv2.dilate((grad > ALBEDO_EDGE).astype(np.uint8), np.ones((3, 3), np.uint8)) == 0
    h, w = s.shape
    nan = np.full((h, w), np.nan)
    empty = np.zeros((h, w), bool)
    if ok.sum() < 10:
        return ShadowEvidence(ratio=nan, dark=empty, tied=empty, weight=np.zeros((h, w)), sigma=float("nan"),
                              lit_level=nan, reach=empty, shading=np.asarray(shading, np.float64),
                              basis=np.ones((h, w, 1)))
    logs = np.where(ok, np.log(np.where(ok, s, 1.0)), 0.0)
    X = lit_basis(points, up, ok, albedo)
    lit = ok.copy()
    sigma = WEBER
    level = nan
    for _ in range(LIT_ITERS):
        # the lit level in log space (exposure and albedo scale out), from lit pixels only
        beta = np.linalg.lstsq(X[lit], logs[lit], rcond=None)[0]
        lv = np.full((h, w), np.nan)
        lv[ok] = X[ok] @ beta
        res = np.where(ok, logs - np.nan_to_num(lv), np.nan)
        rl = res[lit]
        if len(rl) < 10:
            break
        med = float(np.median(rl))
        sigma = max(1.4826 * float(np.median(np.abs(rl - med))), WEBER / DARK_SIGMAS)
        # the envelope: lit pixels scatter about it, dark ones fall below
        dark = ok & (res < med + math.log(1.0 - max(DARK_SIGMAS * sigma, WEBER)))
        lit = ok & ~dark
        level = np.exp(lv + med)
    ratio = np.where(ok, s / np.where(np.isfinite(level) & (level > 0), level, np.nan), np.nan)
    dark = ok & np.isfinite(ratio) & (ratio < 1.0 - max(DARK_SIGMAS * sigma, WEBER))
    # regions, and which of them touch a caster that stands on the support
    n_lab, lab = cv2.connectedComponents(dark.astype(np.uint8), connectivity=8)
    casters = np.asarray(casters, bool)
    reach_m = within_reach(points, casters, up, np.asarray(support, bool), labels)
    # (beyond the band the support's outline and the albedo's edges leave unread: a
    # pixel each)
    reach = max(1, int(round(ATTACH_REL * max(h, w)))) + UNREAD_PX
    kern = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * reach + 1, 2 * reach + 1))
    near_caster = cv2.dilate(casters.astype(np.uint8), kern) > 0
    tied = np.zeros((h, w), bool)
    min_px = max(3, int(MIN_REGION_REL * ok.sum()))
    if n_lab > 1:
        sizes = np.bincount(lab.ravel(), minlength=n_lab)
        touch = np.bincount(lab[near_caster & dark], minlength=n_lab) > 0
        keep = touch & (sizes >= min_px)
        keep[0] = False
        tied = keep[lab] & dark & reach_m
    weight = np.where(ok & ~(dark & ~tied), 1.0, 0.0)
    return ShadowEvidence(ratio=ratio, dark=dark, tied=tied, weight=weight, sigma=float(sigma),
                          lit_level=np.where(ok, level, np.nan), reach=reach_m, shading=s, basis=X)


__all__ = ["ShadowEvidence", "shadow_evidence"]
