"""Executors run the job stage of a batch (``pipeline.batch`` stage 4).

:class:`Executor` is the interface ``run_batch`` uses: ``preflight()`` before anything
is written (refuse what cannot work: Ray not installed, no cluster), ``check(ctx,
n_jobs)`` once the output folder exists and the plan is made (Ray: every node sees it;
the workers start), ``run(ctx, works)`` the job
stage, ``renders_objects`` (True: the executor renders the object intrinsics itself,
stage 3 is left to it) and ``info`` (figures for the summary).

The local executor takes the jobs in chunks of ``ctx.batch_size``: each job of a chunk is
prepared (steps 1-4 of ``pipeline.job``), the chunk's passes go to the renderer in ONE
``Renderer.render_jobs`` call (a GPU renderer batches them), then each job is finished
(the compositor) and its outputs written. A job that fails in any step is reported and
the others go on; if a chunk's shared renderer call fails, its jobs are rendered one by
one so that the failure stays with the job that caused it. A job holds its lock
(``outguard.job_lock``) from its preparation until its outputs are written; its scene
is freed after the scene's last job (``stages.SceneStore``).

A renderer that works on another device (``overlap_prepare = True``, the zerocomp GPU
renderer) gets the next chunk prepared on a CPU thread while the current chunk renders.
"""

from __future__ import annotations

import logging
import time
from abc import ABC, abstractmethod

from zcomp_cli.errors import ZcompError, log_traceback
from zcomp_cli.limits import field_text
from zcomp_cli.pipeline.outguard import job_lock, release_job_lock
from zcomp_cli.pipeline.outputs import JobStatus, job_report, write_job_outputs
from zcomp_cli.pipeline.stages import BatchContext, JobWork, load_object_bundle

log = logging.getLogger(__name__)


class Executor(ABC):
    """Runs the job stage of a batch (see the module docstring)."""

    name: str = "executor"
    renders_objects: bool = False

    def __init__(self):
        self.info: dict = {"name": self.name}

    def preflight(self) -> None:
        """Before anything is written: raise UsageError for what cannot work."""

    def check(self, ctx: BatchContext, n_jobs: int = 0) -> None:
        """Once ``ctx.out_root`` exists and the plan is made (``n_jobs`` will run),
        before any job runs: e.g. Ray's shared-folder probe, and its workers' start."""

    @abstractmethod
    def run(self, ctx: BatchContext, works: list[JobWork]) -> list[JobStatus]:
        """Run every work item (each with ``error`` None, or reported failed with it)
        and return one status per item."""


# What a job's step may raise and the job (not the batch) then fails with: every error,
# and SystemExit -- a renderer plugin calling sys.exit() in render() ended the batch
# with its jobs pending and exit 0. KeyboardInterrupt still interrupts.
JOB_FAILURES = (Exception, SystemExit)


def _failure(exc: BaseException) -> str:
    return field_text(_failure_text(exc))


def _failure_text(exc: BaseException) -> str:
    if isinstance(exc, ZcompError):
        return str(exc)
    if isinstance(exc, SystemExit):
        return f"the renderer called sys.exit({exc.code!r}) (a plugin's bug: zcomp went on with the other jobs)"
    # A bug must not lose the rest of the batch; -v shows the traceback.
    log_traceback("job crashed", exc)
    return f"internal error: {type(exc).__name__}: {exc}"


def _failed(ctx, w, exc: BaseException, started: float) -> JobStatus:
    """The status of job ``w`` that failed with ``exc``, timed from ``started``."""
    return JobStatus(w.job, "failed", _failure(exc), time.perf_counter() - started, ctx.out_root / w.job.name)


class LocalExecutor(Executor):
    """Runs every job in this process, ``ctx.batch_size`` jobs per renderer call."""

    name = "local"

    def run(self, ctx: BatchContext, works: list[JobWork]) -> list[JobStatus]:
        statuses: list[JobStatus] = []
        total = len(works)
        done = 0
        todo = []
        for w in works:
            if w.error is not None:
                statuses.append(JobStatus(w.job, "failed", w.error, 0.0, ctx.out_root / w.job.name))
                done += 1
            else:
                todo.append(w)
        ctx.scenes.expect(w.job.scene for w in todo)
        chunks = [todo[i:i + ctx.batch_size] for i in range(0, len(todo), ctx.batch_size)]
        if getattr(ctx.renderer, "overlap_prepare", False) and len(chunks) > 1:
            from concurrent.futures import ThreadPoolExecutor

            # the prepare thread alone loads scenes and bundles; this thread renders,
            # finishes, writes and reports
            with ThreadPoolExecutor(max_workers=1) as pool:
                nxt = pool.submit(prepare_chunk, ctx, chunks[0])
                for k, chunk in enumerate(chunks):
                    ctx.report("jobs", done, total, chunk[0].job.name)
                    prep = nxt.result()
                    if k + 1 < len(chunks):
                        nxt = pool.submit(prepare_chunk, ctx, chunks[k + 1])
                    statuses.extend(render_and_finish(ctx, chunk, *prep))
                    done += len(chunk)
        else:
            for chunk in chunks:
                ctx.report("jobs", done, total, chunk[0].job.name)
                statuses.extend(run_chunk(ctx, chunk))
                done += len(chunk)
        ctx.report("jobs", total, total, "")
        return statuses


def run_chunk(ctx: BatchContext, chunk: list[JobWork]) -> list[JobStatus]:
    """Prepare, render (one call), finish and write a chunk of jobs."""
    return render_and_finish(ctx, chunk, *prepare_chunk(ctx, chunk))


def prepare_chunk(ctx: BatchContext, chunk: list[JobWork]):
    """Steps 1-4 of every job of the chunk -> (prepared, statuses, started, locks)."""
    from zcomp_cli.light.ledger import light_entries
    from zcomp_cli.pipeline.job import prepare_job

    statuses: dict[int, JobStatus] = {}
    started: dict[int, float] = {}
    locks: dict[int, object] = {}
    prepared = []  # (work, scene, PreparedJob)
    for w in chunk:
        t0 = started[w.job.index] = time.perf_counter()
        try:
            locks[w.job.index] = job_lock(ctx.out_root, w.job.name)
            loads = ctx.scenes.loads
            scene = ctx.scenes.get(w.job.scene)
            t_load = time.perf_counter() - t0
            w.facts["scene_loaded"] = ctx.scenes.loads > loads
            t1 = time.perf_counter()
            fitted = ctx.lights.get(scene, w.job.seed) if ctx.lights is not None else None
            t_light = time.perf_counter() - t1
            t2 = time.perf_counter()
            bundle = load_object_bundle(ctx, w, scene)
            t_object = time.perf_counter() - t2
            w.facts["glossy"] = bundle.roughness is not None
            # (the light's ledger entries, not the fitted light: a batch keeps its works)
            w.facts["light"] = None if fitted is None else light_entries(fitted, getattr(scene, "light", None), t_light)
            prep = prepare_job(scene, bundle, shading_radius=w.job.shading_radius, seed=w.job.seed,
                               debug=ctx.debug, aovs=ctx.aovs, fitted_light=fitted)
            prep.timings = {"scene_load_s": t_load, "object_load_s": t_object,
                            **({"light_s": t_light} if fitted is not None else {}), **prep.timings}
            prepared.append((w, scene, prep))
        except Exception as exc:  # noqa: BLE001 - reported per job
            statuses[w.job.index] = _failed(ctx, w, exc, t0)
    return prepared, statuses, started, locks


def render_and_finish(ctx: BatchContext, chunk, prepared, statuses, started, locks) -> list[JobStatus]:
    """Step 5 (one renderer call for the chunk) and step 6 (compositor, outputs); then
    the chunk's job locks are released and its scenes counted down."""
    try:
        _render_and_finish(ctx, prepared, statuses, started)
    finally:
        prepared.clear()  # the chunk's maps go before its scenes are counted down
        for w in chunk:
            release_job_lock(locks.pop(w.job.index, None))
            ctx.scenes.job_done(w.job.scene)
    return [statuses[w.job.index] for w in chunk]


def _render_and_finish(ctx: BatchContext, prepared, statuses, started) -> None:
    from zcomp_cli.pipeline.job import finish_job
    from zcomp_cli.pipeline.ledger import job_ledger

    renderer = ctx.renderer

    # 5. One renderer call for the chunk; on failure, one call per job.
    outputs: dict[int, object] = {}
    if prepared:
        t = time.perf_counter()
        try:
            outs = renderer.render_jobs([p.requests for _, _, p in prepared], [p.seed for _, _, p in prepared])
            share = (time.perf_counter() - t) / len(prepared)
            for (w, _, p), out in zip(prepared, outs):
                p.timings["render_s"] = share
                outputs[w.job.index] = out
        except JOB_FAILURES as exc:  # noqa: BLE001
            if len(prepared) == 1:  # nothing to isolate: the one job failed
                w = prepared[0][0]
                statuses[w.job.index] = _failed(ctx, w, exc, started[w.job.index])
            else:
                for w, _, p in prepared:
                    t1 = time.perf_counter()
                    try:
                        outputs[w.job.index] = renderer.render(p.requests, seed=p.seed)
                        p.timings["render_s"] = time.perf_counter() - t1
                    except JOB_FAILURES as exc1:  # noqa: BLE001
                        statuses[w.job.index] = _failed(ctx, w, exc1, started[w.job.index])

    # 6. Compositor and outputs, job by job.
    for w, scene, prep in prepared:
        if w.job.index not in outputs:
            continue
        out_dir = ctx.out_root / w.job.name
        try:
            result = finish_job(prep, outputs.pop(w.job.index), renderer.name, renderer.settings(), debug=ctx.debug,
                                aovs=ctx.aovs)
            report = job_report(ctx.manifest, w.job, w.fingerprint, scene, w.pose, w.bundle_dir, result,
                                renderer_spec=ctx.renderer_spec)
            report["stages"] = job_ledger(report, scene=scene, loaded=w.facts.get("scene_loaded", True),
                                          object_kind=ctx.manifest.objects[w.job.object].kind,
                                          rendered=w.facts.get("object"), light=w.facts.get("light"),
                                          glossy=w.facts.get("glossy", False))
            write_job_outputs(out_dir, scene, result, report, debug=ctx.debug, aovs=ctx.aovs, started=started[w.job.index])
            statuses[w.job.index] = JobStatus(w.job, "done", None, time.perf_counter() - started[w.job.index],
                                              out_dir)
        except JOB_FAILURES as exc:  # noqa: BLE001
            statuses[w.job.index] = _failed(ctx, w, exc, started[w.job.index])
