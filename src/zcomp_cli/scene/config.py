"""The scene's configs: its depth mesh, its frame and walls, a probe's split, the
screen-space march (each field declared once with its provenance and range:
``zcomp_cli.knobs``).

* ``MeshConfig``: the depth mesh the light rays are cast through (``depthmesh``);
* ``FrameConfig``: the scene's frame, support and walls (``frame``, ``planes``, and
  the light fit's pixels);
* ``ProbeConfig``: a light probe's split into sources and sky (``probe``);
* ``MarchConfig``: the screen-space march and the sky's visibility (``march``,
  ``skyvis``);
* ``BrdfTable``: the tables of the GGX specular layer (``brdf``).
"""

from __future__ import annotations

from dataclasses import dataclass

from zcomp_cli.knobs import knob, sub


@dataclass(frozen=True, kw_only=True)
class MeshConfig:
    """The depth mesh (``depthmesh``)."""

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
                                                "normals wander a few degrees)", hi=90.0)
    support_height_rel: float = knob(0.03, "heuristic", "and its height within this share of its distance of "
                                                       "the support's (a table top 0.3 m up at 4 m is not floor)")
    min_thickness_rel: float = knob(0.02, "sampling", "the thinnest extrusion, as a share of the occluder's "
                                                     "distance: a sliver of a few pixels still blocks rays")
    wall_half_length: float = knob(100.0, "physical", "metres of a wall beyond the frame either side: without "
                                                     "end for shadows")
    sky_edges_cast: bool = knob(False, "setting", "an occluder's edge with the sky above it (pixels of no geometry: "
                                                 "a wall's top seen) is a silhouette, and the wall a caster whose "
                                                 "shadow is read. Off: on the four development seeds of "
                                                 "benchmarks/run_benchmark.py (88 cases) it moved 6 cases, +0.7, "
                                                 "+0.6, +0.3, -0.1, -0.1 and -9.9 dB near the object (a far floor "
                                                 "past a wall's end tied to it: a low sun drawn; "
                                                 "docs/design-notes.md)")

@dataclass(frozen=True, kw_only=True)
class FrameConfig:
    """The scene's frame, support and walls (``scene_frame``, ``planes``, ``atoms``)."""

    support_deg: float = knob(15.0, "heuristic", "a fit pixel is on the support when its normal is within this of "
                                                "up", hi=90.0)
    holdout_blocks: int = knob(12, "sampling", "the frame is cut into this many blocks of its long side, held out "
                                              "in a checkerboard: a share of the frame at any resolution")
    specular_roughness: tuple = knob((0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0), "sampling",
                                     "the roughnesses of the scene's specular layer the fit chooses among "
                                     "(light.atoms.specular_roughness; a dielectric's, F0 0.04): Blender's range, "
                                     "every 0.1 from 0.2 (smoother: a mirror's reflection, not a sheen)", hi=1.0)
    wall_vertical_deg: float = knob(15.0, "heuristic", "a wall's normal is within this of the ground", hi=90.0)
    wall_azimuth_bins: int = knob(36, "sampling", "azimuth bins of the walls' vote")
    wall_offset_bin_rel: float = knob(0.03, "sampling", "offset bins of the walls' vote, a share of the depth")
    min_wall_share: float = knob(0.02, "heuristic", "a plane thinner in the frame than this share of the valid "
                                                   "pixels tells too little of itself to be a wall", hi=1.0)
    max_walls: int = knob(4, "heuristic", "walls found at most")
    support_bins: int = knob(400, "sampling", "directions of the sphere world up is voted on (scene_frame)")
    max_tilt_deg: float = knob(60.0, "heuristic", "a support's normal is within this of the camera's +y (a wall "
                                                 "facing the camera is no support)", hi=90.0)
    min_support_normals: int = knob(3, "statistical", "fewer normals than this elect no support")

@dataclass(frozen=True, kw_only=True)
class ProbeConfig:
    """A light probe's split into sources and sky (``probe``)."""

    max_sources: int = knob(3, "heuristic", "a probe's compact sources taken as lights at most (the rest stays in "
                                            "its sky): a judgement, each costs a shadow march and filter a job")
    min_source_share: float = knob(0.02, "physical", "a source is taken while it brings at least this share of the "
                                                     "probe's irradiance on the support: a fainter shadow is under "
                                                     "Weber's 2 % contrast", hi=1.0)
    max_width: int = knob(2048, "sampling", "a probe is read at most this wide (area-averaged), its sources' sizes "
                                            "measured at that resolution (the bundled maps are 1024 wide: 0.35 "
                                            "deg texels)", hi=16384)
    sky_width: int = knob(128, "sampling", "width of the copy the sky's order-2 SH is projected from (smooth at "
                                           "any finer one)", hi=4096)


@dataclass(frozen=True, kw_only=True)
class MarchConfig:
    """The screen-space march through the depth map (``march``) and the sky's visibility
    it measures (``skyvis``): the light fit's sky atoms and the synthesis read the same,
    so that the fit and the synthesis see one sky."""

    march_range_rel: float = knob(0.8, "heuristic", "a screen-space shadow ray's length, a share of its point's "
                                                    "depth (a lamp's ends at the lamp if nearer): a judgement, long "
                                                    "enough for a standing object's shadow across its support", hi=100.0)
    march_bias_rel: float = knob(0.01, "heuristic", "a shadow ray starts this share of its point's depth off the "
                                                    "surface, and a texel occludes only this far in front of it (the "
                                                    "object's shadow map's bias too): about the depth map's own step, "
                                                    "so a surface does not shadow itself", hi=1.0)
    march_thickness_rel: float = knob(0.15, "heuristic", "the 2.5D depth has no back side: a texel occludes a ray "
                                                         "passing less than this share of its depth behind it (the "
                                                         "guessed thickness of what it shows; thicker lengthens a "
                                                         "thin object's shadow, docs/calibration-record.md)")
    sky_directions: int = knob(8, "sampling", "cosine-distributed directions per pixel of the sky's screen-space "
                                              "visibility, turned per pixel (the blur averages the neighbours' "
                                              "turns)")
    sky_steps: int = knob(12, "sampling", "samples per ray of the sky's visibility")
    sky_range_rel: float = knob(0.8, "heuristic", "a sky ray's length, a share of its point's depth: as far as a "
                                                  "shadow ray goes (march_range_rel), so that a wall metres away "
                                                  "hides the sky behind it", hi=100.0)


@dataclass(frozen=True, kw_only=True)
class ObjectShadowConfig:
    """The inserted object's shadow map from each light (``objectshadow``)."""

    mesh_shadow_cells: int = knob(256, "sampling", "cells of the object's shadow map across the posed mesh's "
                                                   "extent seen from the light", hi=4096)
    mesh_sample_density: float = knob(8.0, "sampling", "surface samples of the mesh per shadow-map cell of its "
                                                       "area (stratified; a 3 x 3 max filter closes the gaps)", hi=1024.0)
    mesh_max_samples: int = knob(200_000, "sampling", "at most this many shadow-map samples: a dense mesh's "
                                                      "shadow costs no more (20 ms)")
    lamp_map_cells: int = knob(1 << 22, "sampling", "a lamp's shadow map at most this many cells whatever the "
                                                    "lamp's place (a lamp 1 cm beside a box made one of 11 GB from "
                                                    "its samples' tangents near its plane): 4 Mi float64 cells, "
                                                    "32 MB, about a 2048 x 2048 image's map; met by coarser cells "
                                                    "only where the receivers' field is that much wider than the "
                                                    "mesh", hi=1 << 26)
    lamp_near_plane_tan: float = knob(1e-3, "heuristic", "samples and receivers within this tangent of a lamp's "
                                                         "plane (0.06 deg) are left out of its gnomonic map (their "
                                                         "tangents pass its inverse)", hi=0.1)
    lamp_one_map_tan: float = knob(1.0, "heuristic", "one gnomonic map serves a lamp that sees the mesh within "
                                                     "this tangent of its centre (45 deg); a nearer lamp (beside "
                                                     "the object, inside a lampshade), whose one map's cells would "
                                                     "stretch (10 times narrower at tangent 3), gets a cube map of "
                                                     "six faces within tangent 1", hi=10.0)


@dataclass(frozen=True, kw_only=True)
class ReachConfig:
    """Where a given light's shadow of the inserted object falls beyond the shading mask
    (``shadowreach``: the mask is grown along it, by every renderer that draws it)."""

    march_steps: int = knob(32, "sampling", "samples per screen-space shadow ray of the reach (the physical "
                                            "renderer's own march's)", hi=4096)
    full_res_pixels: int = knob(256 * 256, "sampling", "frames with more pixels than this are marched on a stride-2 "
                                                       "grid (the physical renderer's synthesis's threshold)",
                                hi=10**8)
    max_penumbra_px: float = knob(32.0, "sampling", "the widest penumbra the reach is grown by (pixels: the physical "
                                                    "renderer's widest blur level)", hi=1024.0)
    object_shadow: ObjectShadowConfig = sub(ObjectShadowConfig, "the object's shadow map from each light")


@dataclass(frozen=True, kw_only=True)
class BrdfTable:
    """The GGX specular layer's tables (``brdf``): the physical renderer's ``GlossConfig``
    takes its defaults from here (the object's gloss), the light's fit uses them as they
    are (the scene's own specular layer)."""

    min_alpha: float = knob(1e-3, "heuristic", "the least GGX alpha (roughness squared): a perfect mirror's delta "
                                               "lobe cannot be evaluated toward a light; a judgement: a roughness "
                                               "below 0.03 is drawn as 0.03", hi=1.0)
    env_lut_size: int = knob(32, "sampling", "roughness x n.v nodes of the split-sum environment BRDF's table "
                                             "(bilinear between them)", hi=512)
    env_lut_samples: int = knob(1024, "sampling", "GGX samples per node of that table (Hammersley points): within "
                                                  "1e-4 of 64x as many at the median node, 0.025 at the worst "
                                                  "(grazing n.v = 0.03); 0.08 s once per process", hi=65536)


__all__ = ["MeshConfig", "FrameConfig", "ProbeConfig", "MarchConfig", "ObjectShadowConfig", "ReachConfig", "BrdfTable"]
