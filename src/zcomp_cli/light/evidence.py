"""Cast shadows the photograph shows on its support, tied to what casts them (DESIGN.md
section 8, "The light from the shadows").

On the support (``depthmesh``: the plane the scene stands on), the known shading is the
light that reaches each point: a cast shadow is a region darker than its lit
surroundings on the same surface. Dividing the shading by the **lit level** -- a smooth
upper envelope of the support's shading, fitted on the pixels not yet called dark and
refitted coarse to fine (``lit_iters``: one degree more at each fit) -- leaves the
**ratio** ``r = shading / lit level``: about 1 where the light reaches, the shadowed/lit
ratio in an umbra (the sky's share of the light there, Madsen and Nielsen's
measurement), in between across a penumbra. Dividing by the albedo (the caller's
shading) keeps texture out of it. Where the caller gives the share of the sky the
scene's geometry leaves each support pixel (``sky_view``: a wall's foot sees half the
sky), the lit level is ``(1 - s) + s V`` of its smooth surface, ``s`` the sky's share of
the open support's light: the sky a wall hides is no cast shadow (off in the light
stage by default: ``EvidenceConfig.sky_view_directions``).

The dark pixels are split into regions, one per basin of the ratio (``shadow_basins``:
two shadows joined through a shallower strip are two). A region counts as a cast shadow
only where it can be tied to a caster: its pixels next to (within ``attach_rel`` of the
frame) an occluder of the depth mesh that stands on the support (has a base), and within
its reach. Dark regions tied to nothing (the shadow of something outside the frame, an
albedo error) are left out of the evidence: ``weight`` is 0 there, 1 on the lit support
and on tied dark regions.

``ShadowEvidence`` is a soft mask with a confidence, on the working copy's pixel grid
(the debug outputs show it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from zcomp_cli.light.config import EvidenceConfig



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


def lit_basis(points, up, ok, albedo=None, *, albedo_spread: float, degree: int) -> np.ndarray:
    """(h, w, P) the lit level's basis: the monomials up to ``degree`` of the pixels'
    ground coordinates (along the ground's right and forward axes, centred and scaled by
    their spread on ``ok``), and, with ``albedo`` (h, w), its log and the log's square (a
    surface's apparent shading depends on its albedo: its specular layer adds a share
    that does not scale with it, more at grazing angles), where it varies."""
    from zcomp_cli.worldframe import ground_frame

    right, _, fwd = ground_frame(np.asarray(up, np.float64))
    u, v = points @ right, points @ fwd
    su, sv = u[ok], v[ok]
    u = (u - su.mean()) / max(float(su.std()), 1e-9)
    v = (v - sv.mean()) / max(float(sv.std()), 1e-9)
    cols = [u ** (k - j) * v ** j for k in range(int(degree) + 1) for j in range(k + 1)]
    if albedo is not None:
        la = np.log(np.maximum(np.nan_to_num(np.asarray(albedo, np.float64)), 1e-4))
        sa = la[ok]
        if len(sa) and float(sa.std()) > albedo_spread:
            la = (la - sa.mean()) / float(sa.std())
            cols += [la, la * la]
    return np.stack(cols, -1)


def within_reach(points: np.ndarray, casters: np.ndarray, up, support: np.ndarray,
                 labels: np.ndarray | None = None, cfg: EvidenceConfig | None = None) -> np.ndarray:
    """(h, w) bool: the support's pixels whose distance along the ground from a caster is
    at most ``cfg.reach_heights`` times that caster's height above the support: where its
    shadow can fall under a light at least ``atan(1 / reach_heights)`` above the horizon.
    ``labels``: the casters' components (each with its own height; None: one)."""
    cfg = EvidenceConfig() if cfg is None else cfg
    from scipy.spatial import cKDTree

    from zcomp_cli.threads import compute_threads
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
        if len(C) > cfg.max_reach_points:  # a stride of its points: the ground distance to within a pixel or two
            C = C[np.linspace(0, len(C) - 1, cfg.max_reach_points).astype(np.int64)]
        height = float(np.max(C @ up) - h0)
        if height <= 0:
            continue
        tree = cKDTree(np.stack([C @ right, C @ fwd], 1))
        dist, _ = tree.query(Sg, k=1, distance_upper_bound=cfg.reach_heights * height, workers=compute_threads())
        hit |= np.isfinite(dist)
    out[support] = hit
    return out


def shadow_basins(ratio: np.ndarray, region: np.ndarray, depth: float, blur_px: float) -> tuple[int, np.ndarray]:
    """The dark ``region`` split into its basins: ``(n, labels)``, labels (h, w) int in
    [0, n) (0 off the region), one per minimum of the ratio at least ``depth`` deeper
    than the lowest pass that joins it to a deeper one (an h-minimum), every pixel of the
    region flooded to one of them (a watershed).

    Two shadows joined only through a shallower strip (an unseen occluder's band and a
    caster's shadow, reached along the floor at a wall's foot, which the wall's
    occlusion of the sky shades a little) are two basins; one shadow over a checker's
    tiles, or across the bands left unread between them, is one (no pass rises between
    its parts). A region's global minimum is always a basin: the outside counts as lit.

    Args:
        ratio: (h, w) shading over the lit level (nan where unread: filled with the
            nearest read pixel's value).
        region: (h, w) bool, the pixels to split.
        depth: the least depth of a basin below its pass (the dark threshold, in ratio).
        blur_px: a Gaussian's sigma over the ratio first (a pixel's noise does not make
            a basin); 0: none.
    """
    from scipy import ndimage as ndi
    from skimage.morphology import local_minima, reconstruction
    from skimage.segmentation import watershed

    region = np.asarray(region, bool)
    r = np.asarray(ratio, np.float64)
    valid = np.isfinite(r)
    if not region.any() or not valid.any():
        return 1, np.zeros(region.shape, np.int32)
    idx = ndi.distance_transform_edt(~valid, return_distances=False, return_indices=True)
    filled = r[tuple(idx)]
    if blur_px > 0:
        import cv2

        filled = cv2.GaussianBlur(filled, (0, 0), float(blur_px))
    # (outside the region the ratio is taken as above any shadow's: 2, the lit floor's 1
    # and more)
    img = np.where(region, filled, 2.0)
    # the h-minima transform: every basin filled up to ``depth`` above its floor, or to
    # its pass where that is lower; its regional minima are the basins deeper than
    # ``depth`` (a plateau where shallower ones joined: one basin, not one per floor)
    filled_up = reconstruction(img + float(depth), img, method="erosion")
    markers, _ = ndi.label(local_minima(filled_up, connectivity=2) & region, structure=np.ones((3, 3)))
    lab = watershed(img, markers, mask=region, connectivity=2)
    return int(lab.max()) + 1, lab.astype(np.int32)


def dark_depth(sigma: float, cfg: EvidenceConfig) -> float:
    """How far below the lit level (in ratio) a pixel is dark, at noise scale ``sigma``:
    ``cfg.dark_sigmas`` of it, at least Weber's contrast, at most ``cfg.darkest``."""
    return min(max(cfg.dark_sigmas * sigma, cfg.weber), cfg.darkest)


def shadow_evidence(shading: np.ndarray, support: np.ndarray, casters: np.ndarray, points: np.ndarray, up,
                    known: np.ndarray | None = None, albedo: np.ndarray | None = None,
                    labels: np.ndarray | None = None, sky_view: np.ndarray | None = None,
                    sky_share: float = 0.5, cfg: EvidenceConfig | None = None) -> ShadowEvidence:
    """The support's cast-shadow evidence (module docstring).

    Args:
        shading: (h, w) luminance of image / albedo (linear, any exposure).
        support: (h, w) bool, the support's pixels; casters: (h, w) bool, the pixels of
            the objects standing on it (``depthmesh.DepthMesh.casters``).
        known: (h, w) bool, the pixels whose shading is known (default: finite > 0).
        points: (h, w, 3) the pixels' camera-frame points; up: (3,) world up.
        labels: (h, w) int, the occluders' components (each caster's reach its own).
        cfg: the evidence's constants (``settings.EvidenceConfig``).
        albedo: (h, w) luminance of the albedo: where it changes from pixel to pixel the
            image and the albedo map rarely line up (an anti-aliased edge over a sampled
            one), and the ratio there tells nothing (weight 0).
        sky_view: (h, w) in [0, 1], the share of a uniform sky each support pixel sees
            past the scene's geometry (``skyvis.mesh_sky_view``), None: not known; and
            ``sky_share`` the sky's share of the open support's light: the lit level is
            ``(1 - sky_share) + sky_share * sky_view`` of its smooth surface (module
            docstring).
    """
    cfg = EvidenceConfig() if cfg is None else cfg
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
        ok &= ~(grad > cfg.albedo_edge)  # (the 3 x 3 Sobel already marks both sides of an edge)
    h, w = s.shape
    nan = np.full((h, w), np.nan)
    empty = np.zeros((h, w), bool)
    if ok.sum() < 10:
        return ShadowEvidence(ratio=nan, dark=empty, tied=empty, weight=np.zeros((h, w)), sigma=float("nan"),
                              lit_level=nan, reach=empty, shading=np.asarray(shading, np.float64),
                              basis=np.ones((h, w, 1)))
    logs = np.where(ok, np.log(np.where(ok, s, 1.0)), 0.0)
    X = lit_basis(points, up, ok, albedo, albedo_spread=cfg.albedo_spread, degree=cfg.lit_degree)
    view = _view(sky_view, ok, sky_share)
    # the sky the geometry hides, as a log factor of the lit level (0: none given)
    g = np.zeros((h, w)) if view is None else np.log(np.maximum((1.0 - sky_share) + sky_share * view,
                                                                cfg.min_sky_factor))
    lit = ok.copy()
    # the lit level is fitted on the pixels not called dark, called dark at the pixels'
    # own noise (the differences between neighbours on the support: a render's noise, a
    # texture's residue), so that any light the lit level does not hold -- an unseen
    # occluder's band, a shadow -- is left out of it, however large
    pair = ok[:, 1:] & ok[:, :-1]
    diffs = np.abs(np.diff(logs, axis=1))[pair]
    floor = cfg.weber / cfg.dark_sigmas
    sigma = max(1.4826 * float(np.median(diffs)) / math.sqrt(2.0), floor) if len(diffs) else floor
    level = nan
    med = 0.0
    res = np.full((h, w), np.nan)
    X_ok = X[ok]  # (the basis at the known pixels, gathered once for every iteration)
    # coarse to fine: the k-th fit has the monomials up to degree k (the albedo's terms
    # always), so that the surface gains a degree of freedom only once the pixels the
    # coarser fit calls dark are set aside. A cubic fitted at once to a floor a third of
    # which an unseen occluder shades bends down into that band, calls the band lit and
    # the open floor beside it dark (the shipped example's job 0: 0.85 of its level)
    n_alb = X.shape[-1] - (cfg.lit_degree + 1) * (cfg.lit_degree + 2) // 2
    for it in range(cfg.lit_iters):
        d = min(it, cfg.lit_degree)
        cols = np.r_[0:(d + 1) * (d + 2) // 2, X.shape[-1] - n_alb:X.shape[-1]]
        fit_px = np.flatnonzero(lit.ravel())
        if len(fit_px) > cfg.max_lit_pixels:  # a stride: a low-order surface needs few
            fit_px = fit_px[np.linspace(0, len(fit_px) - 1, cfg.max_lit_pixels).astype(np.int64)]
        Xf = X.reshape(-1, X.shape[-1])[fit_px][:, cols]
        beta = np.linalg.lstsq(Xf, logs.ravel()[fit_px] - g.ravel()[fit_px], rcond=None)[0]
        lv = np.full((h, w), np.nan)
        lv[ok] = X_ok[:, cols] @ beta + g[ok]
        res = np.where(ok, logs - np.nan_to_num(lv), np.nan)
        rl = res[lit]
        if len(rl) < 10:
            break
        med = float(np.median(rl))
        lit = ok & ~(res < med + math.log(1.0 - dark_depth(sigma, cfg)))
        level = np.exp(lv + med)
    # then the noise of a pixel's ratio is the lit level's own misfit on the lit pixels
    # (at least the pixels' noise): what a dark pixel must stand out of
    rl = res[lit & np.isfinite(res)]
    if len(rl) >= 10:
        sigma = max(1.4826 * float(np.median(np.abs(rl - med))), sigma)
    ratio = np.where(ok, s / np.where(np.isfinite(level) & (level > 0), level, np.nan), np.nan)
    depth = dark_depth(sigma, cfg)
    dark = ok & np.isfinite(ratio) & (ratio < 1.0 - depth)
    # regions (the dark region's basins, ``shadow_basins``), and which of them touch a
    # caster that stands on the support; a region is grouped across the unread bands (an
    # albedo edge's, the outline's) it crosses: a shadow on a checker floor is one
    # shadow, not a piece per tile
    unread = np.asarray(support, bool) & ~ok
    k = 2 * cfg.unread_px + 1
    near_dark = cv2.dilate(dark.astype(np.uint8), np.ones((k, k), np.uint8)) > 0
    n_lab, lab = shadow_basins(ratio, dark | (unread & near_dark), depth, cfg.basin_blur_px)
    casters = np.asarray(casters, bool)
    reach_m = within_reach(points, casters, up, np.asarray(support, bool), labels, cfg)
    # (beyond the band the support's outline and the albedo's edges leave unread)
    reach = max(1, int(round(cfg.attach_rel * max(h, w)))) + cfg.unread_px
    kern = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * reach + 1, 2 * reach + 1))
    near_caster = cv2.dilate(casters.astype(np.uint8), kern) > 0
    tied = np.zeros((h, w), bool)
    min_px = max(3, int(cfg.min_region_rel * ok.sum()))
    if n_lab > 1:
        sizes = np.bincount(lab[dark], minlength=n_lab)
        touch = np.bincount(lab[near_caster & (dark | unread)], minlength=n_lab) > 0
        keep = touch & (sizes >= min_px)
        keep[0] = False
        tied = keep[lab] & dark & reach_m
    weight = np.where(ok & ~(dark & ~tied), 1.0, 0.0)
    return ShadowEvidence(ratio=ratio, dark=dark, tied=tied, weight=weight, sigma=float(sigma),
                          lit_level=np.where(ok, level, np.nan), reach=reach_m, shading=s,
                          basis=X if view is None else np.concatenate([X, g[..., None]], -1))


def _view(sky_view, ok: np.ndarray, sky_share: float) -> np.ndarray | None:
    """(h, w) the sky's visible share (``shadow_evidence``'s ``sky_view``) in [0, 1];
    None where none is given or it does not vary over the support (nothing stands on
    it: no term). Raises ValueError on a share map of another shape than the shading's
    or a ``sky_share`` outside [0, 1]."""
    if sky_view is None:
        return None
    if np.shape(sky_view) != ok.shape:
        raise ValueError(f"shadow_evidence: sky_view is {np.shape(sky_view)}, the shading {ok.shape}")
    if not 0.0 <= float(sky_share) <= 1.0:
        raise ValueError(f"shadow_evidence: sky_share {sky_share} is outside [0, 1]")
    v = np.clip(np.nan_to_num(np.asarray(sky_view, np.float64), nan=1.0, posinf=1.0, neginf=1.0), 0.0, 1.0)
    return v if ok.sum() >= 10 and float(np.ptp(v[ok])) > 1e-6 else None


__all__ = ["ShadowEvidence", "shadow_basins", "shadow_evidence"]
