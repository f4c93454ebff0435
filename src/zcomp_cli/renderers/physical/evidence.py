"""Cast-shadow evidence: where would each candidate light put the shadows of the visible
geometry, and are those pixels darker than the same surface around them?

1. Darkness ``e(p) = 1 - Y(p) / B(p)``: ``B`` is the local level of the same surface
   (the dominant surface, usually the floor, and the rest apart), a wide normalised
   blur over the pixels not already much darker than it (two passes), so smooth
   gradients and highlights do not read as shadows.
2. For a candidate direction ``l``, the predicted cast shadow ``C_l`` is the set of
   pixels facing the light (``n . l > 0``) whose screen-space ray toward ``l`` is blocked.
3. ``score(l) = sum over C_l of (e(p) - tau)``: each predicted shadow pixel that is dark
   adds, each one on a lit pixel costs. Dark pixels that no visible occluder explains
   (the shadows of things outside the frame) add nothing to any candidate: they
   cannot cancel the evidence of the visible ones.

The best score, in pixels of full darkness (at the estimation resolution), says how
much evidence there is; below a threshold the direction is unconstrained.
"""

from __future__ import annotations

import numpy as np

from zcomp_cli.camera import Camera
from zcomp_cli.renderers.physical.softshadow import normalized_blur
from zcomp_cli.renderers.physical.visibility import march_visibility

# Darkness a predicted-shadow pixel must exceed to count for a direction: above the
# 10 % of the shadow metric, since screen-space shadows spill onto some lit pixels.
EVIDENCE_TAU = 0.2
# Pixels darker than this (relative) are "dark" and all kept in the sample.
DARK_LEVEL = 0.15
# Local-level blur radius as a fraction of the long side.
BASELINE_RADIUS_FRAC = 0.1
# Pixels this close (fraction of the long side) to a crease give no evidence as they
# are: their darkness is first reduced by what ambient occlusion explains
# (``ao_corrected_band``).
CREASE_FRAC = 0.03
# Pixels this close (in pixels) to a crease give none at all: mixed pixels across the
# orientation change or depth jump.
CREASE_CORE_PX = 1.5
# Width of one albedo bin of ``same_material_level`` (natural log: 1.25x apart).
ALBEDO_RANGE = float(np.log(1.25))


def orientation_labels(normals: np.ndarray, valid: np.ndarray, up: np.ndarray) -> np.ndarray:
    """(H, W) int label of each pixel's orientation: 0 invalid, 1 the dominant surface
    (within 15 deg of ``up``), else 2 + the nearest of 32 directions."""
    from zcomp_cli.renderers.physical.lighting import fibonacci_sphere

    bins = fibonacci_sphere(32)
    lab = 2 + np.argmax(normals @ bins.T, axis=-1)
    lab = np.where(normals @ up > np.cos(np.deg2rad(15)), 1, lab)
    return np.where(valid, lab, 0)


def same_material_level(values: np.ndarray, weight: np.ndarray, radius: float,
                        albedo: np.ndarray | None) -> np.ndarray:
    """Local level of ``values`` (H, W) over the ``weight`` pixels within ``radius``, each
    pixel compared with those of a similar albedo only (a bilateral filter in log albedo,
    ``ALBEDO_RANGE`` per bin, splatted with linear weights between bins).

    Why: image over albedo is not the shading alone. The glossy reflection and the
    light bounced from the surroundings add nearly the same radiance to a dark tile as
    to a bright one, so a checker floor's bright tiles read 10-30 % "darker" than the
    dark ones around them: a pattern of fake shadows. Against pixels of their own
    albedo they read level. Where too few such pixels are near (under 2 % of the
    blur's full weight), the level of all orientation-mates is used.

    Args:
        values, weight: (H, W). radius: Gaussian blur radius in pixels.
        albedo: (H, W) albedo luminance (> 0), or None: orientation only.
    Returns: (H, W) float64 level.
    """
    plain = normalized_blur(values, weight, radius)
    if albedo is None:
        return plain
    from zcomp_cli.renderers.physical.softshadow import gaussian_blur

    la = np.log(np.clip(np.nan_to_num(np.asarray(albedo, np.float64), nan=0.5, posinf=1.0), 1e-3, None))
    sel = weight > 0
    if not sel.any():
        return plain
    lo, hi = float(la[sel].min()), float(la[sel].max())
    if hi - lo < ALBEDO_RANGE:
        return plain
    # bins at fixed log-albedo positions: a pixel's bins depend on its own albedo alone
    t = la / ALBEDO_RANGE
    k0 = np.floor(t).astype(np.int64)
    frac = t - k0
    w = weight.astype(np.float32)
    num = np.zeros(values.shape)
    den = np.zeros(values.shape)
    full = np.maximum(gaussian_blur(w, radius), 1e-6)
    for k in range(int(np.floor(lo / ALBEDO_RANGE)), int(np.floor(hi / ALBEDO_RANGE)) + 2):
        # splat: each pixel's weight in bin k (linear between its two nearest bins)
        sk = np.where(k0 == k, 1.0 - frac, np.where(k0 + 1 == k, frac, 0.0))
        if not (sk * w).any():
            continue
        nk = gaussian_blur((values * w * sk).astype(np.float32), radius)
        dk = gaussian_blur((w * sk).astype(np.float32), radius)
        # slice: read bin k back at each pixel's own albedo
        num += sk * nk
        den += sk * dk
    return np.where(den > 0.02 * full, num / np.maximum(den, 1e-9), plain)


def darkness_map(lum: np.ndarray, normals: np.ndarray, valid: np.ndarray, up: np.ndarray,
                 depth: np.ndarray | None = None, *, albedo: np.ndarray | None = None,
                 return_band: bool = False):
    """Relative darkness of each pixel against the same orientation (and, with
    ``albedo``, the same material: ``same_material_level``) around it.

    Returns:
        e: (H, W) ``1 - Y / local level`` in [-0.5, 1], 0 where invalid;
        usable: (H, W) bool, valid pixels away from creases (orientation changes and
            depth jumps, ``CREASE_FRAC`` of the long side): the darkening of concave
            corners (ambient occlusion, where a wall meets the floor) is no cast shadow;
        band: (H, W) bool, only with ``return_band``: the valid pixels of that crease
            band beyond its mixed-pixel core (``CREASE_CORE_PX``), for
            ``ao_corrected_band``.
    """
    import cv2

    H, W = lum.shape
    rad = max(2.0, BASELINE_RADIUS_FRAC * max(H, W))
    lab = orientation_labels(normals, valid, up)
    e = np.zeros((H, W))
    for g in np.unique(lab[lab > 0]):
        grp = lab == g
        b0 = same_material_level(lum, grp, rad, albedo)
        lit = grp & (lum > 0.8 * b0)
        b = same_material_level(lum, lit if lit.any() else grp, rad, albedo)
        e = np.where(grp, 1.0 - lum / np.maximum(b, 1e-9), e)
    edge = np.zeros((H, W), bool)
    edge[:, 1:] |= lab[:, 1:] != lab[:, :-1]
    edge[1:] |= lab[1:] != lab[:-1]
    if depth is not None:
        dz = depth.astype(np.float64)
        jx = np.abs(np.diff(dz, axis=1)) > 0.05 * np.maximum(dz[:, 1:], dz[:, :-1])
        jy = np.abs(np.diff(dz, axis=0)) > 0.05 * np.maximum(dz[1:], dz[:-1])
        edge[:, 1:] |= jx
        edge[1:] |= jy
    dist = cv2.distanceTransform((~edge).astype(np.uint8), cv2.DIST_L2, 3)
    usable = valid & (dist > CREASE_FRAC * max(H, W))
    if return_band:
        return np.clip(e, -0.5, 1.0), usable, valid & ~usable & (dist > CREASE_CORE_PX)
    return np.clip(e, -0.5, 1.0), usable


def ao_corrected_band(e: np.ndarray, band: np.ndarray, points: np.ndarray, normals: np.ndarray,
                      depth: np.ndarray, camera: Camera) -> np.ndarray:
    """Darkness of the crease band's pixels beyond what ambient occlusion explains.

    Near a crease (a box standing on the floor, a wall meeting it) the surface is darker
    whatever the light's direction: the occluded part of the sky. A cast shadow that
    starts at its occluder's base (the common case) lies in that band too, and is far
    darker on the light's far side than the occlusion. Ambient occlusion ``a`` darkens a
    surface by ``k (1 - a)``, ``k`` the ambient's share of the light (read from the band
    itself: the median darkness per unit of occlusion), so ``e - k (1 - a)`` is darkness
    no ambient occlusion explains: it depends on the light's direction.

    Args:
        e: (H, W) relative darkness (``darkness_map``). band: (H, W) bool.
        points, normals: (H, W, 3) camera frame (normals unit where ``band``).
        depth: (H, W) z-depth (0 invalid). camera: of these maps.
    Returns:
        (H, W) corrected darkness on ``band`` (unchanged ``e`` elsewhere).
    """
    from zcomp_cli.renderers.physical.softshadow import ambient_occlusion

    ys, xs = np.nonzero(band)
    if len(ys) == 0:
        return e
    ao = np.zeros(e.shape)
    ao[ys, xs] = ambient_occlusion(points[ys, xs].astype(np.float64), normals[ys, xs].astype(np.float64),
                                   ys, xs, depth, camera)
    # the per-pixel rotation makes it noisy by design: filter it within the band
    occ = 1.0 - np.clip(normalized_blur(ao, band, 1.5), 0.0, 1.0)
    # AO darkens by ``share * occ`` (share: the ambient's part of the light, unknown
    # here). Most of the band lies outside any cast shadow, so the median darkness per
    # unit of occlusion over the band measures it; the cast shadows are its outliers.
    sel = band & (occ > 0.05)
    k = float(np.median(e[sel] / occ[sel])) if sel.sum() >= 10 else 1.0
    k = max(k, 0.0)
    return np.where(band, e - k * occ, e)


def evidence_sample(e: np.ndarray, valid: np.ndarray, max_dark: int = 1500, max_other: int = 1500):
    """Flat indices and weights: every dark pixel (up to ``max_dark``, strided) and a
    strided sample of the rest, each weighted by how many pixels it stands for."""
    flat_e = e.ravel()
    v = valid.ravel()
    dark = np.flatnonzero(v & (flat_e > DARK_LEVEL))
    other = np.flatnonzero(v & (flat_e <= DARK_LEVEL))
    out_i, out_w = [], []
    for idx, cap in ((dark, max_dark), (other, max_other)):
        if len(idx) == 0:
            continue
        take = idx if len(idx) <= cap else idx[np.linspace(0, len(idx) - 1, cap).astype(np.int64)]
        out_i.append(take)
        out_w.append(np.full(len(take), len(idx) / len(take)))
    if not out_i:
        return np.zeros(0, np.int64), np.zeros(0)
    return np.concatenate(out_i), np.concatenate(out_w)


def evidence_scores(points, normals, e, weights, dirs, depth, camera: Camera, *, steps: int = 16,
                    chunk: int = 32, tau: float = EVIDENCE_TAU) -> np.ndarray:
    """score(l) for each of ``dirs`` (C, 3) over sampled pixels: (C,) float64; ``tau``
    the darkness a predicted-shadow pixel must exceed to add."""
    P = np.asarray(points, np.float64)
    N = np.asarray(normals, np.float64)
    gain = weights * (e - tau)
    out = []
    for c0 in range(0, len(dirs), chunk):
        D = np.asarray(dirs[c0:c0 + chunk])
        C = len(D)
        facing = (N @ D.T) > 0.05  # (N, C); attached shadows are orientation, not evidence
        Pr = np.repeat(P[None], C, 0).reshape(-1, 3)
        Nr = np.repeat(N[None], C, 0).reshape(-1, 3)
        Lr = np.repeat(D, len(P), 0)
        live = facing.T.reshape(-1)
        blocked = np.zeros(len(Pr), bool)
        if live.any():
            blocked[live] = march_visibility(Pr[live], Nr[live], Lr[live], depth, camera, steps=steps) < 0.5
        out.append(blocked.reshape(C, -1) @ gain)
    return np.concatenate(out) if out else np.zeros(0)
