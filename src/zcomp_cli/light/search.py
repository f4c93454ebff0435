"""The light from the photograph's shadows and shading (DESIGN.md section 8, "The light
from the shadows").

Where a photograph shows cast shadows, they are what fixes the light's direction; the
shading of the rest of the frame says little about it and a great deal about things
the model does not hold (a floor's fall-off, an albedo error, a wall's bounce). So the
direction is read off the shadows first, the rest of the shading is a second, weaker
witness, and what neither fixes stays uncertain -- and the composite says so.

The steps (``fit.fit_light`` runs them on the scene ``prepare`` made, step 1, for a
light whose direction is free; each returns a dataclass; every constant is
``LightConfig``'s, with its provenance):

2. ``search_scorer``: the support's cast-shadow evidence (``evidence``: dark regions
   tied to the casters that stand on it) and the scorer of candidate lights;
3. ``search``: a grid of directions on the hemisphere, refined around the best; each
   scored by **two likelihoods** that multiply -- the support's shading under the
   shadow that direction casts (``shadowcast``: rays from the support's pixels) and the
   photometric fit of the whole frame (the sky lobes plus a sun of that direction,
   robust NNLS scored on held-out blocks) -- with a prior over the elevation
   (``search.elevation_prior_power``), into one **posterior** tempered by one constant
   (``search.temperature``). Each cue's weight is read off the case's own blocks
   (``cueweight``: the block bootstrap) and reported; whether the search weighs the
   cues by them (``search.cue_weights``), how much each cue, as a density, is mixed
   with the uniform (``search.gate``), the temperature and the prior's power are fitted
   by ``benchmarks/fit_light_constants.py`` with the log score of the true direction
   on hundreds of generated cases. A lamp is a sun with a distance: each direction's
   likelihood is marginalised over a sun and lamps along it from the caster's base;
4. ``choose_size``: a light's size, one rule for every sun and lamp: the likelihoods of
   its cone-averaged shadow among ``search.radii_deg`` and the Sun's own, the Sun's (a
   bulb's) where they cannot tell -- the penumbra's width says it, never the
   direction's doubt;
5. ``split_from_shadows``: the sun/sky split from the shadows themselves (the
   shadowed/lit ratio across the edges of the most probable light's shadow, Madsen and
   Nielsen), shrunk toward the prior split by the tied shadow that measurement stands
   on; one robust NNLS then fits the exposure and the sky's shape (``fit``);
6. the lights drawn: the posterior's modes (``DirectionPosterior.modes``), each a sun or
   a lamp of the mass it holds, all at the size step 4 chose, and the rest of the mass
   as sky, its radiance where that mass lies (a lamp's rest is shared among the lamps:
   a sky cannot stand for a near light) -- the expected shadow over the posterior, as
   far as its modes tell it. A confident posterior is one crisp light; a spread one its
   likely lights, each as faint as its mass, over the soft shade of the rest; never one
   light at a mean direction where the posterior may have no mass, nor one widened to
   stand for the doubt.

The posterior is mixed with the prior by the chance that the cues mislead together
(``search.misled``, ``posterior.with_misled``: a bias every pixel shares, which no
temperature mends without flattening the cases the cues get right); that share is
stated, not drawn (step 6). The stated uncertainty (``fit.direction_uncertainty_deg``) is
the RMS angle of the rest (``DirectionPosterior.informed``) about its mean direction,
beside that chance (``fit.misled``); the fit returns the posterior (``posterior.DirectionPosterior``)
for the audit (``benchmarks/audit_light.py``).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from zcomp_cli.light import atoms as at
from zcomp_cli.light.config import LightConfig
from zcomp_cli.light.cueweight import CueWeight, block_ids, block_sums, combined, cue_weight
from zcomp_cli.light.posterior import DirectionPosterior, log_integral
from zcomp_cli.light.prepare import Prepared
from zcomp_cli.light.shadowcast import shadow_fit, sun_visibility
from zcomp_cli.light.solver import base_sigma, candidate_losses
from zcomp_cli.scene.lightparams import LAMP_RADIUS_M, SUN_RADIUS_DEG, Origin
from zcomp_cli.scene.sampling import fine_spiral, hemisphere, spacing_deg
from zcomp_cli.threads import beside, map_over


@dataclass(frozen=True)
class FitLight:
    """A sun or lamp while the fit runs: ``kind`` sun/lamp, ``param`` direction or
    position (camera frame), ``radius`` (deg for a sun, m for a lamp; None: to be
    chosen), its ``column`` over the fit pixels (unit strength), how its size came, a
    lamp's panel ``facing`` (None: a sphere). Frozen: a step returns a new one."""

    kind: str
    param: np.ndarray
    radius: float | None
    column: np.ndarray
    radius_from: Origin = Origin.FIT
    facing: np.ndarray | None = None


def held_out_blocks(fp: at.FitPixels) -> int:
    blk = max(fp.depth.shape) / fp.blocks
    held = ~fp.train
    ids = (fp.ys[held] // blk).astype(int) * (fp.blocks + 1) + (fp.xs[held] // blk).astype(int)
    return max(1, len(np.unique(ids)))


def log_elevation_prior(dirs: np.ndarray, up, power: float) -> np.ndarray:
    """(K,) log density (per steradian, up to a constant) of the prior over directions,
    ``cos(elevation) ** -power``: ``power`` 1 is uniform in the elevation angle (a
    ninth of the light within 10 deg of the zenith), 0 uniform over the hemisphere
    (``search.elevation_prior_power``, fitted), bounded at 89 deg (a pole, not a
    spike)."""
    e = np.arcsin(np.clip(np.asarray(dirs, np.float64) @ np.asarray(up, np.float64), -1.0, 1.0))
    return -float(power) * np.log(np.maximum(np.cos(e), math.cos(math.radians(89.0))))


@dataclass(frozen=True)
class Search:
    """Step 3: the posterior over directions (``DirectionPosterior``), the unweighted
    scores it was made of (``scored``: ``Scored``; ``ll_shadow``, ``ll_photo`` the sun's),
    with the cues' measured ``weights`` and the options' prior (``log_opt_prior``), and
    per grid direction the shadowed/lit ratio its shadow fits and the shadow it casts
    on the receivers (blocks); the lights drawn (``modes``: (``FitLight``, its share of the light) per mode, heaviest first:
    a sun's share its mass, a lamp's its mass over ``mode_mass``, the modes' sum;
    ``light`` the heaviest; ``rest_sh`` (9,) the rest of the mass the suns stand for,
    as a sky's radiance SH per unit of the light's strength, camera frame, or None),
    the most probable light (``map_light``: what the split is read across) and the
    caster's base the lamps' directions are measured from (``anchor``)."""

    posterior: DirectionPosterior
    scored: "Scored"
    ratio: np.ndarray
    shadow_blocks: np.ndarray
    light: FitLight
    evidence: object
    receivers: object
    map_light: FitLight | None = None
    anchor: np.ndarray | None = None
    modes: tuple = ()
    mode_mass: float = 1.0
    rest_sh: np.ndarray | None = None
    weights: tuple = ()
    log_opt_prior: np.ndarray | None = None

    @property
    def ll_shadow(self) -> np.ndarray:
        """(K,) the sun's shadow log-likelihood at each grid direction, unweighted."""
        return self.scored.sun_shadow

    @property
    def ll_photo(self) -> np.ndarray:
        """(K,) the sun's photometric log-likelihood at each grid direction, unweighted."""
        return self.scored.sun_photo


@dataclass(frozen=True)
class _Shadow:
    """A scored shadow fit: (K,) log-likelihoods and shadowed/lit ratios; ``blocks``
    (n, K) the log-likelihoods' share of each block where asked (``suns_any_size``)."""

    loglik: np.ndarray
    ratio: np.ndarray
    blocks: np.ndarray | None = None


def softened(V: np.ndarray, dirs: np.ndarray, soft_deg: float) -> np.ndarray:
    """(R, K) each direction's visibility ``V`` (R, K) averaged with its neighbours'
    among ``dirs`` (K, 3, unit) within ``soft_deg`` degrees (itself included): the
    soft alternative of ``suns_any_size``. A sparse product: a direction has a handful
    of neighbours on the search's grids, and the dense (K, K) product was 5-8 % of the
    light estimate's time; the same values (each term is the one weight of its row)."""
    from scipy.sparse import csr_matrix

    D = np.asarray(dirs, np.float64).reshape(-1, 3)
    near = (D @ D.T >= math.cos(math.radians(soft_deg))).astype(np.float64)
    return np.asarray(np.asarray(V, np.float64) @ csr_matrix((near / near.sum(1, keepdims=True)).T))


class _Scorer:
    """Both likelihoods of candidate lights (module docstring, step 3), sharing the
    receivers, the base dictionary and the noise scales."""

    def __init__(self, pp: Prepared, evidence, settings: LightConfig):
        from zcomp_cli.light.shadowcast import receivers

        fp = pp.fp
        self.pp, self.fp, self.settings, self.evidence = pp, fp, settings, evidence
        self.rec = receivers(pp.grid.mesh, evidence, max_receivers=settings.max_receivers,
                             bias_rel=settings.search.bias_rel, blocks=settings.frame.holdout_blocks)
        self.y = pp.lum
        self.B = pp.lobe_columns
        self.scale = max(float(np.median(np.abs(self.y[fp.train]))), 1e-12)
        self.sig = base_sigma(self.B[fp.train], self.y[fp.train], scale=self.scale, cfg=settings.solver)
        self.blocks = held_out_blocks(fp)
        self.sigma = None  # the shadow fit's noise scale, set by the first (coarse) scoring
        self.photo_s2 = None  # the photometric fit's noise (over the data scale squared), likewise
        self.lh_ref = 0.0  # the held-out loss the photometric log-likelihoods are relative to, likewise
        # the blocks each receiver and each held-out pixel lie in (the units the cues'
        # weights resample: cueweight)
        self.rec_blocks = block_ids(self.rec.ys, self.rec.xs, pp.grid.mesh.shape, settings.search.weight_blocks)
        held = ~fp.train if (~fp.train).any() else fp.train
        self.held = held
        self.held_blocks = block_ids(fp.ys[held], fp.xs[held], fp.depth.shape, settings.search.weight_blocks)
        self.weights = None  # (shadow, photometric) CueWeight the cues are weighed by, set by set_weights
        self.measured = None  # and the ones their blocks bear out (the same where search.cue_weights is on)
        self.norms = (0.0, 0.0)  # each weighted cue's log normaliser over the grid (cueweight.gated)

    def suns(self, dirs, radius_deg: float = 0.0, seed: int = 0):
        """(shadow ShadowFit, photometric held-out losses (K,)) of suns toward ``dirs``."""
        from zcomp_cli.scene.sampling import cone_directions

        D = np.asarray(dirs, np.float64).reshape(-1, 3)
        if radius_deg > 0:
            k = self.settings.cone_samples
            V = np.zeros((len(self.rec), len(D)))
            C = np.zeros((len(self.fp), len(D)))
            for j, d in enumerate(D):
                V[:, j] = self.visibility("sun", d, radius_deg, seed)
                C[:, j] = at.sun_columns(self.fp, cone_directions(d, radius_deg, k, seed=seed),
                                         steps=self.settings.estimate_march_steps).mean(1)
        else:
            V = sun_visibility(self.pp.grid.caster, self.rec, D)
            C = at.sun_columns(self.fp, D, steps=self.settings.estimate_march_steps)
        lh = self.photo_losses(C)
        return self._scored(shadow_fit(self.rec, V, self.settings.search)), lh, C

    def suns_any_size(self, dirs):
        """``suns`` of hard shadows, the shadow likelihood marginalised over the light's
        size: a hard shadow, or one softened over ``search.soft_deg`` (each direction's
        visibility averaged with its neighbours' within that angle), each with
        probability 1/2. Returns (scored shadow fit, held-out losses, columns, hard
        visibility (R, K))."""
        D = np.asarray(dirs, np.float64).reshape(-1, 3)

        def photometric():
            C = at.sun_columns(self.fp, D, steps=self.settings.estimate_march_steps)
            return C, self.photo_losses(C, by_block=True)

        # the photometric cue on a second thread while this one traces the shadows (the
        # two read nothing of each other's)
        photo = beside(photometric)
        V = sun_visibility(self.pp.grid.caster, self.rec, D)
        hard = shadow_fit(self.rec, V, self.settings.search)
        soft = shadow_fit(self.rec, softened(V, D, self.settings.search.soft_deg), self.settings.search)
        if self.sigma is None:
            self.sigma = min(hard.best_sigma, soft.best_sigma)
        ids, n = self.rec_blocks
        (lhard, bhard), (lsoft, bsoft) = hard.block_loglik(self.sigma, ids, n), soft.block_loglik(self.sigma, ids, n)
        ll = np.logaddexp(lhard, lsoft) - math.log(2.0)
        is_soft = lsoft > lhard
        ratio = np.where(is_soft, soft.ratio, hard.ratio)
        # per block: the likelier of the two, the mixture's remainder shared evenly
        blk = np.where(is_soft[None], bsoft, bhard)
        blk += ((ll - np.maximum(lhard, lsoft)) / max(n, 1))[None]
        C, (lh, lh_blocks) = photo.result()
        return _Shadow(ll, ratio, blk), (lh, lh_blocks), C, V

    def lamps(self, positions):
        """(scored shadow fit, photometric held-out losses, columns) of point lamps at
        ``positions`` (K, 3)."""
        from zcomp_cli.light.shadowcast import lamp_visibility

        Q = np.asarray(positions, np.float64).reshape(-1, 3)

        def photometric():
            C = at.lamp_columns(self.fp, Q, steps=self.settings.estimate_march_steps)
            return C, self.photo_losses(C)

        photo = beside(photometric)  # (as suns_any_size: the cues apart)
        V = lamp_visibility(self.pp.grid.caster, self.rec, Q)
        scored = self._scored(shadow_fit(self.rec, V, self.settings.search))
        C, lh = photo.result()
        return scored, lh, C

    def lamp_sized(self, position, radius_m: float, facing=None):
        """(scored shadow fit, photometric held-out losses (1,)) of one lamp of radius
        ``radius_m`` at ``position`` (a panel facing ``facing``): its shadow averaged over
        ``cone_samples`` points of its sphere, its column ``lamp_column``'s."""
        q = np.asarray(position, np.float64)
        V = self.visibility("lamp", q, float(radius_m))[:, None]
        C = lamp_column(self.fp, q, float(radius_m), facing, self.settings, 0)[:, None]
        return self._scored(shadow_fit(self.rec, V, self.settings.search)), self.photo_losses(C)

    def visibility(self, kind: str, param, radius: float | None = None, seed: int = 0) -> np.ndarray:
        """(R,) how much of a light each receiver sees past the depth mesh: a sun
        (``param`` its direction) over ``cone_samples`` directions of its disc of
        ``radius`` degrees, a lamp (``param`` its position) over as many points of its
        sphere of ``radius`` metres; 1 or 0 for a point (``radius`` None, 0 or nan)."""
        from zcomp_cli.light.shadowcast import lamp_visibility
        from zcomp_cli.scene.sampling import cone_directions, fibonacci_sphere

        q = np.asarray(param, np.float64)
        k = max(1, self.settings.cone_samples)
        r = 0.0 if radius is None or not np.isfinite(radius) else float(radius)
        if kind == "sun":
            dirs = cone_directions(q, r, k, seed=seed) if r > 0 else q[None]
            return sun_visibility(self.pp.grid.caster, self.rec, dirs).mean(1)
        pts = q[None] + r * fibonacci_sphere(k) if r > 0 else q[None]
        return lamp_visibility(self.pp.grid.caster, self.rec, pts).mean(1)

    def _scored(self, fit_) -> "_Shadow":
        if self.sigma is None:
            self.sigma = fit_.best_sigma
        return _Shadow(fit_.loglik(self.sigma), fit_.ratio)

    def photo_losses(self, C, iters: int | None = None, by_block: bool = False):
        """(K,) the photometric held-out losses of candidate columns ``C`` (N, K): the
        base dictionary plus each, scored alike at the base's noise scale
        (``solver.candidate_losses``), the mean over the held-out pixels; ``by_block``:
        also (n, K) each held-out block's share of that mean."""
        loss = candidate_losses(self.B, C, self.y, self.fp.train, sigma=self.sig, iters=iters,
                                cfg=self.settings.solver, rows=self.held)
        lh = loss.mean(0)
        if not by_block:
            return lh
        ids, n = self.held_blocks
        return lh, block_sums(loss / max(len(loss), 1), ids, n)

    def set_weights(self, dirs, solid_angle, shadow_blocks, photo_blocks, seed: int = 0,
                    measure: bool = True) -> None:
        """Each cue's weight (``cueweight.cue_weight``) over the directions ``dirs`` (K, 3),
        each standing for ``solid_angle`` (K,), from their per-block shadow
        log-likelihoods ``shadow_blocks`` (n, K) and held-out losses ``photo_blocks``
        (m, K) (``suns_any_size``'s) -- ``measured``; the ones the search weighs the cues
        by (``weights``): those, or 1 each where ``search.cue_weights`` is off (each block
        one observation, the one temperature for the rest); and each weighted cue's log
        normaliser over the directions (the gate's). ``measure`` False: 1 each, not
        measured (a grid whose weights nothing would use)."""
        lh = photo_blocks.sum(0)
        if self.photo_s2 is None:
            self.set_photo_noise(float(lh.min()))
        lp = log_elevation_prior(dirs, self.fp.up, self.settings.search.elevation_prior_power)
        ph_blocks = -self.blocks * self.settings.search.photo_weight * photo_blocks / (2.0 * self.photo_s2)
        if measure:
            ws = cue_weight(shadow_blocks, lp, solid_angle, dirs, self.settings.search, seed=seed)
            wp = cue_weight(ph_blocks, lp, solid_angle, dirs, self.settings.search, seed=seed)
        else:
            ws, wp = (CueWeight(1.0, float("nan"), len(b)) for b in (shadow_blocks, ph_blocks))
        self.measured = (ws, wp)
        if not self.settings.search.cue_weights:
            ws, wp = (dataclasses.replace(w, k=1.0) for w in (ws, wp))
        self.weights = (ws, wp)
        self.norms = (log_integral(ws.k * shadow_blocks.sum(0), solid_angle),
                      log_integral(wp.k * self.loglik_photo(lh), solid_angle))

    def ensure_weights(self, seed: int = 0) -> None:
        """The cues' weights, where no search set them (a light whose direction is given):
        from the search's coarse grid where a weight or the gate would use them, else 1
        each."""
        if self.weights is None:
            cfg = self.settings
            if not cfg.search.cue_weights and cfg.search.gate == 0.0:
                # nothing would use them: 1 each, and with no gate the normalisers shift
                # every candidate alike (the same choices, without scoring a grid)
                one = CueWeight(1.0, float("nan"), 0)
                self.weights = self.measured = (one, one)
                self.norms = (0.0, 0.0)
                return
            coarse = hemisphere(cfg.n_light_candidates, self.fp.up, cfg.search.min_elevation_deg)
            sf, (_, lh_blocks), _, _ = self.suns_any_size(coarse)
            self.set_weights(coarse, np.full(len(coarse), 2 * math.pi / len(coarse)), sf.blocks, lh_blocks, seed)

    def set_photo_noise(self, lh_best: float) -> None:
        """The photometric fit's noise: the one the best candidate's held-out loss
        ``lh_best`` implies (the model's misfit counts as noise, as the shadow term's
        does), over every kind of light scored, so that a lamp whose pool of light the
        support shows is not judged at the noise of the suns that cannot explain it."""
        self.photo_s2 = max(2.0 * float(lh_best), (self.settings.solver.sigma_floor) ** 2)
        self.lh_ref = float(lh_best)

    def loglik_photo(self, lh) -> np.ndarray:
        """(K,) the photometric log-likelihoods of held-out losses ``lh`` (per pixel, over
        the data scale squared: half a squared residual where it is small) relative to
        the best candidate's (``set_photo_noise``: a common reference, so that separate
        calls compare), each held-out block ``search.photo_weight`` observations, at the
        noise of ``set_photo_noise`` (not set: the best of ``lh``'s)."""
        lh = np.asarray(lh, np.float64)
        if self.photo_s2 is None:
            self.set_photo_noise(float(lh.min()))
        n = self.blocks * self.settings.search.photo_weight
        return -n * (lh - self.lh_ref) / (2.0 * self.photo_s2)

    def loglik(self, sfit, lh):
        """((K,) the cues' weighted log-likelihoods summed, (K,) the photometric part
        unweighted)."""
        ll_photo = self.loglik_photo(lh)
        return self.weighted(sfit.loglik, ll_photo), ll_photo

    def weighted(self, ll_shadow, ll_photo) -> np.ndarray:
        """The two cues' log-likelihoods, each at its weight and gated
        (``cueweight.gated``, ``search.gate``), summed (the weights set first:
        ``ensure_weights``)."""
        self.ensure_weights()
        return combined(ll_shadow, ll_photo, self.weights, self.settings.search.gate, self.norms)


def _shadow_area_blocks(rec, V) -> np.ndarray:
    """(K,) how many of the frame's blocks the shadow of each candidate covers on the
    receivers (weighted by the support area each receiver stands for)."""
    if len(rec) == 0:
        return np.zeros(V.shape[1])
    share = (rec.weight[:, None] * (1.0 - V)).sum(0) / max(float(rec.weight.sum()), 1e-12)
    return share * rec.blocks


def search_scorer(pp: Prepared, settings: LightConfig):
    """(the support's shadow evidence, the scorer of candidate lights over it): step 2
    and what step 3 scores with."""
    from zcomp_cli.light.evidence import shadow_evidence
    from zcomp_cli.scene.skyvis import support_sky_view

    mesh = pp.grid.mesh
    ec = settings.evidence
    view = None
    if ec.sky_view_directions > 0:
        view = support_sky_view(mesh.points, mesh.support, mesh.up, pp.grid.caster, directions=ec.sky_view_directions,
                                stride=ec.sky_view_stride, bias_rel=settings.search.bias_rel)
    ev = shadow_evidence(pp.grid.shading, mesh.support, mesh.casters, mesh.points, mesh.up, known=pp.grid.known,
                         albedo=pp.grid.albedo, labels=mesh.labels, sky_view=view,
                         sky_share=settings.search.prior_sky_share, cfg=settings.evidence)
    return ev, _Scorer(pp, ev, settings)


def caster_anchor(pp: Prepared, evidence, cfg) -> np.ndarray:
    """(3,) where a lamp's direction is measured from in the search: the base of the
    caster with the most tied shadow beside it (its shadow's rays meet at the lamp;
    ``cfg`` the evidence's config: beside is within its attachment reach), else the
    support's centre."""
    mesh = pp.grid.mesh
    if not evidence.tied.any() or not mesh.base.any():
        return pp.anchor
    import cv2

    best, best_n = None, 0
    tied = evidence.tied.astype(np.uint8)
    for k in np.unique(mesh.labels[mesh.casters]):
        comp = (mesh.labels == k).astype(np.uint8)
        reach = max(1, int(round(cfg.attach_rel * max(mesh.shape)))) + cfg.unread_px
        near = cv2.dilate(comp, np.ones((2 * reach + 1, 2 * reach + 1), np.uint8)) > 0
        n = int((near & (tied > 0)).sum())
        if n > best_n and (mesh.base & (mesh.labels == k)).any():
            best, best_n = k, n
    if best is None:
        return pp.anchor
    return np.median(mesh.points[mesh.base & (mesh.labels == best)], 0)


@dataclass(frozen=True)
class Scored:
    """The search's unweighted scores over its posterior's directions (K): the sun's
    shadow and photometric log-likelihoods (``sun_shadow``, ``sun_photo`` (K,)), and per
    direction the lamps scored along it (``lamps``: K lists of (distance index, shadow,
    photometric)). What the cues' weights, the gate and the temperature turn into a
    posterior (``weighted_marginal``), so that another gate or temperature can be tried
    without scoring again (``benchmarks/fit_light_constants.py``)."""

    sun_shadow: np.ndarray
    sun_photo: np.ndarray
    lamps: tuple

    def norms(self, weights, solid_angle) -> tuple[float, float]:
        """Each weighted cue's log normaliser over the directions (the sun's, each
        standing for ``solid_angle``): what makes it a density (``cueweight.gated``)."""
        ws, wp = weights
        return log_integral(ws.k * self.sun_shadow, solid_angle), log_integral(wp.k * self.sun_photo, solid_angle)


def weighted_marginal(scored: Scored, weights, gate: float, T: float, log_opt_prior,
                      solid_angle) -> tuple[np.ndarray, np.ndarray]:
    """Per direction: the likelihood marginalised over the options scored (the sun, and
    each lamp of ``scored.lamps``), each cue at its weight (``weights``: shadow,
    photometric ``CueWeight``) and gated (``cueweight.gated``: each a density over the
    sun's directions, each standing for ``solid_angle``); and the best option (-1 the
    sun, else the lamp's distance index). The options' prior (``log_opt_prior``: the
    sun's, then each distance's) enters at the posterior's temperature ``T`` (log p
    times T here)."""
    norms = scored.norms(weights, solid_angle)
    ll_sun = combined(scored.sun_shadow, scored.sun_photo, weights, gate, norms)
    marg = np.empty(len(ll_sun))
    best = np.full(len(ll_sun), -1)
    for i, ls in enumerate(ll_sun):
        terms = [(-1, ls + T * log_opt_prior[0])]
        for j, a, b in scored.lamps[i]:
            terms.append((j, float(combined(a, b, weights, gate, norms)) + T * log_opt_prior[1 + j]))
        vals = np.array([t for _, t in terms])
        marg[i] = T * np.logaddexp.reduce(vals / T)
        best[i] = terms[int(np.argmax(vals))][0]
    return marg, best


def _drawn(post: DirectionPosterior, opts: np.ndarray, anchor, dists, cfg) -> tuple[tuple, float, np.ndarray | None]:
    """Step 6: the lights drawn -- (((``FitLight``, share) per mode of ``post``,
    heaviest first), the modes' mass, the rest's sky SH or None). Each mode is a sun or a
    lamp as the best option at its peak says (``opts``: -1 a sun, else the index of its
    distance in ``dists`` from ``anchor``), of the mass it holds; the rest of the mass,
    where the modes are suns, is drawn as sky (the radiance where it lies:
    ``DirectionPosterior.sun_sky_sh``), and where they are lamps shared among them (a sky
    is at infinity and cannot stand for a near light). The lights' columns are made at
    their size (step 4).

    The posterior drawn is what the cues state (``DirectionPosterior.informed``), not
    the prior's share where they mislead (``search.misled``): that share tells no
    direction, and drawn as sky it would only wash out the shadow of every case the cues
    get right, against the split the shadows measured (the light is a sun however
    unsure its direction; the doubt is stated, ``fit.misled``, not drawn)."""
    post = post.informed
    modes = post.modes(cfg.max_modes, cfg.mode_radius_deg, cfg.modes_mass)
    drawn = []
    for m in modes:
        k = int(opts[int(np.argmax(post.dirs @ m.peak))])
        drawn.append(FitLight("sun", m.direction, None, np.zeros(0)) if k < 0 else
                     FitLight("lamp", anchor + dists[k] * m.direction, None, np.zeros(0)))
    total = sum(m.mass for m in modes)
    is_lamp = [fl.kind == "lamp" for fl in drawn]
    sun_part = sum(m.mass for m, lamp in zip(modes, is_lamp) if not lamp) / total
    rest_sh = sun_part * post.sun_sky_sh(~np.any([m.members for m in modes], axis=0))
    shares = [m.mass / total if lamp else m.mass for m, lamp in zip(modes, is_lamp)]
    return tuple(zip(drawn, shares)), float(total), (rest_sh if np.any(rest_sh != 0.0) else None)


def search(pp: Prepared, settings: LightConfig, seed: int = 0) -> tuple[Search, "_Scorer"]:
    """Step 3 (module docstring): the posterior over the light's direction, each
    direction's likelihood marginalised over its distance (a sun, or a lamp at one of
    ``lamp_distances_rel`` along it from the caster's base: a priori a sun and a lamp
    alike; the lamps scored are those an unshadowed photometric screen of every
    direction and distance ranks among the ``lamp_top`` best, and those along the
    ``lamp_top`` best suns; a lamp not scored counts as unlikely). Each cue's weight
    (``cueweight``) is read off the posterior's own grid and reported; where
    ``search.cue_weights`` applies them, they are read off the coarse grid first too, to
    steer the lamps and the refinement."""
    fp = pp.fp
    cfg = settings.search
    T = cfg.temperature
    ev, sc = search_scorer(pp, settings)
    up = fp.up
    # a priori a sun or a lamp alike, each lamp distance alike (so a lamp at one distance
    # must explain the photograph better than the sun by the log of their number)
    n_lamp = len(cfg.lamp_distances_rel)
    log_opt_prior = np.log(np.array([0.5] + [0.5 / max(n_lamp, 1)] * n_lamp))
    dists = float(np.median(np.linalg.norm(fp.support_points, axis=1))) * np.asarray(cfg.lamp_distances_rel, np.float64)
    anchor = caster_anchor(pp, ev, settings.evidence)

    def lamps(positions):
        """(shadow, photometric) log-likelihoods of lamps at ``positions``, unweighted."""
        sl, lhl, _ = sc.lamps(np.asarray(positions, np.float64).reshape(-1, 3))
        return sl.loglik, sc.loglik_photo(lhl)

    coarse = hemisphere(settings.n_light_candidates, up, cfg.min_elevation_deg)
    omega = np.full(len(coarse), 2 * math.pi / len(coarse))
    # the lamps worth scoring: every (direction, distance) screened by its unshadowed
    # photometric fit plus the sun's shadow along that direction; the LAMP_TOP best, and
    # the lamps along the LAMP_TOP best suns (the screen's fits on a second thread while
    # this one scores the suns: neither reads the other)
    K, nd = len(coarse), len(dists)
    Q = anchor[None, None] + dists[None, :, None] * coarse[:, None, :]
    screening = beside(lambda: sc.photo_losses(at.lamp_columns(fp, Q.reshape(-1, 3)), iters=cfg.screen_iters))
    sf_c, (lh_c, lhb_c), _, V_c = sc.suns_any_size(coarse)
    lh0 = screening.result()
    # the photometric noise and reference: the best candidate's, sun or lamp
    sc.set_photo_noise(float(min(lh_c.min(), lh0.min())))
    # each cue's weight off the coarse grid (where they are used: the lamps screened and
    # the refinement steered by them)
    sc.set_weights(coarse, omega, sf_c.blocks, lhb_c, seed, measure=cfg.cue_weights)
    ph_c = sc.loglik_photo(lh_c)
    prior_c = log_elevation_prior(coarse, up, cfg.elevation_prior_power)
    screen = sc.weighted(sf_c.loglik[:, None], sc.loglik_photo(lh0).reshape(K, nd)) / T + prior_c[:, None]
    pairs = {tuple(int(v) for v in np.unravel_index(i, (K, nd))) for i in np.argsort(-screen.ravel())[:cfg.lamp_top]}
    for i in np.argsort(-(sc.weighted(sf_c.loglik, ph_c) / T + prior_c))[:cfg.lamp_top]:
        pairs |= {(int(i), j) for j in range(nd)}
    pairs = sorted(pairs)
    sh_l, ph_l = lamps(np.array([Q[i, j] for i, j in pairs])) if pairs else (np.zeros(0), np.zeros(0))
    lamp_c = [[] for _ in range(K)]
    for (i, j), a, b in zip(pairs, sh_l, ph_l):
        lamp_c[i].append((j, float(a), float(b)))
    marg, option = weighted_marginal(Scored(sf_c.loglik, ph_c, tuple(lamp_c)), sc.weights, cfg.gate, T, log_opt_prior,
                                     omega)
    # the refinement: a finer spiral around the best, standing for its cap's share
    ib = int(np.argmax(marg / T + prior_c))
    best = coarse[ib]
    cap = 1.5 * spacing_deg(2 * settings.n_light_candidates)
    fine = fine_spiral(best, cap, cfg.refine_directions, up=up)
    fine = fine[fine @ up > math.sin(math.radians(cfg.min_elevation_deg))]
    sf_f, (lh_f, lhb_f), _, V_f = sc.suns_any_size(fine)
    ph_f = sc.loglik_photo(lh_f)
    if option[ib] >= 0:  # the best option a lamp: its distance along the fine directions
        sh_lf, ph_lf = lamps(anchor[None] + dists[option[ib]] * fine)
        lamp_f = [[(int(option[ib]), float(a), float(b))] for a, b in zip(sh_lf, ph_lf)]
    else:
        lamp_f = [[] for _ in fine]
    inside = coarse @ best >= math.cos(math.radians(cap))
    cap_area = float(omega[inside].sum())
    dirs = np.concatenate([coarse[~inside], fine])
    om = np.concatenate([omega[~inside], np.full(len(fine), cap_area / len(fine))])
    # the cues' weights again, off the posterior's own grid (the refinement tells what the
    # coarse grid could not: whether the best direction holds within its cell)
    sc.set_weights(dirs, om, np.concatenate([sf_c.blocks[:, ~inside], sf_f.blocks], 1),
                   np.concatenate([lhb_c[:, ~inside], lhb_f], 1), seed)
    scored = Scored(np.concatenate([sf_c.loglik[~inside], sf_f.loglik]), np.concatenate([ph_c[~inside], ph_f]),
                    tuple(x for x, out in zip(lamp_c, inside) if not out) + tuple(lamp_f))
    marg, opts = weighted_marginal(scored, sc.weights, cfg.gate, T, log_opt_prior, om)
    post = DirectionPosterior.from_parts(dirs, marg, log_elevation_prior(dirs, up, cfg.elevation_prior_power), om, T,
                                         cfg.misled)
    drawn, mode_mass, rest_sh = _drawn(post, opts, anchor, dists, cfg)
    i_map = int(np.argmax(post.log_post))
    k = int(opts[i_map])
    best_light = (FitLight("sun", post.dirs[i_map], None, np.zeros(0)) if k < 0 else
                  FitLight("lamp", anchor + dists[k] * post.dirs[i_map], None, np.zeros(0)))
    return Search(posterior=post, scored=scored,
                  ratio=np.concatenate([sf_c.ratio[~inside], sf_f.ratio]),
                  shadow_blocks=np.concatenate([_shadow_area_blocks(sc.rec, V_c)[~inside],
                                                _shadow_area_blocks(sc.rec, V_f)]),
                  light=drawn[0], evidence=ev, receivers=sc.rec, map_light=best_light, anchor=anchor,
                  modes=drawn, mode_mass=mode_mass, rest_sh=rest_sh, weights=sc.measured,
                  log_opt_prior=log_opt_prior), sc


def choose_size(pp: Prepared, sc: _Scorer, light: FitLight, settings: LightConfig, seed: int,
                anchor=None) -> FitLight:
    """Step 4: a light's size, one rule for every sun and lamp whose size is not given:
    its angular radius seen from the caster's base (``anchor``; a sun's is the same from
    everywhere) among the Sun's own (``SUN_RADIUS_DEG``, the default) and
    ``search.radii_deg``, the one whose cone-averaged shadow has the largest summed
    log-likelihood -- unless the default is within the default's odds of it in tempered
    log-likelihood (``default_odds``: a sun's fitted, a lamp's none). The width of a
    shadow's soft edge against its caster's distance is what tells the radii apart (a
    light's size is the penumbra's, never the direction's doubt). A lamp's radius in
    metres covers that angle at its distance from ``anchor``. The renderer's
    ``shadow_softness`` forces one (a sun's angle)."""
    if light.kind == "sun" and settings.shadow_softness is not None:
        r = float(settings.shadow_softness)
        return dataclasses.replace(light, radius=r, radius_from=Origin.MANIFEST, column=at.sun_column(
            pp.fp, light.param, r, steps=settings.estimate_march_steps, cone_samples=settings.cone_samples, seed=seed))
    r, origin = chosen_radius(sc, light, pp.anchor if anchor is None else anchor, settings, seed)
    return sized(pp, light, r, origin, settings, seed, anchor)


def light_direction(light: FitLight, anchor) -> np.ndarray:
    """(3,) toward ``light`` from ``anchor`` (a sun's direction as it is)."""
    if light.kind == "sun":
        return np.asarray(light.param, np.float64)
    v = np.asarray(light.param, np.float64) - np.asarray(anchor, np.float64)
    return v / max(float(np.linalg.norm(v)), 1e-12)


def chosen_radius(sc: _Scorer, light: FitLight, anchor, settings: LightConfig, seed: int) -> tuple[float, Origin]:
    """(angular radius in degrees seen from ``anchor``, its origin): ``choose_size``'s rule
    for ``light`` (``Origin.DEFAULT`` where the likelihoods cannot tell the radii apart,
    ``Origin.SHADOWS`` where they chose it). A sun's candidates are suns of each radius; a
    lamp's, lamps at its place whose radius covers each angle at its distance, scored on
    their own shadows and columns (a big lamp's pool of light is not a bulb's). The most
    likely radius, unless the default (the Sun's, a bulb's) is within its odds
    (``default_odds``) of it at the posterior's temperature (``picked_radius``)."""
    radii, ll = radius_scores(sc, light, anchor, settings, seed)
    return picked_radius(radii, ll, settings.search.temperature, default_odds(light, settings))


def default_odds(light: FitLight, settings: LightConfig) -> float:
    """The default size's prior odds (tempered log-likelihood) for ``light``: a sun's
    angular size is the Sun's, to within the sky's haze, so its default is kept unless
    the shadows beat it (``search.default_radius_odds``, fitted); a lamp has no typical
    size (a bulb, a panel, a window's softbox), so no candidate is preferred."""
    return settings.search.default_radius_odds if light.kind == "sun" else 0.0


def radius_scores(sc: _Scorer, light: FitLight, anchor, settings: LightConfig, seed: int) -> tuple[tuple, np.ndarray]:
    """(the candidate angular radii, the Sun's own first; (n,) each one's untempered
    log-likelihood): ``light`` at each radius (``chosen_radius``)."""
    radii = (SUN_RADIUS_DEG,) + tuple(r for r in settings.search.radii_deg if r != SUN_RADIUS_DEG)
    d = light_direction(light, anchor)
    dist = float(np.linalg.norm(np.asarray(light.param, np.float64) - np.asarray(anchor, np.float64)))

    def score(r: float) -> float:
        if light.kind == "sun":
            sf, lh, _ = sc.suns(d[None], r, seed=seed)
        else:
            rm = LAMP_RADIUS_M if r == SUN_RADIUS_DEG else dist * math.tan(math.radians(r))
            sf, lh = sc.lamp_sized(light.param, rm, light.facing)
        ll, _ = sc.loglik(sf, lh)
        return float(ll[0])

    # the first radius alone: a scorer made for a given light sets its noise scales from
    # the first light it scores (``_Scorer._scored``, ``loglik_photo``); the others, which
    # only read them, share the cores
    first = score(radii[0])
    return radii, np.asarray([first] + map_over(score, radii[1:]))


def picked_radius(radii, ll: np.ndarray, temperature: float, odds: float) -> tuple[float, Origin]:
    """(radius, origin) the rule picks from ``radius_scores``: the likeliest, unless the
    first (the default) is within ``odds`` of it at ``temperature``."""
    t = np.asarray(ll, np.float64) / float(temperature)
    i = int(np.argmax(t))
    if i == 0 or t[i] - t[0] < odds:
        return SUN_RADIUS_DEG, Origin.DEFAULT
    return float(radii[i]), Origin.SHADOWS


def sized(pp: Prepared, light: FitLight, radius_deg: float, origin: Origin, settings: LightConfig, seed: int,
          anchor=None) -> FitLight:
    """``light`` at angular radius ``radius_deg`` seen from ``anchor`` (``chosen_radius``),
    its column made again: a sun's radius is that angle; a lamp's the metres that cover it
    at its distance from ``anchor`` (a bulb's ``LAMP_RADIUS_M`` where the radius is the
    default)."""
    if light.kind == "sun":
        col = at.sun_column(pp.fp, light.param, float(radius_deg), steps=settings.estimate_march_steps,
                            cone_samples=settings.cone_samples, seed=seed)
        return dataclasses.replace(light, radius=float(radius_deg), radius_from=origin, column=col)
    a = pp.anchor if anchor is None else anchor
    rm = (LAMP_RADIUS_M if origin is Origin.DEFAULT else
          float(np.linalg.norm(np.asarray(light.param) - a)) * math.tan(math.radians(radius_deg)))
    col = lamp_column(pp.fp, light.param, rm, light.facing, settings, seed)
    return dataclasses.replace(light, radius=rm, radius_from=origin, column=col)


def sun_column(fp, direction, radius_deg: float, settings: LightConfig, seed: int) -> np.ndarray:
    """(N,) a sun's column over the fit pixels (``atoms.sun_column``, the fit's samples)."""
    return at.sun_column(fp, direction, radius_deg, steps=settings.estimate_march_steps,
                         cone_samples=settings.cone_samples, seed=seed)


def lamp_column(fp, position, radius_m: float, facing, settings: LightConfig, seed: int) -> np.ndarray:
    """(N,) a lamp's column over the fit pixels: a sphere of ``radius_m`` at ``position``
    (``atoms.lamp_columns``), or a one-sided Lambertian panel facing ``facing`` (its
    emission profile ``4 max(0, cos)``)."""
    q = np.asarray(position, np.float64)
    col = at.lamp_columns(fp, q[None], steps=settings.estimate_march_steps, radius_m=radius_m,
                          cone_samples=settings.cone_samples, seed=seed)[:, 0]
    if facing is not None:
        v = q[None] - fp.points
        d = v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-9)
        col = col * 4.0 * np.maximum(-(d @ np.asarray(facing, np.float64)), 0.0)
    return col


def _shrunk_share(rho: float, n_eff: float, sigma: float, cfg) -> float:
    """The measured shadowed/lit ratio ``rho`` behind ``n_eff`` blocks of shadow, shrunk
    toward the prior: the posterior mean of a Gaussian prior (``cfg.prior_sky_share``,
    spread ``cfg.prior_sky_share_spread``) and a measurement whose noise is the shadow
    fit's ``sigma`` per block (each block one observation)."""
    n0 = (max(sigma, 1e-6) / cfg.prior_sky_share_spread) ** 2  # the prior's weight in blocks
    return (n_eff * rho + n0 * cfg.prior_sky_share) / (n_eff + n0)


def unshadowed(light: FitLight, points: np.ndarray, up) -> np.ndarray:
    """(N,) ``light``'s irradiance per unit strength on a floor facing ``up`` (3,) at
    ``points`` (N, 3), nothing in its way, in its column's units (``sun_column``,
    ``lamp_column``): a sun's ``max(0, up.d)``, the same everywhere; a lamp's
    ``max(0, up.(q - p)) / |q - p|^3``, times its panel's profile where it faces."""
    P = np.asarray(points, np.float64).reshape(-1, 3)
    u = np.asarray(up, np.float64)
    q = np.asarray(light.param, np.float64)
    if light.kind == "sun":
        return np.full(len(P), max(float(q @ u), 0.0))
    v = q[None] - P
    r = np.maximum(np.linalg.norm(v, axis=1), 1e-6)
    e = np.maximum(v @ u, 0.0) / r ** 3
    if light.facing is not None:
        e = e * 4.0 * np.maximum(-((v / r[:, None]) @ np.asarray(light.facing, np.float64)), 0.0)
    return e


def share_moved(rho: float, c: float) -> float:
    """The sky's share where ``light``'s irradiance is ``c`` times what it is where the
    share is ``rho`` (the sky the same at both, an open floor's): ``rho / (rho + c (1 -
    rho))``; ``c`` 1 (a sun on a floor) leaves it, 0 (out of the light's reach) makes it
    1."""
    rho, c = float(np.clip(rho, 0.0, 1.0)), max(float(c), 0.0)
    den = rho + c * (1.0 - rho)
    return 1.0 if den <= 1e-12 else rho / den


def split_from_shadows(sc: "_Scorer", light: FitLight, radius: float | None = None) -> tuple[float, float]:
    """Step 5: (the sky's share of the support's light, the blocks of shadow evidence
    behind it): Madsen and Nielsen's shadowed/lit ratio of the same surface, read across
    the edges of the shadow ``light`` (the most probable one) casts (its shadow fit's
    ``rho``), as much as that shadow falls on cast shadows tied to their casters (its
    overlap with them, in the frame's blocks), shrunk toward the prior
    (``_shrunk_share``, the shadow fit's noise). A shadow that falls on lit floor only
    tells nothing of the split (no overlap, the prior's).

    ``rho`` is the sky's share where the shadow lies; the share is stated where the key
    light's atom states it, at the support's median (``fit._unit``). A sun lights both
    alike; a lamp's light falls off, so ``rho`` is moved by its unshadowed irradiance
    there against the shadow's (``share_moved``)."""
    cfg = sc.settings.search
    V = sc.visibility(light.kind, light.param, radius)[:, None]
    tied = sc.evidence.tied[sc.rec.ys, sc.rec.xs]
    w = sc.rec.weight * (1.0 - V[:, 0]) * tied  # the receivers in its shadow and in a tied one
    share = float(w.sum()) / max(float(sc.rec.weight.sum()), 1e-12)
    n_eff = share * sc.rec.blocks
    if n_eff <= 0:
        return cfg.prior_sky_share, 0.0
    fit_ = shadow_fit(sc.rec, V, cfg)
    # (no search scored a light before, as with a given direction: this shadow's own
    # noise scale, as the first scoring of a search sets it)
    sigma = fit_.best_sigma if sc.sigma is None else sc.sigma
    rho = float(np.clip(fit_.ratio[0], 0.0, 1.0))
    fp = sc.fp
    e_shadow = float((w * unshadowed(light, sc.rec.origins, fp.up)).sum()) / max(float(w.sum()), 1e-12)
    pts = fp.support_points
    e_support = float(np.median(unshadowed(light, pts, fp.up))) if len(pts) else e_shadow
    if e_shadow > 1e-12:
        rho = share_moved(rho, e_support / e_shadow)
    return _shrunk_share(rho, n_eff, sigma, cfg), n_eff


__all__ = ["FitLight", "Search", "Scored", "search", "search_scorer", "choose_size", "chosen_radius", "sized",
           "radius_scores", "picked_radius", "default_odds", "split_from_shadows", "share_moved", "unshadowed",
           "sun_column", "lamp_column", "log_elevation_prior", "weighted_marginal"]
