"""Run every job of a manifest, in numbered stages:

1. plan: select the jobs (``--jobs``), lock them in the output folder
   (``pipeline.outguard``: a second run of the same jobs is refused), clear what killed
   runs left behind, and decide from the folder which jobs run;
2. poses: a job's pose, or its placement on the scene (scenes load once, lazily);
3. objects: every mesh job's intrinsics in ONE Blender batch (cached);
4. jobs: an executor runs the jobs, several per renderer call (``batch_size``), and
   writes each job's outputs (``pipeline.outputs``); a failed job is recorded and the
   batch goes on;
5. the summary.

A :class:`BatchContext` carries what every stage shares; each job travels as a
:class:`JobWork` that the stages fill in.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from zcomp_cli.errors import InputError, UsageError, ZcompError
from zcomp_cli.pipeline.manifest import JobSpec, Manifest, RendererSpec
from zcomp_cli.pipeline.outputs import BatchSummary, JobStatus, plan_outputs, write_summary
from zcomp_cli.pipeline.selection import select_jobs, shard_jobs

Progress = Callable[[str, int, int, str], None]


class SceneStore:
    """Scenes of one batch, each loaded once on first use; a scene that fails to load
    fails every job that needs it with the same message, without retrying."""

    def __init__(self, manifest: Manifest, estimates_dir: Path | None):
        self.manifest = manifest
        self.estimates_dir = estimates_dir
        self._scenes: dict[str, object] = {}
        self._errors: dict[str, str] = {}

    def get(self, name: str):
        from zcomp_cli.pipeline.scene import load_scene

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
        self._scenes[name] = sc
        return sc


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


@dataclass
class BatchContext:
    """What every stage of one batch shares."""

    manifest: Manifest
    out_root: Path
    renderer_spec: RendererSpec
    scenes: SceneStore
    debug: bool = False
    cache_root: Path | None = None
    batch_size: int = 1
    progress: Progress | None = None
    renderer: object | None = None  # built once, before the job stage
    blender_session: object | None = None  # a kept Blender process (Ray workers), else one per batch

    @property
    def samples(self) -> int:
        return self.manifest.defaults.samples

    def report(self, stage: str, done: int, total: int, label: str = "") -> None:
        if self.progress is not None:
            self.progress(stage, done, total, label)


def run_batch(
    manifest: Manifest,
    out_root,
    *,
    renderer_spec: RendererSpec | None = None,
    jobs_subset: str | None = None,
    resume: bool = False,
    overwrite: bool = False,
    debug: bool = False,
    cache_dir=None,
    batch_size: int | None = None,
    shard: tuple[int, int] | None = None,
    executor=None,
    progress: Progress | None = None,
) -> BatchSummary:
    """Run the manifest's jobs. ``progress(stage, done, total, label)`` is called for
    the object-render stage ("objects") and the job stage ("jobs"). ``cache_dir`` is
    the cache root (``zcomp_cli.cache``); ``batch_size`` jobs share one renderer call
    (default: the renderer's own ``batch_size``, e.g. zerocomp's GPU batch, else 1).
    ``shard=(i, n)`` runs shard i of n of the selected jobs (``selection.shard_jobs``)
    and writes its own ``summary.shard-i-of-n.json``. ``executor`` runs stage 4
    (default: ``LocalExecutor``; see ``pipeline.ray_executor``)."""
    from zcomp_cli.cache import cache_dir as cache_folder
    from zcomp_cli.cache import cache_root
    from zcomp_cli.pipeline.executor import LocalExecutor
    from zcomp_cli.pipeline.outguard import (DigestCache, OutputLock, clean_job_folder,
                                             sweep_dead_temporaries)

    t_batch = time.perf_counter()
    out_root = Path(out_root)
    try:
        out_root.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UsageError(f"--out: cannot create {out_root}: {exc.strerror or exc}") from exc
    ctx = BatchContext(manifest, out_root, renderer_spec or manifest.defaults.renderer,
                       SceneStore(manifest, cache_folder("estimates", cache_dir)), debug=debug,
                       cache_root=cache_dir, batch_size=max(1, int(batch_size or 1)), progress=progress)

    # 1. Plan, holding the selected jobs' locks until the batch ends.
    jobs = select_jobs(manifest.jobs, jobs_subset)
    shard_info = None
    if shard is not None:
        jobs = shard_jobs(jobs, *shard)
        shard_info = {"index": shard[0], "count": shard[1], "jobs": [j.name for j in jobs]}
    executor = executor if executor is not None else LocalExecutor()
    # Locks are per job: shards of one manifest, holding disjoint jobs, share --out.
    with OutputLock(out_root, manifest.path, _manifest_id(manifest), [j.name for j in jobs]):
        for j in jobs:  # ours now: what a killed run left in them can go
            clean_job_folder(out_root / j.name)
        sweep_dead_temporaries(cache_root(cache_dir))
        digests = DigestCache(_digest_store(cache_dir))
        to_run, skipped = plan_outputs(manifest, jobs, out_root, ctx.renderer_spec, ctx.samples,
                                       resume=resume, overwrite=overwrite, digests=digests)
        digests.save()
        summary = BatchSummary(statuses=list(skipped), shard=shard_info)
        running = {job.name for job, _ in to_run}
        if shard_info is None:  # (a shard's own summary tells `zcomp status` it finished)
            write_summary(out_root, summary, manifest, running=running)
        completed = False
        try:
            if to_run:
                _run_planned(ctx, summary, to_run, batch_size, executor)
            completed = True
        finally:  # also after Ctrl-C or a renderer that cannot start: the folder's true state
            summary.statuses.sort(key=lambda s: s.job.index)
            summary.seconds = time.perf_counter() - t_batch
            if completed or shard_info is None:
                write_summary(out_root, summary, manifest)
    return summary


def _manifest_id(manifest: Manifest) -> str:
    """Identifies a manifest for the output lock: runs (shards) of the same manifest may
    share a folder, runs of different ones may not."""
    import hashlib

    try:
        return hashlib.sha256(manifest.path.read_bytes()).hexdigest()[:16]
    except OSError:
        return str(manifest.path)


def _digest_store(cache_dir) -> Path | None:
    from zcomp_cli.cache import cache_root

    return cache_root(cache_dir) / "file-hashes.json"


def _run_planned(ctx: BatchContext, summary: BatchSummary, to_run, batch_size: int | None, executor) -> None:
    """Stages 2-4 for the planned jobs (``batch_size`` None: the renderer's own)."""
    from zcomp_cli.renderers import get_renderer

    executor.check(ctx)
    ctx.renderer = get_renderer(ctx.renderer_spec.name, **ctx.renderer_spec.settings)
    if batch_size is None:
        ctx.batch_size = max(1, int(getattr(ctx.renderer, "batch_size", 1)))
    works = [JobWork(job, fp) for job, fp in to_run]

    # 2. Poses (placement needs the scene's depth and normals).
    resolve_poses(ctx, works)

    # 3. Object intrinsics (here, unless the executor's workers render their own).
    if not executor.renders_objects:
        t_obj = time.perf_counter()
        summary.blender = render_objects(ctx, works)
        summary.blender["objects_s"] = time.perf_counter() - t_obj

    # 4. Jobs.
    summary.statuses.extend(executor.run(ctx, works))
    summary.executor = getattr(executor, "info", {})


def resolve_poses(ctx: BatchContext, works: list[JobWork]) -> None:
    """Stage 2: a ``pose`` is taken as given; a ``placement`` stands the object on the
    scene surface (image objects are placed later, from their own mask)."""
    from zcomp_cli.pipeline.placement import pose_from_placement

    for w in works:
        try:
            if w.job.pose is not None:
                w.pose = w.job.pose
            elif ctx.manifest.objects[w.job.object].kind != "image":
                sc = ctx.scenes.get(w.job.scene)
                w.pose = pose_from_placement(w.job.placement, sc.maps.depth, sc.maps.normals, sc.camera)
        except ZcompError as exc:
            w.error = str(exc)


def render_objects(ctx: BatchContext, works: list[JobWork]) -> dict:
    """Stage 3: every mesh job's object intrinsics in one Blender batch (cached).
    Sets ``bundle_dir`` (or ``error``) on each mesh job; returns Blender's figures."""
    from zcomp_cli.blender.intrinsics import IntrinsicsRequest, render_object_intrinsics

    requests, owners = [], []
    for w in works:
        obj = ctx.manifest.objects[w.job.object]
        if w.error is not None or obj.kind != "mesh":
            continue
        try:
            sc = ctx.scenes.get(w.job.scene)
        except ZcompError as exc:
            w.error = str(exc)
            continue
        requests.append(IntrinsicsRequest(id=f"job{w.job.index}", mesh=obj.mesh, pose=w.pose,
                                          camera=sc.camera, out_dir=None))
        owners.append(w)
    info: dict = {"requests": len(requests)}
    if not requests:
        return info

    def _cb(done, total, ident):
        ctx.report("objects", done, total, str(ident))

    results = render_object_intrinsics(requests, cache_dir=ctx.cache_root, samples=ctx.samples, progress=_cb,
                                       session=ctx.blender_session)
    for w, res in zip(owners, results):
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
        return ObjectBundle.load(w.bundle_dir)
    if obj.kind == "bundle":
        return ObjectBundle.load(obj.bundle)
    from zcomp_cli.estimators.object2d import object_bundle_from_image
    from zcomp_cli.imageio import read_alpha_or_grey, read_image

    job = w.job
    if job.placement is None:
        raise InputError(f"image object {job.object!r} needs a 'placement' (pixel, height), not a 'pose'")
    if job.placement.height is None:
        raise InputError(f"image object {job.object!r} needs 'placement.height' (metres): a photo has no scale")
    img = read_image(obj.image)
    mask = read_alpha_or_grey(obj.mask)
    if img.shape[:2] != mask.shape:
        raise InputError(f"mask is {mask.shape[1]}x{mask.shape[0]}, image is {img.shape[1]}x{img.shape[0]}",
                         where=str(obj.mask))
    return object_bundle_from_image(
        img, mask, scene.camera, job.placement.pixel, job.placement.height,
        scene.maps.depth, scene.maps.normals)


__all__ = ["run_batch", "BatchContext", "JobWork", "SceneStore", "JobStatus", "BatchSummary",
           "resolve_poses", "render_objects", "load_object_bundle"]
