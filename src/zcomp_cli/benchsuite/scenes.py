"""Whole scenes for Blender renders: description, random sampler, and the geometry the
render script receives.

Frames. A scene is described in its own **scene frame**: metres, +Y up, the camera at
the origin, the floor the plane ``y = -camera_height``. The camera is pitched down by
``pitch_deg``; instead of turning the Blender camera, the scene is turned (the render
script keeps the camera at the world origin with identity rotation, so Blender's world
frame IS zcomp's camera frame, DESIGN.md section 3)::

    p_cam = R_sc @ p_scene,   R_sc = Rx(+pitch)      (scene_to_camera)

A camera looking down by ``pitch`` sees the world turned up by ``pitch``.

The HDR environment map is Z-up (Blender's convention). Its up axis must become the
scene's up, so environment directions map to camera-frame directions by::

    d_cam = R_sc @ Rx(-90 deg) @ Rz(hdr_rotation) @ d_env           (env_to_camera)

Rx(-90 deg) takes +Z to +Y. The render script feeds the world shader the inverse
rotation (``camera_to_env``), as Euler XYZ angles of a Mapping node.
"""

from __future__ import annotations

import math
from pathlib import Path
from dataclasses import asdict, dataclass, field

import numpy as np

from zcomp_cli.camera import Camera
from zcomp_cli.errors import InputError
from zcomp_cli.pose import euler_deg_to_matrix

# Blender's bundled HDR maps (bpy/<ver>/datafiles/studiolights/world/<name>.exr).
BUNDLED_HDRS = ("city", "courtyard", "forest", "interior", "night", "studio", "sunrise", "sunset")
# "night" is almost black; random scenes leave it out (it can still be asked for).
SAMPLED_HDRS = tuple(h for h in BUNDLED_HDRS if h != "night")

FLOOR_HALF_EXTENT = 25.0  # metres: far beyond any frustum we sample
WALL_HEIGHT = 3.0


def _rx(deg: float) -> np.ndarray:
    return euler_deg_to_matrix(deg, 0.0, 0.0)


@dataclass(frozen=True)
class Material:
    """A Principled material: linear ``color`` albedo, ``roughness``; with
    ``checker_color`` set, a checkerboard of squares ``checker_size`` metres wide."""

    color: tuple[float, float, float] = (0.5, 0.5, 0.5)
    roughness: float = 0.7
    checker_color: tuple[float, float, float] | None = None
    checker_size: float = 0.5

    def __post_init__(self):
        for c in (self.color,) + ((self.checker_color,) if self.checker_color is not None else ()):
            if len(c) != 3 or not all(math.isfinite(v) and 0.0 <= v <= 1.0 for v in c):
                raise InputError(f"material colours must be 3 values in [0, 1], got {c}")
        if not (0.0 <= self.roughness <= 1.0):
            raise InputError(f"roughness must be in [0, 1], got {self.roughness}")
        if not (self.checker_size > 0 and math.isfinite(self.checker_size)):
            raise InputError(f"checker_size must be > 0, got {self.checker_size}")


@dataclass(frozen=True)
class Wall:
    """A vertical wall: ``side`` "back" (plane z = -distance), "left" (x = -distance) or
    "right" (x = +distance), scene frame."""

    side: str
    distance: float
    material: Material = field(default_factory=Material)

    def __post_init__(self):
        if self.side not in ("back", "left", "right"):
            raise InputError(f"wall side must be back, left or right, got {self.side!r}")
        if not (self.distance > 0.1 and math.isfinite(self.distance)):
            raise InputError(f"wall distance must be > 0.1 m, got {self.distance}")


@dataclass(frozen=True)
class Box:
    """A box standing on the floor (an object already in the scene, casting its own
    shadow): base centre ``(x, z)`` in the scene frame, ``size`` (sx, sy, sz) metres,
    turned by ``yaw_deg`` about the vertical."""

    x: float
    z: float
    size: tuple[float, float, float]
    yaw_deg: float = 0.0
    material: Material = field(default_factory=Material)

    @property
    def radius(self) -> float:
        """Radius of the footprint's circumscribed circle (for non-overlap tests)."""
        return 0.5 * math.hypot(self.size[0], self.size[2])


@dataclass(frozen=True)
class Lamp:
    """A light. ``kind`` "SUN": parallel light travelling along ``direction`` (scene
    frame, pointing from the lamp to the scene), ``strength`` in W/m^2, ``angle_deg`` its
    angular diameter (small = crisp shadows). ``kind`` "AREA": a square of ``size`` metres
    at ``distance`` from the point ``target`` (scene frame), facing along ``direction``,
    ``strength`` in watts."""

    kind: str
    direction: tuple[float, float, float]
    strength: float
    angle_deg: float = 1.0
    size: float = 1.0
    distance: float = 4.0
    target: tuple[float, float, float] = (0.0, -1.5, -3.0)
    color: tuple[float, float, float] = (1.0, 1.0, 1.0)

    def __post_init__(self):
        if self.kind not in ("SUN", "AREA"):
            raise InputError(f"lamp kind must be SUN or AREA, got {self.kind!r}")
        d = np.asarray(self.direction, dtype=np.float64)
        if d.shape != (3,) or not np.all(np.isfinite(d)) or np.linalg.norm(d) < 1e-9:
            raise InputError(f"lamp direction must be a non-zero 3-vector, got {self.direction}")
        object.__setattr__(self, "direction", tuple(float(v) for v in d / np.linalg.norm(d)))
        if not (self.strength >= 0 and math.isfinite(self.strength)):
            raise InputError(f"lamp strength must be >= 0, got {self.strength}")


@dataclass(frozen=True)
class BenchScene:
    """A scene lit by an HDR map (plus optional lamps): floor, walls, boxes.

    Attributes:
        width, height: image size in pixels.
        fov_deg: horizontal field of view (principal point at the image centre).
        camera_height: metres above the floor.
        pitch_deg: the camera looks down by this angle (0 = horizontal).
        hdr: a name of ``BUNDLED_HDRS`` or a path to an HDR/EXR equirectangular map.
        hdr_rotation_deg: turn of the map about the vertical.
        hdr_strength: multiplier of the map's radiance.
        floor, walls, boxes, lamps: the rest of the scene.
    """

    width: int
    height: int
    fov_deg: float = 50.0
    camera_height: float = 1.5
    pitch_deg: float = 20.0
    hdr: str = "courtyard"
    hdr_rotation_deg: float = 0.0
    hdr_strength: float = 1.0
    floor: Material = field(default_factory=Material)
    walls: tuple[Wall, ...] = ()
    boxes: tuple[Box, ...] = ()
    lamps: tuple[Lamp, ...] = ()

    def __post_init__(self):
        if int(self.width) < 8 or int(self.height) < 8:
            raise InputError(f"scene resolution must be at least 8x8, got {self.width}x{self.height}")
        if not (5.0 <= self.fov_deg <= 150.0):
            raise InputError(f"fov_deg must be in [5, 150], got {self.fov_deg}")
        if not (self.camera_height > 0.05 and math.isfinite(self.camera_height)):
            raise InputError(f"camera_height must be > 0.05 m, got {self.camera_height}")
        if not (-80.0 <= self.pitch_deg <= 80.0):
            raise InputError(f"pitch_deg must be in [-80, 80], got {self.pitch_deg}")
        object.__setattr__(self, "walls", tuple(self.walls))
        object.__setattr__(self, "boxes", tuple(self.boxes))
        object.__setattr__(self, "lamps", tuple(self.lamps))

    # -- frames ----------------------------------------------------------------------
    @property
    def camera(self) -> Camera:
        return Camera.from_fov(self.fov_deg, int(self.width), int(self.height))

    @property
    def scene_to_camera(self) -> np.ndarray:
        """3x3 rotation taking scene-frame vectors to the camera frame."""
        return _rx(self.pitch_deg)

    @property
    def up(self) -> np.ndarray:
        """The scene's up direction (floor normal) in the camera frame."""
        return self.scene_to_camera[:, 1].copy()

    @property
    def floor_plane(self) -> tuple[np.ndarray, float]:
        """``(n, d)`` with ``n . p = d`` for camera-frame floor points, ``n`` = up."""
        return self.up, -float(self.camera_height)

    def env_to_camera(self) -> np.ndarray:
        """3x3 rotation from environment-map directions (Z-up) to the camera frame."""
        return self.scene_to_camera @ _rx(-90.0) @ euler_deg_to_matrix(0.0, 0.0, self.hdr_rotation_deg)

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "BenchScene":
        d = dict(d)

        def mat(m):
            m = dict(m)
            if m.get("checker_color") is not None:
                m["checker_color"] = tuple(m["checker_color"])
            m["color"] = tuple(m["color"])
            return Material(**m)

        d["floor"] = mat(d["floor"])
        d["walls"] = tuple(Wall(w["side"], w["distance"], mat(w["material"])) for w in d.get("walls", ()))
        d["boxes"] = tuple(Box(b["x"], b["z"], tuple(b["size"]), b["yaw_deg"], mat(b["material"]))
                           for b in d.get("boxes", ()))
        d["lamps"] = tuple(Lamp(**{**lp, "direction": tuple(lp["direction"]), "target": tuple(lp["target"]),
                                   "color": tuple(lp["color"])}) for lp in d.get("lamps", ()))
        return cls(**d)


# -- geometry handed to Blender ------------------------------------------------------------

def _quad(p0, u, v):
    """A rectangle from corner ``p0`` spanned by ``u`` and ``v``: vertices (4, 3), two
    triangles, UVs in metres along u and v. Faces wind so the normal is u x v."""
    p0, u, v = (np.asarray(a, dtype=np.float64) for a in (p0, u, v))
    verts = np.array([p0, p0 + u, p0 + u + v, p0 + v])
    lu, lv = np.linalg.norm(u), np.linalg.norm(v)
    uv = np.array([[0, 0], [lu, 0], [lu, lv], [0, lv]], dtype=np.float64)
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    return verts, faces, uv


def material_dict(m: Material) -> dict:
    return {"color": list(m.color), "roughness": float(m.roughness),
            "checker_color": None if m.checker_color is None else list(m.checker_color),
            "checker_size": float(m.checker_size)}


def scene_geometry(scene: BenchScene) -> list[dict]:
    """Every surface of ``scene`` as camera-frame triangle meshes for the render script.

    Returns a list of ``{"name", "vertices": (N, 3) list, "faces": (F, 3) list,
    "uv": (N, 2) list (metres), "material": dict}``; normals face the camera side.
    """
    R = scene.scene_to_camera
    h = float(scene.camera_height)
    L = FLOOR_HALF_EXTENT
    out = []

    def add(name, verts, faces, uv, material):
        out.append({"name": name, "vertices": (np.asarray(verts) @ R.T).tolist(),
                    "faces": np.asarray(faces).tolist(), "uv": np.asarray(uv).tolist(),
                    "material": material_dict(material)})

    # Floor: normal +Y = (+x) x (-z).
    v, f, uv = _quad([-L, -h, L], [2 * L, 0, 0], [0, 0, -2 * L])
    add("floor", v, f, uv, scene.floor)
    for i, w in enumerate(scene.walls):
        D = float(w.distance)
        if w.side == "back":  # plane z = -D, normal +z (toward the camera) = x * y
            v, f, uv = _quad([-L, -h, -D], [2 * L, 0, 0], [0, WALL_HEIGHT, 0])
        elif w.side == "left":  # plane x = -D, normal +x = (-z) x (+y)
            v, f, uv = _quad([-D, -h, L], [0, 0, -2 * L], [0, WALL_HEIGHT, 0])
        else:  # right: x = +D, normal -x = (+z) x (+y)
            v, f, uv = _quad([D, -h, -L], [0, 0, 2 * L], [0, WALL_HEIGHT, 0])
        add(f"wall_{i}_{w.side}", v, f, uv, w.material)
    for i, b in enumerate(scene.boxes):
        v, f, uv = box_mesh(b, h)
        add(f"box_{i}", v, f, uv, b.material)
    return out


def box_mesh(b: Box, camera_height: float):
    """Scene-frame triangles of a floor-standing box (outward normals), vertex UVs."""
    import trimesh

    m = trimesh.creation.box(extents=list(b.size))
    m.apply_translation([0.0, b.size[1] / 2.0, 0.0])
    yaw = euler_deg_to_matrix(0.0, b.yaw_deg, 0.0)
    verts = m.vertices @ yaw.T + np.array([b.x, -camera_height, b.z])
    uv = m.vertices[:, [0, 1]] + m.vertices[:, [2, 2]]
    return verts, np.asarray(m.faces), uv


def lamps_for_blender(scene: BenchScene) -> list[dict]:
    """Lamps with camera-frame direction (and position for area lamps)."""
    R = scene.scene_to_camera
    out = []
    for lp in scene.lamps:
        d = R @ np.asarray(lp.direction)
        item = {"kind": lp.kind, "direction": d.tolist(), "strength": float(lp.strength),
                "angle_deg": float(lp.angle_deg), "size": float(lp.size), "color": list(lp.color)}
        if lp.kind == "AREA":
            target = R @ np.asarray(lp.target, dtype=np.float64)
            item["position"] = (target - d * float(lp.distance)).tolist()
        out.append(item)
    return out


def matrix_to_euler_xyz(R) -> tuple[float, float, float]:
    """Angles (radians) ``(ax, ay, az)`` with ``R = Rz(az) @ Ry(ay) @ Rx(ax)`` (Blender's
    'XYZ' Euler order, as used by the Mapping node). Gimbal lock picks ``az = 0``."""
    R = np.asarray(R, dtype=np.float64)
    sy = -R[2, 0]
    ay = math.asin(max(-1.0, min(1.0, sy)))
    if abs(R[2, 0]) < 1.0 - 1e-9:
        ax = math.atan2(R[2, 1], R[2, 2])
        az = math.atan2(R[1, 0], R[0, 0])
    else:
        ax = math.atan2(-R[1, 2], R[1, 1])
        az = 0.0
    return ax, ay, az


def scene_for_blender(scene: BenchScene) -> dict:
    """Everything the render script needs about ``scene``, in the camera frame."""
    from zcomp_cli.blender.intrinsics import blender_camera_from_K

    cam = scene.camera
    return {
        "width": cam.width,
        "height": cam.height,
        "camera": blender_camera_from_K(cam.K, cam.width, cam.height),
        "hdr": scene.hdr,
        "hdr_strength": float(scene.hdr_strength),
        # The world shader looks up the map with camera->env directions.
        "hdr_euler_xyz": list(matrix_to_euler_xyz(scene.env_to_camera().T)),
        "meshes": scene_geometry(scene),
        "lamps": lamps_for_blender(scene),
    }


# -- random scenes ----------------------------------------------------------------------------

def _rand_color(rng, lo=0.08, hi=0.8) -> tuple[float, float, float]:
    base = rng.uniform(lo, hi)
    tint = rng.uniform(-0.08, 0.08, size=3)
    return tuple(float(np.clip(base + t, 0.02, 0.95)) for t in tint)


def sample_scene(rng: np.random.Generator, width: int, height: int, *, hdrs=SAMPLED_HDRS) -> BenchScene:
    """A random scene in the spirit of the paper's synthetic benchmark: a floor (plain or
    checkered), sometimes walls, sometimes a box already standing there, an HDR map with
    random turn and strength, and with probability 0.6 a sun (crisp to soft shadows) or
    with 0.25 an area lamp."""
    floor = Material(color=_rand_color(rng), roughness=float(rng.uniform(0.3, 0.95)),
                     checker_color=_rand_color(rng) if rng.uniform() < 0.35 else None,
                     checker_size=float(rng.uniform(0.25, 0.8)))
    pitch = float(rng.uniform(12.0, 35.0))
    cam_h = float(rng.uniform(1.0, 1.8))
    walls = []
    if rng.uniform() < 0.6:
        walls.append(Wall("back", float(rng.uniform(4.5, 8.0)), Material(_rand_color(rng, 0.3, 0.85), 0.9)))
    if rng.uniform() < 0.35:
        walls.append(Wall(str(rng.choice(["left", "right"])), float(rng.uniform(2.2, 4.0)),
                          Material(_rand_color(rng, 0.3, 0.85), 0.9)))
    boxes = []
    if rng.uniform() < 0.5:
        depth = float(rng.uniform(3.5, 5.5))
        side = float(rng.choice([-1.0, 1.0]))
        s = rng.uniform(0.25, 0.6, size=3)
        boxes.append(Box(x=side * float(rng.uniform(0.8, 1.6)), z=-depth, size=tuple(float(v) for v in s),
                         yaw_deg=float(rng.uniform(0, 90)), material=Material(_rand_color(rng, 0.2, 0.8), 0.6)))
    lamps = []
    u = rng.uniform()
    if u < 0.6:
        elev = math.radians(rng.uniform(30, 70))
        az = rng.uniform(0, 2 * math.pi)
        d = (-math.cos(elev) * math.sin(az), -math.sin(elev), -math.cos(elev) * math.cos(az))
        lamps.append(Lamp("SUN", d, strength=float(rng.uniform(1.5, 5.0)), angle_deg=float(rng.uniform(0.5, 12.0))))
    elif u < 0.85:
        elev = math.radians(rng.uniform(40, 80))
        az = rng.uniform(0, 2 * math.pi)
        d = (-math.cos(elev) * math.sin(az), -math.sin(elev), -math.cos(elev) * math.cos(az))
        lamps.append(Lamp("AREA", d, strength=float(rng.uniform(300, 1200)), size=float(rng.uniform(0.3, 2.0)),
                          distance=4.0, target=(0.0, -cam_h, -3.0)))
    return BenchScene(
        width=int(width), height=int(height), fov_deg=float(rng.uniform(40.0, 65.0)),
        camera_height=cam_h, pitch_deg=pitch, hdr=str(hdrs[int(rng.integers(len(hdrs)))]),
        hdr_rotation_deg=float(rng.uniform(0, 360)), hdr_strength=float(rng.uniform(0.7, 1.5)),
        floor=floor, walls=tuple(walls), boxes=tuple(boxes), lamps=tuple(lamps))


def floor_depth(scene: BenchScene) -> np.ndarray:
    """Analytic z-depth (H, W) of the floor plane through every pixel centre; 0 where the
    ray misses it (above the horizon). Used by tests and placement."""
    rays = scene.camera.pixel_rays()  # z = -1
    n, d = scene.floor_plane
    denom = rays @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        t = d / denom
    return np.where((denom < -1e-9) & np.isfinite(t) & (t > 0), t, 0.0).astype(np.float32)


def bundled_hdr_path(name: str) -> Path:
    """Path of one of Blender's bundled HDR maps, found without importing bpy."""
    import importlib.util

    spec = importlib.util.find_spec("bpy")
    if spec is None or not spec.submodule_search_locations:
        raise InputError("the bpy package is not installed: its bundled HDR maps are needed")
    root = Path(list(spec.submodule_search_locations)[0])
    hits = sorted(root.glob(f"*/datafiles/studiolights/world/{name}.exr"))
    if not hits:
        raise InputError(f"no bundled HDR map {name!r} under {root}")
    return hits[0]


# Solid angle (sr) of the brightest texels counted as an HDR map's sun.
HDR_SUN_SOLID_ANGLE_SR = 0.02
HDR_SUN_PATCH_DEG = 15.0


def hdr_lights(scene: BenchScene, hdr_image: np.ndarray | None = None) -> dict:
    """The HDR map's own sun and sky as the scene lights them (camera frame).

    Several bundled maps hold a sun as bright as the lamps (studio, interior, city,
    sunrise): its shadows are in the ground truth too. Its brightest
    ``HDR_SUN_SOLID_ANGLE_SR`` of texels around the brightest one are the sun. Blender's equirectangular
    lookup: ``u = 0.5 - atan2(y, x) / 2 pi``, ``v = 0.5 + asin(z) / pi`` (Z up).

    Returns:
        {"sun_direction": (3,) toward the sun, camera frame; "sun_floor_irradiance":
        its irradiance on the floor (luma, times the map's strength); "sky_floor_irradiance":
        the rest of the map's on the floor}.
    """
    import cv2

    from zcomp_cli.conventions import REC601
    from zcomp_cli.imageio import read_image

    img = read_image(bundled_hdr_path(scene.hdr)) if hdr_image is None else hdr_image
    img = cv2.resize(np.asarray(img, np.float32), (256, 128), interpolation=cv2.INTER_AREA).astype(np.float64)
    h, w = img.shape[:2]
    i, j = np.mgrid[0:h, 0:w]
    lat = (0.5 - (i + 0.5) / h) * np.pi
    az = -((j + 0.5) / w - 0.5) * 2 * np.pi
    dirs = np.stack([np.cos(lat) * np.cos(az), np.cos(lat) * np.sin(az), np.sin(lat)], -1).reshape(-1, 3)
    dirs = dirs @ scene.env_to_camera().T
    d_omega = ((2 * np.pi / w) * (np.pi / h) * np.cos(lat)).reshape(-1)
    L = np.maximum(np.nan_to_num(img.reshape(-1, 3)), 0.0) @ REC601.astype(np.float64) * float(scene.hdr_strength)
    order = np.argsort(-L)
    k = int(np.searchsorted(np.cumsum(d_omega[order]), HDR_SUN_SOLID_ANGLE_SR)) + 1
    sun = np.zeros(len(L), bool)
    sun[order[:k]] = True
    # one patch: the brightest texels within HDR_SUN_PATCH_DEG of the brightest (a studio
    # map's several softboxes are several lights, not one sun between them)
    sun &= dirs @ dirs[order[0]] > np.cos(np.deg2rad(HDR_SUN_PATCH_DEG))
    p = L * d_omega
    sdir = (dirs[sun] * p[sun, None]).sum(0)
    sdir = sdir / max(float(np.linalg.norm(sdir)), 1e-12)
    cos = np.maximum(dirs @ scene.up, 0.0)
    return {"sun_direction": sdir, "sun_floor_irradiance": float((p * cos)[sun].sum()),
            "sky_floor_irradiance": float((p * cos)[~sun].sum())}


def occluded(scene: BenchScene, points, directions, max_t=math.inf, *, parts=("wall", "box")) -> np.ndarray:
    """Whether rays from ``points`` (N, 3) along unit ``directions`` ((N, 3) or (3,),
    camera frame) hit a wall or a box of ``scene`` (``parts``: which kinds) within
    ``max_t`` metres (scalar or (N,)). The floor is left out: the points stand on it.
    Returns (N,) bool.

    Möller-Trumbore against every triangle (scenes hold a few dozen), in chunks of rays.
    """
    o = np.atleast_2d(np.asarray(points, np.float64))
    d = np.broadcast_to(np.asarray(directions, np.float64), o.shape)
    tmax = np.broadcast_to(np.asarray(max_t, np.float64), o.shape[:1])
    out = np.zeros(len(o), bool)
    geo = [g for g in scene_geometry(scene) if g["name"].split("_")[0] in parts]
    if not geo:
        return out
    tri = np.concatenate([np.asarray(g["vertices"], np.float64)[np.asarray(g["faces"])] for g in geo])
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    for s in range(0, len(o), 4096):
        oc, dc = o[s:s + 4096, None], d[s:s + 4096, None]
        pv = np.cross(dc, e2)
        det = np.einsum("nij,nij->ni", np.broadcast_to(e1, pv.shape), pv)
        ok = np.abs(det) > 1e-12
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        tv = oc - tri[:, 0]
        u = np.einsum("nij,nij->ni", tv, pv) * inv
        qv = np.cross(tv, e1)
        v = np.einsum("nij,nij->ni", qv, np.broadcast_to(dc, qv.shape)) * inv
        t = np.einsum("nij,nij->ni", qv, np.broadcast_to(e2, qv.shape)) * inv
        hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 1e-6) & (t < tmax[s:s + 4096, None])
        out[s:s + 4096] = hit.any(1)
    return out


def lamp_rays(lamp: dict, points) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rays from ``points`` (N, 3) to a lamp of ``lamps_for_blender`` (camera frame).

    Returns ``(directions (N, 3) toward the lamp, reach (N,) metres to it (inf for a
    sun), irradiance (N,) on a surface facing it)``: a sun's ``strength``; an area lamp's
    ``P cos_e / (pi r^2)`` (a Lambertian square of power P at distance r, ``cos_e`` off
    its facing direction).
    """
    p = np.atleast_2d(np.asarray(points, np.float64))
    travel = np.asarray(lamp["direction"], np.float64)
    if lamp["kind"] != "AREA":
        n = len(p)
        return np.tile(-travel, (n, 1)), np.full(n, np.inf), np.full(n, float(lamp["strength"]))
    to = np.asarray(lamp["position"], np.float64) - p
    r = np.maximum(np.linalg.norm(to, axis=1), 1e-9)
    d = to / r[:, None]
    return d, r, float(lamp["strength"]) * np.maximum(-(d @ travel), 0.0) / (math.pi * r * r)


# Height (metres) above the floor at which a light's visibility is tested: the object's
# shadow starts at its base, and a point on the floor itself grazes the floor's triangles.
LIGHT_PROBE_HEIGHT = 0.05


def lights_at(scene: BenchScene, base, *, with_hdr: bool = True) -> list[dict]:
    """Every directional light of ``scene`` as the floor point ``base`` sees it (camera
    frame), brightest first: the lamps and (``with_hdr``) the HDR map's own sun.

    An object standing at ``base`` casts a shadow from a light only if the light reaches
    it: a sun behind a back wall lights nothing in front of the wall, whatever its
    strength. An area lamp is seen from ``base``, not from its aim point: its shadows
    point away from where it is.

    Returns:
        list of ``{"kind": "SUN" | "AREA" | "HDR-sun", "direction": (3,) unit vector
        toward the light, "floor_irradiance": irradiance it brings to the floor at
        ``base`` (0 when blocked: ``lamp_rays`` times the cosine on the floor), "visible":
        bool, "lamp": it as a ``lamps_for_blender`` item for ``cast_shadow_masks`` (the
        HDR sun as a sun of strength 1: only its direction is used there)}``.
    """
    up = scene.up
    p = np.asarray(base, np.float64)[None] + LIGHT_PROBE_HEIGHT * up
    out, reaches = [], []
    for lp in lamps_for_blender(scene):
        d, reach, e = lamp_rays(lp, p)
        out.append({"kind": lp["kind"], "direction": d[0], "floor_irradiance": float(e[0]) * max(float(d[0] @ up), 0.0),
                    "lamp": lp})
        reaches.append(float(reach[0]))
    if with_hdr:
        h = hdr_lights(scene)
        sun = np.asarray(h["sun_direction"], np.float64)
        out.append({"kind": "HDR-sun", "direction": sun, "floor_irradiance": h["sun_floor_irradiance"],
                    "lamp": {"kind": "SUN", "direction": (-sun).tolist(), "strength": 1.0}})
        reaches.append(math.inf)
    for li, reach in zip(out, reaches):
        li["visible"] = li["floor_irradiance"] > 0 and not occluded(scene, p, li["direction"], reach)[0]
        if not li["visible"]:
            li["floor_irradiance"] = 0.0
    return sorted(out, key=lambda x: -x["floor_irradiance"])


# A light's cast shadows count as shown when the background holds at least this many
# floor pixels its boxes shadow and as many it lights (an edge to read it from).
MIN_CAST_SHADOW_PX = 100


def cast_shadow_masks(scene: BenchScene, depth, lights: list[dict]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per light (``lamps_for_blender`` items: kind, direction of travel, strength, an
    area lamp's position): which of the background's floor pixels the scene's **boxes**
    shadow from it, and which it reaches past them (walls not counted), from the
    background's z-depth (H, W).

    Boxes only: they stand in frame with the edges that cast their shadows. A wall's
    shadow is cast by its top edge, mostly above the frame, so no depth explains it.

    Returns a list of ``(shadowed, lit)`` (H, W) bool masks.
    """
    depth = np.asarray(depth, np.float64)
    pts = scene.camera.unproject(depth).reshape(-1, 3)
    n, d = scene.floor_plane
    floor = (depth.reshape(-1) > 0) & (np.abs(pts @ n - d) < 0.01)
    p = pts[floor] + LIGHT_PROBE_HEIGHT * n
    out = []
    for lp in lights:
        dirs, reach, e = lamp_rays(lp, p)
        lit = (e > 0) & (dirs @ n > 0)
        shadowed = np.zeros(len(p), bool)
        shadowed[lit] = occluded(scene, p[lit], dirs[lit], reach[lit], parts=("box",))
        masks = []
        for m in (shadowed, lit & ~shadowed):
            full = np.zeros(depth.size, bool)
            full[floor] = m
            masks.append(full.reshape(depth.shape))
        out.append(tuple(masks))
    return out
