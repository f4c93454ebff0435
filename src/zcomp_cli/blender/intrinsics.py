"""Object intrinsics (depth, normals, albedo, mask, footprint) rendered by Blender.

The Python API the compositing pipeline and ``zcomp render-intrinsics`` use::

    results = render_object_intrinsics([IntrinsicsRequest(id, mesh, pose, camera, out_dir)])

Steps for a batch:

1. prepare every request in the parent: read and hash the mesh (trimesh), place it
   (``Pose.object_to_camera`` on its bounding box), refuse objects behind the camera
   or outside the view, derive the Blender camera from K, compute the cache key;
2. answer cache hits by copying (hard-linking) the cached bundle;
3. render the rest in ONE Blender process (``zcomp_cli/blender/scripts/render_intrinsics.py``
   through ``runner.run_blender_batch``): appearance, geometry and footprint passes;
4. as each item finishes, convert its passes in numpy (``passes``) into an
   ``ObjectBundle``, store it in the cache, copy it to the item's output folder.

A failure of one item (bad mesh, Blender crash, object out of view) is reported in its
``IntrinsicsResult``; the function never raises for a per-item failure.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from zcomp_cli.camera import Camera
from zcomp_cli.errors import InputError, ZcompError
from zcomp_cli.pose import Pose, transform_points

from zcomp_cli.blender import DEFAULT_SAMPLES
from zcomp_cli.cache import cache_dir as _cache_dir

from . import cache as _cache
from .meshes import MeshInfo, check_in_view, load_mesh_info

__all__ = [
    "IntrinsicsRequest",
    "IntrinsicsResult",
    "render_object_intrinsics",
    "blender_camera_from_K",
    "footprint_matrix",
    "SCRIPT",
    "SCRIPT_VERSION",
    "DEFAULT_SAMPLES",
]

SCRIPT = "render_intrinsics.py"
# Bump when the script or the conversions change what a bundle holds: old cache
# entries then stop matching.
SCRIPT_VERSION = "2"
# The footprint is the mesh squashed to this fraction of its height onto its base plane
# (not exactly 0, which would give Blender a singular object matrix).
FOOTPRINT_FLATTEN = 1e-6
# Border renders sample only the object's screen box, padded by this many pixels: more
# than the anti-aliasing filter's reach (1.5 px wide).
BORDER_PAD_PX = 3


@dataclass(frozen=True)
class IntrinsicsRequest:
    """One object x pose x camera to render. ``out_dir`` None: the bundle stays in the
    cache (or a temporary folder without a cache) and its path is returned."""

    id: str
    mesh: Path
    pose: Pose
    camera: Camera
    out_dir: Path | None = None


@dataclass
class IntrinsicsResult:
    """Outcome of one request: ``bundle_dir`` holds an ``ObjectBundle`` when ``ok``."""

    id: str
    ok: bool
    bundle_dir: Path | None = None
    error: str | None = None
    cached: bool = False
    seconds: float = 0.0


@dataclass
class _Prepared:
    index: int
    request: IntrinsicsRequest
    mesh: MeshInfo
    mesh_to_camera: np.ndarray
    footprint_to_camera: np.ndarray
    blender_camera: dict
    key: str
    borders: dict = field(default_factory=dict)
    meta: dict = field(default_factory=dict)
    t0: float = 0.0


def blender_camera_from_K(K, width: int, height: int, *, sensor_width_mm: float = 36.0) -> dict:
    """Blender camera settings reproducing pinhole ``K`` for a ``width`` x ``height`` image.

    With ``sensor_fit = 'HORIZONTAL'`` the focal length is ``fx * sensor_width / width``
    and both lens shifts are fractions of the image width: ``shift_x = (W/2 - cx) / W``,
    ``shift_y = (cy - H/2) / W`` (pixel rows grow downward, Blender's y upward).

    Returns ``{"lens_mm", "sensor_width_mm", "shift_x", "shift_y"}``.
    Raises InputError for non-square pixels (fx != fy) or a skewed K, which a Blender
    camera with square pixels cannot represent.
    """
    K = np.asarray(K, dtype=np.float64)
    if K.shape != (3, 3) or not np.all(np.isfinite(K)):
        raise InputError(f"K must be a finite 3x3 matrix, got {K.tolist()}")
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    if fx <= 0 or fy <= 0:
        raise InputError(f"K focal lengths must be positive, got fx={fx}, fy={fy}")
    if abs(fx - fy) > 1e-6 * max(fx, fy):
        raise InputError(f"non-square pixels are not supported (fx={fx:g} != fy={fy:g})")
    if abs(K[0, 1]) > 1e-9 or np.any(np.abs(K[2] - [0, 0, 1]) > 1e-9) or abs(K[1, 0]) > 1e-9:
        raise InputError("K must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (no skew)")
    if width <= 0 or height <= 0:
        raise InputError(f"resolution must be positive, got {width}x{height}")
    return {
        "lens_mm": float(fx * sensor_width_mm / width),
        "sensor_width_mm": float(sensor_width_mm),
        "shift_x": float((width / 2.0 - cx) / width),
        "shift_y": float((cy - height / 2.0) / width),
    }


def render_box(points_cam, camera: Camera, *, pad: int = BORDER_PAD_PX, near: float = 1e-3):
    """Pixel window holding the image of ``points_cam``, or None for the whole frame.

    Args:
        points_cam: (N, 3) camera-frame points (the placed mesh's vertices); the image of
            a mesh lies inside the convex hull of its vertices' images, so their box
            bounds it.
        camera: the ``Camera`` rendered.
        pad: whole pixels added on every side.
    Returns:
        ``[x0, x1, y0, y1]`` integer pixels, top-left origin, ends exclusive, inside the
        frame; None when the box covers the frame or a point is at or behind the camera
        plane (its image is unbounded).
    """
    p = np.asarray(points_cam, dtype=np.float64).reshape(-1, 3)
    if p.size == 0 or not np.all(np.isfinite(p)) or np.any(p[:, 2] >= -near):
        return None
    px, _ = camera.project(p)
    W, H = camera.width, camera.height
    x0 = max(0, int(np.floor(px[:, 0].min())) - pad)
    x1 = min(W, int(np.ceil(px[:, 0].max())) + pad)
    y0 = max(0, int(np.floor(px[:, 1].min())) - pad)
    y1 = min(H, int(np.ceil(px[:, 1].max())) + pad)
    if x1 <= x0 or y1 <= y0:  # wholly outside: check_in_view has refused it already
        return None
    if x0 == 0 and y0 == 0 and x1 == W and y1 == H:
        return None
    return [x0, x1, y0, y1]


def footprint_matrix(mesh_to_camera, bbox_min, *, flatten: float = FOOTPRINT_FLATTEN) -> np.ndarray:
    """4x4 mesh->camera matrix of the mesh flattened onto its support plane.

    In mesh coordinates (Y-up) the flattening keeps x and z and maps
    ``y -> min_y + flatten * (y - min_y)``; ``mesh_to_camera`` then carries the plane
    ``y = min_y`` to the support plane through the pose's base point, perpendicular to
    ``Pose.up``.
    """
    M = np.asarray(mesh_to_camera, dtype=np.float64)
    min_y = float(np.asarray(bbox_min, dtype=np.float64)[1])
    flat = np.eye(4)
    flat[1, 1] = flatten
    flat[1, 3] = (1.0 - flatten) * min_y
    return M @ flat


def _prepare(i: int, req: IntrinsicsRequest, settings: dict, mesh_cache: dict) -> _Prepared:
    if not isinstance(req.camera, Camera):
        raise InputError("camera must be a zcomp_cli.camera.Camera")
    if not isinstance(req.pose, Pose):
        raise InputError("pose must be a zcomp_cli.pose.Pose")
    mesh_path = Path(req.mesh)
    # One read and hash per mesh file, however many poses use it.
    ck = str(mesh_path.resolve()) if mesh_path.exists() else str(mesh_path)
    if ck not in mesh_cache:
        try:
            mesh_cache[ck] = load_mesh_info(mesh_path)
        except ZcompError as exc:
            mesh_cache[ck] = exc
    info = mesh_cache[ck]
    if isinstance(info, Exception):
        raise info
    cam = req.camera
    bcam = blender_camera_from_K(cam.K, cam.width, cam.height)
    M = req.pose.object_to_camera(info.bbox_min, info.bbox_max)
    placed = transform_points(M, info.vertices)
    check_in_view(placed, cam)
    F = footprint_matrix(M, info.bbox_min)
    box = render_box(placed, cam)
    borders = {"appearance": box, "geometry": box,
               "footprint": render_box(transform_points(F, info.vertices), cam)}
    key = _cache.cache_key(
        mesh_hash=info.content_hash, pose=req.pose.to_dict(), K=cam.K,
        resolution=(cam.width, cam.height), settings=settings, version=SCRIPT_VERSION,
    )
    s = req.pose.uniform_scale(info.bbox_min, info.bbox_max)
    meta = {
        "id": req.id,
        "mesh": str(info.path),
        "mesh_hash": info.content_hash,
        "mesh_format": info.format,
        "mesh_bbox_min": info.bbox_min.tolist(),
        "mesh_bbox_max": info.bbox_max.tolist(),
        "pose": req.pose.to_dict(),
        "object_to_camera": M.tolist(),
        "object_height_m": float(s * (info.bbox_max[1] - info.bbox_min[1])),
        "up_camera": req.pose.up.tolist(),
        "base_point_camera": list(req.pose.position),
        "render_settings": settings,
        "script_version": SCRIPT_VERSION,
        "cache_key": key,
        "conventions": {
            "depth": "z-depth, metres, 0 = no surface at the pixel centre",
            "normals": "camera frame, OpenGL (x right, y up, +z toward the viewer), unit",
            "albedo": "linear RGB base colour",
            "mask": "anti-aliased coverage",
            "footprint_depth": "z-depth of the mesh flattened on its support plane, 0 outside",
        },
    }
    return _Prepared(i, req, info, M, F, bcam, key, meta=meta, borders=borders)


def _finish(p: _Prepared, event: dict, work_dir: Path) -> Path:
    """Convert a finished render into a bundle folder inside ``work_dir``."""
    from zcomp_cli.bundle import ObjectBundle

    from .passes import appearance_maps, footprint_depth, geometry_maps, paste_window, read_multilayer_exr

    files = event.get("files") or {}
    boxes = event.get("boxes") or {}
    W, H = p.request.camera.width, p.request.camera.height

    def full(name, arr):  # border renders hold only the object's window
        return paste_window(arr, boxes.get(name), W, H)

    try:
        app = {k: full("appearance", v) for k, v in
               appearance_maps(read_multilayer_exr(files["appearance"])).items()}
        depth, normals, _ = geometry_maps(read_multilayer_exr(files["geometry"]),
                                          cam_to_world=event.get("cam_to_world"))
        depth, normals = full("geometry", depth), full("geometry", normals)
        fp = full("footprint", footprint_depth(read_multilayer_exr(files["footprint"])))
    except KeyError as exc:
        raise InputError(f"Blender reported no {exc} render") from exc
    if float(app["mask"].max(initial=0.0)) <= 0.0 and not np.any(depth > 0):
        from zcomp_cli.errors import GeometryError

        raise GeometryError("object covers no pixel of the image (too small or out of view)")
    meta = dict(p.meta)
    meta["blender_version"] = event.get("blender_version")
    meta["render_seconds"] = float(event.get("seconds", float("nan")))
    meta["render_timings"] = event.get("timings")
    meta["blender_mesh_reused"] = event.get("mesh_reused")
    bundle = ObjectBundle(
        depth=depth, normals=normals, albedo=app["albedo"], mask=app["mask"],
        footprint_depth=fp, camera=p.request.camera, meta=meta,
        roughness=app.get("roughness") if event.get("has_roughness") else None,
        metallic=app.get("metallic") if event.get("has_metallic") else None,
    )
    folder = work_dir / f"bundle-{p.index}"
    bundle.save(folder)
    return folder


def _deliver(bundle_folder: Path, p: _Prepared, cache_dir: Path | None) -> Path:
    """Put a finished bundle into the cache and/or the request's output folder."""
    out = Path(p.request.out_dir) if p.request.out_dir is not None else None
    if cache_dir is not None:
        entry = _cache.store(cache_dir, p.key, bundle_folder)
        if out is None:
            return entry
        _cache.copy_bundle(entry, out)
        return out
    if out is None:
        keep = Path(tempfile.mkdtemp(prefix=f"zcomp-intrinsics-{_safe(p.request.id)}-"))
        _cache.copy_bundle(bundle_folder, keep)
        return keep
    _cache.copy_bundle(bundle_folder, out)
    return out


def _safe(s: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in str(s))[:40]


def render_object_intrinsics(
    requests: list[IntrinsicsRequest],
    *,
    cache_dir: str | Path | None = None,
    samples: int = DEFAULT_SAMPLES,
    progress: Callable[[int, int, str], None] | None = None,
    use_cache: bool = True,
    log_path: str | Path | None = None,
    stats: dict | None = None,
    session=None,
) -> list[IntrinsicsResult]:
    """Render (or fetch from the cache) the intrinsics bundle of every request.

    Args:
        requests: items with unique ids.
        cache_dir: the cache ROOT (``--cache-dir``; default ``zcomp_cli.cache.cache_root()``);
            bundles live in its ``intrinsics/`` folder. Ignored when ``use_cache`` is False.
        samples: Cycles samples of the anti-aliased pass (mask, albedo); depth and
            normals always come from one sample through each pixel centre.
        progress: called as ``progress(done_count, total, id)`` after every item.
        use_cache: False renders everything and stores nothing in the cache.
        log_path: where Blender's own output goes (default: a temporary file).
        stats: if given, filled with ``startup_s`` (Blender start-up seconds per
            process), ``restarts`` and ``log_path`` of the batch (benchmarks, reports).
        session: a ``runner.BlenderSession`` to render in (its Blender process stays
            up for later calls); default: a Blender process for this call.
    Returns:
        One ``IntrinsicsResult`` per request, in the same order.
    """
    ids = [str(r.id) for r in requests]
    if len(set(ids)) != len(ids):
        dup = sorted({i for i in ids if ids.count(i) > 1})
        raise InputError(f"request ids must be unique, repeated: {dup}")
    if not (isinstance(samples, int) and samples >= 1):
        raise InputError(f"samples must be an integer >= 1, got {samples!r}")
    total = len(requests)
    results: list[IntrinsicsResult | None] = [None] * total
    done = 0

    def report(i: int, res: IntrinsicsResult) -> None:
        nonlocal done
        results[i] = res
        done += 1
        if progress is not None:
            progress(done, total, res.id)

    settings = {"engine": "CYCLES", "samples": int(samples), "geometry_samples": 1,
                "filter_width": 1.5, "footprint_flatten": FOOTPRINT_FLATTEN}
    cdir = _cache_dir("intrinsics", cache_dir) if use_cache else None

    # 1. prepare
    prepared: list[_Prepared] = []
    mesh_cache: dict = {}
    for i, req in enumerate(requests):
        t0 = time.monotonic()
        try:
            p = _prepare(i, req, settings, mesh_cache)
            p.t0 = t0
        except (ZcompError, ValueError) as exc:
            report(i, IntrinsicsResult(str(req.id), False, error=str(exc), seconds=time.monotonic() - t0))
            continue
        # 2. cache hits
        hit = _cache.lookup(cdir, p.key) if cdir is not None else None
        if hit is not None:
            try:
                bundle_dir = hit
                if req.out_dir is not None:  # naming this request's mesh file, not the first one's
                    _cache.copy_bundle(hit, req.out_dir, meta_update={"mesh": str(p.mesh.path)})
                    bundle_dir = Path(req.out_dir)
                report(i, IntrinsicsResult(str(req.id), True, bundle_dir, cached=True,
                                           seconds=time.monotonic() - t0))
            except OSError as exc:
                report(i, IntrinsicsResult(str(req.id), False, error=f"cannot copy cached bundle: {exc}"))
            continue
        prepared.append(p)
    if not prepared:
        return results  # type: ignore[return-value]

    # 3. render the rest in one Blender process
    from .runner import run_blender_batch

    if cdir is not None:
        cdir.mkdir(parents=True, exist_ok=True)
    # Work folder on the cache's filesystem so finished bundles move in by rename.
    # The pid in the name lets a later run remove the folder if this process is killed.
    work = Path(tempfile.mkdtemp(prefix=f".work-{os.getpid()}-", dir=cdir)) if cdir is not None else Path(
        tempfile.mkdtemp(prefix=f"zcomp-intrinsics-work-{os.getpid()}-"))
    by_id = {str(p.request.id): p for p in prepared}
    items = []
    # Poses of one mesh next to each other: the script keeps an imported mesh (and
    # Cycles' synced scene) for consecutive items of the same file.
    for p in sorted(prepared, key=lambda q: (str(q.mesh.path), q.mesh.format, q.index)):
        wd = work / f"item-{p.index}"
        wd.mkdir()
        items.append({
            "id": str(p.request.id), "mesh": str(p.mesh.path), "format": p.mesh.format,
            "mesh_to_camera": p.mesh_to_camera.tolist(),
            "footprint_to_camera": p.footprint_to_camera.tolist(),
            "width": p.request.camera.width,
            "height": p.request.camera.height, "camera": p.blender_camera, "work_dir": str(wd),
            "borders": p.borders,
            "mesh_radius": float(np.linalg.norm(p.mesh.vertices, axis=1).max()),
        })

    def on_event(ev: dict) -> None:
        kind, iid = ev.get("event"), str(ev.get("id"))
        if kind == "start" and iid in by_id:
            by_id[iid].t0 = time.monotonic()
        if kind not in ("done", "error") or iid not in by_id:
            return
        p = by_id[iid]
        if results[p.index] is not None:
            return
        if kind == "error":
            report(p.index, IntrinsicsResult(iid, False, error=f"Blender: {ev.get('error')}",
                                             seconds=time.monotonic() - p.t0))
            return
        # 4. convert, cache, deliver -- while Blender renders the next item
        t_conv = time.monotonic()
        blender_s = float(ev.get("seconds", 0.0))
        try:
            folder = _finish(p, ev, work)
            bundle_dir = _deliver(folder, p, cdir)
            report(p.index, IntrinsicsResult(iid, True, bundle_dir,
                                             seconds=blender_s + time.monotonic() - t_conv))
        except (ZcompError, OSError, ValueError) as exc:
            report(p.index, IntrinsicsResult(iid, False, error=str(exc),
                                             seconds=blender_s + time.monotonic() - t_conv))

    try:
        if session is not None:
            batch = session.run(items, common={"samples": int(samples)}, on_event=on_event)
        else:
            batch = run_blender_batch(SCRIPT, items, common={"samples": int(samples)},
                                      on_event=on_event, log_path=log_path)
        if stats is not None:
            stats.update(startup_s=list(batch.startup_s), restarts=batch.restarts,
                         log_path=str(batch.log_path))
        for p in prepared:  # anything the runner settled without telling on_event
            if results[p.index] is None:
                ev = batch.results.get(str(p.request.id), {"event": "error", "error": "no result"})
                on_event({**ev, "id": str(p.request.id)})
                if results[p.index] is None:
                    report(p.index, IntrinsicsResult(str(p.request.id), False,
                                                     error=f"Blender: {ev.get('error', 'no result')}"))
    except Exception as exc:  # noqa: BLE001 -- the batch as a whole failed to run
        for p in prepared:
            if results[p.index] is None:
                report(p.index, IntrinsicsResult(str(p.request.id), False, error=f"Blender batch failed: {exc}"))
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return results  # type: ignore[return-value]
