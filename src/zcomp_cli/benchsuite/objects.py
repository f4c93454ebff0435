"""Procedural objects for benchmarks and examples, built with trimesh and written as GLB.

Every object is in metres, +Y up (glTF), standing on ``y = 0`` and centred on the
y axis, so its base point (DESIGN.md section 3, ``pose.py``) is the origin. Colours are
linear albedo (glTF ``baseColorFactor`` is linear); textures are sRGB images (glTF
``baseColorTexture`` is sRGB), which Blender's glTF importer decodes accordingly.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from zcomp_cli.errors import GeometryError, InputError

SHAPES = ("box", "cylinder", "sphere", "cone", "torus", "capsule", "chair", "mug", "vase")


@dataclass(frozen=True)
class ObjectRecipe:
    """What a procedural object is made of.

    Attributes:
        shape: one of ``SHAPES``.
        color: linear RGB albedo in [0, 1].
        roughness: Principled roughness in [0, 1].
        texture: None, ``"checker"`` or ``"stripes"`` (a painted base-colour texture;
            ``color`` and ``color2`` are its two colours).
        color2: the second texture colour (linear RGB).
        aspect: width/height of the shape (the GLB is 1 m tall; poses rescale it).
    """

    shape: str
    color: tuple[float, float, float] = (0.6, 0.6, 0.6)
    roughness: float = 0.5
    texture: str | None = None
    color2: tuple[float, float, float] = (0.1, 0.1, 0.1)
    aspect: float = 0.6

    def __post_init__(self):
        if self.shape not in SHAPES:
            raise InputError(f"unknown procedural shape {self.shape!r}; known: {', '.join(SHAPES)}")
        if self.texture not in (None, "checker", "stripes"):
            raise InputError(f"unknown texture {self.texture!r}; known: checker, stripes")
        for c in (self.color, self.color2):
            if len(c) != 3 or not all(np.isfinite(v) and 0.0 <= v <= 1.0 for v in c):
                raise InputError(f"colours must be 3 values in [0, 1], got {c}")
        if not (0.05 <= self.aspect <= 20.0):
            raise InputError(f"aspect must be in [0.05, 20], got {self.aspect}")

    def to_dict(self) -> dict:
        return {"shape": self.shape, "color": list(self.color), "roughness": self.roughness,
                "texture": self.texture, "color2": list(self.color2), "aspect": self.aspect}


def _stack(parts):
    import trimesh

    return trimesh.util.concatenate(parts)


def _translated(mesh, xyz):
    mesh = mesh.copy()
    mesh.apply_translation(xyz)
    return mesh


def shape_mesh(shape: str, aspect: float = 0.6):
    """A watertight-ish trimesh of ``shape``, 1 m tall (+Y up), base point at the origin.

    ``aspect`` is the footprint width over the height (ignored by ``sphere``). Composite
    shapes (chair, mug) are unions of primitives, not booleans: rendering only needs
    closed surfaces, not a manifold.
    """
    import trimesh
    from trimesh import creation

    w = float(aspect)
    # trimesh builds cylinders/cones along +Z: turn them to +Y.
    z_to_y = trimesh.transformations.rotation_matrix(-np.pi / 2, [1, 0, 0])
    if shape == "box":
        m = creation.box(extents=[w, 1.0, w * 0.8])
    elif shape == "cylinder":
        m = creation.cylinder(radius=w / 2, height=1.0, sections=48)
        m.apply_transform(z_to_y)
    elif shape == "sphere":
        m = creation.icosphere(subdivisions=3, radius=0.5)
    elif shape == "cone":
        m = creation.cone(radius=w / 2, height=1.0, sections=48)
        m.apply_transform(z_to_y)
    elif shape == "torus":
        # A ring lying on the ground is flat; stand it up (a hoop) so it has height.
        m = creation.torus(major_radius=0.38, minor_radius=0.12, major_sections=48, minor_sections=16)
    elif shape == "capsule":
        m = creation.capsule(height=1.0 - w, radius=w / 2, count=[24, 24])
        m.apply_transform(z_to_y)
    elif shape == "chair":
        s = max(w, 0.4)
        leg, seat_h = 0.06, 0.45
        parts = [_translated(creation.box(extents=[leg, seat_h, leg]), [x * (s / 2 - leg / 2), seat_h / 2, z * (s / 2 - leg / 2)])
                 for x in (-1, 1) for z in (-1, 1)]
        parts.append(_translated(creation.box(extents=[s, 0.06, s]), [0, seat_h + 0.03, 0]))
        parts.append(_translated(creation.box(extents=[s, 1.0 - seat_h - 0.06, 0.05]),
                                 [0, seat_h + 0.06 + (1.0 - seat_h - 0.06) / 2, -s / 2 + 0.025]))
        m = _stack(parts)
    elif shape == "mug":
        r = max(w, 0.3) / 2
        body = creation.cylinder(radius=r, height=1.0, sections=48)
        body.apply_transform(z_to_y)
        # trimesh's torus lies in the XY plane: already an upright handle.
        handle = creation.torus(major_radius=0.22, minor_radius=0.045, major_sections=32, minor_sections=12)
        handle.apply_translation([r + 0.08, 0, 0])
        m = _stack([body, handle])
    elif shape == "vase":
        h = np.linspace(0, 1, 24)
        radius = (w / 2) * (0.55 + 0.45 * np.sin(np.pi * (0.15 + 0.85 * h)) ** 2)
        radius[0] = 0.0  # closed bottom
        profile = np.column_stack([np.r_[radius, 0.0], np.r_[h, 1.0]])
        m = creation.revolve(profile, sections=48)
        m.apply_transform(z_to_y)
    else:
        raise InputError(f"unknown procedural shape {shape!r}; known: {', '.join(SHAPES)}")
    # Base point to the origin: bbox bottom centre.
    lo, hi = m.bounds
    m.apply_translation([-(lo[0] + hi[0]) / 2, -lo[1], -(lo[2] + hi[2]) / 2])
    ext = m.extents[1]
    if not ext > 1e-9:
        raise GeometryError(f"procedural {shape} has no height")
    m.apply_scale(1.0 / ext)
    return m


def texture_image(kind: str, color, color2, size: int = 256) -> np.ndarray:
    """(size, size, 3) uint8 sRGB texture of two linear colours: ``checker`` (8x8) or
    ``stripes`` (8 diagonal bands)."""
    from zcomp_cli.imageio import to_uint8_srgb

    i, j = np.meshgrid(np.arange(size), np.arange(size), indexing="ij")
    cell = size // 8
    if kind == "checker":
        sel = ((i // cell) + (j // cell)) % 2 == 0
    elif kind == "stripes":
        sel = ((i + j) // cell) % 2 == 0
    else:
        raise InputError(f"unknown texture {kind!r}")
    lin = np.where(sel[..., None], np.asarray(color, np.float32), np.asarray(color2, np.float32))
    return to_uint8_srgb(lin)


def box_project_uv(mesh):
    """Give ``mesh`` per-corner UVs by box (tri-planar) projection: each face takes the
    two coordinates orthogonal to its dominant normal axis. Vertices are unmerged so
    that faces on different planes do not share UVs. Returns (mesh, uv (N, 2))."""
    m = mesh.copy()
    m.unmerge_vertices()
    fn = np.abs(m.face_normals)
    axis = np.argmax(fn, axis=1)
    uv = np.zeros((len(m.vertices), 2))
    keep = {0: (2, 1), 1: (0, 2), 2: (0, 1)}
    for f, a in zip(m.faces, axis):
        i, j = keep[int(a)]
        uv[f] = m.vertices[f][:, [i, j]]
    return m, uv


def build_object(recipe: ObjectRecipe):
    """The trimesh of ``recipe`` with its material (PBR colour or texture) attached."""
    import trimesh
    from PIL import Image

    m = shape_mesh(recipe.shape, recipe.aspect)
    if recipe.texture is None:
        mat = trimesh.visual.material.PBRMaterial(
            baseColorFactor=[*recipe.color, 1.0], roughnessFactor=recipe.roughness, metallicFactor=0.0)
        # No texture: the material's factor is the colour; UVs are not needed but a
        # TextureVisuals is what carries a glTF material in trimesh.
        m.visual = trimesh.visual.TextureVisuals(material=mat)
        return m
    m, uv = box_project_uv(m)
    img = Image.fromarray(texture_image(recipe.texture, recipe.color, recipe.color2))
    mat = trimesh.visual.material.PBRMaterial(
        baseColorTexture=img, baseColorFactor=[1.0, 1.0, 1.0, 1.0],
        roughnessFactor=recipe.roughness, metallicFactor=0.0)
    m.visual = trimesh.visual.TextureVisuals(uv=uv, material=mat)
    return m


def write_object_glb(recipe: ObjectRecipe, path) -> Path:
    """Build ``recipe`` and write it as a binary glTF at ``path`` (atomically)."""
    from zcomp_cli.imageio import atomic_path

    mesh = build_object(recipe)
    path = Path(path)
    data = mesh.export(file_type="glb")
    with atomic_path(path) as tmp:
        Path(tmp).write_bytes(data)
    return path


def sample_recipe(rng: np.random.Generator, shapes=SHAPES) -> ObjectRecipe:
    """A random procedural object: shape, a saturated-ish linear colour, roughness,
    and a texture one time in three."""
    shape = str(shapes[int(rng.integers(len(shapes)))])
    hsv = (float(rng.uniform()), float(rng.uniform(0.2, 0.8)), float(rng.uniform(0.35, 0.9)))
    color = _hsv_to_linear(*hsv)
    color2 = _hsv_to_linear((hsv[0] + 0.5) % 1.0, hsv[1], hsv[2] * 0.35)
    tex = None if rng.uniform() < 0.67 else str(rng.choice(["checker", "stripes"]))
    return ObjectRecipe(shape=shape, color=color, roughness=float(rng.uniform(0.25, 0.9)),
                        texture=tex, color2=color2, aspect=float(rng.uniform(0.35, 0.9)))


def _hsv_to_linear(h, s, v) -> tuple[float, float, float]:
    import colorsys

    from zcomp_cli.conventions import srgb_to_linear

    rgb = np.asarray(colorsys.hsv_to_rgb(h, s, v), dtype=np.float64)
    return tuple(float(x) for x in srgb_to_linear(rgb))
