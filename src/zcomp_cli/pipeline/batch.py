"""Run every job of a manifest: scenes loaded once, every object rendered in one
Blender batch, jobs run one by one; a failed job is recorded and the batch goes on.

Outputs per job in ``OUT/<job name>/``: ``composite.png`` (sRGB 8-bit), ``composite.exr``
(linear), ``report.json`` (written last: its presence with ``status: done`` marks a
finished job), and with ``debug`` the intermediate maps and ``grid.png``.
"""

from __future__ import annotations

import hashlib
import json
import logging
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from zcomp_cli import __version__
from zcomp_cli.errors import InputError, UsageError, ZcompError
from zcomp_cli.pipeline.manifest import JobSpec, Manifest, RendererSpec

log = logging.getLogger(__name__)

REPORT = "report.json"


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

    def count(self, status: str) -> int:
        return sum(1 for s in self.statuses if s.status == status)

    @property
    def ok(self) -> bool:
        return self.count("failed") == 0

    def to_dict(self) -> dict:
        return {
            "done": self.count("done"), "skipped": self.count("skipped"), "failed": self.count("failed"),
            "seconds": self.seconds, "blender": self.blender,
            "jobs": [{"index": s.job.index, "name": s.job.name, "status": s.status, "reason": s.reason,
                      "seconds": s.seconds} for s in self.statuses],
        }


def select_jobs(jobs: list[JobSpec], subset: str | None) -> list[JobSpec]:
    """``--jobs`` syntax: comma-separated indices, ranges ``a-b`` and job names."""
    if not subset:
        return list(jobs)
    by_name = {j.name: j for j in jobs}
    picked: dict[int, JobSpec] = {}
    for part in (p.strip() for p in subset.split(",") if p.strip()):
        if part in by_name:
            picked[by_name[part].index] = by_name[part]
            continue
        try:
            if "-" in part:
                a, b = (int(v) for v in part.split("-", 1))
                rng = range(a, b + 1)
            else:
                rng = range(int(part), int(part) + 1)
        except ValueError:
            raise UsageError(f"--jobs: {part!r} is neither a job index, a range a-b, nor a job name") from None
        for i in rng:
            if not 0 <= i < len(jobs):
                raise UsageError(f"--jobs: index {i} out of range (the manifest has {len(jobs)} jobs)")
            picked[i] = jobs[i]
    return [picked[i] for i in sorted(picked)]


def job_fingerprint(manifest: Manifest, job: JobSpec, renderer: RendererSpec, samples: int) -> str:
    """Identifies a job's inputs: paths, sizes and mtimes of its files, its pose, settings."""
    scene = manifest.scenes[job.scene]
    obj = manifest.objects[job.object]
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
        "renderer": {"name": renderer.name, **{k: str(v) for k, v in renderer.settings.items()}},
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

    Returns (to_run, skipped statuses). Raises UsageError when finished outputs exist
    and neither --resume nor --overwrite says what to do with them (nothing is lost)."""
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
    progress: Callable[[str, int, int, str], None] | None = None,
) -> BatchSummary:
    """Run the manifest's jobs. ``progress(stage, done, total, label)`` is called for
    the object-render stage ("objects") and the job stage ("jobs")."""
    from zcomp_cli.renderers import get_renderer

    t_batch = time.perf_counter()
    out_root = Path(out_root)
    out_root.mkdir(parents=True, exist_ok=True)
    renderer_spec = renderer_spec or manifest.defaults.renderer
    samples = manifest.defaults.samples
    jobs = select_jobs(manifest.jobs, jobs_subset)
    to_run, skipped = plan_outputs(manifest, jobs, out_root, renderer_spec, samples,
                                   resume=resume, overwrite=overwrite)
    summary = BatchSummary(statuses=list(skipped))
    if not to_run:
        summary.seconds = time.perf_counter() - t_batch
        return summary
    renderer = get_renderer(renderer_spec.name, **renderer_spec.settings)

    # 1. Scenes: loaded once each, lazily, failures remembered per scene.
    from zcomp_cli.pipeline.scene import load_scene

    scenes: dict[str, object] = {}
    scene_errors: dict[str, str] = {}

    def get_scene(name):
        if name in scenes:
            return scenes[name]
        if name in scene_errors:
            raise InputError(scene_errors[name])
        try:
            sc = load_scene(manifest.scenes[name], manifest.defaults.resolution, cache_dir=cache_dir)
        except ZcompError as exc:
            scene_errors[name] = f"scene {name!r}: {exc}"
            raise InputError(scene_errors[name]) from exc
        scenes[name] = sc
        return sc

    # 2. Poses (placement needs the scene's depth and normals).
    from zcomp_cli.pipeline.placement import pose_from_placement

    poses: dict[int, object] = {}
    failed: dict[int, str] = {}
    for job, _ in to_run:
        try:
            if job.pose is not None:
                poses[job.index] = job.pose
            elif manifest.objects[job.object].kind != "image":
                sc = get_scene(job.scene)
                poses[job.index] = pose_from_placement(job.placement, sc.maps.depth, sc.maps.normals, sc.camera)
        except ZcompError as exc:
            failed[job.index] = str(exc)

    # 3. Object intrinsics: every mesh job in ONE Blender batch (cached).
    bundles: dict[int, object] = {}
    t_obj = time.perf_counter()
    mesh_jobs = [(j, fp) for j, fp in to_run if j.index not in failed and manifest.objects[j.object].kind == "mesh"]
    if mesh_jobs:
        bundles_dirs, blender_info = _render_objects(manifest, mesh_jobs, poses, get_scene, failed,
                                                      samples, cache_dir, progress)
        summary.blender = blender_info
        bundles.update(bundles_dirs)
    summary.blender["objects_s"] = time.perf_counter() - t_obj

    # 4. Jobs.
    total = len(to_run)
    for k, (job, fp) in enumerate(to_run):
        if progress:
            progress("jobs", k, total, job.name)
        t0 = time.perf_counter()
        out_dir = out_root / job.name
        if job.index in failed:
            summary.statuses.append(JobStatus(job, "failed", failed[job.index], 0.0, out_dir))
            continue
        try:
            _run_one(manifest, job, fp, get_scene, bundles.get(job.index), poses.get(job.index),
                     renderer, renderer_spec, out_dir, debug, cache_dir)
            summary.statuses.append(JobStatus(job, "done", None, time.perf_counter() - t0, out_dir))
        except ZcompError as exc:
            summary.statuses.append(JobStatus(job, "failed", str(exc), time.perf_counter() - t0, out_dir))
        except Exception as exc:  # a bug must not lose the rest of the batch
            log.debug("job %s crashed:\n%s", job.name, traceback.format_exc())
            summary.statuses.append(JobStatus(job, "failed", f"internal error: {type(exc).__name__}: {exc}",
                                              time.perf_counter() - t0, out_dir))
    if progress:
        progress("jobs", total, total, "")
    summary.statuses.sort(key=lambda s: s.job.index)
    summary.seconds = time.perf_counter() - t_batch
    from zcomp_cli.imageio import write_json_atomic

    write_json_atomic(out_root / "summary.json", summary.to_dict())
    return summary


def _render_objects(manifest, mesh_jobs, poses, get_scene, failed, samples, cache_dir, progress):
    from zcomp_cli.blender.intrinsics import IntrinsicsRequest, render_object_intrinsics

    requests, owners = [], []
    for job, _ in mesh_jobs:
        try:
            sc = get_scene(job.scene)
        except ZcompError as exc:
            failed[job.index] = str(exc)
            continue
        obj = manifest.objects[job.object]
        requests.append(IntrinsicsRequest(id=f"job{job.index}", mesh=obj.mesh, pose=poses[job.index],
                                          camera=sc.camera, out_dir=None))
        owners.append(job)
    info: dict = {"requests": len(requests)}
    if not requests:
        return {}, info

    def _cb(done, total, ident):
        if progress:
            progress("objects", done, total, str(ident))

    results = render_object_intrinsics(requests, cache_dir=cache_dir, samples=samples, progress=_cb)
    out = {}
    for job, res in zip(owners, results):
        if res.ok:
            out[job.index] = res.bundle_dir
        else:
            failed[job.index] = f"object {job.object!r}: {res.error}"
    info["cached"] = sum(1 for r in results if getattr(r, "cached", False))
    info["render_s"] = [round(float(getattr(r, "seconds", 0.0)), 3) for r in results]
    return out, info


def _object_bundle(manifest, job, scene, bundle_dir, pose):
    from zcomp_cli.bundle import ObjectBundle

    obj = manifest.objects[job.object]
    if obj.kind == "mesh":
        return ObjectBundle.load(bundle_dir)
    if obj.kind == "bundle":
        return ObjectBundle.load(obj.bundle)
    # A 2D object (image + mask), placed on the support surface.
    from zcomp_cli.estimators.object2d import object_bundle_from_image
    from zcomp_cli.imageio import read_alpha_or_grey, read_image

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


def _run_one(manifest, job, fp, get_scene, bundle_dir, pose, renderer, renderer_spec, out_dir, debug, cache_dir):
    from zcomp_cli.imageio import write_exr, write_json_atomic, write_png
    from zcomp_cli.pipeline.job import run_job

    t0 = time.perf_counter()
    scene = get_scene(job.scene)
    t_load = time.perf_counter() - t0
    bundle = _object_bundle(manifest, job, scene, bundle_dir, pose)
    result = run_job(scene, bundle, renderer, shading_radius=job.shading_radius, seed=job.seed, debug=debug)
    out_dir.mkdir(parents=True, exist_ok=True)
    # A stale report must not vouch for new files while they are being written.
    stale = out_dir / REPORT
    if stale.exists():
        stale.unlink()
    t = time.perf_counter()
    write_exr(out_dir / "composite.exr", result.image)
    write_png(out_dir / "composite.png", result.image)
    if debug:
        _write_debug(out_dir, scene, result)
    t_write = time.perf_counter() - t
    report = {
        "status": "done",
        "zcomp_version": __version__,
        "fingerprint": fp,
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
    report["timings"] = {"scene_load_s": t_load, **report["timings"], "write_s": t_write,
                         "job_total_s": time.perf_counter() - t0}
    write_json_atomic(out_dir / REPORT, report)


def _write_debug(out_dir: Path, scene, result) -> None:
    from zcomp_cli.imageio import write_exr, write_png

    d = result.debug
    for name in ("f_bg", "f_comp", "ratio", "ratio_blurred", "shading_mask", "object_mask", "weight",
                 "comp_depth", "comp_normals", "comp_albedo", "shading"):
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
