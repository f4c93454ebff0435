"""One compositing job (DESIGN.md section 2), in numbered steps:

1. align the object's depth to the background on its footprint;
2. occlusion by nearer background geometry, then the intrinsic composite (eq. 1);
3. the shading mask s (eq. 3) and the region of interest the renderer must produce;
4. the background shading, masked by s for both passes;
5. the renderer, both passes in one call;
6. the shadow-opacity compositor (eq. 4-5).

Steps 1-4 are :func:`prepare_job` and step 6 is :func:`finish_job`, so that a batch can
hand the renderer the passes of several jobs at once (step 5, ``Renderer.render_jobs``);
:func:`run_job` chains the three for one job.
"""

from __future__ import annotations

import logging

import time
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from zcomp_cli.bundle import ObjectBundle
from zcomp_cli.compositing import (
    align_depth,
    apply_alignment,
    composite,
    composite_intrinsics,
    occlusion_mask,
    shading_from_image,
    shading_mask,
)
from zcomp_cli.compositing.compositor import BLUR_SIZE, keep_untouched
from zcomp_cli.conventions import DEFAULT_SEED, valid_depth_mask
from zcomp_cli.errors import GeometryError, NumericalError, RenderError
from zcomp_cli.limits import type_name
from zcomp_cli.pipeline.scene import Scene
from zcomp_cli.maps import SceneMaps
from zcomp_cli.renderers.base import Renderer, RenderOutput, RenderRequest

log = logging.getLogger(__name__)

ROI_CONTEXT_PX = 16
# A renderer's image is linear radiance in the photograph's units: never below 0 (beyond
# float rounding and a denoiser's ringing) and, in a photograph's range, far below 1e6
# (the shading the renderers clamp to; a plugin's 3e38 overflowed the compositor).
RADIANCE_TOL = 1e-3
MAX_RADIANCE = 1e6


@dataclass
class JobOutput:
    """Everything a job produced: the composite and, for --debug, the intermediates
    (``debug``, the pipeline's) and the renderer's own maps (``renderer_debug``,
    ``RenderOutput.debug_maps`` checked), for --aovs, the render passes
    (``compositing.aovs``)."""

    image: np.ndarray  # (H, W, 3) linear composite
    report: dict
    debug: dict = field(default_factory=dict)
    aovs: dict = field(default_factory=dict)
    renderer_debug: dict = field(default_factory=dict)


def roi_around(mask: np.ndarray, margin: int) -> tuple[int, int, int, int]:
    """Half-open box ``(x0, y0, x1, y1)`` around True pixels, grown by ``margin``."""
    rows = np.flatnonzero(mask.any(axis=1))
    cols = np.flatnonzero(mask.any(axis=0))
    h, w = mask.shape
    if rows.size == 0:
        return (0, 0, 0, 0)
    return (max(0, int(cols[0]) - margin), max(0, int(rows[0]) - margin),
            min(w, int(cols[-1]) + 1 + margin), min(h, int(rows[-1]) + 1 + margin))


@dataclass
class PreparedJob:
    """A job after steps 1-4: its two render requests (background, composite) and what
    step 6 needs. ``seed`` is the job's own, passed to the renderer with its requests."""

    requests: list[RenderRequest]
    seed: int
    scene: Scene
    object_mask: np.ndarray  # m, (H, W) coverage after occlusion
    shading_mask: np.ndarray  # s, (H, W) bool
    roi: tuple[int, int, int, int]
    report: dict
    timings: dict
    notes: list
    debug_maps: dict


def lamps_inside_object(light, cam, obj_depth, obj_mask, footprint_depth) -> list[str]:
    """Notes for the given lamps whose centre lies inside the object's bounds (camera
    frame: the box of its visible surface and of its footprint, which covers the base
    the camera does not see). Such a lamp lights the object from within: its outside
    is drawn unlit and its shadow swallows the scene. Said, not refused: a lamp inside a
    lampshade is a real scene, a typo in a position is the likelier one.

    Args:
        light: the scene's ``LightParams`` (None or no lamps: no note).
        obj_depth, footprint_depth: (H, W) z-depth, metres, > 0 where valid (aligned).
        obj_mask: (H, W) coverage in [0, 1].
    """
    lamps = getattr(light, "lamps", ()) or ()
    if not lamps:
        return []
    seen = (obj_mask > 0.5) & np.isfinite(obj_depth) & (obj_depth > 0)
    foot = np.isfinite(footprint_depth) & (footprint_depth > 0)
    pts = np.concatenate([cam.unproject(np.where(seen, obj_depth, 0.0))[seen],
                          cam.unproject(np.where(foot, footprint_depth, 0.0))[foot]])
    if len(pts) < 4:
        return []
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    notes = []
    for i, lp in enumerate(lamps):
        q = np.asarray(lp.position.value, np.float64) if lp.position.value is not None else None
        if q is not None and q.shape == (3,) and np.all(q >= lo) and np.all(q <= hi):
            notes.append(f"light: lamp {i} at {np.round(q, 3).tolist()} (camera frame, m) is inside the object "
                         f"(its bounds {np.round(lo, 3).tolist()} .. {np.round(hi, 3).tolist()}): it lights the "
                         "object from within, so the object's outside is drawn unlit; move the lamp out of it")
    return notes


def _size_note(m: np.ndarray, obj_depth: np.ndarray, scene_name: str) -> str | None:
    """A note (also logged) when the object's size on screen is implausible
    (``estimators.ground_suggest.object_size_note``)."""
    from zcomp_cli.estimators.ground_suggest import object_size_note

    cover = m > 0.5
    depth = float(np.median(obj_depth[cover & (obj_depth > 0)])) if (cover & (obj_depth > 0)).any() else None
    note = object_size_note(int(cover.sum()), m.size, depth)
    if note:
        log.warning("scene %s: %s", scene_name, note)
    return note


def prepare_job(
    scene: Scene,
    bundle: ObjectBundle,
    *,
    shading_radius: float = 1.0,
    seed: int = DEFAULT_SEED,
    debug: bool = False,
    aovs: bool = False,
    fitted_light=None,
) -> PreparedJob:
    """Steps 1-4 of one job. Raises ZcompError subclasses for per-job failures.
    ``fitted_light``: the scene's light as the light stage fitted it
    (``light.stage.FittedLight``), handed to the renderer with the requests."""
    timings: dict[str, float] = {}
    notes: list[str] = list(scene.notes)
    cam = scene.camera
    H, W = cam.height, cam.width
    if (bundle.camera.width, bundle.camera.height) != (W, H):
        raise GeometryError(
            f"object intrinsics are {bundle.camera.width}x{bundle.camera.height}, scene is {W}x{H}")
    if not np.allclose(bundle.camera.K, cam.K, rtol=1e-4, atol=1e-3):
        raise GeometryError("object intrinsics were rendered with another camera K than the scene's")
    bg = scene.maps
    obj_mask = np.clip(np.nan_to_num(bundle.mask), 0.0, 1.0)
    if not (obj_mask > 0).any():
        raise GeometryError("the object lies fully outside the frame")

    # 1. Depth alignment on the footprint.
    t = time.perf_counter()
    alignment = align_depth(bg.depth, bundle.footprint_depth)
    if alignment.fallback:
        notes.append(f"depth alignment: {alignment.fallback}")
    obj_depth = apply_alignment(bundle.depth, alignment)
    timings["align_s"] = time.perf_counter() - t

    # 2. Occlusion and intrinsic composite.
    t = time.perf_counter()
    m = occlusion_mask(obj_mask, obj_depth, bg.depth)
    if not (m > 0).any():
        raise GeometryError("the object is fully occluded by the background")
    size = _size_note(m, obj_depth, scene.name)
    if size:
        notes.append(size)
    obj_maps = SceneMaps(depth=obj_depth, normals=bundle.normals, albedo=np.clip(np.nan_to_num(bundle.albedo), 0, 1),
                         roughness=bundle.roughness, metallic=bundle.metallic)
    comp = composite_intrinsics(bg, obj_maps, m)
    timings["composite_intrinsics_s"] = time.perf_counter() - t

    # 3. Shading mask and region of interest.
    t = time.perf_counter()
    sm = shading_mask(bg.depth, obj_depth, m, cam, radius_scale=shading_radius)
    s = sm.mask
    roi = roi_around(s | (m > 0), BLUR_SIZE // 2 + ROI_CONTEXT_PX)
    timings["shading_mask_s"] = time.perf_counter() - t

    # 4. Background shading, known outside s (and where the albedo/depth are valid).
    t = time.perf_counter()
    shading = shading_from_image(scene.image, bg.albedo)
    known = ~s & valid_depth_mask(bg.depth)
    timings["shading_s"] = time.perf_counter() - t

    common = dict(shading=shading, known=known, camera=cam, roi=roi, image=scene.image, scene_key=scene.key,
                  light=getattr(scene, "light", None), fitted_light=fitted_light, debug=debug, aovs=aovs)
    # the object's occluder (its shadow, the sky it hides, its self-shadowing): the posed
    # mesh when the bundle references one; else, for a bundle of maps, its visible
    # surface extruded backwards to its footprint's far edge (``maps_occluder``); 2D image
    # objects keep the 2.5D depth alone
    occluder, occluder_kind = None, None
    try:
        from zcomp_cli.posed_mesh import load_posed_mesh

        occluder = load_posed_mesh(bundle.meta or {}, {"a": alignment.a, "b": alignment.b})
        occluder_kind = "mesh" if occluder is not None else None
    except Exception as exc:  # an unreadable mesh must not fail the job: the maps stand in
        notes.append(f"object mesh not used for shadows: {type(exc).__name__}: {exc}")
    if occluder is None and (bundle.meta or {}).get("source") != "image":
        try:
            from zcomp_cli.maps_occluder import occluder_from_maps

            occluder = occluder_from_maps(obj_depth, obj_mask, apply_alignment(bundle.footprint_depth, alignment),
                                          cam, normals=bundle.normals, up=(bundle.meta or {}).get("up_camera"))
            occluder_kind = "maps, extruded" if occluder is not None else None
        except Exception as exc:  # nor must maps that make no solid: 2.5D shadows
            occluder = None
            notes.append(f"object maps not used as an occluder: {type(exc).__name__}: {exc}")
    notes += lamps_inside_object(getattr(scene, "light", None), cam, obj_depth, obj_mask,
                                 apply_alignment(bundle.footprint_depth, alignment))
    requests = [RenderRequest(maps=bg, **common),
                RenderRequest(maps=comp, **common, occluder=occluder, coverage=m, object_maps=obj_maps)]
    x0, y0, x1, y1 = roi
    report = {
        "alignment": alignment.to_dict(),
        "object_pixels": int((m > 0).sum()),
        "object_coverage_frac": float((m > 0).mean()),
        "occluded_pixels": int(((obj_mask > 0) & (m == 0)).sum()),
        "shading_mask": {
            "pixels": int(s.sum()),
            "frac": float(s.mean()),
            "radius_m": sm.radius_m,
            "object_extent_m": sm.object_extent_m,
            "lambda": shading_radius,
        },
        "roi": {"box": list(roi), "frac": (x1 - x0) * (y1 - y0) / float(H * W)},
        "occluder": occluder_kind,
        "seed": seed,
        **({"light_stage": fitted_light.ledger()} if fitted_light is not None else {}),
    }
    dbg = {}
    if debug:
        dbg = {"shading_mask": s.astype(np.float32), "object_mask": m, "comp_depth": comp.depth,
               "comp_normals": comp.normals, "comp_albedo": comp.albedo, "shading": shading}
    return PreparedJob(requests, seed, scene, m, s, roi, report, timings, notes, dbg)


def _whose_bug(renderer_name: str) -> str:
    """Who to blame for a renderer's impossible output: a plugin's author, or, for one of
    zcomp's own renderers, an input it could not handle (and zcomp, to be told)."""
    from zcomp_cli.renderers.registry import BUILTIN_RENDERERS

    if renderer_name in BUILTIN_RENDERERS:
        return (f"zcomp's own {renderer_name} renderer met an input it cannot handle: check the scene's maps "
                "(depth, normals, albedo) against docs/limits.md, and please report it")
    return "a plugin's bug"


def finish_job(prep: PreparedJob, out: RenderOutput, renderer_name: str, renderer_settings: dict,
               *, debug: bool = False, aovs: bool = False) -> JobOutput:
    """Check the renderer's two images (step 5's output) and run step 6, the compositor."""
    H, W = prep.scene.camera.height, prep.scene.camera.width
    images = list(out.images) if isinstance(out.images, (list, tuple)) else None
    if images is None or len(images) != len(prep.requests):
        raise NumericalError(f"renderer {renderer_name} returned {type_name(out.images)} "
                             f"{'of ' + str(len(images)) + ' images ' if images is not None else ''}for "
                             f"{len(prep.requests)} requests (one image per request)")
    for name, im in zip(("f(i_bg)", "f(i_comp)"), images):
        kind = getattr(getattr(im, "dtype", None), "kind", None)
        if not isinstance(im, np.ndarray) or kind != "f":
            # an integer image is display-encoded (0..255), not linear radiance
            raise NumericalError(f"renderer {renderer_name} returned {name} as "
                                 f"{str(im.dtype) + ' array' if isinstance(im, np.ndarray) else type_name(im)}: "
                                 f"expected a float array of linear radiance ({_whose_bug(renderer_name)})")
    f_bg, f_comp = (np.asarray(im, dtype=np.float32) for im in images)
    for name, im in (("f(i_bg)", f_bg), ("f(i_comp)", f_comp)):
        if im.shape != (H, W, 3):
            raise NumericalError(f"renderer returned {name} of shape {im.shape}, expected {(H, W, 3)}")
        if not np.all(np.isfinite(im)):
            raise NumericalError(f"renderer {renderer_name} returned non-finite values in {name}")
        lo, hi = float(im.min()), float(im.max())
        if lo < -RADIANCE_TOL or hi > MAX_RADIANCE:
            raise NumericalError(f"renderer {renderer_name} returned {name} in [{lo:.3g}, {hi:.3g}]: linear "
                                 f"radiance is in [0, {MAX_RADIANCE:g}] ({_whose_bug(renderer_name)}; the job is "
                                 "not composited from it)")

    f_object = _object_layer(out, len(images) - 1, (H, W), renderer_name)
    # 6. Compositor.
    timings = dict(prep.timings)
    t = time.perf_counter()
    x0, y0, x1, y1 = prep.roi
    region = np.zeros((H, W), bool)
    region[y0:y1, x0:x1] = True
    s = prep.shading_mask
    if out.shading_mask is not None:
        grown = np.asarray(out.shading_mask, bool)
        if grown.shape != (H, W):
            raise NumericalError(f"renderer returned a shading mask of shape {grown.shape}, expected {(H, W)}")
        # the renderer re-shaded more (an object's long shadow): the ratio applies there too
        s = s | grown
    res = composite(prep.scene.image, f_bg, f_comp, s, prep.object_mask, balance_region=region & ~s,
                    f_object=f_object)
    if not np.all(np.isfinite(res.image)):
        raise NumericalError("the composite has non-finite values")
    timings["compositor_s"] = time.perf_counter() - t

    # back to the photograph's units (``Scene.working_scale``: a power of two, exact)
    k = np.float32(getattr(prep.scene, "working_scale", 1.0))
    x_bg, image = prep.scene.image, res.image
    if k != 1.0:
        x_bg, image, f_bg, f_comp = x_bg * k, image * k, f_bg * k, f_comp * k
        f_object = None if f_object is None else f_object * k
    if prep.scene.photo is not None:  # its negative pixels, in its own units: kept where nothing is edited
        x_bg = prep.scene.photo
        image = keep_untouched(image, x_bg, res.weight, prep.object_mask)
    report = {
        **prep.report,
        **({"working_scale": float(k)} if k != 1.0 else {}),
        **({"shading_mask_grown_px": int((s & ~prep.shading_mask).sum())} if out.shading_mask is not None else {}),
        "colour_balance": res.balance.tolist(),
        "renderer": {"settings": renderer_settings, "info": out.info, "timings": out.timings},
        "timings": timings,
        "notes": prep.notes + list(res.notes),
    }
    dbg, rdbg = {}, {}
    if debug:
        dbg = {**prep.debug_maps, "shading_mask": s.astype(np.float32), "f_bg": f_bg, "f_comp": f_comp, "ratio": res.ratio,
               "ratio_blurred": res.ratio_blurred, "weight": res.weight}
        if k != 1.0 and "shading" in dbg:
            dbg["shading"] = dbg["shading"] * k
        rdbg = check_debug_maps(out.debug_maps, (H, W), renderer_name)
    layers = {}
    if aovs:
        from zcomp_cli.compositing.aovs import aov_layers

        layers = aov_layers(x_bg, f_bg, f_comp, res.ratio_blurred, prep.object_mask, res.balance, image, f_object)
        layers.update(check_aov_layers(out.aov_layers, (H, W), renderer_name, set(layers)))
    return JobOutput(image, report, dbg, layers, rdbg)


def _object_layer(out: RenderOutput, k: int, shape: tuple[int, int], renderer_name: str):
    """The renderer's object layer of image ``k`` (``RenderOutput.object_layers``), checked
    as its images are (float, (H, W, 3), finite, in radiance's range), or None."""
    layers = list(getattr(out, "object_layers", None) or [])
    lay = layers[k] if k < len(layers) else None
    if lay is None:
        return None
    a = np.asarray(lay)
    if a.dtype.kind != "f" or a.shape != (*shape, 3) or not np.all(np.isfinite(a)) or (
            a.size and (float(a.min()) < -RADIANCE_TOL or float(a.max()) > MAX_RADIANCE)):
        raise NumericalError(f"renderer {renderer_name} returned an object layer of {a.dtype} {a.shape}: expected "
                             f"finite float linear radiance of shape {(*shape, 3)}")
    return a.astype(np.float32)


def check_aov_layers(layers, shape: tuple[int, int], renderer_name: str, taken: set) -> dict[str, np.ndarray]:
    """A renderer's own render passes (``RenderOutput.aov_layers``) checked for
    ``aovs.exr``: each name lower-case letters, digits and ``_`` and none of ``taken``
    (the pipeline's layers), each (H, W) or (H, W, C) with C 1, 3 or 4 at ``shape``, finite.
    Returns them as float32 (H, W, C). Raises ``RenderError`` naming the layer."""
    import re

    out = {}
    for name, a in (layers or {}).items():
        if not isinstance(name, str) or not re.fullmatch(r"[a-z0-9_]{1,64}", name) or name in taken:
            raise RenderError(f"renderer {renderer_name} returned an AOV layer named {name!r}: a layer is lower-case "
                              f"letters, digits and '_', none of {', '.join(sorted(taken))}")
        arr = np.asarray(a, np.float32)
        if arr.ndim == 2:
            arr = arr[..., None]
        if arr.ndim != 3 or arr.shape[:2] != tuple(shape) or arr.shape[2] not in (1, 3, 4):
            raise RenderError(f"renderer {renderer_name} returned AOV layer {name!r} of shape {np.shape(a)}, "
                              f"expected {tuple(shape)} with 1, 3 or 4 channels")
        if not np.all(np.isfinite(arr)):
            raise RenderError(f"renderer {renderer_name} returned non-finite values in AOV layer {name!r}")
        out[name] = np.ascontiguousarray(arr)
    return out


def check_debug_maps(maps, shape: tuple[int, int], renderer_name: str) -> dict[str, np.ndarray]:
    """A renderer's debug maps (``RenderOutput.debug_maps``) checked for writing: each
    name a file name's stem (``outputs.DEBUG_MAP_NAME``: lower-case letters, digits, ``_``,
    ``-``; no path, no extension) that is none of the pipeline's own maps, each map (H, W) or (H, W, C)
    with C 1, 3 or 4 at the job's ``shape`` (H, W). Returns them as float32 (NaN kept:
    a map may mark where it holds no value). Raises ``RenderError`` naming the map."""
    from zcomp_cli.pipeline.outputs import DEBUG_MAP_NAME, DEBUG_MAPS

    if maps is None:
        return {}
    if not isinstance(maps, Mapping):
        raise RenderError(f"renderer {renderer_name} returned debug maps as {type(maps).__name__}, "
                          "expected a mapping of names to arrays")
    H, W = shape
    out: dict[str, np.ndarray] = {}
    for name, a in maps.items():
        if not isinstance(name, str) or not DEBUG_MAP_NAME.fullmatch(name):
            raise RenderError(f"renderer {renderer_name} returned a debug map named {name!r}: a name is 1-64 "
                              "lower-case letters, digits, '_' and '-', starting with a letter or digit (no "
                              "path, no extension)")
        if name in DEBUG_MAPS:
            raise RenderError(f"renderer {renderer_name} returned a debug map named {name!r}, the name of one "
                              "of the pipeline's own debug maps")
        try:
            arr = np.asarray(a, dtype=np.float32)
        except (TypeError, ValueError) as exc:
            raise RenderError(f"renderer {renderer_name} returned debug map {name!r} that is not a numeric "
                              f"array ({exc})") from exc
        if not (arr.shape == (H, W) or (arr.ndim == 3 and arr.shape[:2] == (H, W) and arr.shape[2] in (1, 3, 4))):
            raise RenderError(f"renderer {renderer_name} returned debug map {name!r} of shape {arr.shape}, "
                              f"expected ({H}, {W}) or ({H}, {W}, C) with C 1, 3 or 4 (the job's working "
                              "resolution)")
        out[name] = arr
    return out


def run_job(
    scene: Scene,
    bundle: ObjectBundle,
    renderer: Renderer,
    *,
    shading_radius: float = 1.0,
    seed: int = DEFAULT_SEED,
    debug: bool = False,
    aovs: bool = False,
) -> JobOutput:
    """Composite one object bundle into one scene (steps 1-6). Raises ZcompError
    subclasses for per-job failures (the batch records them and goes on)."""
    prep = prepare_job(scene, bundle, shading_radius=shading_radius, seed=seed, debug=debug, aovs=aovs)
    # 5. Renderer: background and composite in one call, same mask, same seed.
    t = time.perf_counter()
    out = renderer.render(prep.requests, seed=seed)
    prep.timings["render_s"] = time.perf_counter() - t
    return finish_job(prep, out, renderer.name, renderer.settings(), debug=debug, aovs=aovs)
