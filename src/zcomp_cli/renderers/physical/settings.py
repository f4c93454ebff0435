"""The physical renderer's settings and constants: declared once, each with its provenance
and range (``zcomp_cli.knobs``).

``PhysicalSettings`` holds the settings a user sets (the manifest's ``renderer: {name:
physical, <setting>: ...}``, the API's ``PhysicalRenderer(**settings)``) and, nested,
the renderer's knobs as frozen config dataclasses:

* ``TransportConfig``: the synthesis's shadows, the sky's visibility's blur and bounce,
  the object's posed mesh (``renderer``, ``softshadow``, ``scene.meshrays``);
* ``GlossConfig``: the object's glossy reflection (``gloss``);
* ``light``: the light stage's ``LightConfig`` (``zcomp_cli.light.config``): the fit of
  the light the renderer draws, and the screen-space march both read (one sky).

The light's settings may also stand beside the renderer's own, as before the light was
a stage of its own (``n_light_candidates=64``, ``search={...}``): they go into ``light``.
The whole config goes into each job's ``report.json`` (``PhysicalRenderer.settings``),
and what it holds is taken back (``from_kwargs``): a calibration script builds
configs, it never edits source files.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

from zcomp_cli.errors import UsageError
from zcomp_cli.knobs import KINDS, as_dict, from_mapping, knob, provenance as _provenance, sub
from zcomp_cli.light.config import LightConfig
from zcomp_cli.scene.config import BrdfTable, ObjectShadowConfig

LABEL = "physical renderer setting"


@dataclass(frozen=True, kw_only=True)
class TransportConfig:
    """The synthesis's light transport (``renderer``, ``softshadow``, ``scene.meshrays``): each
    light's soft shadow (one screen-space march, ``scene.march``, whose reach and
    bias are the light config's ``march``, then the penumbra filter), the sky's
    visibility's blur and bounce, and the object's posed mesh (its shadow map and the
    sky it hides)."""

    penumbra_levels_px: tuple = knob((0.0, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0), "sampling",
                                     "radii (pixels) of the blur levels the penumbra filter interpolates between "
                                     "(linear in log2(1 + r): no bands); the first is the hard shadow, the last "
                                     "the widest penumbra drawn", hi=1024.0)
    blocker_search_px: int = knob(24, "heuristic", "radius (pixels) over which the blocker search averages the "
                                                   "occluder distance of the shadowed pixels around a pixel (its "
                                                   "penumbra's width): a judgement, reaching across most of the "
                                                   "widest penumbra", hi=1024)
    full_res_pixels: int = knob(256 * 256, "sampling", "frames with more pixels than this march the direct shadow "
                                                       "on a stride-2 grid and the sky's visibility on a stride-4 "
                                                       "one (else 1 and 2): a quarter of the rays, which the "
                                                       "filters smooth anyway", hi=10**8)
    sky_blur_px: float = knob(3.0, "heuristic", "radius (pixels) of the class-wise blur that smooths the sky's "
                                                "visibility (at least 1.5 strides of its grid): a judgement, wide "
                                                "enough to average its few directions' per-pixel turns", hi=1024.0)
    sky_bounce: float = knob(0.5, "heuristic", "share of the scene's mean albedo the occluded sky directions still "
                                               "receive (the light bounced off the occluders, mostly vertical "
                                               "faces, which see half the sky): pure occlusion made an object's "
                                               "base on its floor too dark", lo=0.0, lo_open=False, hi=1.0)
    mesh_ao_fade: float = knob(0.35, "heuristic", "outer share of the shading mask's radius over which the "
                                                  "object's sky occlusion fades out (cut at the mask's edge it drew "
                                                  "an ellipse; the fade was measured on seed 8128, "
                                                  "docs/calibration-record.md; the share is a judgement)", hi=1.0)
    edge_fade_blurs: float = knob(2.0, "heuristic", "an estimated light's shadow fades out at the shading mask's "
                                                    "edge over this many sky blur radii (sky_blur_px): the width "
                                                    "over which the compositor's blur would otherwise show the cut", lo=0.0, lo_open=False)
    object_shadow: ObjectShadowConfig = sub(ObjectShadowConfig, "the object's shadow map from each light")
    mesh_fade_samples: int = knob(512, "sampling", "surface samples of the object's mesh a pixel's distance to it "
                                                   "is measured from (the sky occlusion's fade toward the shading "
                                                   "mask's edge)", hi=65536)
    bounce_rays: int = knob(16, "sampling", "cosine-distributed rays per pixel of the object along which the "
                                            "light of what is not sky (the floor, a wall, itself) is gathered "
                                            "(reflect.bounce); 0: the support's radiance below its horizon and "
                                            "the occluders' bounce as a share of the scene's albedo, as the scene's "
                                            "own pixels get them", lo=0, lo_open=False, hi=4096)
    bounce_blur_px: float = knob(3.0, "sampling", "radius (pixels; sigma half of it) of the blur over the object's "
                                                  "pixels that averages the neighbours' bounce rays (each pixel's "
                                                  "turned apart): the bounce is an irradiance, smooth over the "
                                                  "surface; 16 rays a pixel under the film's filter alone left a "
                                                  "grain 8x the sky's and the sun's on a sphere", lo=0.0,
                                 lo_open=False, hi=64.0)
    support_trim: float = knob(0.1, "heuristic", "share of the support's pixels left out at either end of each "
                                                 "channel when what it reflects of the light is measured for the "
                                                 "floor beyond the frame (reflect.support_reflectance): the floor "
                                                 "a glint toward the camera or a prop misread as floor may take, "
                                                 "a judgement; symmetric, so a two-tone checker keeps its mean",
                               lo=0.0, lo_open=False, hi=0.45)
    light_samples: int = knob(16, "sampling", "points per pixel of a sun's or lamp's disc: the object's mesh is "
                                              "tested toward them (its soft shadow, scene.meshrays) and the direct "
                                              "shading is their mean (lightmodel.disc_shading)", hi=4096)
    sky_rays: int = knob(32, "sampling", "rays per point toward the sky the object's mesh may hide, drawn where "
                                         "the sky is bright", hi=4096)
    sky_pool: int = knob(512, "sampling", "directions drawn from the sky's map in proportion to its radiance, "
                                          "which the points share out (sky_rays each, stratified)", hi=65536)
    mesh_ray_bias_rel: float = knob(1e-3, "sampling", "a ray toward the object's mesh starts this share of its "
                                                      "point's depth off the surface: float32's precision in "
                                                      "Embree, far below the depth map's step", hi=1.0)
    film_sigma_px: float = knob(0.83, "physical", "standard deviation (pixels) of the film's pixel filter the "
                                                    "synthesised shading is filtered with: Cycles' Blackman-Harris "
                                                    "window of filter_width 1.5 (Blender's default, the ground "
                                                    "truth's), which Cycles stretches to +-1.5 px (scene/film.cpp); "
                                                    "0: shading at the pixel's centre only", lo=0.0, lo_open=False,
                                hi=8.0)
    whole_coverage: float = knob(0.999, "sampling", "an object's coverage from this up is whole (the anti-aliased "
                                                    "mask's own float rounding below 1)", hi=1.0)
    edge_reach_px: float = knob(2.0, "sampling", "radius (pixels; sigma half of it) over which a partly covered "
                                                 "pixel takes the object's and the surface's albedo and shading "
                                                 "from the pixels each covers wholly: a silhouette's anti-aliased "
                                                 "band is one or two pixels wide", hi=64.0)

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
class GlossConfig:
    """The object's glossy reflection (``gloss``): the prefiltered sky it looks up (a
    given probe's, or the fitted sky's map) and the GGX BRDF's table."""

    gloss_width: int = knob(64, "sampling", "width of the copy the glossy prefilter convolves (every pair of its "
                                            "texels: the cost grows as its fourth power)", hi=512)
    gloss_roughness: tuple = knob((0.05, 0.15, 0.3, 0.5, 0.75, 1.0), "sampling",
                                  "perceptual GGX roughness levels of the prefiltered sky (linear between them)", hi=1.0)
    model_map_width: int = knob(64, "sampling", "width of the equirectangular map (height half) a fitted light's "
                                                "sky, order-2 SH and smooth, is rendered into for its prefilter", hi=1024)
    # the GGX tables' sizes (scene.brdf), the scene's defaults: the same tables the light's fit reads
    min_alpha: float = knob(BrdfTable.min_alpha, "heuristic", "the least GGX alpha (scene.config.BrdfTable)", hi=1.0)
    env_lut_size: int = knob(BrdfTable.env_lut_size, "sampling", "nodes of the split-sum environment BRDF's table "
                                                                 "(scene.config.BrdfTable)", hi=512)
    env_lut_samples: int = knob(BrdfTable.env_lut_samples, "sampling", "GGX samples per node of that table "
                                                                       "(scene.config.BrdfTable)", hi=65536)

    highlight_samples: int = knob(16, "sampling", "points of each sun's and lamp's disc the object's highlight sums, "
                                             "each lobe widened by its point's share of the disc (its angular "
                                             "radius over sqrt of this); 1: the disc's centre, its lobe widened "
                                             "by the whole radius", hi=1024)
    reflect_rays: int = knob(8, "sampling", "GGX-distributed rays per pixel the object's reflection of its "
                                            "surroundings is gathered along (the mesh, the scene's texels, the "
                                            "support, the sky: scene.gather); 0: the prefiltered sky alone, "
                                            "occluded as the diffuse sky is", lo=0, lo_open=False, hi=256)
    reflect_steps: int = knob(16, "sampling", "samples per reflected ray through the depth map", hi=4096)
    reflect_blur_px: float = knob(1.5, "sampling", "radius (pixels; sigma half of it) of the blur over the "
                                                   "object's pixels that averages the neighbours' rays (each "
                                                   "pixel's turned apart)", lo=0.0, lo_open=False, hi=64.0)

    def __post_init__(self):
        r = self.gloss_roughness
        if len(r) < 2 or any(b <= a for a, b in zip(r, r[1:])) or r[-1] > 1:
            raise UsageError(f"physical renderer setting gloss.gloss_roughness: expected increasing roughness "
                             f"levels in [0, 1], at least two, got {list(r)}")

@dataclass(frozen=True, kw_only=True)
class PhysicalSettings:
    """Settings of the physical renderer (all optional; module docstring)."""

    march_steps: int = knob(32, "setting", "samples per shadow ray when synthesising", hi=4096)
    transport: TransportConfig = sub(TransportConfig, "the synthesis's shadows, sky occlusion and mesh shadow")
    gloss: GlossConfig = sub(GlossConfig, "the object's glossy reflection")
    light: LightConfig = sub(LightConfig, "the light stage's settings: the fit of the light this renderer draws")

    @classmethod
    def from_kwargs(cls, **kw) -> "PhysicalSettings":
        """Validated settings; unknown names or bad values raise ``UsageError``. A nested
        config is given as a mapping of its fields; the light's settings may stand
        beside the renderer's own (module docstring)."""
        return from_mapping(cls, with_light_settings(cls, kw, LABEL), LABEL)

    def as_dict(self) -> dict:
        return as_dict(self)


def with_light_settings(cls, kw: dict, label: str) -> dict:
    """``kw`` with the light stage's settings that stand beside a renderer's own (names of
    ``LightConfig``'s fields that ``cls`` has not) moved into its ``light`` mapping; one
    given both ways is refused."""
    own = {f.name for f in dataclasses.fields(cls)}
    flat = {k: kw[k] for k in kw if k not in own and k in {f.name for f in dataclasses.fields(LightConfig)}}
    if not flat:
        return dict(kw)
    out = {k: v for k, v in kw.items() if k not in flat}
    base = out.get("light", {})
    base = as_dict(base) if isinstance(base, LightConfig) else base
    if not isinstance(base, dict):
        return out  # from_mapping says what is wrong with it
    both = sorted(set(base) & set(flat))
    if both:
        raise UsageError(f"{label} {', '.join(both)}: given both beside the renderer's settings and in its "
                         "'light' mapping")
    out["light"] = {**base, **flat}
    return out


def provenance(settings: "PhysicalSettings | None" = None) -> list[dict]:
    """Every field of the settings and their nested configs (``knobs.provenance``)."""
    return _provenance(DEFAULTS if settings is None else settings)


DEFAULTS = PhysicalSettings()

__all__ = ["PhysicalSettings", "DEFAULTS", "TransportConfig", "GlossConfig", "KINDS", "knob", "provenance",
           "with_light_settings", "LABEL"]
