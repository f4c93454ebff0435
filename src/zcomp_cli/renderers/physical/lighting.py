"""Light estimation from the known shading of the background (DESIGN.md section 5).

Model (luminance for the search, per channel for the final fit):
    shading(p) ~ a . [1, n] + I * mean_k max(0, n.l_k) V(p, l_k)
with a ridge-regularised order-1 SH ambient (the ridge keeps the ambient's linear
part from absorbing the directional term) and Huber IRLS weights. Candidate light
directions on the upper hemisphere are scored by robust residual; the cast shadows
that the depth explains are what pin the direction down.
"""

from __future__ import annotations

from dataclasses import dataclass, asdict

import numpy as np

from zcomp_cli.camera import Camera
from zcomp_cli.conventions import DEFAULT_SEED, REC601
from zcomp_cli.renderers.physical.shading import cone_directions, direct_term, sh_basis
from zcomp_cli.renderers.physical.visibility import march_visibility

SOFTNESS_CANDIDATES_DEG = (0.0, 3.0, 8.0, 15.0, 30.0)
PRIOR_SOFTNESS_DEG = 15.0
PRIOR_AMBIENT_SHARE = 0.4


@dataclass
class LightEstimate:
    """direction: (3,) camera-frame unit vector toward the light; intensity: (3,) RGB;
    ambient_sh: (4, 3) order-1 SH ambient coefficients; ambient_share: ambient /
    (ambient + direct) on the dominant surface (shadow darkness); softness_deg: cone
    half-angle; residual: robust relative residual of the fit; contrast: score gap
    between best and median candidate (0 = flat landscape); fallback: reason or None."""

    direction: np.ndarray
    intensity: np.ndarray
    ambient_sh: np.ndarray
    ambient_share: float
    softness_deg: float
    residual: float
    contrast: float
    normal_spread: float
    fallback: str | None = None
    direction_uncertainty_deg: float = 0.0

    @property
    def cone_deg(self) -> float:
        """Cone half-angle used to render: the light's own size, widened to the spread
        of its plausible directions (an uncertain light casts the average of its
        possible shadows: softer and lighter), capped at MAX_SOFTNESS_DEG."""
        return float(min(max(self.softness_deg, self.direction_uncertainty_deg), MAX_SOFTNESS_DEG))

    def to_info(self) -> dict:
        d = asdict(self)
        d["cone_deg"] = self.cone_deg
        return {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in d.items()}


def fibonacci_sphere(n: int) -> np.ndarray:
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    r = np.sqrt(np.maximum(0, 1 - z * z))
    ph = i * np.pi * (3 - np.sqrt(5))
    return np.stack([r * np.cos(ph), r * np.sin(ph), z], 1)


# Screen-space visibility can only MISS occluders (outside the frame, or hidden behind
# other surfaces), never invent them: a pixel darker than the model predicts may sit in
# the shadow of something unseen, but a pixel brighter than predicted contradicts the
# light. Residuals on the dark side therefore weigh this much less, in the fit and in
# the score that ranks light directions.
DARK_RESIDUAL_WEIGHT = 0.5


def _robust_fit(X, y, ridge, iters=4, dark_weight=None):
    """Asymmetric Huber-IRLS ridge least squares; ridge: (P,) penalties.
    Returns (coef, robust relative residual)."""
    dark_weight = DARK_RESIDUAL_WEIGHT if dark_weight is None else dark_weight
    w = np.ones(len(y))
    scale = max(np.median(np.abs(y)), 1e-6)
    for _ in range(iters):
        Xw = X * w[:, None]
        A = X.T @ Xw + np.diag(ridge) * len(y)
        coef = np.linalg.solve(A + 1e-9 * np.eye(len(A)), Xw.T @ y)
        r = y - X @ coef
        s = 1.4826 * np.median(np.abs(r)) + 1e-3 * scale
        c = 1.345 * s
        side = np.where(r < 0, dark_weight, 1.0)
        w = side * np.where(np.abs(r) <= c, 1.0, c / np.maximum(np.abs(r), 1e-12))
    # Huber loss normalised by the data scale: comparable across candidates.
    a = np.abs(r)
    loss = side * np.where(a <= c, 0.5 * a * a, c * (a - 0.5 * c))
    return coef, float(np.mean(loss)) / scale ** 2


def _fit_candidate(basis, direct, y, ridge_lin, dark_weight=None):
    """Fit y ~ basis @ a + I * direct with I >= 0. Returns (coef (5,), score)."""
    X = np.concatenate([basis, direct[:, None]], 1)
    ridge = np.array([0.0, ridge_lin, ridge_lin, ridge_lin, 0.0])
    coef, score = _robust_fit(X, y, ridge, dark_weight=dark_weight)
    if coef[-1] < 0:
        c2, score = _robust_fit(basis, y, ridge[:4], dark_weight=dark_weight)
        coef = np.concatenate([c2, [0.0]])
    return coef, score


# Direction uncertainty: candidates are weighted by a tempered likelihood
# exp(-(score - best) / (TEMPERATURE * best)). Model errors are strongly correlated
# between pixels, so the effective number of independent observations is small and the
# likelihood is tempered accordingly.
UNCERTAINTY_TEMPERATURE = 0.3
MAX_SOFTNESS_DEG = 45.0


def direction_uncertainty_deg(cands, scores, best) -> float:
    """RMS angle (degrees) between ``best`` and the candidates, weighted by their
    tempered likelihood: how far the plausible light directions spread."""
    scores = np.asarray(scores, np.float64)
    s0 = max(float(scores.min()), 1e-12)
    w = np.exp(-(scores - scores.min()) / (UNCERTAINTY_TEMPERATURE * s0))
    ang = np.arccos(np.clip(np.asarray(cands) @ best, -1.0, 1.0))
    return float(np.degrees(np.sqrt((w * ang ** 2).sum() / max(w.sum(), 1e-12))))


def _downsample(depth, normals, shading, known, camera, max_res):
    import cv2

    H, W = depth.shape
    s = min(1.0, max_res / max(H, W))
    if s >= 1.0:
        return depth, normals, shading, known, camera
    w, h = max(1, round(W * s)), max(1, round(H * s))
    d = cv2.resize(depth.astype(np.float32), (w, h), interpolation=cv2.INTER_NEAREST)
    n = cv2.resize(normals.astype(np.float32), (w, h), interpolation=cv2.INTER_NEAREST)
    sh = cv2.resize(shading.astype(np.float32), (w, h), interpolation=cv2.INTER_AREA)
    # a low-res pixel is known only if its whole footprint is known (no mask bleed)
    k = cv2.resize((~known).astype(np.float32), (w, h), interpolation=cv2.INTER_AREA) <= 0
    return d, n, sh, k, camera.resized(w, h)


def estimate_lighting(depth, normals, shading, known, camera: Camera, *,
                      n_candidates: int = 256, max_resolution: int = 160,
                      march_steps: int = 24, max_fit_pixels: int = 4000,
                      ridge: float = 0.05, cone_samples: int = 8,
                      softness_deg: float | None = None, flat_threshold: float = 0.02,
                      seed: int = DEFAULT_SEED) -> LightEstimate:
    """Estimate one directional light + SH ambient from the known shading.

    Args:
        depth: (H, W) z-depth (0 invalid). normals: (H, W, 3) camera frame.
        shading: (H, W, 3) linear shading (used where ``known``). known: (H, W) bool.
        n_candidates: hemisphere candidate directions (coarse search; then refined).
        softness_deg: force the cone half-angle instead of fitting it.
        flat_threshold: relative score contrast below which the direction is declared
            unconstrained and the prior is used.
    Returns:
        LightEstimate (never raises on degenerate evidence: it falls back to the prior
        "light from above, tilted 30 deg toward the camera, ambient share 0.4, 15 deg").
    """
    d, n, sh, k, cam = _downsample(depth, normals, shading, known, camera, max_resolution)
    nn = np.linalg.norm(n, axis=-1)
    valid = k & (d > 0) & (np.abs(nn - 1) < 0.2) & np.all(np.isfinite(sh), -1) & np.all(sh > 0, -1)
    pts_all = cam.unproject(d).astype(np.float64)
    idx = np.flatnonzero(valid.ravel())
    if len(idx) > max_fit_pixels:  # deterministic stride subsample
        idx = idx[np.linspace(0, len(idx) - 1, max_fit_pixels).astype(np.int64)]
    P = pts_all.reshape(-1, 3)[idx]
    Nrm = n.reshape(-1, 3)[idx].astype(np.float64)
    Nrm /= np.maximum(np.linalg.norm(Nrm, axis=1, keepdims=True), 1e-12)
    S = sh.reshape(-1, 3)[idx].astype(np.float64)
    Y = S @ REC601.astype(np.float64)

    # dominant surface normal (the floor, usually) -> "up" for the hemisphere and prior
    up = np.array([0.0, 1.0, 0.0])
    spread = 0.0
    if len(idx) >= 3:
        bins = fibonacci_sphere(200)
        votes = (Nrm @ bins.T > np.cos(np.deg2rad(15))).sum(0)
        dom = bins[votes.argmax()]
        dom = Nrm[Nrm @ dom > np.cos(np.deg2rad(15))].mean(0)
        dom /= np.linalg.norm(dom)
        if dom @ up > 0.5:
            up = dom
        ev = np.linalg.eigvalsh(np.cov(Nrm.T))
        spread = float(np.sqrt(max(ev[-2], 0.0)))
    march = dict(steps=march_steps)
    prior_dir = up * np.cos(np.deg2rad(30)) + np.array([0, 0, 1.0]) * np.sin(np.deg2rad(30))
    prior_dir /= np.linalg.norm(prior_dir)

    def prior(reason: str) -> LightEstimate:
        ymean = np.median(S, 0) if len(S) else np.full(3, 0.5)
        ndl = max(prior_dir @ up, 0.1)
        amb = PRIOR_AMBIENT_SHARE * ymean
        inten = (1 - PRIOR_AMBIENT_SHARE) * ymean / ndl
        sh_c = np.zeros((4, 3))
        sh_c[0] = amb
        return LightEstimate(prior_dir, inten, sh_c, PRIOR_AMBIENT_SHARE,
                             PRIOR_SOFTNESS_DEG if softness_deg is None else float(softness_deg),
                             float("nan"), 0.0, spread, reason)

    if len(idx) < 50:
        return prior(f"too few known pixels with valid geometry ({len(idx)} < 50)")

    basis = sh_basis(Nrm)
    hard = lambda l: direct_term(P, Nrm, l[None], d, cam, march_visibility, **march)

    def score_dirs(dirs):
        out = []
        for l in dirs:
            _, s = _fit_candidate(basis, hard(l), Y, ridge)
            out.append(s)
        return np.array(out)

    cands = fibonacci_sphere(2 * n_candidates)
    cands = cands[cands @ up > 0.05]
    scores = score_dirs(cands)
    best = cands[np.argmin(scores)]
    spread_deg = direction_uncertainty_deg(cands, scores, best)
    med = float(np.median(scores))
    contrast = float((med - scores.min()) / max(med, 1e-12))
    # refine: a finer spiral inside a cone around the coarse winner
    step_deg = np.rad2deg(np.sqrt(4 * np.pi / (2 * n_candidates)))
    fine = cone_directions(best, 1.5 * step_deg, 40, seed=0)
    fine = np.concatenate([best[None], fine[fine @ up > 0.02]])
    fs = score_dirs(fine)
    best = fine[np.argmin(fs)]
    if not np.isfinite(contrast) or contrast < flat_threshold:
        return prior(f"light direction unconstrained: flat score landscape "
                     f"(contrast {contrast:.3g} < {flat_threshold}), normal spread {spread:.3g}")

    # softness: refit with cone-averaged visibility
    radii = SOFTNESS_CANDIDATES_DEG if softness_deg is None else (float(softness_deg),)
    fits = []
    for r in radii:
        dirs = cone_directions(best, r, cone_samples if r > 0 else 1, seed=seed)
        dt = direct_term(P, Nrm, dirs, d, cam, march_visibility, **march)
        coef, s = _fit_candidate(basis, dt, Y, ridge)
        fits.append((s, r, dt))
    # prefer the crisper light unless a softer one is clearly better (1%)
    s_best = min(f[0] for f in fits)
    s_r, radius, dt = next(f for f in fits if f[0] <= s_best * 1.01 + 1e-12)
    # An uncertain direction is rendered as the average over its plausible directions:
    # a wider cone, i.e. a softer and lighter shadow, rather than a crisp shadow that
    # may point the wrong way (the expected image under the uncertainty). The light's
    # strength is fitted with that same cone, so the render stays consistent with it.
    uncertainty = spread_deg if softness_deg is None else 0.0
    cone = min(max(radius, uncertainty), MAX_SOFTNESS_DEG)
    if cone > radius:
        dirs = cone_directions(best, cone, cone_samples, seed=seed)
        dt = direct_term(P, Nrm, dirs, d, cam, march_visibility, **march)

    # per-channel final fit (same design, same IRLS) with I >= 0
    # (symmetric here: the asymmetry ranks directions; the light's strength and the
    # ambient share must not be biased toward the brightest pixels)
    coefs = np.stack([_fit_candidate(basis, dt, S[:, c], ridge, dark_weight=1.0)[0] for c in range(3)], 1)
    inten = np.maximum(coefs[4], 0.0)
    sh_c = coefs[:4]
    amb_up = float(np.maximum(sh_basis(up[None]) @ sh_c, 0).mean())
    dir_up = float(inten.mean() * max(best @ up, 0.0))
    share = amb_up / max(amb_up + dir_up, 1e-12)
    if inten.max() <= 0:
        return prior("no directional component found (fitted intensity 0)")
    return LightEstimate(best, inten, sh_c, float(share), float(radius), float(s_r),
                         contrast, spread, None, float(uncertainty))
