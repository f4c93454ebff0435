"""Analytic test scenes in zcomp's conventions (no Blender).

Everything is ray cast exactly in numpy, so tests get ground-truth depth, normals,
albedo, shading and the true light. Conventions (DESIGN.md section 3):

* world frame: metres, +Y up; the ground plane is ``y = 0``; the camera sits at
  ``(0, camera_height, 0)`` and, before pitching, looks along world -z.
* camera frame: OpenGL (x right, y up, looks along -z); ``cam_to_world`` is the 3x3
  rotation taking camera-frame vectors to world vectors (a pitch about x).
* depth: z-depth in metres (0 = invalid / sky); normals: camera-frame unit vectors
  (0 where invalid); albedo, shading, image: linear RGB float32, image = albedo * shading.
* light: a directional light; ``light_dir`` points FROM the surface TOWARD the light
  (world frame), shading = ambient + intensity * max(0, n.l) * visibility.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from zcomp_cli.bundle import ObjectBundle
from zcomp_cli.camera import Camera
from zcomp_cli.errors import InputError

__all__ = ["SyntheticScene", "floor_scene", "sphere_object_bundle", "insert_bundle", "write_floor_batch", "estimate_light"]


@dataclass
class SyntheticScene:
    """A rendered analytic scene. Maps are H x W (x 3) float32.

    ``light_dir_cam`` is the unit direction toward the light in the camera frame;
    ``ambient`` and ``light_intensity`` are the true shading terms (grey light).
    """

    camera: Camera
    depth: np.ndarray
    normals: np.ndarray
    albedo: np.ndarray
    shading: np.ndarray
    image: np.ndarray
    visibility: np.ndarray
    light_dir_cam: np.ndarray
    ambient: float
    light_intensity: float
    cam_to_world: np.ndarray
    camera_origin: np.ndarray
    meta: dict = field(default_factory=dict)

    def world_to_camera(self, points) -> np.ndarray:
        """World points (..., 3) -> camera-frame points (..., 3)."""
        p = np.asarray(points, dtype=np.float64) - self.camera_origin
        return p @ self.cam_to_world  # R^T p for row vectors

    @property
    def up_cam(self) -> np.ndarray:
        """World +Y in the camera frame."""
        return self.cam_to_world.T @ np.array([0.0, 1.0, 0.0])


def _rot_x(deg: float) -> np.ndarray:
    a = np.deg2rad(deg)
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]], dtype=np.float64)


def _rot_z(deg: float) -> np.ndarray:
    a = np.deg2rad(deg)
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]], dtype=np.float64)


def _ray_box(o, d, lo, hi):
    """Slab test. o, d: (N, 3). Returns (t_hit (N,), normal (N, 3)); t = inf on miss."""
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / np.where(np.abs(d) < 1e-12, 1e-12, d)
        t1 = (lo - o) * inv
        t2 = (hi - o) * inv
    tmin = np.minimum(t1, t2)
    tmax = np.maximum(t1, t2)
    tn = tmin.max(axis=1)
    tf = tmax.min(axis=1)
    hit = (tf >= tn) & (tf > 1e-6)
    t = np.where(hit, np.where(tn > 1e-6, tn, np.inf), np.inf)
    axis = tmin.argmax(axis=1)
    n = np.zeros_like(o)
    idx = np.arange(len(o))
    n[idx, axis] = -np.sign(d[idx, axis])
    return t, n


# Directions over which the sky's and a soft light's visibility are averaged.
SKY_SAMPLES = 64
SUN_SAMPLES = 32


def _sky_visibility(normals, blocked) -> np.ndarray:
    """(n,) cosine-weighted share of the sky seen along SKY_SAMPLES directions (a
    Fibonacci spiral on the unit disc lifted onto the hemisphere of each normal)."""
    k = np.arange(SKY_SAMPLES) + 0.5
    r = np.sqrt(k / SKY_SAMPLES)
    ph = k * np.pi * (3 - np.sqrt(5))
    n = normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    a = np.where(np.abs(n[:, :1]) < 0.9, np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]]))
    u = np.cross(n, a)
    u /= np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-12)
    v = np.cross(n, u)
    acc = np.zeros(len(n))
    for ri, pi in zip(r, ph):
        d = np.sqrt(max(1 - ri * ri, 0.0)) * n + ri * (np.cos(pi) * u + np.sin(pi) * v)
        acc += ~blocked(d)
    return acc / SKY_SAMPLES


def floor_scene(width: int = 128, height: int = 96, *, fov_deg: float = 50.0,
                camera_height: float = 1.2, pitch_deg: float = -25.0,
                light_dir=(0.5, 1.0, 0.3), light_intensity: float = 1.0,
                ambient: float = 0.3, albedo=(0.6, 0.6, 0.6), with_box: bool = False,
                box_center=(0.0, -3.0), box_size=(0.6, 0.8, 0.6),
                box_albedo=(0.5, 0.4, 0.3), with_wall: bool = False,
                wall_distance: float = 6.0, occluders=(), extra_lights=(), lamp=None,
                sky_occlusion: bool = False, sun_radius_deg: float = 0.0, roll_deg: float = 0.0) -> SyntheticScene:
    """Ray cast a ground plane (+ optional axis-aligned box and back wall).

    Args:
        width, height: image size in pixels.
        fov_deg: horizontal field of view.
        camera_height: camera height above the floor (m).
        pitch_deg: camera pitch; negative looks down.
        roll_deg: camera roll about its optical axis (positive turns the camera
            counter-clockwise: the horizon drops on the right).
        light_dir: world-frame direction toward the directional light (normalised here).
        light_intensity, ambient: shading = ambient + intensity * max(0, n.l) * V (grey).
        albedo: floor (and wall) linear RGB albedo.
        with_box: add a box standing on the floor at world ``(x, z) = box_center``,
            ``box_size = (sx, sy, sz)`` metres; it casts an exact shadow.
        with_wall: add a wall ``z = -wall_distance`` facing the camera.
        occluders: more boxes ``((x, z), (sx, sy, sz))`` standing on the floor, seen and
            casting shadows like the box; put one outside the frustum to get a shadow
            whose occluder the depth map does not show.
        extra_lights: more directional lights ``(world direction toward it, intensity)``,
            each with its own exact shadows (``meta["extra_lights_cam"]``: their
            camera-frame directions).
        lamp: a point lamp ``(world position (3,), intensity)``: it adds
            ``intensity * max(0, n . (p - x)) / |p - x|^3`` with exact shadows
            (``meta["lamp_cam"]``: its camera-frame position).
        sky_occlusion: the ambient is a uniform sky that the boxes and the wall hide
            (``ambient`` times the cosine-weighted share of the sky each point sees,
            ray cast over SKY_SAMPLES directions), as a path tracer renders it; False:
            the ambient reaches everywhere.
        sun_radius_deg: the light's angular radius: its visibility is averaged over
            SUN_SAMPLES directions of that cone (a penumbra); 0: a point light, a
            hard shadow.
    Returns:
        SyntheticScene; sky pixels have depth 0, normals 0, albedo 0, shading 0.
    """
    if width < 1 or height < 1:
        raise InputError(f"image size must be positive, got {width}x{height}")
    cam = Camera.from_fov(fov_deg, width, height)
    R = _rot_x(pitch_deg) @ _rot_z(roll_deg)
    origin = np.array([0.0, camera_height, 0.0])
    rays_cam = cam.pixel_rays().reshape(-1, 3)
    d = rays_cam @ R.T
    o = np.broadcast_to(origin, d.shape).copy()
    n_pix = len(d)
    t_best = np.full(n_pix, np.inf)
    n_best = np.zeros((n_pix, 3))
    alb = np.zeros((n_pix, 3))

    def keep_nearest(t, normal, albedo_):
        sel = t < t_best
        t_best[sel] = t[sel]
        n_best[sel] = normal if np.ndim(normal) == 1 else normal[sel]
        alb[sel] = albedo_

    with np.errstate(divide="ignore", invalid="ignore"):
        keep_nearest(np.where(d[:, 1] < -1e-12, -camera_height / d[:, 1], np.inf), (0, 1, 0), albedo)
        if with_wall:
            keep_nearest(np.where(d[:, 2] < -1e-12, -wall_distance / d[:, 2], np.inf), (0, 0, 1), albedo)
    box = None
    boxes = []
    specs = ([(box_center, box_size)] if with_box else []) + [tuple(b) for b in occluders]
    for (bx, bz), (sx, sy, sz) in specs:
        bb = (np.array([bx - sx / 2, 0.0, bz - sz / 2]), np.array([bx + sx / 2, sy, bz + sz / 2]))
        boxes.append(bb)
        keep_nearest(*_ray_box(o, d, *bb), box_albedo)
    if with_box:
        box = boxes[0]
    hit = np.isfinite(t_best)
    P = o + d * np.where(hit, t_best, 0.0)[:, None]
    def blocked(dirs):
        """(n_pix,) bool: rays from the surface along dirs (n_pix, 3) meet a box or the wall."""
        ps = P + n_best * 1e-4
        out = np.zeros(n_pix, bool)
        for bb in boxes:
            t_sh, _ = _ray_box(ps, np.ascontiguousarray(dirs), *bb)
            out |= np.isfinite(t_sh)
        if with_wall:
            with np.errstate(divide="ignore", invalid="ignore"):
                tw = np.where(dirs[:, 2] < -1e-12, (-wall_distance - ps[:, 2]) / dirs[:, 2], np.inf)
            out |= np.isfinite(tw) & (tw > 1e-6) & (ps[:, 2] > -wall_distance + 1e-6)
        return out

    def lit(l):
        l = np.asarray(l, dtype=np.float64)
        l = l / np.linalg.norm(l)
        if sun_radius_deg > 0:
            from zcomp_cli.scene.sampling import cone_directions

            cone = cone_directions(l, sun_radius_deg, SUN_SAMPLES, seed=0)
        else:
            cone = l[None]
        vis = np.zeros(n_pix)
        for c in cone:
            vis += ~blocked(np.broadcast_to(c, (n_pix, 3)))
        return l, vis / len(cone), np.maximum(0.0, n_best @ l)

    l, vis, ndotl = lit(light_dir)
    sky_vis = np.ones(n_pix)
    if sky_occlusion:
        sky_vis = _sky_visibility(n_best, blocked)
    shade = ambient * sky_vis + light_intensity * ndotl * vis
    extra_cam = []
    for le, ie in extra_lights:
        le, vis_e, ndl_e = lit(le)
        shade = shade + float(ie) * ndl_e * vis_e
        extra_cam.append((R.T @ le).tolist())
    lamp_cam = None
    if lamp is not None:
        lp, li = np.asarray(lamp[0], np.float64), float(lamp[1])
        v = lp[None] - P
        dist = np.maximum(np.linalg.norm(v, axis=1), 1e-9)
        vl = v / dist[:, None]
        vis_l = np.ones(n_pix)
        for bb in boxes:
            t_sh, _ = _ray_box(P + n_best * 1e-4, vl, *bb)
            vis_l = np.where(t_sh < dist, 0.0, vis_l)
        shade = shade + li * np.maximum(0.0, (n_best * vl).sum(1)) / dist ** 2 * vis_l
        lamp_cam = (R.T @ (lp - origin)).tolist()
    shade = np.where(hit, shade, 0.0)
    p_cam = (P - origin) @ R
    depth = np.where(hit, -p_cam[:, 2], 0.0)
    normals = n_best @ R  # R^T n for row vectors
    normals[~hit] = 0
    alb[~hit] = 0
    shading = np.repeat(shade[:, None], 3, axis=1)
    H, W = height, width
    f = lambda a, c: a.reshape(H, W, c).squeeze().astype(np.float32) if c == 1 else a.reshape(H, W, c).astype(np.float32)
    return SyntheticScene(
        camera=cam, depth=f(depth, 1).reshape(H, W), normals=f(normals, 3),
        albedo=f(alb, 3), shading=f(shading, 3), image=f(alb * shading, 3),
        visibility=f(np.where(hit, vis, 1.0), 1).reshape(H, W),
        light_dir_cam=R.T @ l, ambient=float(ambient), light_intensity=float(light_intensity),
        cam_to_world=R, camera_origin=origin,
        meta={"box": None if box is None else [box[0].tolist(), box[1].tolist()],
              "extra_lights_cam": extra_cam, "lamp_cam": lamp_cam},
    )


def sphere_object_bundle(camera: Camera, center, radius: float, albedo=(0.8, 0.8, 0.8), *,
                         floor_normal=None, supersample: int = 4) -> ObjectBundle:
    """An exact sphere as an object bundle.

    Args:
        camera: the view.
        center: sphere centre in the CAMERA frame (metres; in front of the camera z < 0).
        radius: metres (> 0).
        albedo: linear RGB.
        floor_normal: camera-frame normal of the support plane, which touches the sphere
            at ``center - radius * floor_normal``; default the camera's +y.
        supersample: s x s subpixel rays per pixel for the anti-aliased mask.
    Returns:
        ObjectBundle with depth/normals/albedo averaged over the covered subpixels
        (0 where uncovered), mask = coverage in [0, 1], footprint_depth = z-depth of the
        support plane inside the disc of radius ``radius`` around the contact point
        (0 elsewhere), meta ``object_height_m = 2 * radius``.
    """
    c = np.asarray(center, dtype=np.float64).reshape(3)
    if not np.all(np.isfinite(c)) or not np.isfinite(radius) or radius <= 0:
        raise InputError("sphere centre must be finite and radius > 0")
    s = max(1, int(supersample))
    H, W = camera.height, camera.width
    off = (np.arange(s) + 0.5) / s - 0.5
    acc_d = np.zeros((H, W))
    acc_n = np.zeros((H, W, 3))
    cnt = np.zeros((H, W))
    u0 = np.arange(W) + 0.5
    v0 = np.arange(H) + 0.5
    for oy in off:
        for ox in off:
            uu, vv = np.meshgrid(u0 + ox, v0 + oy)
            d = camera.ray(uu, vv)
            dn = d / np.linalg.norm(d, axis=-1, keepdims=True)
            b = dn @ c
            disc = b * b - (c @ c - radius * radius)
            hit = disc >= 0
            t = b - np.sqrt(np.maximum(disc, 0))
            hit &= t > 0
            P = dn * t[..., None]
            n = (P - c) / radius
            acc_d += np.where(hit, -P[..., 2], 0)
            acc_n += np.where(hit[..., None], n, 0)
            cnt += hit
    cov = cnt / (s * s)
    with np.errstate(invalid="ignore", divide="ignore"):
        depth = np.where(cnt > 0, acc_d / np.maximum(cnt, 1), 0)
        nrm = acc_n / np.maximum(np.linalg.norm(acc_n, axis=-1, keepdims=True), 1e-12)
    nrm[cnt == 0] = 0
    alb = np.zeros((H, W, 3))
    alb[cnt > 0] = albedo
    fn = np.array([0.0, 1.0, 0.0]) if floor_normal is None else np.asarray(floor_normal, float)
    fn = fn / np.linalg.norm(fn)
    contact = c - radius * fn
    rays = camera.pixel_rays()
    denom = rays @ fn
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (contact @ fn) / denom
    Pf = rays * t[..., None]
    inside = (t > 0) & (np.linalg.norm(Pf - contact, axis=-1) <= radius) & np.isfinite(t)
    footprint = np.where(inside, -Pf[..., 2], 0)
    return ObjectBundle(depth=depth, normals=nrm, albedo=alb, mask=cov,
                        footprint_depth=np.nan_to_num(footprint), camera=camera,
                        meta={"object_height_m": 2.0 * radius, "source": "synthetic sphere"})


def insert_bundle(depth, normals, albedo, bundle: ObjectBundle, threshold: float = 0.5):
    """Composite maps by mask replacement where ``bundle.mask > threshold`` and the object
    is in front of the scene (or the scene is invalid). Returns new (depth, normals,
    albedo) float32 arrays and the bool replacement mask."""
    d = np.asarray(depth, np.float32).copy()
    sel = (bundle.mask > threshold) & (bundle.depth > 0)
    sel &= (d <= 0) | (bundle.depth < d)
    n = np.asarray(normals, np.float32).copy()
    a = np.asarray(albedo, np.float32).copy()
    d[sel] = bundle.depth[sel]
    n[sel] = bundle.normals[sel]
    a[sel] = bundle.albedo[sel]
    return d, n, a, sel


def write_floor_batch(folder, n_jobs: int, *, n_scenes: int = 3, size=(96, 72), renderer: str = "physical"):
    """A mesh-free batch for executor tests and benchmarks (no Blender, no estimation):
    ``n_scenes`` analytic floor scenes (``floor_scene``, with a box and different
    lights) whose image, depth, normals and albedo are given as files, a 2D card object
    (image + mask), and ``n_jobs`` jobs standing the card at different pixels and
    heights, scenes taken in turn. Returns the jobs.yaml path."""
    from pathlib import Path

    import yaml
    from PIL import Image

    from zcomp_cli.imageio import write_exr, write_png

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    W, H = size
    scenes = {}
    for k in range(n_scenes):
        sc = floor_scene(W, H, with_box=True, light_dir=(0.5 - 0.4 * k, 1.0, 0.3 + 0.2 * k),
                         box_center=(-0.6 + 0.3 * k, -3.5))
        write_png(folder / f"floor{k}.png", np.clip(sc.image, 0, 1))
        write_exr(folder / f"floor{k}_depth.exr", sc.depth)
        write_exr(folder / f"floor{k}_normals.exr", sc.normals)
        write_exr(folder / f"floor{k}_albedo.exr", sc.albedo)
        scenes[f"s{k}"] = {"image": f"floor{k}.png", "fov_deg": 50.0, "depth": f"floor{k}_depth.exr",
                           "normals": f"floor{k}_normals.exr", "albedo": f"floor{k}_albedo.exr"}
    m = np.zeros((40, 20), np.uint8)
    m[3:37, 3:17] = 255
    Image.fromarray(m).save(folder / "mask.png")
    Image.fromarray(np.full((40, 20, 3), 200, np.uint8)).save(folder / "obj.png")
    jobs = []
    for j in range(n_jobs):
        px = [round(W * (0.3 + 0.4 * ((j * 7) % 10) / 10), 1), round(H * (0.7 + 0.2 * ((j * 3) % 5) / 5), 1)]
        jobs.append({"output": f"job{j:03d}", "scene": f"s{j % n_scenes}", "object": "card",
                     "placement": {"pixel": px, "height": 0.15 + 0.03 * (j % 4)}})
    manifest = {"version": 1, "defaults": {"renderer": renderer}, "scenes": scenes,
                "objects": {"card": {"image": "obj.png", "mask": "mask.png"}}, "jobs": jobs}
    path = folder / "jobs.yaml"
    path.write_text(yaml.safe_dump(manifest, sort_keys=False))
    return path


def light_context(*lights, pitch_deg=None, roll_deg=None):
    """The renderer's light tree (``RenderRequest.light``, ``lightparams.LightParams``) of
    manifest light mappings (``pipeline/lightspec.py``), validated as the manifest
    validates them; raises ``InputError`` with the problems."""
    from zcomp_cli.pipeline.lightspec import parse_light, scene_light

    probs = []
    value = list(lights) if len(lights) != 1 else lights[0]
    out = parse_light(value, "light", lambda c, k, w, m: probs.append(f"{w}: {m}"))
    if out is None:
        raise InputError("; ".join(probs))
    tilt = {} if pitch_deg is None else {"pitch_deg": float(pitch_deg), "roll_deg": float(roll_deg or 0.0)}
    return scene_light(out, tilt)


def estimate_light(depth, normals, shading, known, albedo, camera, *, up, up_from=None, cfg=None, seed: int = 0,
                   params=None, with_fit: bool = False):
    """The light of an analytic scene's known shading, as the light stage fits it
    (``light.fit.fit_light``; ``params`` None: estimated; ``cfg`` None: the defaults):
    its ``LightModel``, or with ``with_fit`` the whole ``LightFit`` (the filled tree, the
    posterior, the diagnostics). For tests and calibration scripts."""
    from zcomp_cli.light.config import LightConfig
    from zcomp_cli.light.fit import fit_light
    from zcomp_cli.scene.lightparams import Origin

    res = fit_light(params, depth, normals, shading, known, albedo, camera, up=up,
                    up_from=Origin.SUPPORT if up_from is None else up_from,
                    cfg=LightConfig() if cfg is None else cfg, seed=seed)
    return res if with_fit else res.model
