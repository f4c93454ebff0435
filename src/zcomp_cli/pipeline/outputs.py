"""What a batch leaves in its output folder, and how a re-run reads it back.

Per job, ``OUT/<job name>/``: ``composite.png`` (sRGB 8-bit), ``composite.exr``
(linear), ``report.json`` (written last: its presence with ``status: done`` marks a
finished job), and with ``--debug`` the intermediate maps and ``grid.png``. The batch
ends with ``OUT/summary.json``. Every file is written atomically (``imageio``).

``report.json`` records the size and sha256 of every file of the job (``outputs``);
``--resume`` skips a job only when they all still match and its inputs' fingerprint is
unchanged. The fingerprint hashes input *contents* (paths relative to the manifest), so
``touch`` or moving the project does not invalidate finished jobs.

``summary.json`` is the merged state of the output folder for the manifest's jobs:
``done`` (finished, in this run or an earlier one), ``failed`` (the latest attempt
failed) or ``pending`` (not finished); it is rewritten, under a lock, when a run starts
and when it ends, so a killed run never leaves a summary claiming more than is there.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from zcomp_cli import __version__
from zcomp_cli.errors import UsageError
from zcomp_cli.pipeline.manifest import JobSpec, Manifest, RendererSpec

REPORT = "report.json"
SUMMARY = "summary.json"
DEBUG_MAPS = ("f_bg", "f_comp", "ratio", "ratio_blurred", "shading_mask", "object_mask", "weight",
              "comp_depth", "comp_normals", "comp_albedo", "shading")


@dataclass
class JobStatus:
    job: JobSpec
    status: str  # "done" | "skipped" | "failed"
    reason: str | None = None
    seconds: float = 0.0
    out_dir: Path | None = None


@dataclass
class BatchSummary:
    statuses: list[JobStatus] = field(default_factory=list)
    seconds: float = 0.0
    blender: dict = field(default_factory=dict)
    # --shard: {"index": i, "count": n, "jobs": [names of the shard's jobs]}
    shard: dict | None = None
    executor: dict = field(default_factory=dict)

    def count(self, status: str) -> int:
        return sum(1 for s in self.statuses if s.status == status)

    @property
    def ok(self) -> bool:
        return self.count("failed") == 0

    def to_dict(self) -> dict:
        return {
            "done": self.count("done"), "skipped": self.count("skipped"), "failed": self.count("failed"),
            "seconds": self.seconds, "blender": self.blender, "shard": self.shard,
            "executor": self.executor,
            "jobs": [{"index": s.job.index, "name": s.job.name, "status": s.status, "reason": s.reason,
                      "seconds": s.seconds} for s in self.statuses],
        }


def job_fingerprint(manifest: Manifest, job: JobSpec, renderer: RendererSpec, samples: int,
                    digests=None) -> str:
    """Identifies a job's inputs: the contents of its files (named relative to the
    manifest), its pose, settings (not those that only change speed).
    ``digests`` is a ``outguard.DigestCache``."""
    from zcomp_cli.pipeline.outguard import DigestCache
    from zcomp_cli.renderers.registry import RENDERERS

    digests = digests if digests is not None else DigestCache(None)
    scene = manifest.scenes[job.scene]
    obj = manifest.objects[job.object]
    entry = RENDERERS.get(renderer.name)
    speed_only = set(entry.speed_settings) if entry is not None else set()
    roles = [("scene.image", scene.image), *((f"scene.{k}", v) for k, v in sorted(scene.maps.items())),
             ("object.mesh", obj.mesh), ("object.bundle", obj.bundle), ("object.image", obj.image),
             ("object.mask", obj.mask)]
    stats = []
    for role, f in roles:
        if f is not None and Path(f).exists():
            stats.append([role, os.path.relpath(f, manifest.root), digests.digest(Path(f))])
    payload = {
        "files": stats,
        "scene": {"fov": scene.fov_deg, "K": None if scene.K is None else scene.K.tolist(),
                  "estimators": scene.estimators},
        "pose": None if job.pose is None else job.pose.to_dict(),
        "placement": None if job.placement is None else [job.placement.pixel, job.placement.yaw_deg,
                                                          job.placement.height, job.placement.scale],
        "radius": job.shading_radius, "seed": job.seed,
        "renderer": {"name": renderer.name, **{k: str(v) for k, v in renderer.settings.items()
                                               if k not in speed_only}},
        "resolution": manifest.defaults.resolution, "samples": samples,
    }
    return hashlib.sha256(json.dumps(payload, sort_keys=True, default=str).encode()).hexdigest()[:16]


def read_report(out_dir: Path) -> dict | None:
    p = out_dir / REPORT
    if not p.is_file():
        return None
    try:
        return json.loads(p.read_text())
    except (OSError, json.JSONDecodeError):
        return None


def plan_outputs(manifest, jobs, out_root: Path, renderer, samples, *, resume: bool, overwrite: bool,
                 digests=None):
    """Decide, before any work, which jobs run and which are skipped.

    A job counts as finished only when its report says ``done`` and every output it
    records is still there with its size and hash; a job folder that is a symbolic link
    (or leads outside ``out_root``) is refused. Returns (to_run as ``[(job,
    fingerprint)]``, skipped statuses). Raises UsageError when finished outputs exist
    and neither --resume nor --overwrite says what to do with them (nothing is lost)."""
    from zcomp_cli.pipeline.outguard import check_inside, verify_outputs

    to_run, skipped, clashes, changed = [], [], [], []
    for job in jobs:
        out_dir = out_root / job.name
        field = f"jobs[{job.index}].output ({job.name})"
        check_inside(out_root, out_dir, field)
        if out_dir.is_dir():
            check_inside(out_root, out_dir / "debug", field)
        rep = read_report(out_dir)
        fp = job_fingerprint(manifest, job, renderer, samples, digests)
        finished = rep is not None and rep.get("status") == "done"
        if finished and verify_outputs(out_dir, rep.get("outputs")) is not None:
            finished = False  # a missing, empty or altered output: not finished, redo it
        if not finished or overwrite:
            to_run.append((job, fp))
        elif resume and rep.get("fingerprint") == fp:
            skipped.append(JobStatus(job, "skipped", "finished in an earlier run (--resume)", 0.0, out_dir))
        elif resume:
            changed.append(job.name)
        else:
            clashes.append(job.name)

    def shown(names):
        return ", ".join(names[:5]) + (f" and {len(names) - 5} more" if len(names) > 5 else "")

    if changed:
        raise UsageError(
            f"{len(changed)} finished job(s) in {out_root} were made from other inputs or settings: "
            f"{shown(changed)}. --resume keeps only outputs of the same inputs; pass --overwrite to "
            "replace them (or use another --out).")
    if clashes:
        raise UsageError(
            f"{len(clashes)} job output(s) already exist in {out_root}: {shown(clashes)}. "
            "Pass --resume to skip finished jobs or --overwrite to replace them.")
    return to_run, skipped


def job_report(manifest: Manifest, job: JobSpec, fingerprint: str, scene, pose, bundle_dir, result) -> dict:
    """The ``report.json`` body of a finished job (timings are completed by the writer)."""
    return {
        "status": "done",
        "zcomp_version": __version__,
        "fingerprint": fingerprint,
        "job": {"index": job.index, "name": job.name, "scene": job.scene, "object": job.object,
                "manifest": str(manifest.path), "line": job.line},
        "pose": None if pose is None else pose.to_dict(),
        "placement": None if job.placement is None else vars(job.placement),
        "reference": None if job.reference is None else str(job.reference),
        "scene": {"key": scene.key, "size": [scene.camera.width, scene.camera.height],
                  "K": scene.camera.K.tolist(), "sources": scene.sources, "timings": scene.timings},
        **result.report,
        "object_bundle": None if bundle_dir is None else str(bundle_dir),
    }


def write_job_outputs(out_dir: Path, scene, result, report: dict, *, debug: bool,
                      started: float | None = None) -> float:
    """Write a finished job's files, ``report.json`` last. Returns the seconds spent.
    ``started`` (a ``time.perf_counter()`` value) adds ``job_total_s`` to the report."""
    import time

    from zcomp_cli.imageio import write_exr, write_json_atomic, write_png

    out_dir.mkdir(parents=True, exist_ok=True)
    # A stale report must not vouch for new files while they are being written.
    stale = out_dir / REPORT
    if stale.exists():
        stale.unlink()
    t = time.perf_counter()
    write_exr(out_dir / "composite.exr", result.image)
    write_png(out_dir / "composite.png", result.image)
    if debug:
        write_debug(out_dir, scene, result)
    t_write = time.perf_counter() - t
    from zcomp_cli.pipeline.outguard import output_record

    files = sorted(p for p in out_dir.rglob("*") if p.is_file() and p.name != REPORT
                   and not p.name.startswith("."))
    report["outputs"] = {str(p.relative_to(out_dir)): output_record(p) for p in files}
    report["timings"] = {**report.get("timings", {}), "write_s": t_write}
    if started is not None:
        report["timings"]["job_total_s"] = time.perf_counter() - started
    write_json_atomic(out_dir / REPORT, report)
    return t_write


def summary_name(shard: dict | None) -> str:
    """``summary.json``, or ``summary.shard-I-of-N.json`` for shard I (from 0) of N:
    shards running side by side in one folder never write the same file."""
    if not shard:
        return SUMMARY
    return f"summary.shard-{shard['index']}-of-{shard['count']}.json"


def write_summary(out_root: Path, summary: BatchSummary, manifest: Manifest | None = None, *,
                  running: set[str] | frozenset = frozenset()) -> dict:
    """Merge this run's statuses with the state of ``out_root`` and write the summary
    (``summary_name``; under the summary lock, so runs writing side by side never lose
    each other's jobs). Jobs in ``running`` are reported ``pending`` (being made).
    Returns the document."""
    from zcomp_cli.imageio import write_json_atomic
    from zcomp_cli.pipeline.outguard import clean_root_temporaries, summary_lock

    with summary_lock(out_root):
        clean_root_temporaries(out_root)
        doc = merged_summary(out_root, summary, manifest, running=running)
        write_json_atomic(out_root / summary_name(summary.shard), doc)
    return doc


def merged_summary(out_root: Path, summary: BatchSummary, manifest: Manifest | None, *,
                   running=frozenset()) -> dict:
    """The summary document: every job of the manifest (of the shard, for a shard) with
    its state in the folder; ``this_run`` counts what this run did (done, skipped,
    failed)."""
    prev = {}
    try:
        old = json.loads((out_root / summary_name(summary.shard)).read_text())
        prev = {j["name"]: j for j in old.get("jobs", []) if isinstance(j, dict) and "name" in j}
    except (OSError, ValueError, AttributeError, TypeError):
        pass
    mine = {s.job.name: s for s in summary.statuses}
    jobs = list(manifest.jobs) if manifest is not None else [s.job for s in summary.statuses]
    if summary.shard:
        keep = set(summary.shard.get("jobs") or [])
        jobs = [j for j in jobs if j.name in keep]
    rows = []
    for job in jobs:
        st = mine.get(job.name)
        row = {"index": job.index, "name": job.name, "status": "pending", "reason": None, "seconds": 0.0,
               "this_run": None}
        if job.name in running:
            row["reason"] = "being made"
        elif st is not None and st.status in ("done", "failed"):
            row.update(status=st.status, reason=st.reason, seconds=st.seconds, this_run=st.status)
        else:
            if st is not None:
                row["this_run"] = st.status
            rep = read_report(out_root / job.name)
            if rep is not None and rep.get("status") == "done" and _sizes_match(out_root / job.name, rep):
                row.update(status="done", reason=st.reason if st is not None else "finished in an earlier run",
                           seconds=float((rep.get("timings") or {}).get("job_total_s") or 0.0))
            elif prev.get(job.name, {}).get("status") == "failed":
                row.update(status="failed", reason=prev[job.name].get("reason"))
        rows.append(row)
    count = {k: sum(1 for r in rows if r["status"] == k) for k in ("done", "failed", "pending")}
    return {
        **count,
        "skipped": summary.count("skipped"),
        "this_run": {k: summary.count(k) for k in ("done", "skipped", "failed")},
        "seconds": summary.seconds, "blender": summary.blender, "shard": summary.shard,
        "executor": summary.executor,
        "jobs": rows,
    }


def _sizes_match(job_dir: Path, rep: dict) -> bool:
    """Cheap check (sizes, no hashing) that a report's outputs are still there."""
    outs = rep.get("outputs")
    if not isinstance(outs, dict) or not outs:
        return False
    for name, rec in outs.items():
        p = job_dir / name
        try:
            if not isinstance(rec, dict) or p.stat().st_size != rec.get("bytes") or rec.get("bytes") == 0:
                return False
        except OSError:
            return False
    return True


def write_debug(out_dir: Path, scene, result) -> None:
    from zcomp_cli.imageio import write_exr, write_png

    d = result.debug
    for name in DEBUG_MAPS:
        if name in d:
            write_exr(out_dir / "debug" / f"{name}.exr", d[name])
    write_png(out_dir / "shading_mask.png", d["shading_mask"], srgb_encode=False)
    write_png(out_dir / "grid.png", debug_grid(scene.image, d["f_bg"], d["f_comp"], d["ratio_blurred"],
                                               d["shading_mask"], result.image), srgb_encode=False)


def debug_grid(x_bg, f_bg, f_comp, ratio, mask, result) -> np.ndarray:
    """2 x 3 sheet like the paper's Figure 3: background, f(i_bg), f(i_comp) /
    R', shading mask, result. Returns sRGB-encoded [0, 1] float (H*2, W*3, 3)."""
    from zcomp_cli.conventions import linear_to_srgb

    def col(a):
        a = np.asarray(a, dtype=np.float32)
        return np.repeat(a[..., None], 3, -1) if a.ndim == 2 else a

    top = [linear_to_srgb(col(x)) for x in (x_bg, f_bg, f_comp)]
    bottom = [np.clip(col(ratio), 0, 1), np.clip(col(mask), 0, 1), linear_to_srgb(col(result))]
    return np.concatenate([np.concatenate(top, 1), np.concatenate(bottom, 1)], 0)
