"""What a batch leaves in its output folder, and how a re-run reads it back.

Per job, ``OUT/<job name>/``: ``composite.png`` (sRGB 8-bit), ``composite.exr``
(linear), ``report.json`` (written last: its presence with ``status: done`` marks a
finished job), and with ``--debug`` the intermediate maps and ``grid.png``. The batch
ends with ``OUT/summary.json``. Every file is written atomically (``imageio``).
"""

from __future__ import annotations

import hashlib
import json
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


def job_fingerprint(manifest: Manifest, job: JobSpec, renderer: RendererSpec, samples: int) -> str:
    """Identifies a job's inputs: paths, sizes and mtimes of its files, its pose, settings."""
    from zcomp_cli.renderers.registry import RENDERERS

    scene = manifest.scenes[job.scene]
    obj = manifest.objects[job.object]
    entry = RENDERERS.get(renderer.name)
    speed_only = set(entry.speed_settings) if entry is not None else set()
    files = [scene.image, *scene.maps.values(), obj.mesh, obj.bundle, obj.image, obj.mask]
    stats = []
    for f in files:
        if f is not None and Path(f).exists():
            st = Path(f).stat()
            stats.append([str(f), st.st_size, int(st.st_mtime)])
    payload = {
        "files": stats,
        "scene": {"fov": scene.fov_deg, "K": None if scene.K is None else scene.K.tolist(),
                  "estimators": scene.estimators},
        "pose": None if job.pose is None else job.pose.to_dict(),
        "placement": None if job.placement is None else vars(job.placement),
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


def plan_outputs(manifest, jobs, out_root: Path, renderer, samples, *, resume: bool, overwrite: bool):
    """Decide, before any work, which jobs run and which are skipped.

    Returns (to_run as ``[(job, fingerprint)]``, skipped statuses). Raises UsageError
    when finished outputs exist and neither --resume nor --overwrite says what to do
    with them (nothing is lost)."""
    to_run, skipped, clashes = [], [], []
    for job in jobs:
        out_dir = out_root / job.name
        rep = read_report(out_dir)
        fp = job_fingerprint(manifest, job, renderer, samples)
        if rep is None or rep.get("status") != "done" or overwrite:
            to_run.append((job, fp))
        elif resume and rep.get("fingerprint") == fp:
            skipped.append(JobStatus(job, "skipped", "finished in an earlier run (--resume)", 0.0, out_dir))
        elif resume:
            clashes.append(f"{job.name} (its inputs changed since it was made)")
        else:
            clashes.append(job.name)
    if clashes:
        shown = ", ".join(clashes[:5]) + (f" and {len(clashes) - 5} more" if len(clashes) > 5 else "")
        raise UsageError(
            f"{len(clashes)} job output(s) already exist in {out_root}: {shown}. "
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


def write_summary(out_root: Path, summary: BatchSummary) -> None:
    from zcomp_cli.imageio import write_json_atomic

    write_json_atomic(out_root / summary_name(summary.shard), summary.to_dict())


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
