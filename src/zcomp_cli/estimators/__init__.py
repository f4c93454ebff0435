"""Background intrinsics estimated from a photograph alone (issue 6).

Each missing map gets an estimator; a provided map always wins and is never re-estimated.

* depth: ``{proxy: ground_plane, camera_height: 1.5, pitch_deg: -10}`` (or
  ``horizon_row``), or ``{model: DIR}`` for a local transformers depth model (a
  relative model is aligned to the ground plane when its keys are also given, else to
  ``median_depth``);
* normals: from the depth map (``{from: depth, discontinuity_threshold: 0.1}``,
  default), analytic when the depth is the ground-plane proxy;
* albedo: colour Retinex (``{method: retinex, ...}``, default).

Estimates are cached by (image content hash, camera, estimator, settings) as EXR under
``cache_dir`` and shared by all jobs of a scene.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from zcomp_cli.camera import Camera
from zcomp_cli.compositing.shading import shading_from_image
from zcomp_cli.errors import InputError

__all__ = ["EstimatedMaps", "estimate_scene_maps"]


@dataclass
class EstimatedMaps:
    depth: np.ndarray  # (H, W) float32 z-depth, metres
    normals: np.ndarray  # (H, W, 3) float32 camera-frame unit
    albedo: np.ndarray  # (H, W, 3) float32 linear [0, 1]
    shading: np.ndarray  # (H, W, 3) float32 image / albedo
    sources: dict = field(default_factory=dict)  # map -> 'provided'|'ground_plane'|...
    timings: dict = field(default_factory=dict)  # map -> seconds (0 when cached)
    notes: list = field(default_factory=list)


def _depth_estimate(image, camera, spec, cache, img_key):
    from zcomp_cli.estimators.cache import content_key
    from zcomp_cli.estimators.ground_plane import (GroundPlaneSpec, floor_mask, ground_plane_depth,
                                                   has_ground_plane_keys)

    if spec is None:
        raise InputError("no depth map and no depth estimator: give a depth file or e.g. "
                         "depth: {proxy: ground_plane, camera_height: 1.5, pitch_deg: -10}")
    if not isinstance(spec, dict):
        raise InputError(f"depth estimator must be a mapping, got {spec!r}")
    if "proxy" in spec and spec["proxy"] != "ground_plane":
        raise InputError(f"unknown depth proxy {spec['proxy']!r} (use ground_plane)")
    if spec.get("proxy") == "ground_plane" or ("model" not in spec and has_ground_plane_keys(spec)):
        gp = GroundPlaneSpec.from_dict(spec)
        d, n = ground_plane_depth(camera, gp)
        return d, n, "ground_plane", None
    if "model" in spec:
        from zcomp_cli.estimators.learned import DEFAULT_MEDIAN_DEPTH_M, learned_depth

        settings = {k: v for k, v in spec.items()}
        key = content_key(img_key, "learned", str(spec["model"]), settings)
        cached = cache.get("depth", key, 1)
        if cached is not None:
            return cached, None, f"learned:{spec['model']}", "cached"
        proxy = pmask = None
        if has_ground_plane_keys(spec):
            gp = GroundPlaneSpec.from_dict({k: v for k, v in spec.items()
                                            if k not in ("model", "output", "median_depth",
                                                         "median_depth_m")})
            proxy, _ = ground_plane_depth(camera, gp)
            pmask = floor_mask(camera, gp)
        try:
            med = float(spec.get("median_depth", spec.get("median_depth_m", DEFAULT_MEDIAN_DEPTH_M)))
        except (TypeError, ValueError):
            raise InputError(f"depth model: median_depth must be metres, got {spec.get('median_depth')!r}") from None
        res = learned_depth(image, camera, spec["model"], output=spec.get("output"),
                            proxy_depth=proxy, proxy_mask=pmask, median_depth_m=med)
        cache.put("depth", key, res.depth)
        return res.depth, None, f"learned:{spec['model']}", res.alignment
    raise InputError(f"unknown depth estimator {spec!r}: use proxy: ground_plane or model: DIR")


def estimate_scene_maps(image_lin, camera: Camera, *, depth_spec=None, normals_spec=None,
                        albedo_spec=None, provided: dict | None = None,
                        cache_dir=None) -> EstimatedMaps:
    """Fill the maps a scene lacks; ``provided`` maps are returned untouched.

    Args:
        image_lin: (H, W, 3) linear RGB of the scene at the camera's size.
        camera: its pinhole camera.
        depth_spec, normals_spec, albedo_spec: estimator mappings from the manifest
            (see the module doc) or None for the defaults.
        provided: map name -> array already given by the user ('depth', 'normals', 'albedo').
        cache_dir: where estimates are cached (None = no cache).
    Returns:
        EstimatedMaps with all of depth, normals, albedo and shading (= image / albedo).
    """
    from zcomp_cli.estimators.albedo import retinex_albedo
    from zcomp_cli.estimators.cache import EstimateCache, content_key
    from zcomp_cli.estimators.normals_from_depth import DEFAULT_DISCONTINUITY, normals_from_depth

    img = np.asarray(image_lin, np.float32)
    if img.ndim != 3 or img.shape[2] != 3 or img.shape[:2] != (camera.height, camera.width):
        raise InputError(f"estimate_scene_maps: image {img.shape} does not match the camera "
                         f"{camera.height}x{camera.width}x3")
    provided = dict(provided or {})
    unknown = set(provided) - {"depth", "normals", "albedo", "roughness", "metallic"}
    if unknown:
        raise InputError(f"estimate_scene_maps: unknown provided maps {sorted(unknown)}")
    cache = EstimateCache(cache_dir)
    img_key = content_key(img, camera.K)
    sources: dict[str, str] = {}
    timings: dict[str, float] = {}
    notes: list[str] = []

    # 1. depth
    t = time.perf_counter()
    proxy_normals = None
    if "depth" in provided:
        depth = np.asarray(provided["depth"], np.float32)
        sources["depth"] = "provided"
    else:
        depth, proxy_normals, sources["depth"], how = _depth_estimate(img, camera, depth_spec,
                                                                     cache, img_key)
        if how:
            notes.append(f"depth: {how}")
    if depth.shape != img.shape[:2]:
        raise InputError(f"depth map {depth.shape} does not match the image {img.shape[:2]}")
    timings["depth"] = time.perf_counter() - t

    # 2. normals
    t = time.perf_counter()
    if "normals" in provided:
        normals = np.asarray(provided["normals"], np.float32)
        sources["normals"] = "provided"
    elif proxy_normals is not None and not normals_spec:
        normals, sources["normals"] = proxy_normals, "ground_plane"
    else:
        ns = dict(normals_spec or {})
        src = ns.pop("from", "depth")
        if src != "depth":
            raise InputError(f"normals estimator: only 'from: depth' is supported, got {src!r}")
        thr = float(ns.pop("discontinuity_threshold", DEFAULT_DISCONTINUITY))
        if ns:
            raise InputError(f"normals estimator: unknown keys {sorted(ns)}")
        key = content_key(depth, camera.K, "from_depth", thr)
        normals = cache.get("normals", key, 3)
        if normals is None:
            normals = normals_from_depth(depth, camera, discontinuity_threshold=thr)
            cache.put("normals", key, normals)
        sources["normals"] = "from_depth"
    timings["normals"] = time.perf_counter() - t

    # 3. albedo (and the shading that follows from it)
    t = time.perf_counter()
    if "albedo" in provided:
        albedo = np.asarray(provided["albedo"], np.float32)
        sources["albedo"] = "provided"
    else:
        aspec = dict(albedo_spec or {})
        method = aspec.pop("method", "retinex")
        if method != "retinex":
            raise InputError(f"albedo estimator: unknown method {method!r} (use retinex)")
        key = content_key(img_key, "retinex", aspec)
        albedo = cache.get("albedo", key, 3)
        if albedo is None:
            try:
                albedo, _ = retinex_albedo(img, **aspec)
            except TypeError as exc:
                raise InputError(f"albedo estimator: bad settings {aspec}: {exc}") from exc
            cache.put("albedo", key, albedo)
        sources["albedo"] = "retinex"
    timings["albedo"] = time.perf_counter() - t
    shading = shading_from_image(img, albedo)
    return EstimatedMaps(depth=depth, normals=normals, albedo=albedo, shading=shading,
                         sources=sources, timings=timings, notes=notes)
