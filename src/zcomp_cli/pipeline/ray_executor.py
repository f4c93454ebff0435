"""Run the job stage on a Ray cluster (``zcomp composite --executor ray``).

Ray is an optional dependency: ``pip install 'zcomp[ray]'``. What runs where:

* the driver (this process) plans the batch and resolves poses as a local run does;
* N workers are Ray actors, each holding ONE renderer (``physical`` asks Ray for a CPU,
  ``zerocomp`` for a GPU), the scenes it has loaded, and (once it meets a mesh) ONE
  Blender process (``runner.BlenderSession``) for all its units. Jobs travel in units:
  up to ``unit_size`` jobs of one scene. A worker renders its unit's object
  intrinsics, then runs the jobs exactly as the local executor does
  (``executor.run_chunk``), writing the outputs itself;
* scene affinity: a worker that becomes free takes the next unit of the scene it last
  worked on when there is one, so a scene is loaded (and estimated) by as few workers
  as possible;
* fault tolerance: a worker that dies (killed, out of memory, node lost) is restarted by
  Ray and its unit retried (``max_retries``). A job whose ``report.json`` says done with
  this run's fingerprint is not run again, so a retried unit only does what was left:
  every job ends done once. Outputs are atomic as in a local run (``outputs``).

``OUT`` (and ``--cache-dir``, when meshes are rendered on several machines) must be a
filesystem every worker sees (NFS, a shared volume, the same host): the driver checks it
before any work by writing a probe file that a task on every node must read back.
"""

from __future__ import annotations

import os
import time
import uuid
from pathlib import Path

from zcomp_cli.errors import UsageError
from zcomp_cli.pipeline.executor import Executor, run_chunk
from zcomp_cli.pipeline.outputs import REPORT, JobStatus, job_state, read_report
from zcomp_cli.pipeline.stages import BatchContext, render_objects

RAY_EXTRA_HINT = "pip install 'zcomp[ray]'"
# Test hook: when set to a path that does not exist yet, the first worker to finish a
# job creates it and dies on the spot (after the job's outputs, before reporting back)
# -- the worst moment for a crash. Used by the tests to check retries; never set it.
KILL_ONCE_ENV = "ZCOMP_TEST_RAY_KILL_ONCE"


def import_ray():
    """``ray``, or a UsageError naming the extra that installs it."""
    try:
        import ray
    except ImportError as exc:
        raise UsageError(f"--executor ray needs Ray, which is not installed: {RAY_EXTRA_HINT} ({exc})") from None
    return ray


class _Worker:
    """The body of a Ray actor: one renderer and a scene store for many units."""

    def __init__(self, manifest, out_root: str, renderer_spec, debug: bool, cache_root, batch_size: int,
                 aovs: bool = False):
        from zcomp_cli.renderers import get_renderer

        renderer = get_renderer(renderer_spec.name, **renderer_spec.settings)
        self.ctx = BatchContext.create(manifest, Path(out_root), renderer_spec, renderer, batch_size=batch_size,
                                       debug=debug, aovs=aovs, cache_root=cache_root)
        self._session = None

    def _blender(self):
        """This worker's Blender process, started on the first unit with meshes and
        kept for the next ones (it exits when this worker's process ends)."""
        if self._session is None:
            from zcomp_cli.blender.intrinsics import SCRIPT
            from zcomp_cli.blender.runner import BlenderSession

            self._session = BlenderSession(SCRIPT)
        return self._session

    def close(self) -> None:
        """End this worker's Blender process (and drop its log when all went well)."""
        if self._session is not None:
            self._session.close()
            self._session = None

    def run_unit(self, works) -> tuple[int, list[JobStatus]]:
        """Run a unit (jobs of one scene); returns (this process's pid, statuses)."""
        ctx = self.ctx
        statuses: list[JobStatus] = []
        todo = []
        for w in works:
            out_dir = ctx.out_root / w.job.name
            if job_state(out_dir, w.fingerprint, need_debug=ctx.debug, need_aovs=ctx.aovs).state == "done":
                # finished by an earlier attempt of this unit (the driver removed
                # older reports of every job it sent): do not run it twice
                statuses.append(JobStatus(w.job, "done", None, 0.0, out_dir))
            elif w.error is not None:
                statuses.append(JobStatus(w.job, "failed", w.error, 0.0, out_dir))
            else:
                todo.append(w)
        # a unit is one scene's: the worker keeps that scene (the next unit is likely of
        # the same scene) and frees the others
        ctx.scenes.release_all_but(works[0].job.scene if works else None)
        if any(ctx.manifest.objects[w.job.object].kind == "mesh" for w in todo):
            render_objects(ctx, todo, session=self._blender())
        for w in [w for w in todo if w.error is not None]:
            statuses.append(JobStatus(w.job, "failed", w.error, 0.0, ctx.out_root / w.job.name))
        todo = [w for w in todo if w.error is None]
        for start in range(0, len(todo), ctx.batch_size):
            statuses.extend(run_chunk(ctx, todo[start:start + ctx.batch_size]))
            marker = os.environ.get(KILL_ONCE_ENV)
            if marker and not Path(marker).exists():
                Path(marker).write_text(str(os.getpid()))
                os._exit(1)
        order = {w.job.index: k for k, w in enumerate(works)}
        return os.getpid(), sorted(statuses, key=lambda s: order[s.job.index])


def cpus_per_worker(node_cpus: list[int], workers: int) -> int:
    """The most CPUs each of ``workers`` actors can ask for so that all of them fit on
    the nodes (``node_cpus``: each alive node's CPU count): at most an equal share of the
    cluster, and never more than a node holds (an actor that fits nowhere would wait
    forever). At least 1."""
    nodes = [c for c in node_cpus if c > 0]
    if not nodes or workers < 1:
        return 1
    for per in range(min(sum(nodes) // workers, max(nodes)), 1, -1):
        if sum(c // per for c in nodes) >= workers:
            return per
    return 1


class RayExecutor(Executor):
    """Runs the job stage on Ray actors. ``address``: ``auto``, ``HOST:PORT`` or
    ``ray://HOST:PORT`` (default ``$RAY_ADDRESS``, else a local Ray, or the Ray already
    initialised in this process); ``workers``: actors to start (default: what the
    cluster's CPUs -- GPUs for zerocomp -- allow)."""

    name = "ray"
    renders_objects = True

    def __init__(self, address: str | None = None, workers: int | None = None, *, unit_size: int = 4,
                 max_retries: int = 3, runtime_env: dict | None = None):
        super().__init__()
        self.address = address
        self.runtime_env = runtime_env
        self.workers = workers
        self.unit_size = max(1, int(unit_size))
        self.max_retries = int(max_retries)
        self._ray = None
        self._workers: tuple[list, dict] | None = None  # started by check(), used by run()

    # -- before any work ---------------------------------------------------------
    def preflight(self) -> None:
        """Ray is installed and its cluster reachable (before anything is written)."""
        ray = self._ray = import_ray()
        if not ray.is_initialized():
            address = self.address or os.environ.get("RAY_ADDRESS") or None
            try:
                ray.init(address=address, log_to_driver=False, include_dashboard=False)
            except (ConnectionError, RuntimeError, ValueError) as exc:
                raise UsageError(f"--executor ray: cannot join the Ray cluster at {address or 'a new local Ray'}: "
                                 f"{exc}") from None

    def check(self, ctx, n_jobs: int = 0) -> None:
        """``OUT`` is seen by every node; then the workers start, so that their start
        (a process, zcomp's imports, the renderer) overlaps the driver's own work until
        the job stage."""
        if self._ray is None:
            self.preflight()
        self._check_shared_output(ctx.out_root)
        if n_jobs:
            self._workers = self._start_workers(ctx, n_jobs)

    def _start_workers(self, ctx, at_most: int) -> tuple[list, dict]:
        """(actors, the resources each asked for): at most ``at_most`` workers."""
        ray = self._ray
        n, res = self._worker_count(ctx, at_most)
        opts = dict(max_restarts=self.max_retries, max_task_retries=self.max_retries, **res)
        if self.runtime_env:
            opts["runtime_env"] = self.runtime_env
        actor_cls = ray.remote(**opts)(_Worker)
        return [actor_cls.remote(ctx.manifest, str(ctx.out_root), ctx.renderer_spec, ctx.debug,
                                 ctx.cache_root, ctx.batch_size, ctx.aovs) for _ in range(n)], res

    def _check_shared_output(self, out_root: Path) -> None:
        """Every node with Ray workers must see ``out_root``: write a probe, read it
        back from a task pinned to each alive node."""
        ray = self._ray
        from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

        token = uuid.uuid4().hex
        probe = Path(out_root).resolve() / f".zcomp-probe-{token}"
        probe.write_text(token)

        @ray.remote(num_cpus=0)
        def _read(path):
            import socket

            try:
                return socket.gethostname(), Path(path).read_text()
            except OSError as exc:
                return socket.gethostname(), f"error: {exc}"

        try:
            nodes = [n for n in ray.nodes() if n.get("Alive")]
            refs = [_read.options(scheduling_strategy=NodeAffinitySchedulingStrategy(n["NodeID"], soft=False))
                    .remote(str(probe)) for n in nodes]
            answers = ray.get(refs, timeout=120)
        finally:
            probe.unlink(missing_ok=True)
        blind = [host for host, text in answers if text != token]
        if blind:
            raise UsageError(f"--out {out_root} is not visible from every Ray node (not seen from: "
                             f"{', '.join(sorted(set(blind)))}). With --executor ray, OUT must be a filesystem "
                             "every worker sees, at the same path (e.g. NFS or a shared volume).")
        self.info["nodes"] = len(nodes)

    # -- the job stage -----------------------------------------------------------
    def _units(self, works) -> list[list]:
        by_scene: dict[str, list] = {}
        for w in works:
            by_scene.setdefault(w.job.scene, []).append(w)
        return [g[k:k + self.unit_size] for g in by_scene.values() for k in range(0, len(g), self.unit_size)]

    def _worker_count(self, ctx, n_units: int) -> tuple[int, dict]:
        """How many workers, and what each asks Ray for. A CPU worker gets its share of
        the cluster's cores (``cpus_per_worker``): Ray sets a worker's thread count
        (OMP_NUM_THREADS) from its CPUs, so a lone worker computes with the threads a
        local run has, not with one."""
        gpu = ctx.renderer_spec.name == "zerocomp"
        total = self._ray.cluster_resources()
        if self.workers is not None:
            n = self.workers
        else:
            n = int(total.get("GPU" if gpu else "CPU", 0)) or 1
        n = max(1, min(n, n_units))
        if gpu:
            return n, {"num_cpus": 1, "num_gpus": 1}
        nodes = [int(nd.get("Resources", {}).get("CPU", 0)) for nd in self._ray.nodes() if nd.get("Alive")]
        return n, {"num_cpus": cpus_per_worker(nodes, n), "num_gpus": 0}

    def run(self, ctx, works) -> list[JobStatus]:
        ray = self._ray or import_ray()
        t0 = time.perf_counter()
        total = len(works)
        # An older finished report of a job sent out again (--overwrite) must not pass
        # for this run's work when a retried unit checks what is already done.
        for w in works:
            rep = read_report(ctx.out_root / w.job.name)
            if rep is not None and rep.get("status") == "done":
                (ctx.out_root / w.job.name / REPORT).unlink(missing_ok=True)
        units = self._units(works)
        started, self._workers = self._workers, None
        actors, res = started if started is not None else ([], {})
        if not units:
            for a in actors:
                ray.kill(a)
            return []
        if not actors:
            actors, res = self._start_workers(ctx, len(units))
        for a in actors[len(units):]:  # more workers than units (units hold up to unit_size jobs)
            ray.kill(a)
        actors = actors[:len(units)]
        n = len(actors)
        pending = list(range(len(units)))
        last_scene: dict[int, str] = {}
        in_flight: dict = {}  # ref -> (actor index, unit index)
        statuses: list[JobStatus] = []
        pids: set[int] = set()
        done = 0
        ctx.report("jobs", 0, total, "")

        def submit(a: int) -> None:
            # Scene affinity: this worker's last scene first; else a scene no other
            # worker has touched (its per-scene work is not done twice); else the next.
            mine = last_scene.get(a)
            taken = {s for b, s in last_scene.items() if b != a}
            pick = next((u for u in pending if units[u][0].job.scene == mine), None)
            if pick is None:
                pick = next((u for u in pending if units[u][0].job.scene not in taken), pending[0])
            pending.remove(pick)
            last_scene[a] = units[pick][0].job.scene
            in_flight[actors[a].run_unit.remote(units[pick])] = (a, pick)

        try:
            # two units per worker in flight: the next one waits in the actor's queue, so
            # a worker never idles while the driver collects a result and sends more
            for _ in range(2):
                for a in range(n):
                    if pending:
                        submit(a)
            while in_flight:
                ready, _ = ray.wait(list(in_flight), num_returns=1)
                ref = ready[0]
                a, u = in_flight.pop(ref)
                try:
                    pid, got = ray.get(ref)
                    pids.add(pid)
                except ray.exceptions.RayError as exc:  # retries exhausted, or a bug in the worker
                    reason = f"Ray worker failed after {self.max_retries} retries: {type(exc).__name__}: {exc}"
                    got = [JobStatus(w.job, "failed", reason.splitlines()[0][:500], 0.0, ctx.out_root / w.job.name)
                           for w in units[u]]
                statuses.extend(got)
                done += len(got)
                ctx.report("jobs", done, total, got[-1].job.name if got else "")
                if pending:
                    submit(a)
            try:
                ray.get([a.close.remote() for a in actors], timeout=60)
            except ray.exceptions.RayError:
                pass  # a worker that cannot close is killed below all the same
        finally:  # also when interrupted: no worker (and no Blender of theirs) goes on
            for a in actors:
                ray.kill(a)
        self.info.update(workers=n, cpus_per_worker=res["num_cpus"], units=len(units), worker_pids=sorted(pids),
                         seconds=time.perf_counter() - t0)
        return statuses
