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
from zcomp_cli.conventions import DEFAULT_SEED, REC601, luminance
from zcomp_cli.renderers.physical.evidence import (DARK_LEVEL, EVIDENCE_TAU, ao_corrected_band, darkness_map,
                                                   evidence_sample, evidence_scores)
from zcomp_cli.renderers.physical.nearlamp import fit_near_lamp
from zcomp_cli.renderers.physical.shading import cone_directions, direct_term, sh_basis
from zcomp_cli.renderers.physical.visibility import march_visibility

# Angular radius (degrees) a key light is drawn with: its size is not measured. The fit
# of the image's shading against cones of 0-30 deg (the earlier way) chose 30 deg on 11
# of the 64 scenes of seeds 7777 and 8128, whose suns and lamps are 0.4-14 deg: faint,
# spread shadows: a wide cone also smooths away what the screen-space shadows get wrong and
# the ambient occlusion the order-1 SH cannot hold. A fit of the penumbrae alone
# (predicted against measured darkness across the shadows' edges, at the estimation
# copy's 160 pixels) had edges to read on 2 of those scenes and read 12 deg for 1.9 and
# 5 deg lights. Chosen on seed 8128: 3 and 8 deg gave 33.41 and 33.45 dB, shadow IoU
# 0.397 and 0.404, darkness error 0.166 and 0.163 (the fit: 33.38, 0.400, 0.164).
KEY_SOFTNESS_DEG = 8.0
# Where the radius came from when the caller gives it (``softness_deg``), for the report.
GIVEN_SOFTNESS_SOURCE = "given (the renderer's shadow_softness)"
# Where the prior's radius came from (no light estimated, none given).
PRIOR_SOFTNESS_SOURCE = "prior (not measured)"
PRIOR_SOFTNESS_DEG = 15.0
PRIOR_AMBIENT_SHARE = 0.4
# Pixels in shadow (and lit) on the dominant surface needed to read the ambient share
# directly from them.
MIN_SHADOW_PIXELS = 15
# Cast-shadow evidence (pixels of full darkness at the estimation resolution, see
# ``evidence``) needed to take the direction from the shadows of visible geometry.
MIN_EVIDENCE_PX = 8.0
# Normal spread (second eigenvalue's sqrt) from which shading vs orientation alone is
# trusted for the direction of a cast shadow.
MIN_NORMAL_SPREAD = 0.3
# Shading against orientation is trusted for a cast shadow when its plausible directions
# (``direction_uncertainty_deg``) spread no more than this.
MAX_TRUSTED_SPREAD_DEG = 25.0
# Too little cast-shadow evidence to pick the direction alone, but enough to confirm the
# shading's: the two cues are independent (cast shadows of the visible geometry vs
# shading against orientation), so when the best direction of the cast-shadow evidence
# (crease band included, ``ao_corrected_band``) lies within AGREE_DEG of the shading's,
# the direction is trusted for a cast shadow. Seed 123: no case confirmed; the nearest
# wrong agreements were 18 deg (1.99 px, light 81 deg off) and 25 deg (a wall's foot,
# 144 px, 63 deg off: a straight shadow fits a family of directions), hence 10 deg.
# (Taking the best evidence within AGREE_DEG instead of the argmax confirmed that wall.)
# The two directions are then averaged, as for the relaxed agreement below: two
# independent estimates of one light (the analytic box under a high sun: 5.7 -> 4.3 deg
# at 112x84, 9.5 -> 7.7 at 160x120; the dev seeds 1618, 7777 and 8128 within 0.02 dB).
MIN_AGREE_EVIDENCE_PX = 1.0
AGREE_DEG = 10.0
# A looser agreement for the shadow of a compact occluder at its base: 3-30 px of band
# evidence (a box's short shadow; a wall's foot gave 41-144 px and a family of
# directions) within RELAXED_AGREE_DEG of the shading's. The two directions are then
# averaged. On seeds 123, 8128, 27182, 5077, 6091, 7321 and 4242 that admitted 8 scenes,
# their averaged directions 6-25 deg off (median 7), where the shading's alone were 1-32;
# the nearest wrong agreements left out are at 1.99 px (seed 123, 18 deg) and 25.4 deg
# (seed 123's wall, 144 px).
RELAXED_AGREE_DEG = 22.0
RELAXED_BAND_PX = (3.0, 30.0)
# Least ambient share kept when no cast shadow measured it, for a direction not trusted
# to cast a shadow (the contact-shadow fallback; calibrated on seed 123): it keeps the
# object's shading safe from that direction's error. 0.3 there (with MIN_CAST's value)
# cost report seed 4711 0.23 dB, 4.9 dB on one scene whose shading's direction was off.
MIN_FIT_AMBIENT_SHARE = 0.6
# The same for a direction that casts its shadow (given in the manifest, confirmed by
# cast shadows, or trusted from the shading) whose shadow the photo does not measure.
# 0.6 drew those shadows faint: on seed 8128 given the true directions, where the
# object's shadow overlaps the true one, it kept 0.72 of the background (mean over the
# cases) where the truth kept 0.57. Chosen on seed 8128 given the true directions: 0.6
# gave 33.70 dB, darkness error 0.156; 0.45: 34.07, 0.149; 0.3: 34.16, 0.145; 0.2:
# 34.11, 0.144.
MIN_CAST_AMBIENT_SHARE = 0.3
# Least elevation of a direction taken from shading alone (no cast shadow). On a floor
# the shading hardly constrains the elevation (n.l is one constant there, which the
# ambient absorbs): a fit that goes grazing is unconstrained rather than measured, and
# the middle of a key light's plausible elevations (15-75 deg) errs least. Calibrated on
# seeds 27182, 123, 31415 (median error over all cases' visible lights 40/42/48 deg at
# 30, 35/35/38 at 45, 36/32/33 at 60).
MIN_FIT_ELEVATION_DEG = 45.0
# A second light (two lamps; a lamp and a sunlit window) is taken when the cast-shadow
# evidence the first light leaves unexplained picks a direction this far from it (its
# shadow is another shadow, not the first one's penumbra or a refinement of it).
SECOND_LIGHT_SEP_DEG = 25.0
# A second light is fainter: its shadow keeps more of the lit level (the first light
# still reaches it), so its pixels count from the shadow metric's 10 % darkening.
SECOND_LIGHT_TAU = 0.1
# A lamp read from the support's falloff stands beside the photo's cast shadows when,
# seen from the pixels they darken, it lies within this angle of their direction; else
# the shadows decide.
LAMP_AGREE_DEG = 25.0
# Angular radius a lamp near the scene is drawn with (its size is not measured). On the
# 10 lamp-lit scenes of seed 8128, PSNR / shadow IoU: 32.13 dB / 0.47 with the softness
# refit (0 deg on 8), 33.30 / 0.54 at 3 deg, 33.82 / 0.60 at 8, 33.40 / 0.61 at 15.
LAMP_SOFTNESS_DEG = 8.0
# The ambient keeps at least this share of the lit support when the lights' measured
# shadows add up to more direct light than the support receives.
MIN_SPLIT_AMBIENT_SHARE = 0.05


@dataclass
class ExtraLight:
    """A further directional light beside ``LightEstimate.direction``: direction (3,)
    camera frame, toward it; intensity (3,) RGB; softness_deg its angular radius;
    shadow_ratio the level of its shadow over the lit level on the support (what stays
    where only this light is blocked); direction_source and share_source say where they
    came from."""

    direction: np.ndarray
    intensity: np.ndarray
    softness_deg: float
    shadow_ratio: float
    direction_source: str
    share_source: str

    @property
    def cone_deg(self) -> float:
        """Angular radius the shadow is rendered with (as ``LightEstimate.cone_deg``)."""
        return float(min(self.softness_deg, MAX_SOFTNESS_DEG))


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
    share_source: str = "prior"
    source: str = "estimated"
    evidence_px: float = 0.0  # the best direction's cast-shadow evidence away from creases (px)
    direction_source: str = "prior"
    extra_lights: tuple = ()  # ExtraLight, each drawn with its own shadow
    # a lamp near the scene (``nearlamp``): (3,) camera-frame position, and the support's
    # centre ``direction`` points from; the renderer aims the light at each object
    lamp_position: np.ndarray | None = None
    lamp_aim: np.ndarray | None = None
    softness_source: str = PRIOR_SOFTNESS_SOURCE
    band_evidence_px: float = 0.0  # evidence_px with the crease band counted (``ao_corrected_band``)

    @property
    def cone_deg(self) -> float:
        """Angular radius the shadow is rendered with: the light's own fitted size. The
        direction's uncertainty is reported but does not widen the shadow: averaging
        the possible shadows of an uncertain light made them faint (a shadow that keeps
        87% of the background where the truth keeps 25%); an unconstrained direction
        is rendered as a contact shadow instead (``fallback``)."""
        return float(min(self.softness_deg, MAX_SOFTNESS_DEG))

    def to_info(self) -> dict:
        d = asdict(self)
        d["cone_deg"] = self.cone_deg
        d.pop("extra_lights")
        d = {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in d.items()}
        # the light model as separate lights: a directional one and the sky (ambient)
        d["lights"] = [
            {"kind": "directional", "source": self.source, "direction_camera": d["direction"],
             "direction_from": self.direction_source, "intensity_rgb": d["intensity"],
             "angular_radius_deg": self.cone_deg, "angular_radius_from": self.softness_source,
             "shadow": "contact shadow only" if self.fallback else "cast shadow"},
            *({"kind": "directional", "source": self.source, "direction_camera": np.asarray(x.direction).tolist(),
               "direction_from": x.direction_source, "intensity_rgb": np.asarray(x.intensity).tolist(),
               "angular_radius_deg": x.cone_deg, "shadow": "cast shadow",
               "shadow_ratio": float(x.shadow_ratio), "shadow_ratio_from": x.share_source}
              for x in self.extra_lights),
            {"kind": "ambient (sky, order-1 SH)", "sh_rgb": d["ambient_sh"],
             "share_on_support": self.ambient_share, "share_from": self.share_source},
        ]
        return d


def fibonacci_sphere(n: int) -> np.ndarray:
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    r = np.sqrt(np.maximum(0, 1 - z * z))
    ph = i * np.pi * (3 - np.sqrt(5))
    return np.stack([r * np.cos(ph), r * np.sin(ph), z], 1)


def dominant_normal(normals: np.ndarray) -> np.ndarray:
    """The most common orientation of (N, 3) unit normals, as the support's normal; the
    camera's +y when none is within 60 deg of it."""
    up = np.array([0.0, 1.0, 0.0])
    if len(normals) < 3:
        return up
    bins = fibonacci_sphere(200)
    votes = (normals @ bins.T > np.cos(np.deg2rad(15))).sum(0)
    dom = normals[normals @ bins[votes.argmax()] > np.cos(np.deg2rad(15))].mean(0)
    dom /= max(np.linalg.norm(dom), 1e-12)
    return dom if dom @ up > 0.5 else up


# Screen-space visibility can only MISS occluders (outside the frame, or hidden behind
# other surfaces), never invent them: a pixel darker than the model predicts may sit in
# the shadow of something unseen, but a pixel brighter than predicted contradicts the
# light. Residuals on the dark side therefore weigh this much less, in the fit and in
# the score that ranks light directions.
DARK_RESIDUAL_WEIGHT = 0.25
# The robust scale is at least SIGMA_FLOOR of the data scale (render noise; exact
# synthetic data has none, and a vanishing scale makes every residual an outlier).
# (A redescending dark side -- too-dark pixels leaving the fit entirely -- was tried:
# screen-space shadows are imperfect even for the true light, and it then preferred
# directions predicting little shadow at all.)
SIGMA_FLOOR = 0.02


def _weights_and_loss(r, scale, dark_weight, axis=0):
    """IRLS weights and per-pixel loss of residuals ``r`` (N,) or (N, C): Huber, with
    ``dark_weight`` on the dark side."""
    s = np.maximum(1.4826 * np.median(np.abs(r), axis=axis), SIGMA_FLOOR * scale)
    c = 1.345 * s
    a = np.abs(r)
    side = np.where(r < 0, dark_weight, 1.0)
    w = side * np.where(a <= c, 1.0, c / np.maximum(a, 1e-12))
    loss = side * np.where(a <= c, 0.5 * a * a, c * (a - 0.5 * c))
    return w, loss

def _ambient_given_light(basis, S, inten, dt, ridge, up, amb_f) -> np.ndarray:
    """The ambient's SH coefficients (4 x 3) refitted with the directional light fixed
    (``inten`` per channel times the direct term ``dt``), so other orientations stay
    consistent; then its constant shifted so the ambient on the support (``up``) is the
    measured shadow level ``amb_f``."""
    ridge4 = np.array([0.0, ridge, ridge, ridge])
    sh_c = np.stack([_robust_fit(basis, S[:, c] - inten[c] * dt, ridge4, dark_weight=1.0)[0]
                     for c in range(3)], 1)
    sh_c[0] += amb_f - (sh_basis(up[None]) @ sh_c)[0]
    return sh_c



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
        w, loss = _weights_and_loss(r, scale, dark_weight)
    # Huber loss normalised by the data scale: comparable across candidates.
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


def _robust_fit_batch(basis, direct, y, ridge_lin, iters=4, dark_weight=None) -> np.ndarray:
    """``_fit_candidate``'s score for C candidates at once (the same asymmetric
    Huber-IRLS ridge fit, batched normal equations). basis (N, 4), direct (N, C), y (N,).
    Returns (C,) scores."""
    dark_weight = DARK_RESIDUAL_WEIGHT if dark_weight is None else dark_weight
    N, C = direct.shape
    B = basis
    scale = max(np.median(np.abs(y)), 1e-6)
    ridge = np.array([0.0, ridge_lin, ridge_lin, ridge_lin, 0.0]) * N
    w = np.ones((N, C))
    BB = (B[:, :, None] * B[:, None, :]).reshape(N, 16)
    By = B * y[:, None]
    for _ in range(iters):
        # weighted Gram matrices of all candidates as plain matrix products
        wd = w * direct
        A = np.empty((C, 5, 5))
        A[:, :4, :4] = (BB.T @ w).T.reshape(C, 4, 4)
        bd = (B.T @ wd).T
        A[:, :4, 4] = bd
        A[:, 4, :4] = bd
        A[:, 4, 4] = (wd * direct).sum(0)
        A += np.diag(ridge + 1e-9)[None]
        rhs = np.empty((C, 5))
        rhs[:, :4] = (By.T @ w).T
        rhs[:, 4] = wd.T @ y
        coef = np.linalg.solve(A, rhs[..., None])[..., 0]
        # I >= 0: a negative light is the ambient-only fit
        coef[coef[:, 4] < 0, 4] = 0.0
        r = y[:, None] - B @ coef[:, :4].T - direct * coef[:, 4][None]
        w, loss = _weights_and_loss(r, scale, dark_weight)
    return loss.mean(0) / scale ** 2


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


def _fine_spiral(b: np.ndarray, step_deg: float, up: np.ndarray, keep: np.ndarray | None = None) -> np.ndarray:
    """``b`` and 40 directions around it within 1.5 coarse steps, above the support
    (and where ``keep`` of them, a function of the directions, says so): the refinement
    of a coarse search's best candidate."""
    fine = cone_directions(b, 1.5 * step_deg, 40, seed=0)
    ok = fine @ up > 0.02
    if keep is not None:
        ok &= keep(fine)
    return np.concatenate([b[None], fine[ok]])


def _second_light(best, cands, Pe, Ne, Ee, ew, d, cam, up, march_steps, step_deg):
    """The direction of a second light, or None: the candidate at least
    SECOND_LIGHT_SEP_DEG from ``best`` that explains the most cast-shadow evidence
    left where ``best`` predicts no shadow, when that is at least MIN_EVIDENCE_PX."""
    if len(Pe) == 0:
        return None
    explained = (march_visibility(Pe, Ne, best, d, cam, steps=march_steps) < 0.5) & ((Ne @ best) > 0.05)
    far = cands[cands @ best < np.cos(np.deg2rad(SECOND_LIGHT_SEP_DEG))]
    w = ew * ~explained
    if len(far) == 0 or not w.any():
        return None
    ev = evidence_scores(Pe, Ne, Ee, w, far, d, cam, steps=march_steps, tau=SECOND_LIGHT_TAU)
    if ev.max() < MIN_EVIDENCE_PX:
        return None
    b = far[int(np.argmax(ev))]
    fine = _fine_spiral(b, step_deg, up, keep=lambda f: f @ best < np.cos(np.deg2rad(SECOND_LIGHT_SEP_DEG)))
    return fine[int(np.argmax(evidence_scores(Pe, Ne, Ee, w, fine, d, cam, steps=march_steps,
                                              tau=SECOND_LIGHT_TAU)))]


def shadow_level(e: np.ndarray, predicted: np.ndarray) -> float | None:
    """Level a light's shadow keeps of the lit surface: the median of ``1 - e`` over the
    ``predicted`` shadow pixels that are dark (``e > DARK_LEVEL``), or None with fewer
    than MIN_SHADOW_PIXELS of them.

    Why only the dark ones: a screen-space march extrudes each visible occluder
    endlessly behind its front face, so its predicted shadow spills onto lit floor (and
    a lamp near the scene, taken as directional, puts a wall's shadow where its light
    still falls). Over the whole prediction the median read the lit floor: on three
    scenes of seed 8128 given the true direction, ambient shares of 0.81-0.98 where the
    inserted object's true shadow kept 0.45-0.56 in its darkest tenth. The darkness of
    the pixels that are in shadow is the shadow's.

    Args:
        e: (N,) relative darkness (``evidence.darkness_map``) of evidence samples, every
            pixel darker than DARK_LEVEL among them (``evidence_sample``).
        predicted: (N,) bool, the samples the light's shadow covers.
    """
    dark = predicted & (e > DARK_LEVEL)
    if dark.sum() < MIN_SHADOW_PIXELS:
        return None
    return float(np.clip(np.median(1.0 - e[dark]), 0.02, 1.0))


def _split_lights(best, radius, dt, extra_dirs, share, P, Nrm, S, basis, Pe, Ne, Ee, d, cam, up,
                  march_steps, ridge, extra_source, strict=False):
    """Split the support's lit level between several lights and the ambient.

    Where only light i is blocked the support keeps ``r_i`` of its lit level ``L``, so
    light i brings ``(1 - r_i) L`` and the ambient what is left. Each ``r_i`` is read
    on the evidence pixels in that light's shadow alone. A light without them gets an
    equal part, ``(1 - share) / K`` of the K lights, of the direct light the single-light
    fit found (``share`` its ambient share): K unmeasured lights together bring what one
    light did, and the ambient keeps ``share``. (Each one taken as bright as the single
    light made the ambient ``1 - K (1 - share)``: 0.2 for two manifest lights on a bare
    floor, shadows twice as dark as the photo's.)
    ``strict`` (an estimated second light): None unless every further light's shadow
    was measured and the shadows are consistent, ``sum (1 - r_i) <= 1 -
    MIN_SPLIT_AMBIENT_SHARE``. A "second light" whose shadows are darker than the
    first light leaves room for is the first light's shadow of something unseen (an
    occluder outside the frame) that a visible occluder happens to line up with.
    Returns (first light's intensity (3,), ambient SH (4, 3), ambient share on the
    support, tuple of ExtraLight), or None."""
    dirs = [best, *[np.asarray(x, np.float64) for x in extra_dirs]]
    cos15 = np.cos(np.deg2rad(15))
    on_dom = Ne @ up > cos15
    blocked = [(march_visibility(Pe, Ne, l, d, cam, steps=march_steps) < 0.5) & ((Ne @ l) > 0.05)
               if len(Pe) else np.zeros(0, bool) for l in dirs]
    ratios, sources = [], []
    for i in range(len(dirs)):
        alone = on_dom & blocked[i]
        for j in range(len(dirs)):
            if j != i:
                alone &= ~blocked[j]
        level = shadow_level(Ee, alone)
        if level is not None:
            ratios.append(level)
            sources.append("its cast shadows vs the same surface around them")
        elif strict and i > 0:
            return None
        else:
            ratios.append(1.0 - (1.0 - float(share)) / len(dirs))
            sources.append(f"none measured: 1/{len(dirs)} of the single-light fit's direct light")
    dts = [dt] + [direct_term(P, Nrm, l[None], d, cam, march_visibility, steps=march_steps) for l in dirs[1:]]
    on_up = Nrm @ up > cos15
    lit = on_up.copy()
    for l, t in zip(dirs, dts):
        ndl = np.maximum(Nrm @ l, 0.0)
        lit &= np.where(ndl > 1e-3, t / np.maximum(ndl, 1e-3), 1.0) > 0.8
    pick = lit if lit.sum() >= MIN_SHADOW_PIXELS else (on_up if on_up.sum() >= MIN_SHADOW_PIXELS
                                                       else np.ones(len(S), bool))
    L = np.median(S[pick], 0)
    direct = np.array([(1.0 - r) for r in ratios])  # fractions of L
    if direct.sum() > 1.0 - MIN_SPLIT_AMBIENT_SHARE:
        if strict:
            return None
        direct *= (1.0 - MIN_SPLIT_AMBIENT_SHARE) / direct.sum()
    amb = (1.0 - direct.sum()) * L
    intens = [direct[i] * L / float(max(l @ up, 0.05)) for i, l in enumerate(dirs)]
    rest = S - sum(intens[i][None, :] * dts[i][:, None] for i in range(1, len(dirs)))
    sh_c = _ambient_given_light(basis, rest, intens[0], dts[0], ridge, up, amb)
    extras = tuple(ExtraLight(l, intens[i + 1], float(radius), ratios[i + 1], extra_source, sources[i + 1])
                   for i, l in enumerate(dirs[1:]))
    return intens[0], sh_c, float(1.0 - direct.sum()), extras


def estimate_lighting(depth, normals, shading, known, camera: Camera, *,
                      n_candidates: int = 256, max_resolution: int = 160,
                      march_steps: int = 24, max_fit_pixels: int = 4000,
                      ridge: float = 0.05, cone_samples: int = 8,
                      softness_deg: float | None = None, flat_threshold: float = 0.02,
                      seed: int = DEFAULT_SEED, direction=None, albedo=None) -> LightEstimate:
    """Estimate a directional light (a second one where the cast shadows ask for it,
    ``extra_lights``; a lamp near the scene, ``lamp_position``, where the support's
    shading falls off from one, ``nearlamp``) + SH ambient from the known shading.

    Args:
        depth: (H, W) z-depth (0 invalid). normals: (H, W, 3) camera frame.
        shading: (H, W, 3) linear shading (used where ``known``). known: (H, W) bool.
        n_candidates: hemisphere candidate directions (coarse search; then refined).
        softness_deg: the light's angular radius (degrees), instead of KEY_SOFTNESS_DEG
            (a lamp near the scene: LAMP_SOFTNESS_DEG); it is not measured.
        flat_threshold: relative score contrast below which the direction is declared
            unconstrained and the prior is used.
        direction: (3,) or (K, 3) camera-frame directions toward the lights when they
            are known (a manifest light with ``strength: auto``): the search is skipped,
            the rest (ambient share, strengths, softness) is measured as for estimated
            directions; rows after the first become ``extra_lights``.
        albedo: (H, W, 3) linear albedo of the background, or None: the darkness of a
            pixel is then read against pixels of its own albedo too (a checker floor's
            tiles are no shadows, ``evidence.same_material_level``).
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
        up = dominant_normal(Nrm)
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
                             float("nan"), 0.0, spread, reason,
                             softness_source=(PRIOR_SOFTNESS_SOURCE if softness_deg is None
                                              else GIVEN_SOFTNESS_SOURCE))

    if len(idx) < 50:
        return prior(f"too few known pixels with valid geometry ({len(idx)} < 50)")

    basis = sh_basis(Nrm)
    hard = lambda l: direct_term(P, Nrm, l[None], d, cam, march_visibility, **march)

    def score_dirs(dirs, chunk=32):
        # all candidates of a chunk marched at once (one vectorised march, not one
        # Python loop per direction): the estimate's cost is dominated by these rays
        out = []
        for c0 in range(0, len(dirs), chunk):
            D = np.asarray(dirs[c0:c0 + chunk])
            C = len(D)
            ndl = np.maximum(Nrm @ D.T, 0.0)  # (N, C)
            Pr = np.repeat(P[None], C, 0).reshape(-1, 3)
            Nr = np.repeat(Nrm[None], C, 0).reshape(-1, 3)
            Lr = np.repeat(D, len(P), 0)
            live = ndl.T.reshape(-1) > 0
            v = np.zeros(len(Pr))
            if live.any():
                v[live] = march_visibility(Pr[live], Nr[live], Lr[live], d, cam, **march)
            dt = ndl * v.reshape(C, -1).T
            out.append(_robust_fit_batch(basis, dt, Y, ridge))
        return np.concatenate(out)

    cands = fibonacci_sphere(2 * n_candidates)
    cands = cands[cands @ up > 0.05]
    step_deg = np.rad2deg(np.sqrt(4 * np.pi / (2 * n_candidates)))

    # 0. A lamp near the scene: the support's shading falls off from the point under it
    #    (``nearlamp``). A sun's does not, and a floor's shading against orientation
    #    cannot place a light at all; the falloff can.
    alb_lum = None
    if albedo is not None:
        import cv2

        # the albedo at the estimation copy's size, as ``_downsample`` makes the shading
        a = np.nan_to_num(np.asarray(albedo, np.float32), nan=0.0, posinf=1.0, neginf=0.0)
        if a.shape[:2] != d.shape:
            a = cv2.resize(a, (d.shape[1], d.shape[0]), interpolation=cv2.INTER_AREA)
        alb_lum = luminance(a)
    on_up = Nrm @ up > np.cos(np.deg2rad(15))  # the support's fit pixels
    lamp = None
    if direction is None:
        lamp = fit_near_lamp(P[on_up], Y[on_up], up,
                             albedo=None if alb_lum is None else alb_lum.reshape(-1)[idx][on_up])
        if lamp is not None and not lamp.found:
            lamp = None
    near = lamp is not None
    # 1. Cast shadows of the visible geometry (``evidence``): where the candidate light
    #    puts them, is the surface darker than around? Unseen occluders' shadows add
    #    nothing to any candidate.
    lum0 = luminance(np.asarray(sh, np.float64))
    nvalid = np.where(valid[..., None], n / np.maximum(nn, 1e-12)[..., None], 0.0)
    lamp_note = ""
    while True:
        lum = lum0
        if near:
            # darkness against the lamp's falloff, not against a constant: the far
            # floor is not in shadow (read as one, it pointed the search 40-70 deg off
            # on the lamp-lit scenes of seed 8128)
            sup = valid & ((nvalid @ up) > np.cos(np.deg2rad(15)))
            if sup.any():
                model = lamp.support_shading(pts_all[sup])
                lum = lum0.copy()
                lum[sup] = lum0[sup] * float(np.median(model)) / np.maximum(model, 1e-9)
        e_map, usable, band = darkness_map(lum, nvalid, valid, up, d, albedo=alb_lum, return_band=True)
        ei, ew = evidence_sample(e_map, usable)
        Pe, Ne, Ee = pts_all.reshape(-1, 3)[ei], nvalid.reshape(-1, 3)[ei], e_map.ravel()[ei]
        # (a given direction needs no search: the darkness map still serves the share)
        ev = (evidence_scores(Pe, Ne, Ee, ew, cands, d, cam, steps=march_steps) if direction is None
              else np.zeros(0))
        evidence_px = float(ev.max()) if len(ev) else 0.0
        from_shadows = evidence_px >= MIN_EVIDENCE_PX
        if not (near and from_shadows):
            break
        # Cast shadows beside the lamp's falloff: seen from the shadowed pixels, the
        # lamp must lie along the shadows' direction, else the falloff was something
        # else -- gloss, a wall's occlusion -- and the shadows decide (seed 8128: a
        # sun-lit and a sky-lit scene whose falloff read as a lamp 70 and 105 deg from
        # their shadows' direction; the analytic lamp-and-box scene of the tests: 10).
        bd = cands[int(np.argmax(ev))]
        hit = (march_visibility(Pe, Ne, bd, d, cam, steps=march_steps) < 0.5) & (Ee > EVIDENCE_TAU) & ((Ne @ bd) > 0.05)
        at = Pe[hit].mean(0) if hit.any() else lamp.aim
        lamp_deg = float(np.degrees(np.arccos(np.clip(bd @ lamp.direction_at(at), -1.0, 1.0))))
        if lamp_deg <= LAMP_AGREE_DEG:
            break
        lamp_note = (f"; a falloff read as a lamp (span {lamp.falloff:.2f}) set aside: seen from "
                     f"the shadows, it is {lamp_deg:.3g} deg from their direction")
        lamp, near = None, False
    agree_deg, band_px = float("nan"), 0.0
    # the crease band's direction agrees with the shading's within AGREE_DEG, or within
    # the relaxed agreement; or it decides alone (shading branch only)
    agrees = relaxed = band_alone = False
    band_note, dt_band = "", None
    given = direction is not None
    extra_dirs: list = []
    if given or near:
        if given:
            D = np.asarray(direction, np.float64).reshape(-1, 3)
            D = D / np.maximum(np.linalg.norm(D, axis=1, keepdims=True), 1e-12)
            best, extra_dirs = D[0], list(D[1:])
        else:
            # (a lamp's shadows radiate from its foot: its cast shadows in the photo
            # are no directional light's, so the falloff decides over them)
            best = lamp.direction_at(lamp.aim)
        from_shadows, spread_deg, contrast = False, 0.0, float("nan")
        # the crease band's pixels count for the share: a shadow at its occluder's base
        e_band = ao_corrected_band(e_map, band, pts_all, nvalid, d, cam)
        bi, bw = evidence_sample(e_band, usable | band)
    elif from_shadows:
        best = cands[int(np.argmax(ev))]
        fine = _fine_spiral(best, step_deg, up)
        fe = evidence_scores(Pe, Ne, Ee, ew, fine, d, cam, steps=march_steps)
        best = fine[int(np.argmax(fe))]
        # plausible directions: those explaining nearly as much
        spread_deg = direction_uncertainty_deg(cands, -ev / max(evidence_px, 1e-9) + 2.0, best)
        contrast = float(evidence_px / max(valid.sum(), 1))
        second = _second_light(best, cands, Pe, Ne, Ee, ew, d, cam, up, march_steps, step_deg)
        if second is not None:
            extra_dirs.append(second)
    else:
        # 2. No cast shadow to read: the shading against orientation still says
        #    something about the light (for the object's shading), not enough for a
        #    shadow (rendered as a contact shadow, ``fallback``).
        scores = score_dirs(cands)
        best = cands[np.argmin(scores)]
        spread_deg = direction_uncertainty_deg(cands, scores, best)
        med = float(np.median(scores))
        contrast = float((med - scores.min()) / max(med, 1e-12))
        fine = _fine_spiral(best, step_deg, up)
        fs = score_dirs(fine)
        best = fine[np.argmin(fs)]
        # Confirmation: the evidence again, with the crease band counted for the
        # darkness that ambient occlusion does not explain (a shadow that starts at its
        # occluder's base: a box on the floor). The band alone does not pick the
        # direction (a wall's straight shadow along its foot fits a whole family of
        # directions); it confirms the shading's when both agree.
        e_band = ao_corrected_band(e_map, band, pts_all, nvalid, d, cam)
        bi, bw = evidence_sample(e_band, usable | band)
        evb = evidence_scores(pts_all.reshape(-1, 3)[bi], nvalid.reshape(-1, 3)[bi], e_band.ravel()[bi],
                              bw, cands, d, cam, steps=march_steps)
        band_dir = None
        if len(evb):
            band_px = float(evb.max())
            band_dir = cands[int(np.argmax(evb))]
            agree_deg = float(np.degrees(np.arccos(np.clip(best @ band_dir, -1.0, 1.0))))
        agrees = band_px >= MIN_AGREE_EVIDENCE_PX and agree_deg <= AGREE_DEG
        relaxed = (not agrees and RELAXED_BAND_PX[0] <= band_px <= RELAXED_BAND_PX[1]
                   and agree_deg <= RELAXED_AGREE_DEG)
        if not (agrees or relaxed) and band_px >= MIN_EVIDENCE_PX:
            # Where the two disagree, as much evidence at the base as a cast shadow
            # needs away from it decides alone: on a floor and a wall the shading
            # hardly pins the light (seed 1618 case 14: 23.5 px, the band's direction
            # 5 deg from the HDR map's sun, the shading's 35; case 19: 15 and 26 deg),
            # provided the shading fit finds the light along it -- a "shadow" that the
            # photo's shading says no light casts is something else (seed 1618 case 0:
            # a back wall's foot and a box cut by the frame, 108 deg off).
            Pb, Nb, Eb = pts_all.reshape(-1, 3)[bi], nvalid.reshape(-1, 3)[bi], e_band.ravel()[bi]
            fine = _fine_spiral(band_dir, step_deg, up)
            b_dir = fine[int(np.argmax(evidence_scores(Pb, Nb, Eb, bw, fine, d, cam, steps=march_steps)))]
            r = float(softness_deg) if softness_deg is not None else KEY_SOFTNESS_DEG
            dt_b = direct_term(P, Nrm, cone_directions(b_dir, r, cone_samples if r > 0 else 1, seed=seed),
                               d, cam, march_visibility, **march)
            if max(_fit_candidate(basis, dt_b, S[:, c], ridge, dark_weight=1.0)[0][4] for c in range(3)) > 0:
                best, band_alone, from_shadows, dt_band = b_dir, True, True, dt_b
                # the shadow's darkness is read on these pixels, as measured
                Pe, Ne, Ee = Pb, Nb, e_map.ravel()[bi]
                spread_deg = direction_uncertainty_deg(cands, -evb / max(band_px, 1e-9) + 2.0, best)
                contrast = float(band_px / max(valid.sum(), 1))
            else:
                band_note = (f"; the crease band's best direction ({band_px:.3g} px, {agree_deg:.3g} deg from "
                             "the shading's) set aside: the shading fit finds no light along it")
        if not band_alone and (not np.isfinite(contrast) or contrast < flat_threshold):
            return prior(f"light direction unconstrained: no cast shadow of visible geometry "
                         f"(evidence {evidence_px:.3g} px < {MIN_EVIDENCE_PX}) and a flat score landscape "
                         f"(contrast {contrast:.3g} < {flat_threshold}), normal spread {spread:.3g}")

    if relaxed or agrees:
        # two independent estimates of the same light: their mean
        best = best + band_dir
        best = best / np.linalg.norm(best)
    confirmed = given or near or agrees or relaxed
    if confirmed:
        # the shadow's darkness is read on the crease band too, as measured (a cast
        # shadow at its occluder's base is darkened by the occlusion as well)
        Pe, Ne, Ee = pts_all.reshape(-1, 3)[bi], nvalid.reshape(-1, 3)[bi], e_map.ravel()[bi]
    lifted = not from_shadows and not given and not near and best @ up < np.sin(np.deg2rad(MIN_FIT_ELEVATION_DEG))
    if lifted:
        # A grazing direction from shading alone fits the support with a huge intensity
        # that then floods the object's vertical faces (white objects on the fresh
        # benchmark): lift it to MIN_FIT_ELEVATION_DEG above the support.
        h = best - (best @ up) * up
        h = h / max(np.linalg.norm(h), 1e-12)
        e = np.deg2rad(MIN_FIT_ELEVATION_DEG)
        best = np.cos(e) * h + np.sin(e) * up
    # softness: the light's angular radius is not measured (KEY_SOFTNESS_DEG, a lamp's
    # LAMP_SOFTNESS_DEG) unless given
    radius = float(softness_deg) if softness_deg is not None else (LAMP_SOFTNESS_DEG if near else KEY_SOFTNESS_DEG)
    softness_src = (GIVEN_SOFTNESS_SOURCE if softness_deg is not None else
                    f"not measured: a lamp's {LAMP_SOFTNESS_DEG:g} deg" if near else
                    f"not measured: a key light's {KEY_SOFTNESS_DEG:g} deg")
    if dt_band is not None:  # (the same direction and radius, already marched)
        dt = dt_band
    else:
        dirs = cone_directions(best, radius, cone_samples if radius > 0 else 1, seed=seed)
        dt = direct_term(P, Nrm, dirs, d, cam, march_visibility, **march)
    s_r = _fit_candidate(basis, dt, Y, ridge)[1]
    # The direction's uncertainty is reported, but neither widens the shadow nor
    # enters the fit of the light's strength (that diluted the shadows).
    uncertainty = spread_deg if softness_deg is None else 0.0

    # per-channel final fit (same design, same IRLS) with I >= 0
    # (symmetric here: the asymmetry ranks directions; the light's strength and the
    # ambient share must not be biased toward the brightest pixels)
    coefs = np.stack([_fit_candidate(basis, dt, S[:, c], ridge, dark_weight=1.0)[0] for c in range(3)], 1)
    inten = np.maximum(coefs[4], 0.0)
    sh_c = coefs[:4]
    # (a lifted direction was chosen, not fitted: the fit along it may find no light, as
    # along a given one; it keeps its light with the minimum ambient share below, rather
    # than falling to the prior's direction and share)
    if inten.max() <= 0 and not given and not lifted and not near:
        return prior("no directional component found (fitted intensity 0)")
    # The ambient share straight from the evidence: on the dominant surface, the shading
    # of the pixels the model puts in shadow over that of the lit ones. On lit pixels
    # the directional term is linear in n like the SH ambient, so the regression alone
    # trades one for the other; the shadowed pixels are what pin the share down.
    ndl_fit = np.maximum(Nrm @ best, 0.0)
    frac = np.where(ndl_fit > 1e-3, dt / np.maximum(ndl_fit, 1e-3), 1.0)
    shadow_px, lit_px = on_up & (frac < 0.2), on_up & (frac > 0.8)
    cos_up = float(max(best @ up, 0.05))
    share_src = "fit"
    share_read = False  # from a cast shadow
    fit_only = True  # neither from a cast shadow nor from shadowed vs lit pixels
    if near:
        # The lamp's own split: its fit's ambient A over the lit level A + B g at the
        # support's centre. On the lamp-lit scenes of seeds 8128 and 27182 it was
        # 0.09-0.67 where the ground truth's umbra kept 0.04-0.48 of the background;
        # read on the predicted cast shadow (one direction for a lamp whose shadows
        # diverge) it was 0.73-0.94, and the minimum 0.6 where none was predicted.
        lit_aim = float(lamp.support_shading(lamp.aim[None])[0])
        ratio = float(np.clip(lamp.ambient / max(lit_aim, 1e-9), MIN_SPLIT_AMBIENT_SHARE, 1.0))
        sup_c = np.median(S[on_up], 0) if on_up.any() else np.median(S, 0)
        sup_y = float(np.median(Y[on_up])) if on_up.any() else float(np.median(Y))
        lit_c = sup_c * lit_aim / max(sup_y, 1e-9)
        amb_f = ratio * lit_c
        inten = np.maximum((lit_c - amb_f) / cos_up, 0.0)
        sh_c = _ambient_given_light(basis, S, inten, dt, ridge, up, amb_f)
        share_src = "the lamp's falloff: its ambient over the lit level at the support's centre"
        share_read, fit_only = True, False
    elif from_shadows or confirmed:
        # shadow / lit level of the same surface, read on the predicted cast shadow
        v_e = march_visibility(Pe, Ne, best, d, cam, steps=march_steps) < 0.5
        on_dom = (Ne @ up > np.cos(np.deg2rad(15))) & v_e & ((Ne @ best) > 0.05)
        ratio = shadow_level(Ee, on_dom)
        if ratio is not None:
            lit_c = np.median(S[lit_px], 0) if lit_px.sum() >= MIN_SHADOW_PIXELS else np.median(S[on_up], 0)
            amb_f = ratio * lit_c
            inten = np.maximum((lit_c - amb_f) / cos_up, 0.0)
            sh_c = _ambient_given_light(basis, S, inten, dt, ridge, up, amb_f)
            share_src = "cast shadows of visible geometry vs the same surface around them"
            share_read, fit_only = True, False
    if (not from_shadows and not share_read and shadow_px.sum() >= MIN_SHADOW_PIXELS
            and lit_px.sum() >= MIN_SHADOW_PIXELS):
        lit_c = np.median(S[lit_px], 0)
        shd_c = np.median(S[shadow_px], 0)
        shares = np.clip(shd_c / np.maximum(lit_c, 1e-9), 0.02, 1.0)
        amb_f = shares * lit_c
        inten = np.maximum((lit_c - amb_f) / cos_up, 0.0)
        sh_c = _ambient_given_light(basis, S, inten, dt, ridge, up, amb_f)
        share_src = "shadowed vs lit pixels of the dominant surface"
        fit_only = False
    amb_up = float(np.maximum(sh_basis(up[None]) @ sh_c, 0).mean())
    dir_up = float(inten.mean() * max(best @ up, 0.0))
    share = amb_up / max(amb_up + dir_up, 1e-12)
    # the fit sees no light along a given direction (a bare floor: its shading is the
    # same for any split of ambient and light)
    no_light_fitted = (given or lifted) and fit_only and share > 1.0 - 1e-3
    # Shading against orientation pins the direction only where several orientations
    # are seen (a room's walls and floor); on the calibration benchmark (floors, one
    # wall: spread <= 0.2) its directions were 30-100 deg off.
    # Nor does a narrow score landscape need several orientations: the plausible
    # directions lie within MAX_TRUSTED_SPREAD_DEG of the best (a box's lit and unlit
    # faces; seeds 5077 and 6091: the 3 of 39 such scenes within 25 deg were 3-8 deg off,
    # those within 25-35 deg 11-57 deg).
    sure = (not (from_shadows or given or near or lifted) and np.isfinite(spread_deg)
            and spread_deg <= MAX_TRUSTED_SPREAD_DEG)
    trusted = from_shadows or confirmed or sure or (spread >= MIN_NORMAL_SPREAD and contrast >= 0.1)
    # an untrusted direction draws no cast shadow (a contact shadow): its minimum keeps the
    # object's shading safe from the direction's error; a trusted one's keeps its shadow
    min_share = MIN_CAST_AMBIENT_SHARE if trusted else MIN_FIT_AMBIENT_SHARE
    if not (from_shadows or share_read) and (share < min_share or no_light_fitted):
        # Without a cast shadow the regression may put all the light in the directional
        # term (share 0): faces turned from a wrong direction then go black. Keep at
        # least min_share of the support's shading in the ambient.
        # (the level is the support's median shading: the regression's own split can
        # be wild -- a negative ambient against a huge light -- when shadows mislead it)
        # A given direction whose light the fit cannot see (a bare floor: its shading is
        # the same for any split) keeps its direction and gets the same split: the
        # manifest says there is a light, so it casts a shadow.
        cos_b = float(max(best @ up, 0.05))
        tot = np.median(S[on_up], 0) if on_up.sum() >= MIN_SHADOW_PIXELS else np.median(S, 0)
        sh_c = sh_c.copy()
        sh_c[0] += min_share * tot - (sh_basis(up[None]) @ sh_c)[0]
        inten = (1 - min_share) * tot / cos_b
        share = min_share
        share_src += (f" (no light along the {'given' if given else 'lifted'} direction: ambient share "
                      f"set to {min_share})" if no_light_fitted
                      else f" (raised to the minimum {min_share})")
    extras: tuple = ()
    if extra_dirs:
        # several lights: each one's strength from the darkness of its own shadow
        split = _split_lights(
            best, radius, dt, extra_dirs, share, P, Nrm, S, basis, Pe, Ne, Ee, d, cam, up, march_steps,
            ridge, "given (manifest)" if given else "cast shadows of visible geometry, left unexplained by the first light",
            strict=not given)
        if split is not None:
            inten, sh_c, share, extras = split
    fallback = None if trusted else (
        f"no cast shadow of visible geometry (evidence {evidence_px:.3g} px < {MIN_EVIDENCE_PX}; "
        f"with the crease band {band_px:.3g} px, its best direction {agree_deg:.3g} deg from the "
        f"shading's, more than {AGREE_DEG:g}): "
        "direction from shading vs orientation, shadow rendered as a contact shadow")
    return LightEstimate(best, inten, sh_c, float(share), float(radius), float(s_r),
                         contrast, spread, fallback, float(uncertainty), share_src,
                         evidence_px=evidence_px, band_evidence_px=band_px,
                         direction_source=("given (manifest)" if given else
                                           f"a lamp near the scene: the falloff of the support's shading "
                                           f"(span {lamp.falloff:.2f} of its median), lamp at "
                                           f"{np.round(lamp.position, 2).tolist()} (camera frame)" if near else
                                           "cast shadows of visible geometry" + (
                                               f" at their occluders' base ({band_px:.3g} px with the crease band, "
                                               f"{agree_deg:.3g} deg from the shading's direction)"
                                               if band_alone else "") if from_shadows
                                           else "shading vs surface orientation, confirmed by cast "
                                           f"shadows ({band_px:.3g} px with the crease band, their best direction "
                                           f"{agree_deg:.3g} deg away: the two averaged)"
                                           if confirmed else "shading vs surface orientation"
                                           + (f", its plausible directions within {spread_deg:.3g} deg" if sure
                                              else "")) + lamp_note + band_note,
                         extra_lights=extras,
                         lamp_position=None if lamp is None else lamp.position,
                         lamp_aim=None if lamp is None else lamp.aim, softness_source=softness_src)
