"""What the stages of a batch share, and the per-job stages before the renderer.

* :class:`BatchContext`: what every stage of one batch shares, built once
  (:meth:`BatchContext.create`) when the renderer is known, and never changed after;
* :class:`SceneStore`: the batch's scenes, each loaded on first use and freed after
  its last job (memory stays flat in the number of scenes);
* :class:`LightStore`: the light stage (``light.stage.SceneLight``): each scene's light
  fitted once (per seed), shared by its jobs, kept in zcomp's cache for the other
  shards and workers, and written as ``OUT/lights/<scene>.yaml``;
* :class:`JobWork`: one job on its way through the stages;
* the stages themselves: :func:`resolve_poses` (stage 2), :func:`render_objects`
  (stage 3: every mesh job's object intrinsics in one Blender batch) and
  :func:`load_object_bundle` (a job's object maps, for the job stage).

``pipeline.batch`` orders the stages; ``pipeline.executor`` runs the job stage.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from zcomp_cli.errors import InputError, UsageError, ZcompError
from zcomp_cli.pipeline.manifest import JobSpec, Manifest, RendererSpec

Progress = Callable[[str, int, int, str], None]


class SceneStore:
    """Scenes of one batch, each loaded once while it is in use.

    ``expect(names)`` counts the jobs that will use each scene; ``job_done(name)``
    counts one down, and the scene is dropped after its last job (a later ``get``
    loads it again). A scene that fails to load fails every job that needs it with the
    same message, without retrying. Safe to use from the executor's prepare thread."""

    def __init__(self, manifest: Manifest, estimates_dir: Path | None):
        self.manifest = manifest
        self.estimates_dir = estimates_dir
        self._scenes: dict[str, object] = {}
        self._errors: dict[str, str] = {}
        self._uses: dict[str, int] = {}
        self._lock = threading.RLock()
        self.loads = 0  # scene loads (a scene needed again after it was freed counts twice)

    def get(self, name: str):
        from zcomp_cli.pipeline.scene import load_scene

        with self._lock:
            if name in self._scenes:
                return self._scenes[name]
            if name in self._errors:
                raise InputError(self._errors[name])
            try:
                sc = load_scene(self.manifest.scenes[name], self.manifest.defaults.resolution,
                                cache_dir=self.estimates_dir)
            except ZcompError as exc:
                self._errors[name] = f"scene {name!r}: {exc}"
                raise InputError(self._errors[name]) from exc
            self.loads += 1
            self._scenes[name] = sc
            return sc

    def expect(self, names) -> None:
        """The jobs to come will use these scenes (one name per job)."""
        with self._lock:
            for n in names:
                self._uses[n] = self._uses.get(n, 0) + 1

    def job_done(self, name: str) -> None:
        """A job of scene ``name`` ended (done or failed): its scene is freed after the
        last of the jobs ``expect`` announced (a scene never announced is kept: its
        owner frees it, as a Ray worker does between units)."""
        with self._lock:
            if name not in self._uses:
                return
            left = self._uses[name] - 1
            self._uses[name] = max(0, left)
            if left <= 0:
                self.release(name)

    def release(self, name: str) -> None:
        """Drop a loaded scene now (it is loaded again if needed)."""
        with self._lock:
            self._scenes.pop(name, None)

    def release_all_but(self, keep: str | None) -> None:
        with self._lock:
            for n in [n for n in self._scenes if n != keep]:
                del self._scenes[n]


class LightStore:
    """The batch's light stage: ``get(scene, seed)`` is the scene's fitted light
    (``light.stage.FittedLight``), fitted once per scene, tree, config and seed by the
    renderer's light config, kept in memory and under the cache's ``lights/`` folder, and
    written once a run in the manifest's ``light:`` syntax (``light.written``) at
    ``path_of(scene)`` (default ``OUT/lights/<scene>.yaml``). A fit that fails fails
    every job of that scene with its reason."""

    def __init__(self, cfg, cache_dir: Path | None, out_root: Path, path_of=None):
        from zcomp_cli.light.stage import SceneLight

        self.stage = SceneLight(cfg, cache_dir)
        self.path_of = path_of or (lambda name: Path(out_root) / LIGHTS_DIR / f"{name}.yaml")
        self._written: set = set()
        self._lock = threading.RLock()

    def get(self, scene, seed: int):
        from zcomp_cli.compositing import shading_from_image
        from zcomp_cli.light.stage import LightInputs

        with self._lock:
            scale = float(getattr(scene, "working_scale", 1.0))
            shading = shading_from_image(scene.image, scene.maps.albedo)
            inputs = LightInputs.of(scene.maps, shading, None, scene.camera, scene.key)
            fitted = self.stage.get(inputs, in_photo_units(getattr(scene, "light", None), 1.0 / scale), seed)
            if (scene.name, fitted.key) not in self._written:
                self._written.add((scene.name, fitted.key))
                self.write(scene.name, fitted, scale)
            return fitted

    def write(self, name: str, fitted, scale: float = 1.0) -> None:
        """The fitted light at ``path_of(name)`` (``light.written``), in the photograph's
        units (its values times the scene's ``working_scale``); skipped, with a
        warning, where its folder is not zcomp's to write into (a file, a link)."""
        import dataclasses
        import logging

        from zcomp_cli.light.written import write_light_yaml

        if scale != 1.0:
            fitted = dataclasses.replace(fitted, params=in_photo_units(fitted.params, scale, filled=True))
        path = self.path_of(name)
        folder = path.parent
        if folder.is_symlink() or (folder.exists() and not folder.is_dir()):
            logging.getLogger(__name__).warning("not writing %s: %s is not a folder zcomp made", path, folder)
            return
        try:
            write_light_yaml(path, fitted, name)
        except ZcompError as exc:
            logging.getLogger(__name__).warning("could not write %s: %s", path, exc)


# the folder of an output folder holding each scene's fitted light (``<scene>.yaml``)
LIGHTS_DIR = "lights"


def in_photo_units(params, k: float, *, filled: bool = False):
    """A light tree whose values in the photograph's units are multiplied by ``k`` -- the
    exposure (photograph units per physical unit) and the support's radiance -- where
    they are given (or, ``filled``, fitted): ``1 / working_scale`` takes a manifest's
    light to a scene's working units (``pipeline.scene.Scene.working_scale``),
    ``working_scale`` a fitted one back for writing (an exposure nothing fixed is then
    ``k``: the fitted strengths are in working units). None stays None; k = 1: as it is."""
    import dataclasses

    from zcomp_cli.scene.lightparams import Origin

    if params is None or k == 1.0:
        return params

    def times(p, default=None):
        if p.value is not None and (p.frozen or filled):
            import numpy as np

            return p.filled(np.asarray(p.value, np.float64) * k)
        return p.filled(default, Origin.FIT) if default is not None else p

    sky = dataclasses.replace(params.sky, ground=times(params.sky.ground))
    return dataclasses.replace(params, sky=sky, exposure=times(params.exposure, k if filled else None))


def light_config_of(spec: RendererSpec):
    """The light stage's config a renderer spec's renderer fits with (``LightConfig``;
    the default for one that draws no light, or cannot be built here)."""
    from zcomp_cli.light.config import LightConfig
    from zcomp_cli.renderers import get_renderer

    try:
        r = get_renderer(spec.name, **spec.settings)
    except ZcompError:
        return LightConfig()
    cfg = r.light_config() if getattr(r, "uses_light", False) else None
    close = getattr(r, "close", None)
    if callable(close):
        close()
    return cfg if cfg is not None else LightConfig()


@dataclass
class JobWork:
    """One job on its way through the stages: the plan sets ``fingerprint``, stage 2
    the ``pose``, stage 3 the ``bundle_dir``; any stage may set ``error`` (the job is
    then reported failed and skipped by the later stages)."""

    job: JobSpec
    fingerprint: str
    pose: object | None = None
    bundle_dir: Path | None = None
    error: str | None = None
    # what the job's ledger needs to know of the stages before it (``pipeline.ledger``):
    # ``object`` ({"cached", "seconds"} of its Blender passes), ``scene_loaded``, ``glossy``,
    # ``light`` (the light stage's entries, ``light.ledger.light_entries``)
    facts: dict = field(default_factory=dict)


def resolve_batch_size(requested: int | None, renderer) -> int:
    """Jobs per renderer call: ``requested``, else the renderer's own ``batch_size``
    (zerocomp's GPU batch), else 1."""
    value = requested if requested is not None else getattr(renderer, "batch_size", 1)
    try:
        n = int(value)
    except (TypeError, ValueError):
        raise UsageError(f"batch size must be an integer >= 1, got {value!r}") from None
    if n < 1:
        raise UsageError(f"batch size must be an integer >= 1, got {value!r}")
    return n


@dataclass(frozen=True)
class BatchContext:
    """What every stage of one batch shares; built once by :meth:`create`."""

    manifest: Manifest
    out_root: Path
    renderer_spec: RendererSpec
    renderer: object  # a renderers.base.Renderer, built before any stage runs
    scenes: SceneStore
    lights: LightStore | None = None  # the light stage, for a renderer that draws a light
    batch_size: int = 1
    debug: bool = False
    aovs: bool = False  # also write aovs.exr (compositing.aovs)
    cache_root: Path | None = None
    progress: Progress | None = None

    @classmethod
    def create(cls, manifest: Manifest, out_root, renderer_spec: RendererSpec, renderer, *,
               batch_size: int | None = None, debug: bool = False, aovs: bool = False, cache_root=None,
               progress: Progress | None = None) -> "BatchContext":
        from zcomp_cli.cache import cache_dir as cache_folder

        lights = (LightStore(renderer.light_config(), cache_folder("lights", cache_root), Path(out_root))
                  if getattr(renderer, "uses_light", False) else None)
        return cls(manifest, Path(out_root), renderer_spec, renderer,
                   SceneStore(manifest, cache_folder("estimates", cache_root)), lights=lights,
                   batch_size=resolve_batch_size(batch_size, renderer), debug=debug,
                   aovs=aovs, cache_root=cache_root, progress=progress)

    @property
    def samples(self) -> int:
        return self.manifest.defaults.samples

    def report(self, stage: str, done: int, total: int, label: str = "") -> None:
        if self.progress is not None:
            self.progress(stage, done, total, label)


def by_scene(works: list[JobWork]) -> list[JobWork]:
    """The works with each scene's jobs together (scenes in order of first use, jobs in
    manifest order within a scene): a scene is then in memory for one stretch only."""
    first: dict[str, int] = {}
    for k, w in enumerate(works):
        first.setdefault(w.job.scene, k)
    return sorted(works, key=lambda w: (first[w.job.scene], w.job.index))


def resolve_poses(ctx: BatchContext, works: list[JobWork]) -> None:
    """Stage 2: a ``pose`` is taken as given; a ``placement`` stands the object on the
    scene surface (image objects are placed later, from their own mask). ``works`` go
    scene by scene; each scene is freed after its placements (the job stage loads it
    again), so this stage holds one scene at a time."""
    from zcomp_cli.pipeline.placement import pose_from_placement

    current = None
    for w in works:
        try:
            if w.job.pose is not None:
                w.pose = w.job.pose
            elif ctx.manifest.objects[w.job.object].kind != "image":
                if current not in (None, w.job.scene):
                    ctx.scenes.release(current)
                current = w.job.scene
                sc = ctx.scenes.get(w.job.scene)
                w.pose = pose_from_placement(w.job.placement, sc.maps.depth, sc.maps.normals, sc.camera)
        except ZcompError as exc:
            w.error = str(exc)
    if current is not None:
        ctx.scenes.release(current)


def render_objects(ctx: BatchContext, works: list[JobWork], *, session=None) -> dict:
    """Stage 3: every mesh job's object intrinsics in one Blender batch (cached), in a
    kept ``runner.BlenderSession`` when one is given. Sets ``bundle_dir`` (or ``error``)
    on each mesh job; returns Blender's figures."""
    from zcomp_cli.blender.intrinsics import IntrinsicsRequest, render_object_intrinsics
    from zcomp_cli.pipeline.scene import scene_camera

    requests, owners = [], []
    for w in works:
        obj = ctx.manifest.objects[w.job.object]
        if w.error is not None or obj.kind != "mesh":
            continue
        try:
            camera = scene_camera(ctx.manifest.scenes[w.job.scene], ctx.manifest.defaults.resolution)
        except ZcompError as exc:
            w.error = str(exc)
            continue
        requests.append(IntrinsicsRequest(id=f"job{w.job.index}", mesh=obj.mesh, pose=w.pose,
                                          camera=camera, out_dir=None))
        owners.append(w)
    info: dict = {"requests": len(requests)}
    if not requests:
        return info

    def _cb(done, total, ident):
        ctx.report("objects", done, total, str(ident))

    results = render_object_intrinsics(requests, cache_dir=ctx.cache_root, samples=ctx.samples, progress=_cb,
                                       session=session)
    for w, res in zip(owners, results):
        w.facts["object"] = {"cached": bool(getattr(res, "cached", False)), "seconds": float(getattr(res, "seconds", 0))}
        if res.ok:
            w.bundle_dir = res.bundle_dir
        else:
            w.error = f"object {w.job.object!r}: {res.error}"
    info["cached"] = sum(1 for r in results if getattr(r, "cached", False))
    info["render_s"] = [round(float(getattr(r, "seconds", 0.0)), 3) for r in results]
    return info


def load_object_bundle(ctx: BatchContext, w: JobWork, scene):
    """The job's object intrinsics: a rendered or given bundle, or a 2D object (image +
    mask) stood on the support surface at its placement."""
    from zcomp_cli.bundle import ObjectBundle

    obj = ctx.manifest.objects[w.job.object]
    if obj.kind == "mesh":
        b = ObjectBundle.load(w.bundle_dir)
        # the job's own mesh file: a cached bundle names the file it was first rendered
        # from, maybe another checkout's since moved or deleted, whose content the cache's
        # key shares with this one (without it the object's shadow fell back to its maps)
        b.meta["mesh"] = str(Path(obj.mesh).resolve())
        return b
    if obj.kind == "bundle":  # a given bundle: its normals may be in another frame
        from zcomp_cli.conventions import facing_problem, valid_depth_mask

        b = ObjectBundle.load(obj.bundle)
        problem = facing_problem(b.normals, b.camera.K, (b.mask > 0.5) & valid_depth_mask(b.depth))
        if problem:
            raise InputError(f"the bundle's {problem}", where=str(Path(obj.bundle) / "normals.exr"))
        return b
    from zcomp_cli.estimators.object2d import object_bundle_from_image
    from zcomp_cli.imageio import read_alpha_or_grey, read_image

    job = w.job
    # (the manifest refuses an image object without placement.height; kept for callers
    # that build specs by hand)
    if job.placement is None or job.placement.height is None:
        raise InputError(f"image object {job.object!r} needs 'placement' with 'height' (metres)")
    img = read_image(obj.image)
    mask = read_alpha_or_grey(obj.mask)
    if img.shape[:2] != mask.shape:
        raise InputError(f"mask is {mask.shape[1]}x{mask.shape[0]}, image is {img.shape[1]}x{img.shape[0]}",
                         where=str(obj.mask))
    return object_bundle_from_image(
        img, mask, scene.camera, job.placement.pixel, job.placement.height,
        scene.maps.depth, scene.maps.normals)
