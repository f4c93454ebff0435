"""The physical renderer's settings and constants: declared once, each with its provenance.

``PhysicalSettings`` holds the settings a user sets (the manifest's ``renderer: {name:
physical, <setting>: ...}``, the API's ``PhysicalRenderer(**settings)``) and, nested, the
renderer's knobs as frozen config dataclasses, one per part of the light fit:

* ``MeshConfig``: the depth mesh the light rays are cast through (``depthmesh``);
* ``EvidenceConfig``: the support's cast-shadow evidence (``shadow_evidence``);
* ``SearchConfig``: the direction search, its posterior, the light's size and strength
  (``estimate``, ``shadowcast``);
* ``SolverConfig``: the robust NNLS (``solver``);
* ``FrameConfig``: the scene's frame, support and walls (``scene_frame``, ``planes``,
  ``atoms``).

Every field is declared with ``knob(default, kind, why)``: its **kind** is one of
``KINDS`` (physical, statistical, sampling, fitted, heuristic, setting) and **why** says
where the value comes from -- a physical fact, a statistical convention, a sampling
resolution, a fitting script in ``benchmarks/`` (its output in ``docs/``), or a judgement
that no data has fixed yet (a heuristic, said as such). ``provenance()`` lists them all;
the whole config goes into each job's ``report.json`` (``PhysicalRenderer.settings``).
A nested config may be given as a mapping (``renderer: {name: physical, search:
{temperature: 5}}``): a calibration script builds configs, it never edits source files.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from dataclasses import dataclass, field

from zcomp_cli.errors import UsageError

KINDS = {
    "physical": "a physical fact or unit",
    "statistical": "a statistical convention",
    "sampling": "a sampling resolution: more costs time, not accuracy beyond it",
    "fitted": "fitted by a script in benchmarks/ on the development seeds",
    "heuristic": "a judgement no data has fixed yet",
    "setting": "the user's to set",
}


def knob(default, kind: str, why: str):
    """A config field: its default, its provenance ``kind`` (``KINDS``) and ``why``."""
    if kind not in KINDS:
        raise ValueError(f"unknown provenance kind {kind!r} (known: {', '.join(KINDS)})")
    if not why or not why.strip():
        raise ValueError("a knob says why")
    return field(default=default, metadata={"kind": kind, "why": why})


def _sub(cls, why: str):
    return field(default_factory=cls, metadata={"kind": "config", "why": why})


@dataclass(frozen=True, kw_only=True)
class MeshConfig:
    """The depth mesh (``depthmesh``)."""

    unit_normal_tol: float = knob(0.2, "heuristic", "a normal this far from unit length is not one (a map's invalid "
                                                    "pixels hold zeros or garbage; a stored unit normal, even in half "
                                                    "floats, is within 1e-3 of 1)")
    step_share: float = knob(0.5, "heuristic", "a neighbour continues a pixel's plane within this share of the "
                                              "step the plane predicts: normals a few degrees off keep a grazing "
                                              "floor whole")
    step_cap_rel: float = knob(0.05, "heuristic", "that tolerance at most this share of the depth: a face seen edge "
                                                 "on predicts a step of metres")
    step_max_rel: float = knob(0.25, "physical", "the longest step a plane may predict: a floor 2 deg above the "
                                                "horizon steps 20 % per pixel at 160 pixels")
    noise_rel: float = knob(0.005, "heuristic", "a depth map's own noise, as a share of the depth (a box 30 cm "
                                               "before a wall 6 m away stays apart)")
    join_rel: float = knob(0.02, "heuristic", "neighbours this close in depth are one surface whatever their "
                                             "normals (a box's top and front at a grazing angle)")
    crease_px: float = knob(3.0, "heuristic", "neighbours within this many pixel footprints in space meet at a "
                                             "crease")
    support_deg: float = knob(15.0, "heuristic", "a support pixel's normal is within this of up (estimated "
                                                "normals wander a few degrees)")
    support_height_rel: float = knob(0.03, "heuristic", "and its height within this share of its distance of "
                                                       "the support's (a table top 0.3 m up at 4 m is not floor)")
    min_thickness_rel: float = knob(0.02, "sampling", "the thinnest extrusion, as a share of the occluder's "
                                                     "distance: a sliver of a few pixels still blocks rays")
    wall_half_length: float = knob(100.0, "physical", "metres of a wall beyond the frame either side: without "
                                                     "end for shadows")


@dataclass(frozen=True, kw_only=True)
class EvidenceConfig:
    """The support's cast-shadow evidence (``shadow_evidence``)."""

    lit_degree: int = knob(3, "heuristic", "the lit level is a polynomial of this degree in the ground's "
                                          "coordinates (a lamp's fall-off, a far wall's soft shade; a tabletop "
                                          "object's shadow is too small for it)")
    max_lit_pixels: int = knob(20000, "sampling", "pixels the lit level is fitted on (a stride: a low-order "
                                                 "surface needs few)")
    lit_iters: int = knob(4, "sampling", "iterations of the lit level (fit, call the pixels below it dark, refit); "
                                        "it settles in three")
    dark_sigmas: float = knob(3.0, "statistical", "a pixel this many noise scales below the lit level is dark "
                                                 "(0.1 % of Gaussian noise)")
    weber: float = knob(0.02, "physical", "and at least this much darker: Weber's contrast, the least a viewer sees")
    darkest: float = knob(0.99, "physical", "and at most this much (a shading ratio is above 0): with a noise so "
                                           "large that nothing stands out, the threshold stays finite")
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


@dataclass(frozen=True, kw_only=True)
class SearchConfig:
    """The direction search, its posterior, the light's size and strength (``estimate``,
    ``shadowcast``)."""

    temperature: float = knob(30.0, "fitted", "the posterior's one temperature: the best mean log score of the "
                                              "true direction (benchmarks/fit_light_constants.py, "
                                              "docs/fit_light_constants.txt)")
    elevation_prior_power: float = knob(0.0, "fitted", "the prior over directions has the density "
                                                       "cos(elevation) ** -power per steradian (1: uniform in the "
                                                       "elevation angle; 0: uniform over the hemisphere): the best "
                                                       "mean log score with the temperature and the photometric "
                                                       "weight (fit_light_constants.py --prior-grid)")
    photo_weight: float = knob(1.0, "fitted", "the photometric likelihood's independent observations per held-out "
                                              "block (its pixels are correlated: between one and the block's "
                                              "pixel count): the best mean log score with the temperature "
                                              "(fit_light_constants.py)")
    prior_sky_share: float = knob(0.46, "fitted", "the sky's share of the support's light where the photograph does "
                                                  "not tell it: the median true share (fit_light_constants.py)")
    prior_sky_share_spread: float = knob(0.23, "fitted", "that share's spread over the development cases: the "
                                                         "prior's weight against the shadows' measurement "
                                                         "(fit_light_constants.py)")
    radii_deg: tuple = knob((0.0, 1.0, 2.0, 4.0, 8.0, 16.0), "sampling", "angular radii a sun's size is chosen "
                                                                          "among (the Sun's own besides)")
    lamp_distances_rel: tuple = knob((0.3, 0.6, 1.2, 2.4), "sampling", "a lamp's distances along a direction, in "
                                                                         "units of the support's median distance "
                                                                         "(a relative depth gives the same)")
    lamp_top: int = knob(8, "sampling", "lamps are scored along this many best directions and screen picks")
    screen_iters: int = knob(1, "sampling", "IRLS iterations of the lamps' unshadowed screen (the scored ones get "
                                           "the solver's full count)")
    min_elevation_deg: float = knob(2.0, "physical", "the lowest candidate: a light in the ground's plane lights "
                                                    "nothing on it")
    soft_deg: float = knob(10.0, "sampling", "the soft alternative of each candidate's shadow (its likelihood "
                                            "marginalised over a hard and a soft one): about the grid's spacing")
    refine_directions: int = knob(40, "sampling", "directions of the refinement around the best coarse one")
    cone_per_rms: float = knob(math.sqrt(2.0), "statistical", "a cone of half-angle a spreads directions with RMS "
                                                              "a / sqrt(2): the radius that covers a posterior")
    max_radius_deg: float = knob(45.0, "physical", "the widest light a shadow is drawn for (wider is sky)")
    few_pixels: int = knob(50, "statistical", "fewer fit pixels than this fit nothing: the prior's light")
    bias_rel: float = knob(0.01, "sampling", "a shadow ray starts this share of its depth off the surface (the mesh "
                                            "is float32 in Embree, the depth map steps about a percent)")
    sigma_min: float = knob(0.02 / 3.0, "physical", "the least noise of the log shading: Weber's 2 % over three "
                                                    "(exact renders have none)")
    log_floor: float = knob(1e-3, "physical", "the least shadowed/lit ratio fitted: an umbra with no sky left")



@dataclass(frozen=True, kw_only=True)
class SolverConfig:
    """The robust NNLS of the light's strengths (``solver``)."""

    huber_c: float = knob(1.345, "statistical", "Huber's constant: 95 % efficiency under Gaussian noise")
    mad_to_sigma: float = knob(1.4826, "statistical", "the median absolute deviation of a Gaussian over its sigma")
    sigma_floor: float = knob(0.02, "physical", "the least noise scale over the data's: a render's noise, Weber's "
                                               "2 %")
    irls_iters: int = knob(4, "sampling", "iterations of the reweighted least squares: the weights settle in three")
    max_unseen: float = knob(0.5, "statistical", "unseen shadows hold at most half the pixels (beyond, the light "
                                                "is not what the frame says)")
    unseen_init: float = knob(0.1, "statistical", "the unseen shadows' share the EM starts from")
    prior_ridge: float = knob(0.02 ** 2, "statistical", "the ridge toward the prior weights per pixel over the data "
                                                       "scale squared: a departure as large as the prior costs a "
                                                       "noise-floor residual on every pixel")


@dataclass(frozen=True, kw_only=True)
class FrameConfig:
    """The scene's frame, support and walls (``scene_frame``, ``planes``, ``atoms``)."""

    support_deg: float = knob(15.0, "heuristic", "a fit pixel is on the support when its normal is within this of "
                                                "up")
    holdout_blocks: int = knob(12, "sampling", "the frame is cut into this many blocks of its long side, held out "
                                              "in a checkerboard: a share of the frame at any resolution")
    albedo_offsets: tuple = knob((0.0, 0.01, 0.02, 0.04, 0.08, 0.16), "sampling", "the albedo offsets (a specular "
                                                                                 "layer's share) tried")
    offset_min_gain: float = knob(0.01, "heuristic", "a larger offset is taken when it explains held-out pixels "
                                                    "this much better")
    wall_vertical_deg: float = knob(15.0, "heuristic", "a wall's normal is within this of the ground")
    wall_azimuth_bins: int = knob(36, "sampling", "azimuth bins of the walls' vote")
    wall_offset_bin_rel: float = knob(0.03, "sampling", "offset bins of the walls' vote, a share of the depth")
    min_wall_share: float = knob(0.02, "heuristic", "a plane thinner in the frame than this share of the valid "
                                                   "pixels tells too little of itself to be a wall")
    max_walls: int = knob(4, "heuristic", "walls found at most")
    support_bins: int = knob(400, "sampling", "directions of the sphere world up is voted on (scene_frame)")
    max_tilt_deg: float = knob(60.0, "heuristic", "a support's normal is within this of the camera's +y (a wall "
                                                 "facing the camera is no support)")
    min_support_normals: int = knob(3, "statistical", "fewer normals than this elect no support")


@dataclass(frozen=True, kw_only=True)
class TransportConfig:
    """The synthesis's light transport (``renderer``, ``softshadow``, ``meshshadow``,
    ``visibility``): each light's soft shadow (one screen-space march, then the penumbra
    filter), the sky's visibility, and the object's posed mesh (its shadow map and the
    sky it hides). The light fit's sky atoms read the sky's fields too
    (``atoms.sky_visibility``), so that the fit and the synthesis see one sky."""

    march_range_rel: float = knob(0.8, "heuristic", "a screen-space shadow ray's length, a share of its point's "
                                                    "depth (a lamp's ends at the lamp if nearer): a judgement, long "
                                                    "enough for a standing object's shadow across its support")
    march_bias_rel: float = knob(0.01, "heuristic", "a shadow ray starts this share of its point's depth off the "
                                                    "surface, and a texel occludes only this far in front of it (the "
                                                    "object's shadow map's bias too): about the depth map's own step, "
                                                    "so a surface does not shadow itself")
    march_thickness_rel: float = knob(0.15, "heuristic", "the 2.5D depth has no back side: a texel occludes a ray "
                                                         "passing less than this share of its depth behind it (the "
                                                         "guessed thickness of what it shows; thicker lengthens a "
                                                         "thin object's shadow, docs/calibration-record.md)")
    penumbra_levels_px: tuple = knob((0.0, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0), "sampling",
                                     "radii (pixels) of the blur levels the penumbra filter interpolates between "
                                     "(linear in log2(1 + r): no bands); the first is the hard shadow, the last "
                                     "the widest penumbra drawn")
    blocker_search_px: int = knob(24, "heuristic", "radius (pixels) over which the blocker search averages the "
                                                   "occluder distance of the shadowed pixels around a pixel (its "
                                                   "penumbra's width): a judgement, reaching across most of the "
                                                   "widest penumbra")
    full_res_pixels: int = knob(256 * 256, "sampling", "frames with more pixels than this march the direct shadow "
                                                       "on a stride-2 grid and the sky's visibility on a stride-4 "
                                                       "one (else 1 and 2): a quarter of the rays, which the "
                                                       "filters smooth anyway")
    sky_directions: int = knob(8, "sampling", "cosine-distributed directions per pixel of the sky's screen-space "
                                              "visibility, turned per pixel (the blur averages the neighbours' "
                                              "turns)")
    sky_steps: int = knob(12, "sampling", "samples per ray of the sky's visibility")
    sky_range_rel: float = knob(0.8, "heuristic", "a sky ray's length, a share of its point's depth: as far as a "
                                                  "shadow ray goes (march_range_rel), so that a wall metres away "
                                                  "hides the sky behind it")
    sky_blur_px: float = knob(3.0, "heuristic", "radius (pixels) of the class-wise blur that smooths the sky's "
                                                "visibility (at least 1.5 strides of its grid): a judgement, wide "
                                                "enough to average its few directions' per-pixel turns")
    sky_bounce: float = knob(0.5, "heuristic", "share of the scene's mean albedo the occluded sky directions still "
                                               "receive (the light bounced off the occluders, mostly vertical "
                                               "faces, which see half the sky): pure occlusion made an object's "
                                               "base on its floor too dark")
    mesh_ao_fade: float = knob(0.35, "heuristic", "outer share of the shading mask's radius over which the "
                                                  "object's sky occlusion fades out (cut at the mask's edge it drew "
                                                  "an ellipse; the fade was measured on seed 8128, "
                                                  "docs/calibration-record.md; the share is a judgement)")
    edge_fade_blurs: float = knob(2.0, "heuristic", "an estimated light's shadow fades out at the shading mask's "
                                                    "edge over this many sky blur radii (sky_blur_px): the width "
                                                    "over which the compositor's blur would otherwise show the cut")
    mesh_shadow_cells: int = knob(256, "sampling", "cells of the object's shadow map across the posed mesh's "
                                                   "extent seen from the light")
    mesh_sample_density: float = knob(8.0, "sampling", "surface samples of the mesh per shadow-map cell of its "
                                                       "area (stratified; a 3 x 3 max filter closes the gaps)")
    mesh_max_samples: int = knob(200_000, "sampling", "at most this many shadow-map samples: a dense mesh's "
                                                      "shadow costs no more (20 ms)")
    mesh_ao_discs: int = knob(512, "sampling", "area elements a mesh is cut into for the sky it hides: 1024, at "
                                               "twice the cost, scored 0.04 dB more on seed 8128 (shadow IoU "
                                               "0.387 vs 0.385)")
    near_field_spacings: float = knob(2.0, "sampling", "within this many element spacings (the square root of an "
                                                       "element's area) of a point the mesh's own triangles stand in "
                                                       "for its elements: by a sphere of radius 0.5, 1 and 1.5 "
                                                       "spacings dipped to 0.71 and 0.54 where 0.80 and 0.63 are "
                                                       "exact; 2 is within 0.02 everywhere")
    near_field_triangles: int = knob(1000, "sampling", "triangles a point's near field may hold before the mesh is "
                                                       "simplified for it (vertex clustering; the surface moves "
                                                       "less than its radius / 12.6): a scan's 16x a 20480-face "
                                                       "sphere's cost 0.4 s a job")

    def __post_init__(self):
        lv = self.penumbra_levels_px
        if len(lv) < 2 or lv[0] != 0 or any(b <= a for a, b in zip(lv, lv[1:])):
            raise UsageError(f"physical renderer setting transport.penumbra_levels_px: expected 0 then increasing "
                             f"radii, at least two, got {list(lv)}")

    @property
    def max_penumbra_px(self) -> float:
        """The widest penumbra drawn (pixels): the last blur level."""
        return self.penumbra_levels_px[-1]

    @property
    def window_margin_px(self) -> int:
        """Context (pixels) a shadow's window needs around the pixels it shades: what the
        widest blur level's kernel (3 sigma, sigma = r / 2) and the blocker search read."""
        return int(math.ceil(3 * max(self.max_penumbra_px, self.blocker_search_px) / 2.0))

    @property
    def edge_fade_px(self) -> float:
        """Pixels over which an estimated light's shadow fades out at the mask's edge."""
        return self.edge_fade_blurs * self.sky_blur_px


@dataclass(frozen=True, kw_only=True)
class ProbeConfig:
    """A light probe's split into sources and sky (``probe``), the prefiltered sky the
    object's glossy reflection looks up, and the GGX BRDF's table (``gloss``)."""

    max_sources: int = knob(3, "heuristic", "a probe's compact sources taken as lights at most (the rest stays in "
                                            "its sky): a judgement, each costs a shadow march and filter a job")
    min_source_share: float = knob(0.02, "physical", "a source is taken while it brings at least this share of the "
                                                     "probe's irradiance on the support: a fainter shadow is under "
                                                     "Weber's 2 % contrast")
    max_width: int = knob(2048, "sampling", "a probe is read at most this wide (area-averaged), its sources' sizes "
                                            "measured at that resolution (the bundled maps are 1024 wide: 0.35 "
                                            "deg texels)")
    sky_width: int = knob(128, "sampling", "width of the copy the sky's order-2 SH is projected from (smooth at "
                                           "any finer one)")
    gloss_width: int = knob(64, "sampling", "width of the copy the glossy prefilter convolves (every pair of its "
                                            "texels: the cost grows as its fourth power)")
    gloss_roughness: tuple = knob((0.05, 0.15, 0.3, 0.5, 0.75, 1.0), "sampling",
                                  "perceptual GGX roughness levels of the prefiltered sky (linear between them)")
    model_map_width: int = knob(64, "sampling", "width of the equirectangular map (height half) a fitted light's "
                                                "sky, order-2 SH and smooth, is rendered into for its prefilter")
    min_alpha: float = knob(1e-3, "heuristic", "the least GGX alpha (roughness squared): a perfect mirror's delta "
                                               "lobe cannot be evaluated toward a light; a judgement: a roughness "
                                               "below 0.03 is drawn as 0.03")
    env_lut_size: int = knob(32, "sampling", "roughness x n.v nodes of the split-sum environment BRDF's table "
                                             "(bilinear between them)")
    env_lut_samples: int = knob(1024, "sampling", "GGX samples per node of that table (Hammersley points): within "
                                                  "1e-4 of 64x as many at the median node, 0.025 at the worst "
                                                  "(grazing n.v = 0.03); 0.08 s once per process")

    def __post_init__(self):
        r = self.gloss_roughness
        if len(r) < 2 or any(b <= a for a, b in zip(r, r[1:])) or r[-1] > 1:
            raise UsageError(f"physical renderer setting probe.gloss_roughness: expected increasing roughness "
                             f"levels in [0, 1], at least two, got {list(r)}")


SUBCONFIGS = {"mesh": MeshConfig, "evidence": EvidenceConfig, "search": SearchConfig, "solver": SolverConfig,
              "frame": FrameConfig, "transport": TransportConfig, "probe": ProbeConfig}


@dataclass(frozen=True, kw_only=True)
class PhysicalSettings:
    """Settings of the physical renderer (all optional; module docstring)."""

    n_light_candidates: int = knob(256, "setting", "directions on the hemisphere the light search scores (then "
                                                   "refined around the best): a sampling resolution")
    march_steps: int = knob(32, "setting", "samples per shadow ray when synthesising")
    estimate_march_steps: int = knob(16, "setting", "samples per screen-space ray in the light fit (the sky's "
                                                    "visibility)")
    max_resolution: int = knob(160, "setting", "long side of the copy the light's strengths are fitted on (pixels)")
    cone_samples: int = knob(8, "setting", "directions per pixel over a light's cone in the fit")
    shadow_softness: float | None = knob(None, "setting", "the lights' angular radius in degrees instead of the "
                                                          "fitted one (None: not forced)")
    max_fit_pixels: int = knob(2000, "setting", "pixels of the copy the light is fitted on (a deterministic stride)")
    shadow_resolution: int = knob(256, "setting", "long side of the copy whose depth mesh the light rays are cast "
                                                  "through and whose support's shadows are read")
    max_receivers: int = knob(3000, "setting", "support pixels the candidate lights' shadows are cast from")
    mesh: MeshConfig = _sub(MeshConfig, "the depth mesh")
    evidence: EvidenceConfig = _sub(EvidenceConfig, "the cast-shadow evidence")
    search: SearchConfig = _sub(SearchConfig, "the direction search and its posterior")
    solver: SolverConfig = _sub(SolverConfig, "the robust NNLS")
    frame: FrameConfig = _sub(FrameConfig, "the scene's frame, support and walls")
    transport: TransportConfig = _sub(TransportConfig, "the synthesis's shadows, sky occlusion and mesh shadow")
    probe: ProbeConfig = _sub(ProbeConfig, "the light probe's split and the glossy reflection")

    @classmethod
    def from_kwargs(cls, **kw) -> "PhysicalSettings":
        """Validated settings; unknown names or bad values raise ``UsageError``. A nested
        config is given as a mapping of its fields."""
        from zcomp_cli.limits import shorten

        names = [f.name for f in dataclasses.fields(cls)]
        unknown = set(kw) - set(names)
        if unknown:
            raise UsageError(f"unknown physical renderer setting(s): {', '.join(sorted(unknown))}; "
                             f"known: {', '.join(names)}")
        for k in ("n_light_candidates", "march_steps", "estimate_march_steps", "max_resolution",
                  "cone_samples", "max_fit_pixels", "shadow_resolution", "max_receivers"):
            if k in kw:
                v = kw[k]
                if isinstance(v, bool) or not isinstance(v, numbers.Integral) or not 1 <= v <= 1_000_000:
                    raise UsageError(f"physical renderer setting {k}: expected an integer in [1, 1000000], "
                                     f"got {shorten(v)}")
        sv = kw.get("shadow_softness")
        if sv is not None and (isinstance(sv, bool) or not isinstance(sv, (int, float))
                               or not (0 <= float(sv) <= 60)):
            raise UsageError(f"physical renderer setting shadow_softness: expected degrees in [0, 60], "
                             f"got {shorten(sv)}")
        out = {}
        for k, v in kw.items():
            if k in SUBCONFIGS:
                out[k] = _config_from(k, v)
            elif isinstance(v, numbers.Integral) and not isinstance(v, bool):
                out[k] = int(v)
            elif k == "shadow_softness" and v is not None:
                out[k] = float(v)
            else:
                out[k] = v
        return cls(**out)

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


def _config_from(name: str, value):
    """A nested config from a mapping of its fields (or the config itself), checked."""
    from zcomp_cli.limits import shorten

    cls = SUBCONFIGS[name]
    if isinstance(value, cls):
        return value
    if not isinstance(value, dict):
        raise UsageError(f"physical renderer setting {name}: expected a mapping of {cls.__name__}'s fields, "
                         f"got {shorten(value)}")
    fields = {f.name: f for f in dataclasses.fields(cls)}
    bad = set(value) - set(fields)
    if bad:
        raise UsageError(f"physical renderer setting {name}: unknown field(s) {', '.join(sorted(bad))}; "
                         f"known: {', '.join(fields)}")
    out = {}
    for k, v in value.items():
        default = fields[k].default
        if isinstance(default, tuple):
            ok = isinstance(v, (list, tuple)) and v and all(
                isinstance(x, numbers.Real) and not isinstance(x, bool) and math.isfinite(x) and x >= 0 for x in v)
            if not ok:
                raise UsageError(f"physical renderer setting {name}.{k}: expected a list of non-negative numbers, "
                                 f"got {shorten(v)}")
            out[k] = tuple(float(x) for x in v)
        else:
            ok = isinstance(v, numbers.Real) and not isinstance(v, bool) and math.isfinite(v) and v > 0
            if isinstance(default, int):
                ok = ok and float(v).is_integer()
            if not ok:
                raise UsageError(f"physical renderer setting {name}.{k}: expected a positive "
                                 f"{'integer' if isinstance(default, int) else 'number'}, got {shorten(v)}")
            out[k] = type(default)(v)
    return cls(**out)


def provenance(settings: "PhysicalSettings | None" = None) -> list[dict]:
    """Every field of the settings and their nested configs: ``{"name", "value", "kind",
    "why"}`` (a nested field's name dotted: ``search.temperature``)."""
    settings = DEFAULTS if settings is None else settings
    out = []

    def walk(obj, prefix):
        for f in dataclasses.fields(obj):
            v = getattr(obj, f.name)
            if dataclasses.is_dataclass(v):
                walk(v, f"{prefix}{f.name}.")
            else:
                out.append({"name": prefix + f.name, "value": v, "kind": f.metadata.get("kind"),
                            "why": f.metadata.get("why")})

    walk(settings, "")
    return out


DEFAULTS = PhysicalSettings()

__all__ = ["PhysicalSettings", "DEFAULTS", "MeshConfig", "EvidenceConfig", "SearchConfig", "SolverConfig",
           "FrameConfig", "TransportConfig", "ProbeConfig", "KINDS", "knob", "provenance"]
