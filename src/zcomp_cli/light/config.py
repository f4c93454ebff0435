"""The light stage's configs, each field declared once with its provenance and range
(``zcomp_cli.knobs``):

* ``EvidenceConfig``: the support's cast-shadow evidence (``evidence``);
* ``SearchConfig``: the direction search, its posterior, the light's size and strength
  (``search``, ``shadowcast``);
* ``SolverConfig``: the robust NNLS (``solver``);
* ``LightConfig``: the whole stage: resolutions and samples, and the configs above with
  the scene's (``scene.config``: the depth mesh, the frame, a probe's split, the march,
  where a given light's shadow reaches).
"""

from __future__ import annotations

from dataclasses import dataclass

from zcomp_cli.knobs import knob, sub
from zcomp_cli.scene.config import FrameConfig, MarchConfig, MeshConfig, ProbeConfig, ReachConfig
from zcomp_cli.scene.lightparams import MAX_RADIUS_DEG


@dataclass(frozen=True, kw_only=True)
class EvidenceConfig:
    """The support's cast-shadow evidence (``shadow_evidence``)."""

    lit_degree: int = knob(3, "heuristic", "the lit level is a polynomial of this degree in the ground's "
                                          "coordinates (a lamp's fall-off, a far wall's soft shade; a tabletop "
                                          "object's shadow is too small for it)", lo=0, hi=6)
    max_lit_pixels: int = knob(20000, "sampling", "pixels the lit level is fitted on (a stride: a low-order "
                                                 "surface needs few)")
    lit_iters: int = knob(6, "sampling", "iterations of the lit level (fit, call the pixels below it dark, refit), "
                                        "the k-th of degree min(k, lit_degree) from 0: the full degree is reached at "
                                        "the (lit_degree + 1)-th and settles in three")
    basin_blur_px: float = knob(1.0, "heuristic", "the ratio's Gaussian blur (sigma, working pixels) before the "
                                                 "dark region is split into basins, so that a pixel's noise makes no "
                                                 "basin; against none, the calibration's mean log score was -1.027 / "
                                                 "-0.083 (fit / held out) against -1.052 / -0.086 (measured with "
                                                 "the basins' first markers and four lit-level fits: design-notes)",
                                lo=0.0, hi=8.0)
    dark_sigmas: float = knob(3.0, "statistical", "a pixel this many noise scales below the lit level is dark "
                                                 "(0.1 % of Gaussian noise)")
    weber: float = knob(0.02, "physical", "and at least this much darker: Weber's contrast, the least a viewer sees", hi=1.0)
    darkest: float = knob(0.99, "physical", "and at most this much (a shading ratio is above 0): with a noise so "
                                           "large that nothing stands out, the threshold stays finite", hi=1.0)
    attach_rel: float = knob(1.0 / 60.0, "heuristic", "a dark region within this share of the frame's long side "
                                                      "of a caster is tied to it")
    unread_px: int = knob(2, "sampling", "the band along the support's outline and the albedo's edges whose ratio "
                                        "is not read (the erosion's pixel; a 3 x 3 Sobel marks an edge's two sides)")
    reach_heights: float = knob(4.0, "physical", "a tied shadow lies within this many caster heights of it: the "
                                                "shadow of a light at least atan(1/4) = 14 deg high")
    max_reach_points: int = knob(2000, "sampling", "points of a caster its ground distance is measured to")
    albedo_spread: float = knob(0.02, "heuristic", "an albedo whose log spreads less than this over the support is "
                                                  "one albedo (no albedo terms in the lit level)")
    albedo_edge: float = knob(0.05, "heuristic", "a change of the albedo's log this large between neighbours is an "
                                                "edge, where image and albedo rarely line up")
    min_region_rel: float = knob(1e-3, "heuristic", "a dark region smaller than this share of the support is noise")
    sky_view_directions: int = knob(0, "setting", "directions the share of the sky the scene's geometry leaves each "
                                                 "support pixel is traced in, the same for every pixel (256: steps "
                                                 "of 1/256, under Weber's contrast; 32 called a wall's foot dark), "
                                                 "for the lit level's term of it (shadow_evidence); 0: no such term. "
                                                 "Off: with 256, near the object on the four development seeds of "
                                                 "benchmarks/run_benchmark.py -0.07 / -0.01 / +0.03 / -0.13 dB "
                                                 "(docs/design-notes.md)", lo=0, hi=4096)
    min_sky_factor: float = knob(1e-3, "physical", "the least share of the open support's light that term leaves a "
                                                  "pixel that sees no sky (with all the light the sky's): the bounce "
                                                  "still reaches it, and a log of 0 would stop the fit; below any "
                                                  "shadow the evidence reads", hi=1.0)
    sky_view_stride: int = knob(2, "sampling", "the share is traced at the support's pixels this far apart and spread "
                                              "between them (it varies over many pixels; at 4 a wall's foot is "
                                              "0.12 off where every pixel is traced)", hi=64)

@dataclass(frozen=True, kw_only=True)
class SearchConfig:
    """The direction search, its posterior and how it is drawn, the light's size and
    strength (``search``, ``shadowcast``)."""

    temperature: float = knob(10.0, "fitted", "the posterior's one temperature over the cues' likelihoods: the best "
                                              "mean log score of the true direction over the calibration cases, "
                                              "with misled (benchmarks/fit_light_constants.py, "
                                              "docs/fit_light_constants.txt)")
    misled: float = knob(0.25, "fitted", "the chance that the cues mislead the estimate together (a bias all their "
                                         "pixels share: the depth mesh's caster, the lit level's basis): the "
                                         "posterior is mixed with the prior by this much (posterior.with_misled; "
                                         "the best mean log score with the temperature, fit_light_constants.py "
                                         "--misled-grid)", lo=0.0, lo_open=False, hi=0.9)
    cue_weights: bool = knob(False, "fitted", "weigh each cue by the power its own blocks bear out (cueweight) "
                                              "before the temperature: off, as the calibration's log score chose "
                                              "(fit_light_constants.py; the weights are measured and reported "
                                              "either way)")
    weight_level: float = knob(0.68, "statistical", "a cue's weight holds its own best direction in its highest-"
                                                   "density set of this mass in as many of the resamples: the "
                                                   "audit's 68 % cone, one sigma (cueweight)", hi=1.0)
    weight_resamples: int = knob(128, "sampling", "block-bootstrap resamples per cue: the coverage's standard error "
                                                 "at 68 % is 4 %, under the weights' step (cueweight)", hi=10000)
    weight_blocks: int = knob(4, "sampling", "the units a cue's weight resamples: the frame in this many blocks of "
                                            "its long side, longer than a shadow edge's or a fall-off's "
                                            "correlation, which run across several of the fit's own 12 (cueweight)",
                              hi=64)
    weight_range: tuple = knob((1e-3, 1.0), "physical", "the weights tried (log-spaced): at most 1, each block one "
                                                       "independent observation (the most a block's correlated pixels "
                                                       "are worth); at least 1e-3, flat on any grid the search uses",
                               hi=1.0)
    weight_steps: int = knob(31, "sampling", "the weights tried between the two of weight_range", hi=1000)
    gate: float = knob(0.0, "fitted", "each cue, as a density over the hemisphere, is mixed with the uniform by this "
                                     "much: the chance that it is misled (cueweight.gated; the best mean log score, "
                                     "fit_light_constants.py --gate-grid)", lo=0.0, lo_open=False, hi=0.5)
    elevation_prior_power: float = knob(0.5, "fitted", "the prior over directions has the density "
                                                       "cos(elevation) ** -power per steradian (1: uniform in the "
                                                       "elevation angle; 0: uniform over the hemisphere): the best "
                                                       "mean log score with the temperature and the photometric "
                                                       "weight (fit_light_constants.py --prior-grid)", lo=0.0, lo_open=False, hi=10.0)
    photo_weight: float = knob(1.0, "fitted", "the photometric likelihood's independent observations per held-out "
                                              "block (its pixels are correlated: between one and the block's "
                                              "pixel count): the best mean log score with the temperature "
                                              "(fit_light_constants.py)")
    prior_sky_share: float = knob(0.52, "fitted", "the sky's share of the support's light where the photograph does "
                                                  "not tell it: the median true share (fit_light_constants.py)", lo=0.0, lo_open=False, hi=1.0)
    prior_sky_share_spread: float = knob(0.15, "fitted", "that share's spread over the development cases: the "
                                                         "prior's weight against the shadows' measurement "
                                                         "(fit_light_constants.py)", hi=10.0)
    default_radius_odds: float = knob(3.0, "fitted", "a sun keeps the Sun's size unless another's tempered "
                                                     "log-likelihood beats it by this much: the default's prior "
                                                     "odds, fitted on the calibration cases' true sizes "
                                                     "(benchmarks/fit_light_constants.py --radius-odds-grid); a "
                                                     "lamp has no typical size, no odds (search.default_odds)",
                                      lo=0.0, lo_open=False, hi=100.0)
    radii_deg: tuple = knob((0.0, 1.0, 2.0, 4.0, 8.0, 16.0), "sampling", "angular radii a sun's size is chosen "
                                                                          "among (the Sun's own besides)", hi=MAX_RADIUS_DEG)
    lamp_distances_rel: tuple = knob((0.3, 0.6, 1.2, 2.4), "sampling", "a lamp's distances along a direction, in "
                                                                         "units of the support's median distance "
                                                                         "(a relative depth gives the same)", lo=0.0, lo_open=True)
    lamp_top: int = knob(8, "sampling", "lamps are scored along this many best directions and screen picks")
    screen_iters: int = knob(1, "sampling", "IRLS iterations of the lamps' unshadowed screen (the scored ones get "
                                           "the solver's full count)")
    min_elevation_deg: float = knob(2.0, "physical", "the lowest candidate: a light in the ground's plane lights "
                                                    "nothing on it", lo=0.0, lo_open=False, hi=89.0)
    soft_deg: float = knob(10.0, "sampling", "the soft alternative of each candidate's shadow (its likelihood "
                                            "marginalised over a hard and a soft one): about the grid's spacing", hi=90.0)
    refine_directions: int = knob(40, "sampling", "directions of the refinement around the best coarse one")
    max_modes: int = knob(4, "sampling", "the most lights the posterior over directions is drawn as (its modes, "
                                         "each a light of the mass it holds, the rest as sky: the expected "
                                         "shadow as far as they tell it); each costs the renderer a light",
                          lo=1, hi=8)
    mode_radius_deg: float = knob(15.0, "sampling", "a mode holds the mass within this angle of its peak: about the "
                                                    "search grid's spacing (12.7 deg at 256 directions), below which "
                                                    "the grid does not tell two shadows apart", hi=90.0)
    modes_mass: float = knob(0.9, "statistical", "modes are drawn until they hold this share of the posterior (the "
                                                 "rest, scattered, is drawn as sky)", hi=1.0)
    few_pixels: int = knob(50, "statistical", "fewer fit pixels than this fit nothing: the prior's light")
    bias_rel: float = knob(0.01, "sampling", "a shadow ray starts this share of its depth off the surface (the mesh "
                                            "is float32 in Embree, the depth map steps about a percent)", hi=1.0)
    sigma_min: float = knob(0.02 / 3.0, "physical", "the least noise of the log shading: Weber's 2 % over three "
                                                    "(exact renders have none)")
    log_floor: float = knob(1e-3, "physical", "the least shadowed/lit ratio fitted: an umbra with no sky left")


@dataclass(frozen=True, kw_only=True)
class SolverConfig:
    """The robust NNLS of the light's strengths (``solver``)."""

    huber_c: float = knob(1.345, "statistical", "Huber's constant: 95 % efficiency under Gaussian noise")
    mad_to_sigma: float = knob(1.4826, "statistical", "the median absolute deviation of a Gaussian over its sigma")
    sigma_floor: float = knob(0.02, "physical", "the least noise scale over the data's: a render's noise, Weber's "
                                               "2 %", hi=1.0)
    irls_iters: int = knob(4, "sampling", "iterations of the reweighted least squares: the weights settle in three")
    max_unseen: float = knob(0.5, "statistical", "unseen shadows hold at most half the pixels (beyond, the light "
                                                "is not what the frame says)", hi=1.0)
    unseen_init: float = knob(0.1, "statistical", "the unseen shadows' share the EM starts from", hi=1.0)
    prior_ridge: float = knob(0.02 ** 2, "statistical", "the ridge toward the prior weights per pixel over the data "
                                                       "scale squared: a departure as large as the prior costs a "
                                                       "noise-floor residual on every pixel", lo=0.0, lo_open=False)

@dataclass(frozen=True, kw_only=True)
class LightConfig:
    """The light stage's settings (``zcomp_cli.light``): the fit's resolutions and
    samples, and its parts' configs. The renderers that draw a light hold one (their
    ``light`` setting), so a manifest's ``renderer:`` mapping sets it as it sets theirs."""

    n_light_candidates: int = knob(256, "setting", "directions on the hemisphere the light search scores (then "
                                                   "refined around the best): a sampling resolution")
    estimate_march_steps: int = knob(16, "setting", "samples per screen-space ray in the light fit (the sky's "
                                                    "visibility)")
    max_resolution: int = knob(160, "setting", "long side of the copy the light's strengths are fitted on (pixels)")
    cone_samples: int = knob(8, "setting", "directions per pixel over a light's cone in the fit")
    shadow_softness: float | None = knob(None, "setting", "the lights' angular radius in degrees instead of the "
                                                          "fitted one (None: not forced)", lo=0.0, lo_open=False,
                                         hi=MAX_RADIUS_DEG)
    max_fit_pixels: int = knob(2000, "setting", "pixels of the copy the light is fitted on (a deterministic stride)")
    shadow_resolution: int = knob(256, "setting", "long side of the copy whose depth mesh the light rays are cast "
                                                  "through and whose support's shadows are read")
    max_receivers: int = knob(3000, "setting", "support pixels the candidate lights' shadows are cast from")
    mesh: MeshConfig = sub(MeshConfig, "the depth mesh")
    evidence: EvidenceConfig = sub(EvidenceConfig, "the cast-shadow evidence")
    search: SearchConfig = sub(SearchConfig, "the direction search and its posterior")
    solver: SolverConfig = sub(SolverConfig, "the robust NNLS")
    frame: FrameConfig = sub(FrameConfig, "the scene's frame, support and walls")
    probe: ProbeConfig = sub(ProbeConfig, "a light probe's split into sources and sky")
    march: MarchConfig = sub(MarchConfig, "the screen-space march and the sky's visibility (the synthesis reads "
                                          "the same: one sky)")
    reach: ReachConfig = sub(ReachConfig, "where a given light's shadow of the object falls beyond the shading mask")


DEFAULT_LIGHT = LightConfig()

__all__ = ["EvidenceConfig", "SearchConfig", "SolverConfig", "LightConfig", "DEFAULT_LIGHT"]
