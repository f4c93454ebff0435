"""Background intrinsics estimated from a photograph alone (issues 6 and 29).

Each missing map gets an estimator; a provided map always wins and is never re-estimated.
The mappings and their keys are listed in ``estimators.specs``:

* depth: ``{proxy: ground_plane, camera_height: 1.5, pitch_deg: -10}`` (or
  ``horizon_row``), or ``{model: DIR}``: a local transformers depth model or a diffusers
  depth pipeline (Marigold). A relative prediction is aligned to metric depth: to the
  ground plane when its keys are given, else scaled to ``median_depth`` with its shift
  fitted to the normals when they are learned or provided (``align``);
* normals: from the depth map (``{from: depth, discontinuity_threshold: 0.1}``, the
  default; analytic on the ground-plane proxy), or ``{model: DIR}``, a diffusers normals
  pipeline (Marigold normals);
* albedo: colour Retinex (``{method: retinex, ...}``, default), or ``{model: DIR}``, a
  diffusers intrinsics pipeline (Marigold IID: albedo, and roughness and metallic from
  the appearance model).

Where the normals do not come from the depth itself, their disagreement with the
depth's geometry is measured (``estimators.consistency``) and reported in degrees.
Estimates are cached by (image content hash, camera, estimator, settings) as EXR under
``cache_dir`` and shared by all jobs of a scene.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np

from zcomp_cli.camera import Camera
from zcomp_cli.compositing.shading import shading_from_image
from zcomp_cli.errors import InputError

__all__ = ["EstimatedMaps", "estimate_scene_maps"]

log = logging.getLogger(__name__)
# Median disagreement beyond which the report warns: the shading mask and the light
# read different geometry from the depth than the renderer shades with.
WARN_MEDIAN_DEG = 30.0


@dataclass
class EstimatedMaps:
    depth: np.ndarray  # (H, W) float32 z-depth, metres
    normals: np.ndarray  # (H, W, 3) float32 camera-frame unit
    albedo: np.ndarray  # (H, W, 3) float32 linear [0, 1]
    shading: np.ndarray  # (H, W, 3) float32 image / albedo
    sources: dict = field(default_factory=dict)  # map -> 'provided'|'ground_plane'|...
    timings: dict = field(default_factory=dict)  # map -> seconds (0 when cached)
    notes: list = field(default_factory=list)
    roughness: np.ndarray | None = None  # (H, W) [0, 1], from an appearance model
    metallic: np.ndarray | None = None
    agreement: np.ndarray | None = None  # (H, W) degrees normals vs depth, NaN = not compared
    fits: dict = field(default_factory=dict)  # depth alignment, agreement summary, model runs


@dataclass
class _Depth:
    depth: np.ndarray | None  # final depth, or None while a relative prediction awaits alignment
    source: str
    how: str | None = None
    rel: np.ndarray | None = None  # relative prediction
    kind: str | None = None  # disparity | affine
    proxy_normals: np.ndarray | None = None
    proxy: np.ndarray | None = None  # ground-plane depth and floor mask, when described
    floor: np.ndarray | None = None


def _ground_plane(camera, spec):
    from zcomp_cli.estimators.ground_plane import GroundPlaneSpec, floor_mask, ground_plane_depth
    from zcomp_cli.estimators.specs import GROUND_PLANE_KEYS

    gp = GroundPlaneSpec.from_dict({k: v for k, v in spec.items() if k in GROUND_PLANE_KEYS})
    d, n = ground_plane_depth(camera, gp)
    return d, n, floor_mask(camera, gp)


def _predict_depth(img, camera, spec, cache, img_key, notes, fits) -> _Depth:
    from zcomp_cli.estimators.ground_plane import has_ground_plane_keys
    from zcomp_cli.estimators.specs import check_estimator, form_of

    if spec is None:
        from zcomp_cli.estimators.ground_suggest import ground_plane_suggestion

        raise InputError(ground_plane_suggestion(camera))
    check_estimator("depth", spec)
    if form_of("depth", spec) == "proxy":
        d, n, floor = _ground_plane(camera, spec)
        return _Depth(d, "ground_plane", proxy_normals=n, floor=floor)
    from zcomp_cli.estimators.learned_maps import learned_depth_raw

    res = learned_depth_raw(img, spec, cache=cache, img_key=img_key)
    notes += res.notes
    fits["depth_model"] = res.run
    out = _Depth(None, res.source, rel=res.maps["depth"], kind=res.kind)
    if has_ground_plane_keys(spec):
        out.proxy, _, out.floor = _ground_plane(camera, spec)
    if res.kind == "metric":
        out.depth = np.where(out.rel > 0, out.rel, 0.0).astype(np.float32)
        out.how = "metric output used as z-depth"
    return out


def _align_depth(dp: _Depth, spec, normals, camera, fits) -> None:
    """Turn a relative prediction into metric depth (see the module doc)."""
    from zcomp_cli.estimators.consistency import fit_shift_to_normals
    from zcomp_cli.estimators.depth_alignment import DEFAULT_MEDIAN_DEPTH_M, align_relative_depth

    med = float(spec.get("median_depth", spec.get("median_depth_m", DEFAULT_MEDIAN_DEPTH_M)))
    mode = spec.get("align", "auto")
    if mode == "auto":
        mode = "ground_plane" if dp.proxy is not None else ("normals" if normals is not None else "median")
    if mode == "normals" and normals is None:
        raise InputError("depth: align: normals needs normals that do not come from the depth "
                         "(a normals model or a provided normals map)")
    if mode == "ground_plane":
        from zcomp_cli.estimators.depth_alignment import ground_plane_fit

        fit = ground_plane_fit(dp.rel, dp.kind, dp.proxy, dp.floor) if dp.proxy is not None else None
        if fit is not None:
            dp.depth, dp.how = fit
            return
        fits["depth_ground_plane_fit"] = "failed (too few floor pixels, a flat prediction or a negative scale)"
        mode = "normals" if normals is not None else "median"
    shift = None
    if mode == "normals":
        shift, best, before = fit_shift_to_normals(dp.rel, dp.kind, normals, camera)
        fits["depth_shift_fit"] = {"shift": round(shift, 6), "median_deg": round(best, 2),
                                   "median_deg_default_shift": round(before, 2)}
    dp.depth, dp.how = align_relative_depth(dp.rel, dp.kind, median_depth_m=med, shift=shift)
    if mode == "normals":
        f = fits["depth_shift_fit"]
        dp.how += (f" to the normals (median disagreement {f['median_deg']:.1f} deg; "
                   f"{f['median_deg_default_shift']:.1f} deg with the default shift)")
    if "depth_ground_plane_fit" in fits:
        dp.how = "ground-plane fit failed; " + dp.how


def estimate_scene_maps(image_lin, camera: Camera, *, depth_spec=None, normals_spec=None,
                        albedo_spec=None, provided: dict | None = None,
                        cache_dir=None) -> EstimatedMaps:
    """Fill the maps a scene lacks; ``provided`` maps are returned untouched.

    Args:
        image_lin: (H, W, 3) linear RGB of the scene at the camera's size.
        camera: its pinhole camera.
        depth_spec, normals_spec, albedo_spec: estimator mappings from the manifest
            (see ``estimators.specs``) or None for the defaults.
        provided: map name -> array already given by the user ('depth', 'normals',
            'albedo', 'roughness', 'metallic').
        cache_dir: where estimates are cached (None = no cache).
    Returns:
        EstimatedMaps with all of depth, normals, albedo and shading (= image / albedo);
        roughness and metallic when an appearance model predicted them; the agreement
        of normals and depth (degrees) when they come from different sources.
    """
    from zcomp_cli.estimators.albedo import RETINEX_VERSION, retinex_albedo
    from zcomp_cli.estimators.cache import EstimateCache, content_key
    from zcomp_cli.estimators.normals_from_depth import DEFAULT_DISCONTINUITY, normals_from_depth
    from zcomp_cli.estimators.specs import check_estimator, form_of

    img = np.asarray(image_lin, np.float32)
    if img.ndim != 3 or img.shape[2] != 3 or img.shape[:2] != (camera.height, camera.width):
        raise InputError(f"estimate_scene_maps: image {img.shape} does not match the camera "
                         f"{camera.height}x{camera.width}x3")
    provided = dict(provided or {})
    unknown = set(provided) - {"depth", "normals", "albedo", "roughness", "metallic"}
    if unknown:
        raise InputError(f"estimate_scene_maps: unknown provided maps {sorted(unknown)}")
    for name, spec in (("normals", normals_spec), ("albedo", albedo_spec)):
        if spec:
            check_estimator(name, spec)
    cache = EstimateCache(cache_dir)
    img_key = content_key(img, camera.K)
    sources: dict[str, str] = {}
    timings: dict[str, float] = {}
    notes: list[str] = []
    fits: dict = {}
    extra: dict[str, np.ndarray] = {}

    # 1. depth: provided, the proxy, or a model's raw prediction (aligned in step 3)
    t = time.perf_counter()
    if "depth" in provided:
        dp = _Depth(np.asarray(provided["depth"], np.float32), "provided")
    else:
        dp = _predict_depth(img, camera, depth_spec, cache, img_key, notes, fits)
    sources["depth"] = dp.source
    timings["depth"] = time.perf_counter() - t

    # 2. normals given or learned (from the depth comes after the depth is final)
    t = time.perf_counter()
    normals = None
    if "normals" in provided:
        normals = np.asarray(provided["normals"], np.float32)
        sources["normals"] = "provided"
    elif normals_spec and form_of("normals", normals_spec) == "model":
        from zcomp_cli.estimators.learned_maps import learned_normals

        res = learned_normals(img, normals_spec, cache=cache, img_key=img_key)
        normals, sources["normals"] = res.maps["normals"], res.source
        notes += res.notes
        fits["normals_model"] = res.run
    timings["normals"] = time.perf_counter() - t

    # 3. a relative depth becomes metric: ground plane, normals or median
    t = time.perf_counter()
    if dp.depth is None:
        _align_depth(dp, depth_spec, normals, camera, fits)
    if dp.how:
        notes.append(f"depth: {dp.how}")
        fits["depth"] = dp.how
    depth = dp.depth
    if depth.shape != img.shape[:2]:
        raise InputError(f"depth map {depth.shape} does not match the image {img.shape[:2]}")
    timings["depth"] += time.perf_counter() - t

    # 4. normals from the depth (analytic on the proxy)
    t = time.perf_counter()
    if normals is None:
        if dp.proxy_normals is not None and not normals_spec:
            normals, sources["normals"] = dp.proxy_normals, "ground_plane"
        else:
            ns = dict(normals_spec or {})
            thr = float(ns.get("discontinuity_threshold", DEFAULT_DISCONTINUITY))
            key = content_key(depth, camera.K, "from_depth", thr)
            normals = cache.get("normals", key, 3)
            if normals is None:
                normals = normals_from_depth(depth, camera, discontinuity_threshold=thr)
                cache.put("normals", key, normals)
            sources["normals"] = "from_depth"
    if normals.shape != (*img.shape[:2], 3):
        raise InputError(f"normals map {normals.shape} does not match the image {img.shape[:2]}")

    # 5. do depth and normals describe the same surfaces?
    agree_map = None
    independent = sources["normals"] not in ("from_depth", "ground_plane")
    if independent and not (sources["depth"] == "provided" and sources["normals"] == "provided"):
        from zcomp_cli.estimators.consistency import DEFAULT_THRESHOLD_DEG, agreement

        thr = float((normals_spec or {}).get("agreement_threshold_deg", DEFAULT_THRESHOLD_DEG))
        ag = agreement(depth, normals, camera, threshold_deg=thr)
        agree_map = ag.angle_deg
        fits["agreement"] = ag.summary()
        if ag.pixels:
            notes.append(ag.describe())
        if dp.floor is not None and dp.floor.any():
            # On the proxy's floor the comparison checks the ground-plane keys themselves
            # (a wrong pitch tilts every floor normal); off it the proxy is a stand-in.
            fl = agreement(depth, normals, camera, threshold_deg=thr, mask=dp.floor)
            fits["agreement_floor"] = fl.summary()
            if fl.pixels:
                notes.append("on the ground plane's floor, " + fl.describe())
            if ag.median_deg > WARN_MEDIAN_DEG:
                msg = (f"depth ({sources['depth']}) and normals ({sources['normals']}) disagree by a median "
                       f"{ag.median_deg:.0f} deg: the shading mask and the light read other surfaces than the "
                       "renderer shades; check fov_deg and the ground-plane keys, or estimate the depth with a "
                       "model (align: normals)")
                log.warning(msg)
                notes.append(msg)
    timings["normals"] += time.perf_counter() - t

    # 6. albedo (and the shading that follows from it)
    t = time.perf_counter()
    if "albedo" in provided:
        albedo = np.asarray(provided["albedo"], np.float32)
        sources["albedo"] = "provided"
    elif albedo_spec and form_of("albedo", albedo_spec) == "model":
        from zcomp_cli.estimators.learned_maps import learned_albedo

        res = learned_albedo(img, albedo_spec, cache=cache, img_key=img_key)
        albedo, sources["albedo"] = res.maps["albedo"], res.source
        notes += res.notes
        fits["albedo_model"] = res.run
        for m in ("roughness", "metallic"):
            if m in res.maps and m not in provided:
                extra[m] = res.maps[m]
                sources[m] = res.source
    else:
        aspec = {k: v for k, v in (albedo_spec or {}).items() if k != "method"}
        key = content_key(img_key, RETINEX_VERSION, aspec)
        albedo = cache.get("albedo", key, 3)
        if albedo is None:
            albedo, _ = retinex_albedo(img, **aspec)
            cache.put("albedo", key, albedo)
        sources["albedo"] = "retinex"
    timings["albedo"] = time.perf_counter() - t
    shading = shading_from_image(img, albedo)
    return EstimatedMaps(depth=depth, normals=normals, albedo=albedo, shading=shading, sources=sources,
                         timings=timings, notes=notes, roughness=extra.get("roughness"),
                         metallic=extra.get("metallic"), agreement=agree_map, fits=fits)
