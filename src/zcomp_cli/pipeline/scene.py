"""Load a scene once per batch: the photograph (linear), its camera, and its intrinsic
maps (provided files win; missing maps come from the estimators)."""

from __future__ import annotations

import hashlib
import logging
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from zcomp_cli.camera import Camera
from zcomp_cli.conventions import WORKING_LEVEL_RANGE, facing_problem, normalize, valid_depth_mask, working_scale
from zcomp_cli.errors import InputError
from zcomp_cli.pipeline.manifest import SceneSpec, scene_camera  # noqa: F401 (scene_camera re-exported)
from zcomp_cli.maps import SceneMaps

log = logging.getLogger(__name__)

ALBEDO_BLACK = 1e-3  # an albedo map whose maximum is below this is taken for a mistake


@dataclass
class Scene:
    name: str
    image: np.ndarray  # (H, W, 3) linear, finite, >= 0
    maps: SceneMaps
    camera: Camera
    key: str  # content hash of image + maps + camera + working size
    sources: dict = field(default_factory=dict)  # map -> "provided: path" | estimator
    notes: list = field(default_factory=list)
    timings: dict = field(default_factory=dict)
    light: dict | None = None  # known lighting from the manifest (pipeline/lightspec.py)
    # what the estimators measured: {"fits": {...}, "agreement": (H, W) degrees or None}
    estimated: dict | None = None
    # the photograph as read where it has negative pixels (an EXR's, graded or denoised):
    # kept bit for bit wherever the composite keeps the background; ``image`` (what the
    # renderers read) has them at 0. None when there are none (then it is ``image``).
    photo: np.ndarray | None = None
    # the power of two the photograph was divided by to be worked at
    # (``conventions.working_scale``): ``image`` is the photograph over it, and every job
    # output is multiplied back by it (1.0: the photograph as it is)
    working_scale: float = 1.0

    @property
    def background(self) -> np.ndarray:
        """The photograph the composite keeps outside the edited region, in its own units."""
        if self.photo is not None:
            return self.photo
        return self.image if self.working_scale == 1.0 else self.image * np.float32(self.working_scale)


def _hash_files(paths: list[Path], extra: str) -> str:
    h = hashlib.sha256(extra.encode())
    for p in paths:
        h.update(str(p).encode())
        with open(p, "rb") as f:
            for chunk in iter(lambda: f.read(1 << 20), b""):
                h.update(chunk)
    return h.hexdigest()[:16]


def _resize(arr: np.ndarray, size: tuple[int, int], kind: str) -> np.ndarray:
    import cv2

    W, H = size
    if arr.shape[1] == W and arr.shape[0] == H:
        return arr
    if kind == "image":
        interp = cv2.INTER_AREA if W < arr.shape[1] else cv2.INTER_LINEAR
    else:
        interp = cv2.INTER_NEAREST  # never blend depths or normals across edges
    out = cv2.resize(arr, (W, H), interpolation=interp)
    if arr.ndim == 3 and out.ndim == 2:
        out = out[..., None]
    return out


def sanitize_maps(image, depth, normals, albedo, where: str) -> tuple[np.ndarray, ...]:
    """Make provided data safe: non-finite image values -> 0 (noted), depth invalid -> 0,
    normals renormalised (invalid -> 0), albedo clipped to [0, 1]."""
    notes = []
    bad = ~np.isfinite(image)
    if bad.any():
        notes.append(f"{where}: {int(bad.any(-1).sum())} non-finite image pixels set to 0")
    image = np.clip(np.nan_to_num(image, nan=0.0, posinf=0.0, neginf=0.0), 0.0, None)
    dv = valid_depth_mask(depth)
    if (~dv).any():
        frac = float((~dv).mean())
        if frac > 0:
            notes.append(f"{where}: {frac:.1%} of depth pixels invalid (0, negative or non-finite)")
    depth = np.where(dv, depth, 0.0).astype(np.float32)
    normals = normalize(normals)
    normals = np.where(dv[..., None], normals, 0.0).astype(np.float32)
    nonfinite_alb = ~np.isfinite(albedo)
    if nonfinite_alb.any():
        notes.append(f"{where}: non-finite albedo values set to 0.5")
    albedo = np.clip(np.nan_to_num(albedo, nan=0.5, posinf=1.0, neginf=0.0), 0.0, 1.0).astype(np.float32)
    lit = dv & (image.max(axis=-1) > 1e-4)
    if lit.any() and float(albedo[lit].max()) < ALBEDO_BLACK:
        # shading = image / albedo then hits its clamp everywhere: the renderer sees a
        # scene lit hundreds of times too brightly, and the object is drawn that way.
        msg = (f"{where}: the albedo is ~0 everywhere (max {float(albedo[lit].max()):.2g}) where the image is "
               "lit: shading = image / albedo is meaningless and the object will be far too bright; "
               "check the albedo map (linear [0, 1]) or let zcomp estimate it")
        log.warning(msg)
        notes.append(msg)
    return image.astype(np.float32), depth, normals, albedo, notes


def load_scene(spec: SceneSpec, resolution: tuple[int, int] | None, *, cache_dir=None) -> Scene:
    """Read a scene's files, resample to the working ``resolution`` (W, H) if given, and
    fill missing maps from estimators."""
    import time

    from zcomp_cli.imageio import read_image, read_map

    t0 = time.perf_counter()
    where = f"scene {spec.name!r}"
    image = read_image(spec.image)
    h0, w0 = image.shape[:2]
    camera = scene_camera(spec, resolution, native=(w0, h0))
    size = resolution or (w0, h0)
    if size != (w0, h0):
        image = _resize(image, size, "image")
    W, H = size
    maps: dict[str, np.ndarray] = {}
    sources: dict[str, str] = {}
    for name, path in spec.maps.items():
        ch = 3 if name in ("normals", "albedo") else 1
        arr = read_map(path, channels=ch)
        if arr.shape[:2] != (h0, w0):
            raise InputError(f"{name} map is {arr.shape[1]}x{arr.shape[0]}, image is {w0}x{h0}", where=str(path))
        maps[name] = _resize(arr.astype(np.float32), size, name)
        sources[name] = f"provided: {path}"
    timings = {"read_s": time.perf_counter() - t0}

    missing = [m for m in ("depth", "normals", "albedo") if m not in maps]
    estimated = None
    if missing:
        t1 = time.perf_counter()
        maps, sources, estimated = _estimate_missing(spec, image, camera, maps, sources, cache_dir)
        timings["estimate_s"] = time.perf_counter() - t1

    photo = _negative_kept(image, where)
    image, depth, normals, albedo, notes = sanitize_maps(
        image, maps["depth"], maps["normals"], maps["albedo"], where
    )
    if photo is not None:
        notes.append(f"{where}: {int((photo < 0).any(-1).sum())} pixels of the photograph are negative: kept as "
                     "they are wherever the composite keeps the photograph, read as 0 by the renderer")
    if not valid_depth_mask(depth).any():
        raise InputError("the depth map has no valid pixel", where=where)
    if "normals" in spec.maps:  # (estimated normals face the camera by construction)
        problem = facing_problem(normals, camera.K, valid_depth_mask(depth))
        if problem:
            raise InputError(problem, where=str(spec.maps["normals"]))
    rough = maps.get("roughness")
    metal = maps.get("metallic")
    scene_maps = SceneMaps(
        depth=depth, normals=normals, albedo=albedo,
        roughness=None if rough is None else np.clip(np.nan_to_num(rough), 0, 1).astype(np.float32),
        metallic=None if metal is None else np.clip(np.nan_to_num(metal), 0, 1).astype(np.float32),
    )
    files = [spec.image] + [spec.maps[k] for k in sorted(spec.maps)]
    models = _model_fingerprints(spec.estimators)  # "" without model estimators: keys as before
    if sources.get("albedo") == "retinex":  # (the estimate's version: a changed estimate redoes the jobs)
        from zcomp_cli.estimators.albedo import RETINEX_VERSION

        models = ",".join(filter(None, [models, RETINEX_VERSION]))
    key = _hash_files(files, f"{size}|{camera.K.tolist()}|{sorted(spec.estimators.items())!r}"
                             + (f"|{models}" if models else ""))
    image, scale = _working_image(image, where, notes)
    return Scene(spec.name, image, scene_maps, camera, key + (f"@{scale:g}" if scale != 1.0 else ""), sources, notes,
                 timings, light=getattr(spec, "light", None), estimated=estimated, working_scale=scale,
                 photo=photo)


def _working_image(image: np.ndarray, where: str, notes: list) -> tuple[np.ndarray, float]:
    """(the photograph at its working level, the power of two it was divided by):
    ``conventions.working_scale``; 1.0 (the photograph as it is) where the division
    would not be exact (values that would fall below float32's normal range)."""
    scale = working_scale(image)
    if scale == 1.0:
        return image, 1.0
    s = np.float32(scale)
    worked = image / s
    if not np.array_equal(worked * s, image):
        notes.append(f"{where}: the photograph's level is far from 1 but cannot be rescaled exactly: worked as it is")
        return image, 1.0
    lo, hi = WORKING_LEVEL_RANGE
    notes.append(f"{where}: the photograph's median luminance is outside [{lo:g}, {hi:g}]: worked at "
                 f"2^{-round(math.log2(scale))} of its radiance (the shading's clamp and the shadow ratio's "
                 "epsilon are absolute), every output multiplied back")
    return worked.astype(np.float32), scale


def _negative_kept(image: np.ndarray, where: str) -> np.ndarray | None:
    """The photograph with its negative pixels (non-finite ones 0, as ``sanitize_maps``
    makes them), or None when no pixel is negative."""
    with np.errstate(invalid="ignore"):
        if not (image < 0).any():
            return None
    return np.nan_to_num(image, nan=0.0, posinf=0.0, neginf=0.0).astype(np.float32)


def _model_fingerprints(estimators: dict) -> str:
    """The weights behind each ``{model: DIR}`` estimator: new weights in the same folder
    change the scene's key (``--resume`` redoes its jobs)."""
    from zcomp_cli.estimators.weights import fingerprint

    out = []
    for name in sorted(estimators):
        model = estimators[name].get("model") if isinstance(estimators[name], dict) else None
        if isinstance(model, str) and Path(model).is_dir():
            out.append(f"{name}:{fingerprint(model)}")
    return ",".join(out)


def _estimate_missing(spec, image, camera, maps, sources, cache_dir):
    try:
        from zcomp_cli.estimators import estimate_scene_maps
    except ImportError as exc:  # pragma: no cover - estimators ship with zcomp
        raise InputError(
            f"maps {sorted(set(('depth', 'normals', 'albedo')) - set(maps))} are missing and the "
            f"estimators are unavailable ({exc})", where=f"scene {spec.name!r}") from exc
    est = estimate_scene_maps(
        image, camera,
        depth_spec=spec.estimators.get("depth"),
        normals_spec=spec.estimators.get("normals"),
        albedo_spec=spec.estimators.get("albedo"),
        provided=dict(maps),
        cache_dir=cache_dir,
    )
    out = dict(maps)
    notes = list(getattr(est, "notes", []) or [])
    if notes:
        sources["notes"] = "; ".join(notes)
    for name in ("depth", "normals", "albedo", "roughness", "metallic"):
        if name not in out and getattr(est, name, None) is not None:
            out[name] = getattr(est, name)
            sources[name] = est.sources.get(name, "estimated")
    return out, sources, {"fits": dict(est.fits), "agreement": est.agreement, "timings": dict(est.timings)}
