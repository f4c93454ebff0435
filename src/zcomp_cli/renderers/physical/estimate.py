"""The light from the photograph as one fit (DESIGN.md section 8).

The known shading is linear in the light: ``S(p) = sum_k w_k T_k(p) + bounce(p)``,
``w_k >= 0``, over a dictionary of atoms (``atoms``): sky lobes and the
lights -- suns (a direction and an angular radius) and lamps (a position) -- each
rendered with the renderer's own transport, shadows included. One robust NNLS
(``solver``) explains the shading; the lights are chosen greedily, each the candidate
that best explains **held-out** pixels (whole blocks of the frame the weights were not
fitted on), up to ``MAX_LIGHTS``, while each still improves them by ``MIN_GAIN``
(``held_out_gain``: the held-out loss of the dictionary without it over that with it,
minus 1, above the noise floor: a share, the same at any resolution). A lamp is a sun
with a position: it is taken over the best sun only when it improves on it by
``MIN_GAIN`` too.

Steps of ``estimate_light``:

1. the working copy and its fit pixels, the sky's visibility, the support's bounce, the
   albedo's offset (``atoms.albedo_offset``);
2. the base dictionary: the sky lobes;
3. each light: score every candidate (hemisphere directions with hard shadows, lamp
   positions: unshadowed first, then a shortlist with shadows), refine the best on a
   finer spiral, fit its size (a few angular radii, cone-averaged), keep it when the
   held-out gain reaches ``MIN_GAIN``;
4. the weights of the chosen dictionary, per colour channel (the lights' colours), with
   a ridge toward the prior split of sky and light where the pixels cannot tell them
   apart (a bare floor shades alike under any split);
5. the light model: direction, size, colour and the sun/sky split read off the weights.
   Without a light the held-out pixels ask for, the best candidate's light is spread
   over the directions the pixels allow (their tempered likelihood) into the sky: the
   object is shaded from the plausible side and casts a contact shadow only.

The direction's uncertainty is that same likelihood's RMS angle around the chosen
direction. Its temperature counts the held-out blocks, not pixels: residuals are
correlated within a block, so a block is one observation.

A manifest light freezes its atoms' parameters in the same solver (``known_light.fit_known``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from zcomp_cli.camera import Camera
from zcomp_cli.conventions import REC601
from zcomp_cli.renderers.physical import atoms as at
from zcomp_cli.renderers.physical import sh
from zcomp_cli.renderers.physical.lightmodel import (FitSummary, Lamp, LightModel, Origin, ShadowKind, Sky,
                                                     Sun)
from zcomp_cli.renderers.physical.sampling import fine_spiral, hemisphere, spacing_deg
from zcomp_cli.renderers.physical.settings import DEFAULTS, PhysicalSettings
from zcomp_cli.renderers.physical.solver import SIGMA_FLOOR, Atom, base_sigma, fit, score_candidates

# Calibrated by benchmarks/fit_light_constants.py on the development seeds (its output:
# docs/fit_light_constants.txt)
# (benchmarks/seeds.py): the least held-out gain for which a light's cast shadow is drawn,
# and the sky's share of the support's shading where the pixels do not fix the split.
MIN_GAIN = 0.05
PRIOR_SKY_SHARE = 0.46
# The ridge toward the prior split, per fit pixel over the data scale squared: a
# departure from the prior as large as the prior itself costs what a noise-floor
# residual on every pixel does; where the pixels tell the split (a shadow: a residual
# of tens of percent on its pixels) they decide. (A weaker ridge lets model errors
# decide a bare floor's split: docs/physical.md, "What was tried".)
PRIOR_RIDGE = SIGMA_FLOOR ** 2
MAX_LIGHTS = 3
# Angular radii (degrees) a sun's size is chosen among.
RADII_DEG = (0.0, 1.0, 2.0, 4.0, 8.0, 16.0)
# Lamp candidates: directions above the support's centre, distances in units of its
# median distance from the camera, the shortlist marched with shadows.
LAMP_DIRECTIONS = 60
LAMP_DISTANCES_REL = (0.3, 0.6, 1.2, 2.4)
LAMP_SHORTLIST = 8
# Lowest elevation of a sun candidate (a light in the ground's plane lights nothing on it).
MIN_ELEVATION_DEG = 2.0
FEW_PIXELS = 50


@dataclass
class FitLight:
    """A chosen light while the fit runs: ``kind`` sun/lamp, ``param`` direction or
    position, ``radius`` (deg for a sun, m for a lamp), its column, how its size came."""

    kind: str
    param: np.ndarray
    radius: float
    column: np.ndarray
    radius_from: Origin = Origin.FIT


@dataclass(frozen=True)
class Prepared:
    """Step 1's products: fit pixels, their shading (image over the albedo plus its
    offset) less the bounce (N, 3), the sky seen from them (``atoms.sky_visibility``),
    the ground's radiance (3,), the ground frame (3, 3), the albedo's offset."""

    fp: at.FitPixels
    shading: np.ndarray
    sky_vis: tuple
    ground: np.ndarray
    frame: np.ndarray
    albedo_offset: float = 0.0

    @property
    def lum(self) -> np.ndarray:
        return self.shading @ REC601.astype(np.float64)


def prepare(depth, normals, shading, known, albedo, camera: Camera, up, settings: PhysicalSettings) -> Prepared:
    """Step 1 (module docstring)."""
    from zcomp_cli.worldframe import ground_frame

    d, n, s, k, a, cam = at.working_copy(depth, normals, shading, known, albedo, camera, settings.max_resolution)
    fp, S = at.fit_pixels(d, n, s, k, a, cam, up, max_fit_pixels=settings.max_fit_pixels)
    frame = ground_frame(up)
    if len(fp) == 0:
        return Prepared(fp=fp, shading=S, sky_vis=(np.zeros((1, 0, 3)), np.zeros((1, 0))), ground=np.zeros(3),
                        frame=frame)
    ground = at.ground_radiance(fp, S)
    vis = at.sky_visibility(fp)
    S = np.maximum(S - at.bounce(fp, ground), 0.0)
    lobes = np.stack([at.sky_atom_values(fp, c, vis) for _, c in at.sky_lobes(frame)], 1)
    g = at.albedo_offset(fp, S, lobes) if fp.train.any() else 0.0
    return Prepared(fp=fp, shading=at.offset_shading(fp, S, g), sky_vis=vis, ground=ground, frame=frame,
                    albedo_offset=g)


def sky_atoms(pp: Prepared) -> list[Atom]:
    """Step 2: the sky lobes, grey."""
    return [Atom(name, at.sky_atom_values(pp.fp, c, pp.sky_vis)) for name, c in at.sky_lobes(pp.frame)]


def held_out_gain(loss_without: float, loss_with: float) -> float:
    """How much better a light explains the held-out pixels: the loss without it over
    the loss with it, minus 1, both above the noise floor (a residual of SIGMA_FLOOR of
    the data scale everywhere: exact data must not turn a negligible improvement into a
    large ratio)."""
    floor = 0.5 * SIGMA_FLOOR ** 2
    return (float(loss_without) - float(loss_with)) / (float(loss_with) + floor)


def held_out_blocks(fp: at.FitPixels) -> int:
    blk = max(fp.depth.shape) / at.HOLDOUT_BLOCKS
    held = ~fp.train
    ids = (fp.ys[held] // blk).astype(int) * (at.HOLDOUT_BLOCKS + 1) + (fp.xs[held] // blk).astype(int)
    return max(1, len(np.unique(ids)))


def tempered_likelihood(loss_held: np.ndarray, sigma_rel2: float, blocks: int) -> np.ndarray:
    """Likelihood weights of candidates from their held-out losses: each held-out block
    is one observation (``held_out_blocks``), the loss per pixel over the noise's
    (``sigma_rel2``, squared over the data scale) half its Gaussian log-likelihood."""
    lh = np.asarray(loss_held, np.float64)
    nll = blocks * (lh - lh.min()) / max(sigma_rel2, 1e-12)
    return np.exp(-np.minimum(nll, 700.0))


def _rms_angle(dirs: np.ndarray, weights: np.ndarray, best: np.ndarray) -> float:
    ang = np.arccos(np.clip(np.asarray(dirs) @ best, -1.0, 1.0))
    w = np.asarray(weights, np.float64)
    return float(np.degrees(math.sqrt(float((w * ang ** 2).sum() / max(w.sum(), 1e-300)))))


def _stack(cols) -> np.ndarray:
    return np.stack(cols, 1) if cols else np.zeros((0, 0))


class _Candidates:
    """The search's candidate lights and their columns, marched once per scene and
    reused by each light of the greedy search: the coarse suns (hard shadows), the lamp
    positions (unshadowed; the shadowed columns of a shortlist, as they are asked for)."""

    def __init__(self, pp: Prepared, settings: PhysicalSettings):
        fp = pp.fp
        self.steps = settings.estimate_march_steps
        self.suns = hemisphere(settings.n_light_candidates, fp.up, MIN_ELEVATION_DEG)
        self.sun_cols = at.sun_columns(fp, self.suns, steps=self.steps)
        self.lamps = at.lamp_candidates(fp, LAMP_DIRECTIONS, LAMP_DISTANCES_REL)
        self.lamp_cols0 = at.lamp_columns(fp, self.lamps)
        self._lamp_cols: dict[int, np.ndarray] = {}
        self.fp = fp

    def lamp_cols(self, idx) -> np.ndarray:
        todo = [int(i) for i in idx if int(i) not in self._lamp_cols]
        if todo:
            cols = at.lamp_columns(self.fp, self.lamps[todo], steps=self.steps)
            for k, i in enumerate(todo):
                self._lamp_cols[i] = cols[:, k]
        return np.stack([self._lamp_cols[int(i)] for i in idx], 1)


def _search_light(pp: Prepared, base: list[np.ndarray], cand: _Candidates, settings: PhysicalSettings,
                  seed: int, *, softness: float | None):
    """The best light to add to the grey columns ``base`` (step 3): returns (light,
    held-out loss with it, the coarse suns' held-out losses, the base's held-out loss,
    the noise scale squared over the data's)."""
    fp = pp.fp
    y = pp.lum
    B = _stack(base)
    scale = max(float(np.median(np.abs(y[fp.train]))), 1e-12)
    sig = base_sigma(B[fp.train], y[fp.train], scale=scale)
    zero = np.zeros((len(y), 1))
    l_base = float(score_candidates(B, zero, y, fp.train, sigma=sig)[0][0])
    steps = settings.estimate_march_steps
    lh_s, _ = score_candidates(B, cand.sun_cols, y, fp.train, sigma=sig)
    short = np.zeros(0, int)
    lh_l = np.full(1, np.inf)
    if LAMP_SHORTLIST > 0 and len(cand.lamps):
        lh_l0, _ = score_candidates(B, cand.lamp_cols0, y, fp.train, sigma=sig)
        short = np.argsort(lh_l0)[:LAMP_SHORTLIST]
        cl = cand.lamp_cols(short)
        lh_l, _ = score_candidates(B, cl, y, fp.train, sigma=sig)
    # a lamp is a sun with a position: it is kept only where it explains the held-out
    # pixels by MIN_GAIN better than the best sun (its extra freedom must pay for itself,
    # by the criterion a light pays for itself)
    if not np.isfinite(lh_l.min()) or held_out_gain(float(lh_s.min()), float(lh_l.min())) < MIN_GAIN:
        i = int(np.argmin(lh_s))
        fine = fine_spiral(cand.suns[i], 1.5 * spacing_deg(2 * settings.n_light_candidates), 40, up=fp.up)
        cf = at.sun_columns(fp, fine, steps=steps)
        lh_f, _ = score_candidates(B, cf, y, fp.train, sigma=sig)
        j = int(np.argmin(lh_f))
        light = FitLight("sun", fine[j], 0.0, cf[:, j])
        best_l = float(lh_f[j])
        # its size: the cone-averaged columns of a few radii
        radii = (float(softness),) if softness is not None else RADII_DEG
        cols = [at.sun_column(fp, light.param, r, steps=steps, cone_samples=settings.cone_samples, seed=seed)
                for r in radii]
        lh_r, _ = score_candidates(B, _stack(cols), y, fp.train, sigma=sig)
        k = int(np.argmin(lh_r))
        light = FitLight("sun", light.param, radii[k], cols[k],
                       Origin.MANIFEST if softness is not None else Origin.FIT)
        best_l = float(lh_r[k])
    else:
        i = int(np.argmin(lh_l))
        q = cand.lamps[short][i]
        light = FitLight("lamp", q, 0.0, cl[:, i], Origin.DEFAULT)
        best_l = float(lh_l[i])
    return light, best_l, lh_s, l_base, (sig / scale) ** 2


def prior_weights(atoms: list[Atom], pp: Prepared, light_names: list[str]) -> dict:
    """The prior weights: the support's level split by PRIOR_SKY_SHARE between the
    uniform sky and the lights (equally), nothing in the other lobes; a ``fixed`` atom
    (the manifest's lights in physical units) its own level's exposure."""
    fp = pp.fp
    sup = fp.support if fp.support.sum() >= 3 else np.ones(len(fp), bool)
    level = np.median(pp.shading[sup], axis=0)
    cols = {a.name: a.values for a in atoms}
    out = {}
    if "sky" in cols:
        unit = max(float(np.median(cols["sky"][sup])), 1e-9)
        out["sky"] = PRIOR_SKY_SHARE * level / unit
    for name in light_names:
        unit = float(np.median(cols[name][sup])) if name in cols else 0.0
        if unit > 1e-9:
            out[name] = (1.0 - PRIOR_SKY_SHARE) * level / unit / max(len(light_names), 1)
    if "fixed" in cols:
        f = np.asarray(cols["fixed"], np.float64)
        ratio = np.median(pp.shading[sup] / np.maximum(f[sup], 1e-9), axis=0)
        out["fixed"] = float(np.mean(ratio))
    return out


def sky_from_weights(pp: Prepared, weights: dict, extra_sh: np.ndarray | None = None) -> np.ndarray:
    """(9, 3) sky radiance SH from the lobes' RGB weights."""
    out = np.zeros((sh.N_COEFFS, 3))
    for name, c in at.sky_lobes(pp.frame):
        if name in weights:
            out += c[:, None] * np.asarray(weights[name])[None]
    return out if extra_sh is None else out + extra_sh


def estimate_light(depth, normals, shading, known, albedo, camera: Camera, *, up, up_from: Origin = Origin.SUPPORT,
                   settings: PhysicalSettings = DEFAULTS, seed: int = 0) -> LightModel:
    """The light of the photograph's known shading (module docstring).

    Args:
        depth: (H, W) z-depth, 0 invalid. normals: (H, W, 3) camera frame.
        shading: (H, W, 3) linear image / albedo, used where ``known`` (H, W) bool.
        albedo: (H, W, 3) linear albedo. camera: the view.
        up: (3,) world up, camera frame; ``up_from`` where it came from.
    Returns:
        LightModel (never raises on degenerate evidence: too few pixels give the prior).
    """
    up = np.asarray(up, np.float64)
    pp = prepare(depth, normals, shading, known, albedo, camera, up, settings)
    fp = pp.fp
    if len(fp) < FEW_PIXELS or fp.train.sum() < FEW_PIXELS // 2:
        return prior_model(pp, up, up_from, f"too few known pixels with geometry ({len(fp)} < {FEW_PIXELS})")
    base_atoms = sky_atoms(pp)
    base = [a.values for a in base_atoms]
    cand = _Candidates(pp, settings)
    lights: list[FitLight] = []
    coarse = None
    gain = 0.0
    first = None
    for i in range(MAX_LIGHTS):
        # (a light next to one already found is kept when it pays for itself: two close
        # lights stand for a wider or uneven one; keeping them apart cost the development
        # seeds 0.4 dB)
        light, l_new, lh_s, l_base, s2 = _search_light(
            pp, base + [x.column for x in lights], cand, settings, seed, softness=settings.shadow_softness)
        g = held_out_gain(l_base, l_new)
        if i == 0:
            coarse, first, gain = (cand.suns, lh_s, s2), light, g
        if g < MIN_GAIN:
            break
        lights.append(light)
    names = [f"light{i}" for i in range(len(lights))]
    cast = bool(lights)
    if not cast:
        lights, names = [first], ["light0"]
    fit_atoms = base_atoms + [Atom(n_, x.column) for n_, x in zip(names, lights)]
    res = fit(fit_atoms, pp.shading, train=fp.train, prior=prior_weights(fit_atoms, pp, names), ridge=PRIOR_RIDGE,
              direct=names)
    suns, lh_s, s2 = coarse
    post = tempered_likelihood(lh_s, s2, held_out_blocks(fp))
    key = first.param if first.kind == "sun" else _lamp_dir(first.param, fp)
    unc = _rms_angle(suns, post, key)
    summary = FitSummary(gain=float(gain), uncertainty_deg=unc, residual=float(res.loss_train),
                         pixels=len(fp), note="" if cast else (
                             f"the best light explains held-out pixels {100 * gain:.1f} % better than the sky "
                             f"alone (< {100 * MIN_GAIN:g} %): its direction is not fixed by the photograph "
                             f"(plausible directions within {unc:.0f} deg)"))
    if not cast:
        # the light spread over its plausible directions, into the sky, bringing the
        # support what the fitted light brought it
        w = np.asarray(res.weights["light0"])
        spread = sum(p * sh.directional_radiance(d, w) for p, d in zip(post / post.sum(), suns) if p > 1e-6)
        on_up = float(sh.evaluate(sh.shading_coeffs(spread), up[None])[0].mean())
        brought = float(np.median(first.column[fp.support])) if fp.support.any() else 0.0
        if on_up > 1e-12:
            spread = spread * (brought * float(w.mean()) / on_up)
        sky = Sky(radiance_sh=sky_from_weights(pp, res.weights, spread), ground=pp.ground, up=up)
        return LightModel(sky=sky, shadows=ShadowKind.CONTACT, up_from=up_from,
                          albedo_offset=pp.albedo_offset, walls=fp.walls, fit=summary)
    return model_from_fit(pp, res, lights, names, up, up_from, summary)


def _lamp_dir(q, fp: at.FitPixels) -> np.ndarray:
    pts = fp.points[fp.support] if fp.support.sum() >= 3 else fp.points
    v = np.asarray(q, np.float64) - np.median(pts, 0)
    return v / max(float(np.linalg.norm(v)), 1e-12)


def model_from_fit(pp: Prepared, res, lights: list[FitLight], names: list[str], up, up_from, summary,
           origin: Origin = Origin.FIT, source: str = "estimated") -> LightModel:
    suns, lamps = [], []
    for n_, x in zip(names, lights):
        w = np.asarray(res.weights[n_])
        if x.kind == "sun":
            suns.append(Sun(direction=x.param, radius_deg=x.radius, irradiance=w, direction_from=origin,
                            radius_from=x.radius_from, strength_from=Origin.FIT))
        else:
            lamps.append(Lamp(position=x.param, radius_m=x.radius, intensity=w, position_from=origin,
                              radius_from=x.radius_from, strength_from=Origin.FIT))
    sky = Sky(radiance_sh=sky_from_weights(pp, res.weights), ground=pp.ground, up=up)
    return LightModel(suns=tuple(suns), lamps=tuple(lamps), sky=sky, shadows=ShadowKind.CAST, source=source,
                      up_from=up_from, albedo_offset=pp.albedo_offset, walls=pp.fp.walls, fit=summary)


def prior_model(pp: Prepared, up, up_from, note: str) -> LightModel:
    """The prior's light where nothing can be fitted: the support's level (or 0.5) from
    a uniform sky, contact shadows."""
    fp = pp.fp
    level = (np.median(pp.shading[fp.support], 0) if fp.support.sum() >= 3
             else np.median(pp.shading, 0) if len(fp) else np.full(3, 0.5))
    lobe = dict(at.sky_lobes(pp.frame))["sky"]
    unit = max(float(sh.evaluate(sh.shading_coeffs(lobe[:, None]), np.asarray(up)[None])[0, 0]), 1e-9)
    sky = Sky(radiance_sh=lobe[:, None] * (level / unit)[None], ground=pp.ground, up=up,
              strength_from=Origin.PRIOR)
    return LightModel(sky=sky, shadows=ShadowKind.CONTACT, up_from=up_from, albedo_offset=pp.albedo_offset,
                      walls=fp.walls, fit=FitSummary(note=note, pixels=len(fp)))


__all__ = ["estimate_light", "prepare", "sky_atoms", "prior_model", "MIN_GAIN", "PRIOR_SKY_SHARE", "MAX_LIGHTS",
           "RADII_DEG"]
