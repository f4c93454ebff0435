"""Run every job of a manifest, in numbered stages:

0. preflight, before anything is written: select the jobs (``--jobs``, ``--shard``),
   build the renderer (its settings checked, and its weights: ``Renderer.check``), the
   executor's own checks (``Executor.preflight``: Ray installed, cluster reachable);
1. plan: register the run in the output folder (``pipeline.outguard``: a second run of
   the same jobs is refused), clear what killed runs left behind, and decide from the
   folder which jobs run (``outputs.plan_outputs``);
2. poses: a job's pose, or its placement on the scene (``stages.resolve_poses``);
3. objects: every mesh job's intrinsics in ONE Blender batch (``stages.render_objects``);
4. jobs: an executor (``pipeline.executor``) runs the jobs, scene by scene, several per
   renderer call (``batch_size``), and writes each job's outputs; a failed job is
   recorded and the batch goes on;
5. the summary.

The stages share one :class:`~zcomp_cli.pipeline.stages.BatchContext`, built in step 0
and never changed; each job travels as a :class:`~zcomp_cli.pipeline.stages.JobWork`.
"""

from __future__ import annotations

import contextlib
import logging
import os
import time
from pathlib import Path

from zcomp_cli.errors import UsageError, WeightsError
from zcomp_cli.pipeline.executor import Executor, LocalExecutor
from zcomp_cli.pipeline.manifest import Manifest, RendererSpec
from zcomp_cli.pipeline.outputs import BatchSummary, JobStatus, plan_outputs, write_summary
from zcomp_cli.pipeline.selection import select_jobs, shard_jobs
from zcomp_cli.pipeline.stages import (LIGHTS_DIR, BatchContext, JobWork, Progress, SceneStore, by_scene,
                                       load_object_bundle, render_objects, resolve_poses)


log = logging.getLogger(__name__)

def build_renderer(spec: RendererSpec):
    """The renderer of ``spec``, checked before any job: an unknown name or setting is
    a UsageError, and so is a renderer that cannot work at all (``Renderer.check``:
    zerocomp without its weights)."""
    from zcomp_cli.renderers import get_renderer

    try:
        renderer = get_renderer(spec.name, **spec.settings)
    except TypeError as exc:  # a constructor with an explicit signature: an unknown setting
        raise UsageError(f"renderer {spec.name!r}: {exc}") from None
    try:
        renderer.check()
    except WeightsError as exc:
        raise UsageError(f"renderer {spec.name!r} cannot run: {exc}") from None
    return renderer


def check_renderer_budget(manifest: Manifest, scenes, renderer: str) -> None:
    """Refuse (``UsageError`` naming the scene) one of ``scenes`` whose working size a
    job of ``renderer`` cannot hold in the memory the pixel budget stands for
    (``RendererEntry.kb_per_pixel``: the cycles renderer costs about 3 times the
    physical renderer's 0.3 KB a pixel)."""
    from zcomp_cli.limits import renderer_budget_problem
    from zcomp_cli.renderers.registry import RENDERERS

    entry = RENDERERS.get(renderer)
    kb = float(getattr(entry, "kb_per_pixel", 0.3) or 0.3)
    for name in dict.fromkeys(scenes):
        sc = manifest.scenes[name]
        w, h = manifest.defaults.resolution or (sc.width, sc.height)
        problem = w and h and renderer_budget_problem(w, h, kb, renderer)
        if problem:
            raise UsageError(f"scene {name!r}: {problem}")


def run_batch(
    manifest: Manifest,
    out_root,
    *,
    renderer_spec: RendererSpec | None = None,
    jobs_subset: str | None = None,
    resume: bool = False,
    overwrite: bool = False,
    redo_changed: bool = False,
    debug: bool = False,
    aovs: bool = False,
    cache_dir=None,
    batch_size: int | None = None,
    shard: tuple[int, int] | None = None,
    executor: Executor | None = None,
    progress: Progress | None = None,
) -> BatchSummary:
    """Run the manifest's jobs. ``progress(stage, done, total, label)`` is called for
    the object-render stage ("objects") and the job stage ("jobs"). ``cache_dir`` is
    the cache root (``zcomp_cli.cache``); ``batch_size`` jobs share one renderer call
    (default: the renderer's own ``batch_size``, e.g. zerocomp's GPU batch, else 1).
    ``shard=(i, n)`` runs shard i of n of the selected jobs (``selection.shard_jobs``)
    and writes its own ``summary.shard-i-of-n.json``. ``executor`` runs stage 4
    (default: ``LocalExecutor``; see ``pipeline.ray_executor``). With ``resume``,
    finished jobs are skipped and ``redo_changed`` redoes those made from other
    inputs (else they are refused)."""
    from zcomp_cli.cache import cache_root
    from zcomp_cli.pipeline.outguard import (DigestCache, OutputLock, clean_dead_writers,
                                             clean_job_folder, sweep_dead_temporaries)

    t_batch = time.perf_counter()
    out_root = Path(out_root)

    # 0. Preflight: nothing is written before all that can be checked is.
    jobs = select_jobs(manifest.jobs, jobs_subset)
    shard_info = None
    if shard is not None:
        jobs = shard_jobs(jobs, *shard)
        shard_info = {"index": shard[0], "count": shard[1], "jobs": [j.name for j in jobs]}
    executor = executor if executor is not None else LocalExecutor()
    executor.preflight()
    spec = renderer_spec or manifest.defaults.renderer
    check_renderer_budget(manifest, (j.scene for j in jobs), spec.name)
    ctx = BatchContext.create(manifest, out_root, spec, build_renderer(spec), batch_size=batch_size,
                              debug=debug, aovs=aovs, cache_root=cache_dir, progress=progress)

    created = not out_root.exists()
    try:
        out_root.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UsageError(f"--out: cannot create {out_root}: {exc.strerror or exc}") from exc
    try:
        # 1. Plan, holding the run's registration until the batch ends.
        with OutputLock(out_root, manifest.path, _manifest_id(manifest), [j.name for j in jobs]):
            for j in jobs:  # ours now: what a killed run left in them can go
                clean_job_folder(out_root / j.name)
            clean_dead_writers(out_root / LIGHTS_DIR)  # shared by runs: only dead writers' litter
            sweep_dead_temporaries(cache_root(cache_dir))
            digests = DigestCache(_digest_store(cache_dir))
            to_run, skipped = plan_outputs(manifest, jobs, out_root, spec, ctx.samples, resume=resume,
                                           overwrite=overwrite, redo_changed=redo_changed, debug=debug, aovs=aovs,
                                           digests=digests)
            digests.save()
            if to_run:
                executor.check(ctx, len(to_run))
            summary = BatchSummary(statuses=list(skipped), shard=shard_info)
            running = {job.name for job, _ in to_run}
            if shard_info is None:  # (a shard's own summary tells `zcomp status` it finished)
                write_summary(out_root, summary, manifest, running=running)
            completed = False
            interrupted = None
            try:
                if to_run:
                    _run_planned(ctx, summary, to_run, executor)
                completed = True
            except KeyboardInterrupt as exc:
                interrupted = exc
                raise
            finally:  # also after an interrupt or a renderer that cannot start: the folder's true state
                _close(ctx.renderer)  # its Blender, its work folder and log: not left for exit
                summary.statuses.sort(key=lambda s: s.job.index)
                summary.seconds = time.perf_counter() - t_batch
                if completed or shard_info is None:
                    doc = write_summary(out_root, summary, manifest)
                    if interrupted is not None:  # the CLI says what is on disk
                        interrupted.zcomp_summary = doc
    except UsageError:
        if created:  # refused before any job: leave no empty --out behind
            with contextlib.suppress(OSError):
                os.rmdir(out_root)
        raise
    return summary


def _close(renderer) -> None:
    """End what a renderer holds (the cycles renderer's Blender process and work
    folder) at the end of the batch, not at the interpreter's exit: a process that runs
    batches one after another (a library caller, a test) kept them all. A plugin's
    ``close`` that fails does not hide the batch's own outcome."""
    close = getattr(renderer, "close", None)
    if callable(close):
        try:
            close()
        except Exception:  # noqa: BLE001 - a plugin's bug, logged
            log.warning("renderer %s: close() failed", getattr(renderer, "name", "?"), exc_info=True)


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


def _run_planned(ctx: BatchContext, summary: BatchSummary, to_run, executor: Executor) -> None:
    """Stages 2-4 for the planned jobs, scene by scene."""
    works = by_scene([JobWork(job, fp) for job, fp in to_run])

    # 2. Poses (placement needs the scene's depth and normals).
    resolve_poses(ctx, works)

    # 3. Object intrinsics (here, unless the executor's workers render their own).
    if not executor.renders_objects:
        t_obj = time.perf_counter()
        summary.blender = render_objects(ctx, works)
        summary.blender["objects_s"] = time.perf_counter() - t_obj

    # 4. Jobs.
    summary.statuses.extend(executor.run(ctx, works))
    summary.executor = {**executor.info, "scene_loads": ctx.scenes.loads}


__all__ = ["run_batch", "build_renderer", "BatchContext", "JobWork", "SceneStore", "JobStatus", "BatchSummary",
           "resolve_poses", "render_objects", "load_object_bundle"]
