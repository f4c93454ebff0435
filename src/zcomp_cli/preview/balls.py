"""Three reference balls standing on the support: grey diffuse, matte silver, mirror --
the light-check balls a VFX set shoots beside its HDR probe (issue 38).

The balls sit in a row along the ground's right direction, each touching the support at
its lowest point. ``write_balls_glb`` writes them as one glTF (their materials as glTF's
PBR, which Blender imports as its Principled BSDF); ``ball_bundle`` draws the object's
intrinsic maps analytically (a ray meets a sphere in closed form), so no Blender render
is needed for them, and the pipeline composites the balls as any object.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from zcomp_cli.chromeball import CHROME_REFLECTANCE


@dataclass(frozen=True)
class BallMaterial:
    """A ball's material: linear base colour (grey), metallic, perceptual roughness."""

    name: str
    color: float
    metallic: float
    roughness: float


# The three balls (left to right). Grey: the photographer's 18 % grey card (convention:
# mid-grey in a scene's tonal range), rough and not metallic. Silver: polished silver
# reflects about 0.95 of visible light (physical: handbook values 0.90-0.97), at a
# satin roughness of 0.35 (a judgement: sharp enough to show where the light is, rough
# enough to show its size). Mirror: the chrome ball a set shoots (``chromeball``'s
# reflectance), roughness 0.
BALLS = (
    BallMaterial("grey", 0.18, 0.0, 0.9),
    BallMaterial("silver", 0.95, 1.0, 0.35),
    BallMaterial("mirror", CHROME_REFLECTANCE, 1.0, 0.0),
)
# centre-to-centre spacing in ball diameters: a gap of half a diameter, so that each
# ball's reflection of its neighbour stays small
SPACING = 1.5
# the sphere's tessellation (icosphere subdivisions): 2562 vertices per ball, facets
# under 2 deg (smooth shading hides them at any preview size)
SUBDIVISIONS = 4


def ball_centres(diameter: float) -> np.ndarray:
    """(3, 3) object-frame centres (x right, y up, z toward the viewer; metres): the row
    centred on the origin, the balls' lowest points on y = 0."""
    r = 0.5 * float(diameter)
    step = SPACING * float(diameter)
    return np.array([[(k - 1) * step, r, 0.0] for k in range(len(BALLS))])


def write_balls_glb(path, diameter: float) -> None:
    """The three balls as one binary glTF at ``path`` (object frame of ``ball_centres``,
    Y up as zcomp reads meshes), one mesh and PBR material per ball."""
    import trimesh
    from trimesh.visual import TextureVisuals
    from trimesh.visual.material import PBRMaterial

    from zcomp_cli.imageio import atomic_path

    scene = trimesh.Scene()
    for mat, c in zip(BALLS, ball_centres(diameter)):
        m = trimesh.creation.icosphere(subdivisions=SUBDIVISIONS, radius=0.5 * float(diameter))
        m.apply_translation(c)
        m.visual = TextureVisuals(material=PBRMaterial(
            name=f"zcomp_{mat.name}", baseColorFactor=[mat.color, mat.color, mat.color, 1.0],
            metallicFactor=mat.metallic, roughnessFactor=mat.roughness))
        scene.add_geometry(m, node_name=f"ball_{mat.name}", geom_name=f"ball_{mat.name}")
    with atomic_path(path) as tmp:
        scene.export(str(tmp), file_type="glb")


def ball_bundle(camera, object_to_camera: np.ndarray, diameter: float, *, mesh_path=None, supersample: int = 3):
    """The balls' intrinsic maps seen by ``camera`` (an ``ObjectBundle``): z-depth,
    camera-frame normals, albedo (the base colour), roughness, metallic, the coverage
    mask (``supersample``^2 rays a pixel) and the footprint depth (the support plane's
    depth under each ball's disc of contact, where the depth alignment reads the
    floor). ``object_to_camera``: (4, 4) the pose (``Pose.object_to_camera``), its
    rotation orthonormal times one scale."""
    from zcomp_cli.bundle import ObjectBundle

    M = np.asarray(object_to_camera, np.float64)
    scale = float(np.cbrt(abs(np.linalg.det(M[:3, :3])))) if np.all(np.isfinite(M)) else float("nan")
    if not (math.isfinite(scale) and scale > 0 and math.isfinite(float(diameter)) and float(diameter) > 0):
        raise ValueError("object_to_camera must be a finite, non-degenerate pose and the diameter a positive "
                         f"number, got diameter {diameter!r}")
    C = ball_centres(diameter) @ M[:3, :3].T + M[:3, 3]
    rad = 0.5 * float(diameter) * scale
    up = M[:3, 1] / np.linalg.norm(M[:3, 1])
    base = M[:3, 3]
    H, W = camera.height, camera.width
    n_ss = max(1, int(supersample))
    offs = (np.arange(n_ss) + 0.5) / n_ss
    cover = np.zeros((H, W))
    ys, xs = np.mgrid[0:H, 0:W].astype(np.float64)
    for oy in offs:
        for ox in offs:
            t, _ = _hit(camera.ray(xs + ox, ys + oy), C, rad)
            cover += np.isfinite(t)
    cover /= n_ss * n_ss
    rays = camera.ray(xs + 0.5, ys + 0.5)
    t, which = _hit(rays, C, rad)
    hit = np.isfinite(t)
    depth = np.where(hit, t, 0.0)
    P = rays * depth[..., None]
    N = np.zeros((H, W, 3))
    N[hit] = (P[hit] - C[which[hit]]) / rad
    albedo = np.zeros((H, W, 3))
    rough = np.zeros((H, W))
    metal = np.zeros((H, W))
    for k, mat in enumerate(BALLS):
        sel = hit & (which == k)
        albedo[sel] = mat.color
        rough[sel] = mat.roughness
        metal[sel] = mat.metallic
    # the mask's partly covered edge pixels take their nearest ball's maps
    edge = (cover > 0) & ~hit
    if edge.any():
        from scipy import ndimage

        _, (iy, ix) = ndimage.distance_transform_edt(~hit, return_indices=True)
        for a in (depth, N, albedo, rough, metal):
            a[edge] = a[iy[edge], ix[edge]]
    # the footprint: the support plane (through the base point, normal up) under each
    # ball's contact disc of one radius
    denom = rays @ up
    with np.errstate(divide="ignore", invalid="ignore"):
        tp = np.where(np.abs(denom) > 1e-12, (base @ up) / denom, np.nan)
    Q = rays * tp[..., None]
    foot = np.zeros((H, W), bool)
    for c in C:
        contact = c - rad * up
        foot |= np.linalg.norm(Q - contact, axis=-1) <= rad
    foot &= np.isfinite(tp) & (tp > 0)
    fp = np.where(foot, tp, 0.0)
    meta = {"source": "preview balls", "object_height_m": float(diameter) * scale,
            "object_to_camera": M.tolist(), "up_camera": up.tolist()}
    if mesh_path is not None:
        meta["mesh"] = str(mesh_path)
    f32 = np.float32
    return ObjectBundle(depth=depth.astype(f32), normals=N.astype(f32), albedo=albedo.astype(f32),
                        mask=cover.astype(f32), footprint_depth=fp.astype(f32), camera=camera, meta=meta,
                        roughness=rough.astype(f32), metallic=metal.astype(f32))


def _hit(rays: np.ndarray, centres: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Nearest ray-sphere hit: (t (H, W), inf where none; index of the sphere). The rays
    have z = -1, so t is the z-depth."""
    best = np.full(rays.shape[:2], np.inf)
    which = np.full(rays.shape[:2], -1)
    rr = np.einsum("...k,...k->...", rays, rays)
    for k, c in enumerate(centres):
        b = rays @ c
        disc = b * b - rr * (c @ c - radius * radius)
        ok = disc >= 0
        with np.errstate(invalid="ignore"):
            t = (b - np.sqrt(np.where(ok, disc, 0.0))) / rr
        t = np.where(ok & (t > 0), t, np.inf)
        closer = t < best
        best = np.where(closer, t, best)
        which = np.where(closer, k, which)
    return best, which


__all__ = ["BallMaterial", "BALLS", "SPACING", "ball_centres", "write_balls_glb", "ball_bundle"]
