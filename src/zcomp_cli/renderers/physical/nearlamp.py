"""A lamp near the scene, read from the falloff of the support's shading.

A sun or a sky lights a floor evenly: on one plane their irradiance does not depend on
the point. A lamp a few metres away does not: its irradiance falls off as
``cos / r^2`` from the point under it. On a plane, the shading against orientation
cannot tell a directional light from the order-1 ambient (both are linear in the one
normal the plane has); the falloff is spatial, and places the lamp.

The fit is on the support alone (the dominant surface, ``lighting.estimate_lighting``'s
``up``): ``S(x) = A + B g_p(x)``, ``g_p(x) = max(0, up . (p - x)) / |p - x|^3``, robust
(IRLS, Huber weights: cast shadows, contact darkening and gloss are outliers), for
candidate lamp positions ``p`` above the support's centre; then refined around the best.
The distances are relative to the support's median distance from the camera, so a
depth map of arbitrary scale (an estimator's relative depth) gives the same fit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# Lamp distances from the support's centre tried, in units of the support's median
# distance from the camera (a benchmark floor: ~4 m, so 1 to 9 m).
LAMP_DISTANCES_REL = (0.25, 0.375, 0.5, 0.75, 1.0, 1.5, 2.25)
# Directions tried from the support's centre (a Fibonacci sphere; those above the plane).
LAMP_DIRECTION_CANDIDATES = 300
# The falloff says "a lamp" when the lamp's term spans at least this share of the
# support's median shading (its 5th to 95th percentile over the support). Calibrated on
# benchmark seed 8128: its lamp-lit scenes span 0.26-1.40 (8 of 10 >= 0.5), its sun- and
# sky-lit ones 0.02-0.78 (3 of 17 >= 0.5: gloss and walls' occlusion); checked on 27182.
LAMP_MIN_FALLOFF = 0.5
# Fewer support pixels than this: no fit; more: a deterministic stride subsample (the
# falloff is smooth: a few hundred points pin it, and the cost is linear in them).
MIN_SUPPORT_PIXELS = 100
MAX_SUPPORT_PIXELS = 800
# Huber threshold, in robust standard deviations of the residual.
HUBER_K = 1.5
# Residuals beyond this fraction of the median shading count as this much (a highlight or
# a deep shadow must not choose the lamp).
TRUNCATE_REL = 0.1
# Iterations that assign pixels to a cast shadow (``_robust_line``), after the plain
# robust ones; the shadow's level over the lit one stays in this range.
SHADOW_ITERS = 3
SHADOW_LEVEL_RANGE = (0.05, 0.9)
# Gloss or a lamp: a glossy floor's glow adds the same radiance to its dark and bright
# tiles, a lamp's light multiplies their albedo. On a support of two albedos at least
# GLOSS_MIN_CONTRAST apart (each class at least GLOSS_MIN_CLASS_PIXELS), the falloff's
# strength is fitted on each: B_dark / B_bright (in shading, image over albedo) is 1 for
# a lamp and the albedo ratio for gloss. The gloss index log(B_dark / B_bright) /
# log(albedo ratio) above LAMP_MAX_GLOSS_INDEX (or a falloff missing on either class)
# is gloss. Seeds 8128, 27182 and 5077: the lamps found on checker floors 0.04-0.27 (two
# more with too little contrast to tell); the falloffs of sun- or sky-lit checker floors
# read as lamps 0.67, 0.93 and none on the dark tiles (the last two cost 3 and 7 dB as
# lamps), and one at 0.25, left as a lamp.
GLOSS_MIN_CONTRAST = 1.5
GLOSS_MIN_CLASS_PIXELS = 50
LAMP_MAX_GLOSS_INDEX = 0.5


@dataclass
class LampFit:
    """position: (3,) camera frame, the lamp; aim: (3,) the support's centre the
    distances were measured from; falloff: the lamp term's span over the support's
    shading (``LAMP_MIN_FALLOFF``); residual: robust mean squared relative residual;
    ambient, strength: A and B of ``A + B g`` (``g`` scaled by ``height``^2: 1 at the
    lamp's foot); up: (3,) the support's normal; gloss_index: 0 for a falloff that
    multiplies the albedo (a lamp), 1 for one that adds to it (a glossy reflection), nan
    where the support has no albedo contrast to tell (``GLOSS_MIN_CONTRAST``)."""

    position: np.ndarray
    aim: np.ndarray
    falloff: float
    residual: float
    ambient: float
    strength: float
    height: float
    up: np.ndarray
    gloss_index: float = float("nan")

    @property
    def found(self) -> bool:
        return bool(self.falloff >= LAMP_MIN_FALLOFF and not self.gloss_index > LAMP_MAX_GLOSS_INDEX)

    def support_shading(self, points) -> np.ndarray:
        """(N,) the fitted lit shading ``A + B g`` at (N, 3) points of the support."""
        P = np.asarray(points, np.float64).reshape(-1, 3)
        return self.ambient + self.strength * _falloff(P, self.up, self.position[None],
                                                       np.array([self.height]))[0]

    def direction_at(self, point) -> np.ndarray:
        """(3,) unit vector from ``point`` (3,) toward the lamp."""
        v = self.position - np.asarray(point, np.float64)
        return v / max(float(np.linalg.norm(v)), 1e-12)


def _falloff(points: np.ndarray, up: np.ndarray, lamps: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """(C, N) ``max(0, up . (p - x)) / |p - x|^3 * scale^2`` for lamps (C, 3) and points
    (N, 3); ``scale`` (C,) makes the term about 1 near the lamp's foot."""
    v = lamps[:, None, :] - points[None]
    h = np.maximum(v @ up, 0.0)
    r2 = np.maximum(np.einsum("cnk,cnk->cn", v, v), 1e-12)
    return h / (r2 * np.sqrt(r2)) * (scale ** 2)[:, None]


def _robust_line(g: np.ndarray, y: np.ndarray, iters: int = 3):
    """Row-wise robust fit of (C, N) ``g`` to (N,) ``y``: ``y ~ s (A + B g)``, with
    ``s`` = 1 on lit pixels and ``k`` (one per row, fitted) on those in a cast shadow,
    each pixel assigned to the nearer of the two. Returns (A (C,), B (C,), loss (C,));
    rows with no positive B or a negative A get loss inf.

    The shadow level is what keeps a sun's shadow off the lamp: a wall's shadow over
    half the floor is a step, which the lit level and ``k`` explain with no lamp at all
    (the shipped example: a falloff "span" of 0.87 without it); a lamp's falloff is
    smooth and stays in ``B``.
    """
    C = len(g)
    scale_y = max(float(np.median(y)), 1e-9)
    w = np.ones_like(g)
    sf = np.ones_like(g)  # 1 lit, k in shadow
    k = np.full(C, 0.5)
    A = np.zeros(C)
    B = np.zeros(C)
    ok = np.zeros(C, bool)
    for it in range(iters + SHADOW_ITERS):
        ws = w * sf * sf
        sw, sg, sgg = ws.sum(1), (ws * g).sum(1), (ws * g * g).sum(1)
        sy, sgy = (w * sf) @ y, (w * sf * g) @ y
        det = sw * sgg - sg * sg
        ok = det > 1e-12 * np.maximum(sw * sgg, 1e-30)
        B = np.where(ok, (sw * sgy - sg * sy) / np.where(ok, det, 1.0), 0.0)
        A = (sy - B * sg) / np.maximum(sw, 1e-12)
        m = A[:, None] + B[:, None] * g
        if it >= iters:
            # assign each pixel to the lit or the shadow level, then refit the level
            shade = y[None] < 0.5 * (1.0 + k[:, None]) * m
            num = np.where(shade, y[None] * m, 0.0).sum(1)
            den = np.where(shade, m * m, 0.0).sum(1)
            k = np.where(den > 0, np.clip(num / np.maximum(den, 1e-30), *SHADOW_LEVEL_RANGE), k)
            sf = np.where(shade, k[:, None], 1.0)
        res = y[None] - sf * m
        s = 1.4826 * np.median(np.abs(res), axis=1) + 1e-6 * scale_y
        w = 1.0 / np.maximum(1.0, np.abs(res) / (HUBER_K * s[:, None]))
    # (``res``: the last iteration's, of the returned A, B and levels)
    loss = np.mean(np.minimum((res / scale_y) ** 2, TRUNCATE_REL ** 2), axis=1)
    # (a negative ambient is no sky: a lamp that explains the support only by taking
    # light away elsewhere is a gradient of something else -- walls' occlusion, gloss)
    loss = np.where((B > 0) & (A >= 0) & ok & np.isfinite(loss), loss, np.inf)
    return A, B, loss


def gloss_index(g: np.ndarray, y: np.ndarray, albedo: np.ndarray) -> float:
    """How much of a falloff ``g`` (N,) in the shading ``y`` (N,) adds to the albedo
    rather than multiplying it, from a support's dark and bright pixels (``albedo`` (N,)
    luminance): ``log(B_dark / B_bright) / log(albedo ratio)``; inf when either class
    shows no falloff (B <= 0); nan when the albedo has too little contrast or too few
    pixels per class."""
    a = np.asarray(albedo, np.float64)
    ok = np.isfinite(a) & (a > 0)
    if ok.sum() < 2 * GLOSS_MIN_CLASS_PIXELS:
        return float("nan")
    lo, hi = np.percentile(a[ok], [10, 90])
    mid = np.sqrt(lo * hi)
    dark, bright = ok & (a < mid / 1.1), ok & (a > mid * 1.1)
    if dark.sum() < GLOSS_MIN_CLASS_PIXELS or bright.sum() < GLOSS_MIN_CLASS_PIXELS:
        return float("nan")
    ratio = float(np.median(a[bright]) / np.median(a[dark]))
    if not ratio >= GLOSS_MIN_CONTRAST:
        return float("nan")
    b = []
    for sel in (dark, bright):
        if np.ptp(g[sel]) <= 1e-9 * max(float(np.max(np.abs(g[sel]))), 1e-30):
            return float("nan")  # no falloff across the class to compare
        _, B, _ = _robust_line(g[sel][None], y[sel], iters=3)
        b.append(float(B[0]))
    if not (b[0] > 0 and b[1] > 0):
        return float("inf")
    return float(np.log(b[0] / b[1]) / np.log(ratio))


def fit_near_lamp(points, shading, up, albedo=None) -> LampFit | None:
    """Fit a lamp to the falloff of the support's shading.

    Args:
        points: (N, 3) camera-frame points of the support (one plane, normal ``up``).
        shading: (N,) their linear shading (luminance of image / albedo), > 0.
        up: (3,) the support's unit normal.
        albedo: (N,) their albedo luminance, or None: where it has two levels, whether
            the falloff multiplies it (a lamp) or adds to it (gloss), ``gloss_index``.
    Returns:
        LampFit (``found`` says whether the falloff is a lamp's), or None when there are
        fewer than MIN_SUPPORT_PIXELS finite pixels or the points are degenerate.
    """
    from zcomp_cli.renderers.physical.lighting import fibonacci_sphere
    from zcomp_cli.renderers.physical.shading import cone_directions

    P = np.asarray(points, np.float64).reshape(-1, 3)
    y = np.asarray(shading, np.float64).reshape(-1)
    up = np.asarray(up, np.float64)
    up = up / max(float(np.linalg.norm(up)), 1e-12)
    alb = None if albedo is None else np.asarray(albedo, np.float64).reshape(-1)
    if alb is not None and len(alb) != len(y):
        raise ValueError(f"albedo has {len(alb)} values for {len(y)} points")
    ok = np.all(np.isfinite(P), 1) & np.isfinite(y) & (y > 0)
    P, y = P[ok], y[ok]
    alb = None if alb is None else alb[ok]
    if len(P) < MIN_SUPPORT_PIXELS:
        return None
    if len(P) > MAX_SUPPORT_PIXELS:
        keep = np.linspace(0, len(P) - 1, MAX_SUPPORT_PIXELS).astype(np.int64)
        P, y = P[keep], y[keep]
        alb = None if alb is None else alb[keep]
    depth_scale = float(np.median(np.linalg.norm(P, axis=1)))
    if not np.isfinite(depth_scale) or depth_scale <= 1e-9:
        return None
    aim = np.median(P, 0)
    W = fibonacci_sphere(2 * LAMP_DIRECTION_CANDIDATES)
    W = W[W @ up > 0.1]
    R = depth_scale * np.asarray(LAMP_DISTANCES_REL)
    # (the lamp's height over the aim point sets the term's scale: g = 1 at its foot)
    cand_w = np.repeat(W, len(R), 0)
    cand_r = np.tile(R, len(W))

    def score(ws, rs):
        lamps = aim[None] + rs[:, None] * ws
        height = np.maximum(ws @ up, 0.1) * rs
        out = []
        for c0 in range(0, len(ws), 256):  # bounded memory: (256, N) at a time
            sl = slice(c0, c0 + 256)
            out.append(_robust_line(_falloff(P, up, lamps[sl], height[sl]), y))
        A, B, loss = (np.concatenate(x) for x in zip(*out))
        return lamps, height, A, B, loss

    lamps, height, A, B, loss = score(cand_w, cand_r)
    i = int(np.argmin(loss))
    if not np.isfinite(loss[i]):
        return None
    # refine: nearby directions at nearby distances
    step = np.degrees(np.sqrt(4 * np.pi / (2 * LAMP_DIRECTION_CANDIDATES)))
    fw = cone_directions(cand_w[i], 1.5 * step, 40, seed=0)
    fw = np.concatenate([cand_w[i][None], fw[fw @ up > 0.1]])
    fr = cand_r[i] * np.array([0.8, 0.9, 1.0, 1.12, 1.25])
    l2, h2, A2, B2, loss2 = score(np.repeat(fw, len(fr), 0), np.tile(fr, len(fw)))
    j = int(np.argmin(loss2))
    if loss2[j] < loss[i]:
        lamps, height, A, B, loss, i = l2, h2, A2, B2, loss2, j
    g = _falloff(P, up, lamps[i:i + 1], height[i:i + 1])[0]
    span = float(B[i] * (np.percentile(g, 95) - np.percentile(g, 5)) / max(float(np.median(y)), 1e-9))
    gi = float("nan") if alb is None else gloss_index(g, y, alb)
    return LampFit(lamps[i], aim, span, float(loss[i]), float(A[i]), float(B[i]), float(height[i]), up, gi)


__all__ = ["LampFit", "fit_near_lamp", "LAMP_MIN_FALLOFF"]
