"""What the ``cycles`` renderer hands Blender: pure functions from a request and its light
to meshes, a world and lamps, all in the camera frame (Blender's world frame: the camera
sits at the origin with identity rotation, ``_bpy_common.add_camera``).

Units: the light model (``physical.lightmodel``) is in zcomp's shading units, the
photograph's exposure folded in (a uniform sky of radiance L shades a white surface
with L). Blender's are the same for a world; a sun of strength E (W/m^2) gives ``E / pi``
and a point lamp of power P (W) ``P / (4 pi^2 r^2)`` (``physical.lightfit``, checked
against Cycles in its tests), so a light model converts to Cycles with no exposure of
its own: the background it renders is the photograph where the model explains it.
"""

from __future__ import annotations

import math

import numpy as np

from zcomp_cli import equirect
from zcomp_cli.worldframe import ground_frame

# Blender's units in zcomp's shading (physical: ``physical.lightfit``, inverted).
SUN_WATTS_PER_SHADING = math.pi            # a sun's strength (W/m^2) per unit of shading
LAMP_WATTS_PER_SHADING = 4.0 * math.pi ** 2  # a point lamp's power (W) per shading at 1 m


def world_rows(frame, convention: str = equirect.DEFAULT_CONVENTION, rotation_deg: float = 0.0) -> np.ndarray:
    """(3, 3) rows R such that Blender's equirectangular lookup of ``R @ d`` (Cycles':
    ``u = 0.5 - atan2(y, x) / 2 pi``, ``v = 0.5 + asin(z) / pi`` from the bottom row) reads
    the pixel that ``equirect.direction_to_uv(d, frame, convention, rotation_deg)`` names
    (rows from the top), for every camera-frame direction d.

    Derivation: a probe's column looks at longitude ``lon`` (from forward toward right);
    Blender's column at azimuth ``phi`` (from +x toward +y); ``phi = rot - lon`` (``rot``
    the convention's yaw, ``equirect.longitude``), or ``lon - rot`` for a mirrored probe.
    """
    equirect._check(convention)
    right, up, fwd = (np.asarray(r, np.float64) for r in np.asarray(frame, np.float64))
    rot = math.radians(float(rotation_deg))
    if convention == "blender":
        rot += math.pi / 2
    c, s = math.cos(rot), math.sin(rot)
    first = c * fwd + s * right
    second = (c * right - s * fwd) if convention == "mirrored" else (s * fwd - c * right)
    return np.stack([first, second, up])


def blender_uv(directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(u, v) Cycles' equirectangular lookup gives world directions (..., 3), v from the
    top row (as zcomp's maps) -- for tests of ``world_rows``."""
    d = np.asarray(directions, np.float64)
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    u = (0.5 - np.arctan2(d[..., 1], d[..., 0]) / (2 * math.pi)) % 1.0
    v_bottom = 0.5 + np.arcsin(np.clip(d[..., 2], -1, 1)) / math.pi
    return u, 1.0 - v_bottom


def sky_image(sky, width: int) -> tuple[np.ndarray, np.ndarray]:
    """The fitted sky as a world: (width/2, width, 3) float32 radiance in zcomp's
    convention (rotation 0) and its ``world_rows``. Above the horizon the sky's SH
    radiance (clamped at 0: order 2 rings behind a bright region), below it the
    support's radiance (``Sky.ground``): what an object sees past the mesh's edge."""
    from zcomp_cli.scene import sh

    frame = ground_frame(sky.up)
    h, w = max(1, int(width) // 2), int(width)
    dirs = equirect.pixel_directions(h, w, frame)
    L = np.maximum(sh.evaluate(np.asarray(sky.radiance_sh, np.float64), dirs.reshape(-1, 3)), 0.0)
    below = (dirs.reshape(-1, 3) @ np.asarray(sky.up, np.float64)) < 0
    L[below] = np.asarray(sky.ground, np.float64)[None]
    return L.reshape(h, w, 3).astype(np.float32), world_rows(frame)


def probe_image(probe_params, up, scale: float, max_width: int) -> tuple[np.ndarray, np.ndarray]:
    """The manifest's probe as a world: its radiance (read as the physical renderer reads
    it: non-finite and negative values 0, at most ``max_width`` wide) times ``scale``
    (its strength times the fitted exposure), and the ``world_rows`` of its convention
    and yaw."""
    from zcomp_cli.scene.probe import probe_radiance
    from zcomp_cli.scene.config import ProbeConfig

    frame = ground_frame(up)
    img, convention, rotation = probe_radiance(probe_params, frame, ProbeConfig(max_width=int(max_width)))
    return (img * float(scale)).astype(np.float32), world_rows(frame, convention, rotation)


def _colour(rgb) -> tuple[float, list[float]]:
    """(strength, colour with max 1) of an RGB quantity."""
    rgb = np.maximum(np.nan_to_num(np.asarray(rgb, np.float64)), 0.0)
    top = float(rgb.max())
    return top, ((rgb / top).tolist() if top > 0 else [1.0, 1.0, 1.0])


def lamps_of(model, *, skip_probe_sources: bool) -> list[dict]:
    """Blender lamps of a ``LightModel``'s suns and lamps (``scene`` module docstring's
    units). ``skip_probe_sources``: leave out the suns measured on the probe (the probe,
    given as the world, holds them)."""
    from zcomp_cli.scene.lightparams import Origin

    out = []
    for s in model.suns:
        if skip_probe_sources and s.direction_from is Origin.PROBE:
            continue
        e, col = _colour(s.irradiance)
        if e <= 0:
            continue
        out.append({"kind": "SUN", "direction": (-np.asarray(s.direction)).tolist(),
                    "energy": SUN_WATTS_PER_SHADING * e, "color": col,
                    "angle_rad": 2.0 * math.radians(float(s.radius_deg))})
    for lp in model.lamps:
        e, col = _colour(lp.intensity)
        if e <= 0:
            continue
        d = {"position": np.asarray(lp.position).tolist(), "energy": LAMP_WATTS_PER_SHADING * e, "color": col}
        if lp.facing is None:
            d.update(kind="POINT", direction=[0.0, -1.0, 0.0], radius=float(lp.radius_m))
        else:  # a one-sided panel of the same power (``Lamp``): Blender's area lamp
            d.update(kind="AREA", direction=np.asarray(lp.facing).tolist(), size=2.0 * float(lp.radius_m))
        out.append(d)
    return out


def fill_behind(depth, normals, albedo, valid, hidden, camera, up):
    """The background behind the inserted object, which the composite request's maps do
    not hold: each ``hidden`` pixel (H, W) bool gets the support plane where its ray meets
    it (normal ``up``) and the albedo of the nearest ``valid`` pixel. Without it the
    floor's mesh has a hole there, and a silhouette pixel the object only partly covers
    sees the world below the horizon through it (a dark rim). A ray that does not meet the
    plane in front of the camera stays a hole.

    Returns (depth, normals, albedo, valid) with the hidden pixels filled.
    """
    from scipy import ndimage

    from zcomp_cli.scene.depthmesh import support_mask

    d = np.array(depth, np.float64)
    n = np.array(normals, np.float64)
    a = np.array(albedo, np.float64)
    ok = np.array(valid, bool)
    hidden = np.asarray(hidden, bool) & ~ok
    if not hidden.any() or not ok.any():
        return d, n, a, ok
    up = np.asarray(up, np.float64)
    P = camera.unproject(d.astype(np.float32)).astype(np.float64)
    _, h0 = support_mask(P, n, ok, up)
    if not math.isfinite(h0):
        return d, n, a, ok
    ys, xs = np.nonzero(hidden)
    rays = camera.ray(xs + 0.5, ys + 0.5).astype(np.float64)  # z = -1: t is the z-depth
    denom = rays @ up
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(np.abs(denom) > 1e-9, h0 / denom, -1.0)
    hit = t > 0
    _, (iy, ix) = ndimage.distance_transform_edt(~ok, return_indices=True)
    d[ys[hit], xs[hit]] = t[hit]
    n[ys[hit], xs[hit]] = up
    a[ys[hit], xs[hit]] = a[iy[ys[hit], xs[hit]], ix[ys[hit], xs[hit]]]
    ok[ys[hit], xs[hit]] = True
    return d, n, a, ok


# A wall beyond the frame (``planes.Wall``) is drawn this far behind its plane, relative to
# its distance: the fitted plane is the visible wall's own, and a quad on it would
# z-fight with the depth mesh's wall and shadow it (every shadow ray from the wall hits
# the coplanar quad: a dark, streaked wall). Behind it, the quad is hidden wherever the
# mesh is and stands in only beyond the frame. 2 %: inside the tolerance a plane is
# fitted with (the support's height, ``MeshConfig.support_height_rel``, is 3 %), far beyond
# float32 vertices and Cycles' ray offsets (a heuristic, checked on the dev seeds).
WALL_BEHIND_REL = 0.02


def walls_behind(walls) -> tuple:
    """The walls moved ``WALL_BEHIND_REL`` of their distance away from the camera (a
    ``Wall``'s normal faces the camera's side: ``normal . 0 = 0 > offset``)."""
    import dataclasses

    return tuple(dataclasses.replace(w, offset=float(w.offset) - WALL_BEHIND_REL * abs(float(w.offset)))
                 for w in walls)


# The support's plane beyond the frame: a square this many metres from the camera's foot
# either way (physical: the light model's support is infinite, ``Sky.ground``; from an
# object 2 m above it, the plane beyond 100 m is under 1.2 deg of its horizon), and at
# least GROUND_HALF_HEIGHTS times the camera's height above the support: in metres
# alone, a scene seen from 100 m up (or measured in centimetres) had a floor smaller than
# the one in view, and its objects saw the world below the horizon (with the camera's
# clipping, ``renderer.clip_range``, the 8.8 % of the composite the stability sweep saw at
# 10 km scale: issue 49). From the camera's own height
# the plane beyond 50 heights is under 1.2 deg of the horizon, as above.
GROUND_HALF_M = 100.0
GROUND_HALF_HEIGHTS = 50.0


def with_ground(arrays: dict, mesh, diffuse: np.ndarray) -> dict:
    """``arrays`` (``scene_mesh_arrays``) plus the support's plane beyond the frame: a
    square of ``GROUND_HALF_M`` (at least ``GROUND_HALF_HEIGHTS`` camera heights) about the
    camera's foot, ``WALL_BEHIND_REL`` of the camera's
    height below the support (the visible floor hides it wherever the mesh is), coloured
    the support pixels' mean ``diffuse``. Without it, whatever stands on the floor sees the
    world below the horizon where the floor leaves the frame, not the lit floor the
    photograph's scene has there (objects 5-25 % too dark on dev scenes). Unchanged when
    the mesh found no support."""
    h0 = float(mesh.support_height)
    if not math.isfinite(h0) or not mesh.support.any():
        return arrays
    up = np.asarray(mesh.up, np.float64)
    right, _, fwd = ground_frame(up)
    base = up * (h0 - WALL_BEHIND_REL * abs(h0))
    L = max(GROUND_HALF_M, GROUND_HALF_HEIGHTS * abs(h0))
    V = np.stack([base + a * L * right + b * L * fwd for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))])
    F = np.array([[0, 1, 2], [0, 2, 3]], np.int64)
    # faces wound so that the normal is up (Blender shades both sides alike anyway)
    if np.cross(V[1] - V[0], V[2] - V[0]) @ up < 0:
        F = F[:, ::-1]
    col = np.clip(np.asarray(diffuse, np.float64).reshape(-1, 3)[mesh.support.ravel()].mean(0), 0.0, 1.0)
    n = len(arrays["vertices"])
    return {**arrays, "vertices": np.concatenate([arrays["vertices"], V.astype(np.float32)]),
            "faces": np.concatenate([arrays["faces"], (F + n).astype(np.int32)]),
            "colors": np.concatenate([arrays["colors"], np.repeat(col[None], 4, 0).astype(np.float32)])}


def scene_mesh_arrays(mesh, albedo: np.ndarray, n_walls: int = 0) -> dict[str, np.ndarray]:
    """The depth mesh (``physical.depthmesh.DepthMesh``) as Blender gets it: the vertices
    its faces use, the faces renumbered, a diffuse colour per vertex -- its pixel's
    ``albedo`` (H, W, 3) (an extruded back vertex its front pixel's), the walls beyond
    the frame (``n_walls`` quads, last) the mean albedo."""
    h, w = mesh.shape
    n_px = h * w
    A = np.clip(np.nan_to_num(np.asarray(albedo, np.float64)), 0.0, 1.0).reshape(-1, 3)
    V = np.asarray(mesh.vertices, np.float64)
    idx = np.arange(len(V))
    mean = A[mesh.valid.ravel()].mean(0) if mesh.valid.any() else np.full(3, 0.5)
    per_pixel = idx < len(V) - 4 * int(n_walls)
    colors = np.where(per_pixel[:, None], A[idx % n_px], mean[None])
    F = np.asarray(mesh.faces, np.int64)
    used = np.unique(F) if len(F) else np.zeros(0, np.int64)
    remap = np.full(len(V), -1, np.int64)
    remap[used] = np.arange(len(used))
    return {"vertices": V[used].astype(np.float32), "faces": remap[F].astype(np.int32),
            "colors": colors[used].astype(np.float32)}


# What the background's mesh holds (issue 50, defect 6: meshed whole, a 2048 x 1536
# frame cost 4.9 GB though Cycles traces only a window). A frame of at most
# FULL_MESH_PIXELS is meshed whole, as before; a larger one at full resolution only in
# the window Cycles traces grown by WINDOW_CONTEXT of its size on each side (at least
# MIN_CONTEXT_PX: the contact shadows and bounce that reach the window from just beside
# it; a given light's long shadow has grown the window already), and every STEP-th pixel
# elsewhere, STEP chosen so that the rest holds about COARSE_MESH_PIXELS vertices (what
# lies far from the window shadows and lights it as a whole, not by its pixels' detail).
# Blender holds about 0.9 KB a meshed pixel (measured at 2048 x 1536).
FULL_MESH_PIXELS = 1 << 20
COARSE_MESH_PIXELS = 1 << 18
WINDOW_CONTEXT = 0.1
MIN_CONTEXT_PX = 32


def mesh_regions(shape, box) -> tuple[tuple[int, int, int, int], int] | None:
    """((x0, y0, x1, y1) of the frame meshed at full resolution, the step of the coarse
    mesh elsewhere), or None when the whole frame is meshed (``box`` None: no window;
    the frame small enough; the fine region the whole frame)."""
    H, W = shape
    if box is None or H * W <= FULL_MESH_PIXELS:
        return None
    x0, y0, x1, y1 = (int(v) for v in box)
    gx = max(MIN_CONTEXT_PX, int(math.ceil(WINDOW_CONTEXT * (x1 - x0))))
    gy = max(MIN_CONTEXT_PX, int(math.ceil(WINDOW_CONTEXT * (y1 - y0))))
    fine = (max(0, x0 - gx), max(0, y0 - gy), min(W, x1 + gx), min(H, y1 + gy))
    if fine == (0, 0, W, H):
        return None
    return fine, max(2, int(math.ceil(math.sqrt(H * W / COARSE_MESH_PIXELS))))


def scene_arrays(depth, normals, albedo, valid, camera, model, box=None, cfg=None) -> dict[str, np.ndarray]:
    """The background's mesh as Blender gets it (``scene_mesh_arrays`` and the ground
    beyond the frame, ``with_ground``), over the whole frame or, for a large one, at full
    resolution around the window ``box`` Cycles traces and coarse elsewhere
    (``mesh_regions``). ``model``: the light model (its up, walls and the offset its
    specular layer adds to the albedo, seen from the camera: ``LightModel.albedo_offset``);
    ``cfg``: the mesh's constants (``scene.config.MeshConfig``)."""
    from zcomp_cli.scene.depthmesh import build_depth_mesh

    alb = np.clip(np.asarray(albedo, np.float64), 0.0, 1.0)
    pts = camera.unproject(np.asarray(depth, np.float32)).astype(np.float64)
    diffuse = np.clip(alb + model.albedo_offset(pts, normals, alb).reshape(alb.shape), 0.0, 1.0)
    walls = walls_behind(model.walls)
    regions = mesh_regions(np.shape(depth), box)
    if regions is None:
        mesh = build_depth_mesh(depth, normals, camera, model.up, valid=valid, walls=walls, cfg=cfg)
        return with_ground(scene_mesh_arrays(mesh, diffuse, n_walls=len(model.walls)), mesh, diffuse)
    (fx0, fy0, fx1, fy1), step = regions
    # the rest of the frame, every step-th pixel (its camera: the same rays through them),
    # less what the fine region holds (one coarse cell of overlap: no crack between them)
    c = step // 2
    rows, cols = np.arange(c, depth.shape[0], step), np.arange(c, depth.shape[1], step)
    K = np.array(camera.K, np.float64)
    K[0, 0] /= step
    K[1, 1] /= step
    K[0, 2] = (K[0, 2] - c - 0.5) / step + 0.5
    K[1, 2] = (K[1, 2] - c - 0.5) / step + 0.5
    from zcomp_cli.camera import Camera

    coarse_cam = Camera(K, len(cols), len(rows))
    inner = ((rows[:, None] >= fy0 + step) & (rows[:, None] < fy1 - step)
             & (cols[None, :] >= fx0 + step) & (cols[None, :] < fx1 - step))
    sub = np.ix_(rows, cols)
    coarse = build_depth_mesh(depth[sub], normals[sub], coarse_cam, model.up, valid=valid[sub] & ~inner,
                              walls=walls, cfg=cfg)
    out = with_ground(scene_mesh_arrays(coarse, diffuse[sub], n_walls=len(model.walls)), coarse, diffuse[sub])
    K = np.array(camera.K, np.float64)
    K[0, 2] -= fx0
    K[1, 2] -= fy0
    crop = np.s_[fy0:fy1, fx0:fx1]
    fine = build_depth_mesh(depth[crop], normals[crop], Camera(K, fx1 - fx0, fy1 - fy0), model.up,
                            valid=valid[crop], cfg=cfg)
    return _joined(out, scene_mesh_arrays(fine, diffuse[crop]))


def _joined(a: dict, b: dict) -> dict:
    """Two meshes' arrays as one (``b``'s faces renumbered after ``a``'s vertices)."""
    n = len(a["vertices"])
    return {"vertices": np.concatenate([a["vertices"], b["vertices"]]),
            "faces": np.concatenate([a["faces"], (b["faces"] + n).astype(np.int32)]),
            "colors": np.concatenate([a["colors"], b["colors"]])}


__all__ = ["world_rows", "mesh_regions", "scene_arrays", "fill_behind", "walls_behind", "with_ground", "WALL_BEHIND_REL", "GROUND_HALF_M", "GROUND_HALF_HEIGHTS", "blender_uv", "sky_image", "probe_image", "lamps_of", "scene_mesh_arrays",
           "SUN_WATTS_PER_SHADING", "LAMP_WATTS_PER_SHADING"]
