"""Step 1 of the light fit: the scene as the fit reads it (DESIGN.md section 8).

``prepare`` makes, from the photograph's maps, the working copy and its fit pixels (the
photometric fit's), the support's bounce (measured: the support's own image radiance),
the scene's specular layer (``atoms.specular_roughness``), the walls beyond the frame (``planes``),
the sky seen from each fit pixel (``skyvis``), and the scene's **depth mesh**
(``depthmesh``: discontinuities cut, occluders extruded backwards) with its ray tracer
(``raycast``, Embree), through which every light ray of the fit is cast, on a second
copy (``shadow_resolution``) where the support's cast shadows are read (``ShadowGrid``).

The mesh, its ray tracer and the shadow grid are built only for a fit that reads the
photograph's shadows (``reads_shadows``: a searched direction, a size to choose, the key
light's split from the sky; issue 49). A light given whole -- its directions, sizes and
strengths, or a probe -- is fitted without them: its exposure alone is free, and its
lights' rays are marched through the depth map (``march``), as the synthesis marches
them.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from zcomp_cli.camera import Camera
from zcomp_cli.conventions import REC601, unit_normal_mask
from zcomp_cli.light import atoms as at
from zcomp_cli.light.config import LightConfig
from zcomp_cli.scene.brdf import camera_offset


@dataclass(frozen=True)
class Prepared:
    """Step 1's products: fit pixels (their rays cast through the depth mesh), their
    shading (image over the albedo plus its specular layer's offset) less the bounce
    (N, 3), the sky seen from them (``atoms.sky_visibility``), the ground's radiance
    (3,), the ground frame (3, 3), the sky lobes' columns (N, L) (``atoms.sky_lobes``, in
    their order), the specular layer's roughness (NaN: none); the shadow grid
    (``ShadowGrid``) or None."""

    fp: at.FitPixels
    shading: np.ndarray
    sky_vis: tuple
    ground: np.ndarray
    frame: np.ndarray
    lobe_columns: np.ndarray
    specular_roughness: float = float("nan")
    grid: object | None = None

    @property
    def lum(self) -> np.ndarray:
        return self.shading @ REC601.astype(np.float64)

    @property
    def anchor(self) -> np.ndarray:
        """(3,) the support's centre (median of its fit pixels), where a lamp's direction
        is measured from."""
        pts = self.fp.support_points
        return np.median(pts, 0) if len(pts) else np.zeros(3)


@dataclass(frozen=True)
class ShadowGrid:
    """The copy the shadows are read on (``settings.shadow_resolution``): its depth mesh
    (``depthmesh.DepthMesh``), its ray tracer, the luminance of its shading (image over
    albedo plus offset), its albedo's luminance and known pixels."""

    mesh: object
    caster: object
    shading: np.ndarray
    albedo: np.ndarray
    known: np.ndarray


def reads_shadows(params, settings: LightConfig) -> bool:
    """Whether fitting the light tree ``params`` (``lightparams.LightParams``) reads the
    photograph's shadows -- the depth mesh, its ray tracer and the shadow grid
    (``ShadowGrid``): a sun whose direction is searched, a sun whose angular radius is
    chosen by its shadows (no ``shadow_softness`` forcing one), or a light of free
    strength beside a fitted sky (the key light's split, read across its shadows' edges)."""
    free_sky = params.probe is None and not params.sky.radiance_sh.frozen
    for s in params.suns:
        if not s.direction_given:
            return True
        if settings.shadow_softness is None and not s.radius_deg.frozen:
            return True
    free = [s for s in params.suns if not s.irradiance.frozen and s.share is None]
    free += [lp for lp in params.lamps if not lp.power.frozen]
    return bool(free) and free_sky


def prepare(depth, normals, shading, known, albedo, camera: Camera, up, settings: LightConfig, *,
            shadows: bool = True, steps: dict | None = None) -> Prepared:
    """Step 1 (module docstring).

    Args:
        depth: (H, W) z-depth, 0 invalid. normals: (H, W, 3) camera frame.
        shading: (H, W, 3) linear image / albedo, used where ``known`` (H, W) bool.
        albedo: (H, W, 3) linear albedo. camera: the view. up: (3,) world up, camera frame.
        settings: the light stage's config.
        shadows: build the depth mesh, its ray tracer and the shadow grid
            (``reads_shadows``); False: the fit pixels' rays are marched, ``grid`` is None.
        steps: where the seconds of the mesh and its tracer go (``shadows``; the job's
            ledger, ``light.ledger``), None: not recorded.
    """
    from zcomp_cli.light.ledger import timed
    from zcomp_cli.scene.depthmesh import build_depth_mesh
    from zcomp_cli.scene.planes import find_walls
    from zcomp_cli.threads import beside
    from zcomp_cli.worldframe import ground_frame

    # the shadows' copy: its walls beyond the frame, its mesh
    d2, n2, s2, k2, a2, cam2 = at.working_copy(depth, normals, shading, known, albedo, camera,
                                               settings.shadow_resolution)
    nn = np.linalg.norm(n2, axis=-1)
    geo = (d2 > 0) & unit_normal_mask(n2)
    walls = find_walls(cam2.unproject(d2), n2 / np.maximum(nn, 1e-12)[..., None], geo, up, settings.frame)
    d, n, s, k, a, cam = at.working_copy(depth, normals, shading, known, albedo, camera, settings.max_resolution)
    fp, S = at.fit_pixels(d, n, s, k, a, cam, up, max_fit_pixels=settings.max_fit_pixels, cfg=settings.frame,
                          march=settings.march, bias_rel=settings.search.bias_rel, walls=walls)
    frame = ground_frame(up)
    if len(fp) == 0:
        return Prepared(fp=fp, shading=S, sky_vis=(np.zeros((1, 0, 3)), np.zeros((1, 0))), ground=np.zeros(3),
                        frame=frame, lobe_columns=np.zeros((0, len(at.sky_lobes(frame)))))

    def shadow_mesh():
        with timed({} if steps is None else steps, "shadows"):
            m = build_depth_mesh(d2, n2, cam2, up, walls=walls, cfg=settings.mesh)
            return m, m.caster()

    # the depth mesh and its tracer are built on a second thread while this one fits the
    # photometric atoms (neither reads the other: the atoms' sky is marched on the depth)
    meshing = beside(shadow_mesh) if shadows else None
    ground = at.ground_radiance(fp, S)
    vis = at.sky_visibility(fp)
    S = np.maximum(S - at.bounce(fp, ground), 0.0)
    lobes = np.stack([at.sky_atom_values(fp, c, vis) for _, c in at.sky_lobes(frame)], 1)
    r = (at.specular_roughness(fp, S, lobes, cfg=settings.frame, solver=settings.solver) if fp.train.any()
         else float("nan"))
    if meshing is None:
        return Prepared(fp=fp, shading=at.offset_shading(fp, S, r), sky_vis=vis, ground=ground, frame=frame,
                        lobe_columns=lobes, specular_roughness=r)
    mesh, caster = meshing.result()
    fp = dataclasses.replace(fp, caster=caster)
    # the shadows' shading: the copy's image over its albedo (plus the specular layer's
    # offset), each area-averaged apart -- an anti-aliased albedo edge averages out in both,
    # where the average of per-pixel ratios keeps its error
    a2l = np.clip(np.nan_to_num(a2), 0, None)
    img2 = _area_copy(np.nan_to_num(np.asarray(shading, np.float64)) * np.clip(np.nan_to_num(albedo), 0, None),
                      s2.shape[:2])
    lum_img, lum_alb = img2 @ REC601, a2l @ REC601
    g2 = camera_offset(cam2.unproject(d2.astype(np.float32)), np.nan_to_num(n2), r,
                       np.clip(lum_alb, 0, 1).reshape(-1, 1)).reshape(lum_alb.shape)
    s2o = np.where(lum_alb > 1e-4, lum_img / np.maximum(lum_alb + g2, 1e-6), np.nan_to_num(s2 @ REC601))
    grid = ShadowGrid(mesh=mesh, caster=caster, shading=s2o, albedo=lum_alb, known=k2)
    return Prepared(fp=fp, shading=at.offset_shading(fp, S, r), sky_vis=vis, ground=ground, frame=frame,
                    lobe_columns=lobes, specular_roughness=r, grid=grid)


def _area_copy(img: np.ndarray, shape) -> np.ndarray:
    """``img`` (H, W, C) area-averaged to ``shape`` (h, w) (itself when the same size)."""
    import cv2

    h, w = shape
    if img.shape[:2] == (h, w):
        return img
    return cv2.resize(img.astype(np.float32), (w, h), interpolation=cv2.INTER_AREA).astype(np.float64)


__all__ = ["Prepared", "ShadowGrid", "prepare", "reads_shadows"]
