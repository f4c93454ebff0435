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
# Pixels this close (fraction of the long side) to a crease give no evidence.
CREASE_FRAC = 0.03


def orientation_labels(normals: np.ndarray, valid: np.ndarray, up: np.ndarray) -> np.ndarray:
    """(H, W) int label of each pixel's orientation: 0 invalid, 1 the dominant surface
    (within 15 deg of ``up``), else 2 + the nearest of 32 directions."""
    from zcomp_cli.renderers.physical.lighting import fibonacci_sphere

    bins = fibonacci_sphere(32)
    lab = 2 + np.argmax(normals @ bins.T, axis=-1)
    lab = np.where(normals @ up > np.cos(np.deg2rad(15)), 1, lab)
    return np.where(valid, lab, 0)


def darkness_map(lum: np.ndarray, normals: np.ndarray, valid: np.ndarray, up: np.ndarray,
                 depth: np.ndarray | None = None):
    """Relative darkness of each pixel against the same orientation around it.

    Returns:
        e: (H, W) ``1 - Y / local level`` in [-0.5, 1], 0 where invalid;
        usable: (H, W) bool, valid pixels away from creases (orientation changes and
            depth jumps, ``CREASE_FRAC`` of the long side): the darkening of concave
            corners (ambient occlusion, where a wall meets the floor) is no cast shadow.
    """
    import cv2

    H, W = lum.shape
    rad = max(2.0, BASELINE_RADIUS_FRAC * max(H, W))
    lab = orientation_labels(normals, valid, up)
    e = np.zeros((H, W))
    for g in np.unique(lab[lab > 0]):
        grp = lab == g
        b0 = normalized_blur(lum, grp, rad)
        lit = grp & (lum > 0.8 * b0)
        b = normalized_blur(lum, lit if lit.any() else grp, rad)
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
    return np.clip(e, -0.5, 1.0), usable


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
                    chunk: int = 32) -> np.ndarray:
    """score(l) for each of ``dirs`` (C, 3) over sampled pixels: (C,) float64."""
    P = np.asarray(points, np.float64)
    N = np.asarray(normals, np.float64)
    gain = weights * (e - EVIDENCE_TAU)
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
