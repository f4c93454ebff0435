"""``zcomp make-benchmark``: test cases with physically rendered ground truth, in the
spirit of the paper's Section 4.

Per case: a random scene (HDR map, floor, walls, boxes, lamps; ``scenes.sample_scene``),
a random object (procedural or one of the user's meshes) standing on the floor inside
the frustum with a random yaw and a height fitted to the view. Blender/Cycles renders
the background and the same scene with the object (same samples, same seed), and
exact background maps (1 sample through each pixel centre).

Output layout::

    OUT/cases/<id>/image.exr  image.png       background, linear EXR + sRGB preview
    OUT/cases/<id>/depth.exr  normals.exr  albedo.exr    its exact intrinsic maps
    OUT/cases/<id>/gt.exr     gt.png          ground-truth composite (object rendered in)
    OUT/cases/<id>/gt_depth.exr  object_mask.png   GT depth; where the object is visible
    OUT/objects/*.glb                         procedural objects (user meshes stay put)
    OUT/jobs.yaml                             one scene + one job per case, reference = gt.exr
    OUT/benchmark.json                        everything that defines each case

Steps of ``generate_benchmark``: 1. plan (deterministic for a seed: scenes, objects,
poses); 2. render every case in one Blender process; 3. expose and write the maps;
4. write and validate ``jobs.yaml`` and ``benchmark.json``.
"""

from __future__ import annotations

import math
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from zcomp_cli.benchsuite.objects import SHAPES, ObjectRecipe, sample_recipe, write_object_glb
from zcomp_cli.benchsuite.scenes import BenchScene, sample_scene, scene_for_blender
from zcomp_cli.camera import Camera
from zcomp_cli.conventions import DEFAULT_SEED, luminance
from zcomp_cli.errors import GeometryError, InputError, UsageError
from zcomp_cli.pose import Pose, euler_deg_to_matrix, transform_points

BENCHMARK_VERSION = 1


@dataclass(frozen=True)
class BenchmarkSettings:
    """Knobs of a benchmark run.

    Attributes:
        n: number of cases.
        seed: master seed (everything random derives from it).
        resolution: (W, H) pixels.
        samples: Cycles samples per render (128+ for real benchmarks; tests use few).
        denoise: OpenImageDenoise on the beauty renders (same for bg and GT).
        max_bounces: Cycles light bounces.
        object_paths: user meshes added to the procedural shapes.
        shapes: procedural shapes to draw from (empty: only user meshes).
        frame_fraction: range of the object's height as a fraction of the image height.
        exposure_key: the background's 90th-percentile luminance is exposed to this.
        threads: Cycles threads (0 = all cores).
        lights: ``mixed`` (an HDR map, with probability 0.6 a sun or 0.25 an area lamp,
            ``scenes.sample_scene``) or ``probe`` (the same scenes lit by their HDR map
            alone: the lamps drawn and dropped, so every other draw is the same).
    """

    n: int = 10
    seed: int = 0
    resolution: tuple[int, int] = (512, 512)
    samples: int = 128
    denoise: bool = True
    max_bounces: int = 8
    object_paths: tuple[str, ...] = ()
    shapes: tuple[str, ...] = SHAPES
    frame_fraction: tuple[float, float] = (0.15, 0.35)
    exposure_key: float = 0.5
    threads: int = 0
    lights: str = "mixed"

    def __post_init__(self):
        if int(self.n) < 1:
            raise UsageError(f"--n must be at least 1, got {self.n}")
        w, h = (int(v) for v in self.resolution)
        if w < 16 or h < 16 or w > 8192 or h > 8192:
            raise UsageError(f"--resolution must be within 16..8192 pixels, got {w} x {h}")
        if int(self.samples) < 1:
            raise UsageError(f"--samples must be at least 1, got {self.samples}")
        if self.lights not in ("mixed", "probe"):
            raise UsageError(f"--lights must be mixed or probe, got {self.lights!r}")
        if not self.shapes and not self.object_paths:
            raise UsageError("no objects: give --objects or keep the procedural shapes")
        lo, hi = self.frame_fraction
        if not (0.02 <= lo <= hi <= 0.9):
            raise UsageError(f"frame_fraction must satisfy 0.02 <= lo <= hi <= 0.9, got {self.frame_fraction}")
        object.__setattr__(self, "resolution", (w, h))
        object.__setattr__(self, "object_paths", tuple(str(p) for p in self.object_paths))


@dataclass
class CasePlan:
    """One planned case: its scene, object (mesh file and how it was made), pose."""

    id: str
    seed: int
    scene: BenchScene
    object_name: str
    mesh_path: Path
    pose: Pose
    recipe: ObjectRecipe | None = None
    info: dict = field(default_factory=dict)


# -- 1. planning ------------------------------------------------------------------------------

def place_on_floor(scene: BenchScene, vertices, bbox_min, bbox_max, rng: np.random.Generator, *,
                   frame_fraction=(0.15, 0.35), margin_px: float = 2.0, tries: int = 200) -> Pose:
    """A pose standing the mesh on the floor, fully inside the frame, clear of walls and
    boxes, with a random yaw and a height giving ``frame_fraction`` of the image height.

    Args:
        scene: the scene (floor plane, walls, boxes, camera).
        vertices: (N, 3) mesh vertices (mesh coordinates, Y-up) for frustum checks.
        bbox_min, bbox_max: the mesh bounding box (as ``pose.py`` uses it).
    Returns:
        A ``Pose`` with ``height`` set and rotation = scene tilt @ yaw.
    Raises:
        GeometryError: no valid placement after ``tries`` draws.
    """
    cam: Camera = scene.camera
    W, H = cam.width, cam.height
    R_sc = scene.scene_to_camera
    n, d = scene.floor_plane
    verts = np.asarray(vertices, dtype=np.float64)
    if len(verts) > 4000:  # a deterministic subsample is plenty for frustum checks
        verts = verts[np.linspace(0, len(verts) - 1, 4000).astype(int)]
    # The bbox corners bound the mesh: include them so thin meshes still fit.
    lo, hi = np.asarray(bbox_min, float), np.asarray(bbox_max, float)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    pts = np.vstack([verts, corners])
    for _ in range(tries):
        u = rng.uniform(0.2, 0.8) * W
        v = rng.uniform(0.55, 0.92) * H
        ray = cam.ray(u, v)
        denom = float(ray @ n)
        if denom > -1e-6:
            continue
        t = d / denom
        if not (0.5 < t < 30.0):
            continue
        base = ray * t
        frac = rng.uniform(*frame_fraction)
        height = float(np.clip(frac * H * t / cam.fy, 0.08, 2.5))
        yaw = float(rng.uniform(0.0, 360.0))
        pose = Pose(position=tuple(base), rotation=R_sc @ euler_deg_to_matrix(0.0, yaw, 0.0), height=height)
        p_cam = transform_points(pose.object_to_camera(lo, hi), pts)
        if np.any(p_cam[:, 2] > -0.3):
            continue
        px, _ = cam.project(p_cam)
        if (np.any(~np.isfinite(px)) or px[:, 0].min() < margin_px or px[:, 0].max() > W - margin_px
                or px[:, 1].min() < margin_px or px[:, 1].max() > H - margin_px):
            continue
        if not _clear_of_scene(scene, p_cam @ R_sc, base @ R_sc):
            continue
        return pose
    raise GeometryError(f"could not place the object inside the frame after {tries} tries")


def _clear_of_scene(scene: BenchScene, p_scene: np.ndarray, base_scene: np.ndarray, gap: float = 0.05) -> bool:
    """True when scene-frame object points stay in front of the walls and off the boxes."""
    for w in scene.walls:
        if w.side == "back" and p_scene[:, 2].min() < -w.distance + gap:
            return False
        if w.side == "left" and p_scene[:, 0].min() < -w.distance + gap:
            return False
        if w.side == "right" and p_scene[:, 0].max() > w.distance - gap:
            return False
    r_obj = float(np.max(np.hypot(p_scene[:, 0] - base_scene[0], p_scene[:, 2] - base_scene[2])))
    for b in scene.boxes:
        if math.hypot(base_scene[0] - b.x, base_scene[2] - b.z) < r_obj + b.radius + gap:
            return False
    return True


def plan_benchmark(settings: BenchmarkSettings, out_dir) -> list[CasePlan]:
    """Draw every case (deterministic for ``settings.seed``); writes procedural GLBs to
    ``OUT/objects/``. Each case has its own generator seeded from the master seed, so a
    case does not change when ``n`` grows."""
    from zcomp_cli.blender.meshes import load_mesh_info

    out_dir = Path(out_dir)
    user = []
    for p in settings.object_paths:
        info = load_mesh_info(p)  # InputError / GeometryError name the file
        user.append(info)
    W, H = settings.resolution
    plans = []
    n_choices = len(settings.shapes) + len(user)
    for i in range(int(settings.n)):
        case_seed = int(np.random.SeedSequence([int(settings.seed), i]).generate_state(1)[0])
        rng = np.random.default_rng(case_seed)
        cid = f"case_{i:04d}"
        scene = sample_scene(rng, W, H)
        if settings.lights == "probe":
            import dataclasses

            scene = dataclasses.replace(scene, lamps=())
        k = int(rng.integers(n_choices))
        if k < len(settings.shapes):
            recipe = sample_recipe(rng, shapes=(settings.shapes[k],))
            name = f"{cid}_{recipe.shape}"
            mesh_path = write_object_glb(recipe, out_dir / "objects" / f"{name}.glb")
            info = load_mesh_info(mesh_path)
        else:
            recipe = None
            info = user[k - len(settings.shapes)]
            mesh_path = info.path
            name = _safe_name(Path(mesh_path).stem)
        pose = place_on_floor(scene, info.vertices, info.bbox_min, info.bbox_max, rng,
                              frame_fraction=settings.frame_fraction)
        plans.append(CasePlan(id=cid, seed=case_seed % (2**31), scene=scene, object_name=name,
                              mesh_path=Path(mesh_path), pose=pose, recipe=recipe,
                              info={"format": info.format, "bbox_min": info.bbox_min.tolist(),
                                    "bbox_max": info.bbox_max.tolist(), "content_hash": info.content_hash}))
    return plans


def _safe_name(s: str) -> str:
    import re

    return re.sub(r"[^A-Za-z0-9_.\-]", "_", s) or "object"


# -- 3. exposure ------------------------------------------------------------------------------

def exposure_scale(image, key: float = 0.8, *, quantile: float = 0.9) -> float:
    """The factor exposing linear ``image`` (H, W, 3) so that its ``quantile`` luminance
    becomes ``key``. Guarded: non-finite pixels are ignored, a black image gives 1, the
    factor is clamped to [1e-3, 1e3]."""
    img = np.asarray(image, dtype=np.float32)
    if img.ndim != 3 or img.shape[-1] != 3:
        raise InputError(f"exposure_scale expects (H, W, 3), got {img.shape}")
    lum = luminance(img)
    lum = lum[np.isfinite(lum)]
    if lum.size == 0:
        return 1.0
    q = float(np.quantile(lum, quantile))
    if not (q > 1e-8):
        return 1.0
    return float(np.clip(key / q, 1e-3, 1e3))


# -- the whole run ----------------------------------------------------------------------------

@dataclass
class BenchmarkResult:
    out_dir: Path
    jobs_yaml: Path
    benchmark_json: Path
    cases: list[dict]


def _prepare_out(out_dir: Path, overwrite: bool) -> None:
    if out_dir.exists() and not out_dir.is_dir():
        raise UsageError(f"output path exists and is not a folder: {out_dir}")
    existing = [p for p in ("jobs.yaml", "benchmark.json", "cases", "objects") if (out_dir / p).exists()]
    if existing and not overwrite:
        raise UsageError(f"{out_dir} already holds a benchmark ({', '.join(existing)}); use --overwrite")
    for p in existing:
        target = out_dir / p
        shutil.rmtree(target) if target.is_dir() else target.unlink()
    out_dir.mkdir(parents=True, exist_ok=True)


def render_items(pl: CasePlan, settings: BenchmarkSettings, tmp) -> tuple[dict, dict]:
    """Blender's two render items of case ``pl`` (``render.render_scenes``): its background
    and its ground truth (the same scene with the object), same samples and seed, their
    passes written under ``tmp/<id>/bg`` and ``tmp/<id>/gt``."""
    common = {"samples": int(settings.samples), "seed": pl.seed, "denoise": bool(settings.denoise),
              "max_bounces": int(settings.max_bounces), "scene": scene_for_blender(pl.scene)}
    M = pl.pose.object_to_camera(pl.info["bbox_min"], pl.info["bbox_max"])
    return ({"id": f"{pl.id}/bg", "out_dir": f"{tmp}/{pl.id}/bg", "object": None, **common},
            {"id": f"{pl.id}/gt", "out_dir": f"{tmp}/{pl.id}/gt", **common,
             "object": {"mesh": str(pl.mesh_path), "format": pl.info["format"], "mesh_to_camera": M.tolist()}})


def generate_benchmark(out_dir, settings: BenchmarkSettings, *, overwrite: bool = False,
                       on_progress: Callable[[int, int, str], None] | None = None) -> BenchmarkResult:
    """Build the benchmark (see the module docstring). ``on_progress(done, total, label)``
    is called as renders finish (two per case)."""
    import tempfile

    from zcomp_cli.benchsuite.render import render_scenes
    from zcomp_cli.imageio import write_exr, write_json_atomic, write_png

    out_dir = Path(out_dir)
    _prepare_out(out_dir, overwrite)
    # 1. plan
    plans = plan_benchmark(settings, out_dir)
    # 2. render: background and GT of every case in one Blender process.
    total = 2 * len(plans)
    done = [0]

    def on_event(ev):
        if ev.get("event") in ("done", "error"):
            done[0] += 1
            if on_progress:
                on_progress(done[0], total, str(ev.get("id")))

    with tempfile.TemporaryDirectory(prefix="zcomp-bench-") as tmp:
        items = [item for pl in plans for item in render_items(pl, settings, tmp)]
        if on_progress:
            on_progress(0, total, "starting Blender")
        maps = render_scenes(items, threads=settings.threads, on_event=on_event,
                             log_path=out_dir / "blender.log")

    # 3. expose and write
    cases = []
    for pl in plans:
        bg, gt = maps[f"{pl.id}/bg"], maps[f"{pl.id}/gt"]
        scale = exposure_scale(bg.image, settings.exposure_key)
        cdir = out_dir / "cases" / pl.id
        image, gt_image = bg.image * scale, gt.image * scale
        write_exr(cdir / "image.exr", image)
        write_png(cdir / "image.png", image)
        write_exr(cdir / "depth.exr", bg.depth)
        write_exr(cdir / "normals.exr", bg.normals)
        write_exr(cdir / "albedo.exr", bg.albedo)
        write_exr(cdir / "gt.exr", gt_image)
        write_png(cdir / "gt.png", gt_image)
        write_exr(cdir / "gt_depth.exr", gt.depth)
        mask = object_mask(bg.depth, gt.depth)
        write_png(cdir / "object_mask.png", mask.astype(np.float32), srgb_encode=False)
        cases.append(_case_record(pl, out_dir, scale, float(mask.mean())))

    # 4. manifests
    jobs_yaml = write_jobs_yaml(out_dir, cases, settings.resolution)
    bench_json = out_dir / "benchmark.json"
    write_json_atomic(bench_json, {
        "version": BENCHMARK_VERSION, "generator": "zcomp make-benchmark",
        "settings": {"n": settings.n, "seed": settings.seed, "resolution": list(settings.resolution),
                     "samples": settings.samples, "denoise": settings.denoise,
                     "max_bounces": settings.max_bounces, "object_paths": list(settings.object_paths),
                     "lights": settings.lights},
        "cases": cases})
    return BenchmarkResult(out_dir=out_dir, jobs_yaml=jobs_yaml, benchmark_json=bench_json, cases=cases)


def object_mask(bg_depth, gt_depth, *, rel_tol: float = 1e-4) -> np.ndarray:
    """Where the inserted object is visible: the GT's pixel-centre surface is nearer than
    the background's (or the background saw nothing there). (H, W) bool."""
    bg = np.asarray(bg_depth, dtype=np.float64)
    gt = np.asarray(gt_depth, dtype=np.float64)
    hit = gt > 0
    nearer = gt < bg * (1.0 - rel_tol)
    return hit & ((bg <= 0) | nearer)


def _rel(path: Path, root: Path) -> str:
    try:
        return Path(path).resolve().relative_to(root.resolve()).as_posix()
    except ValueError:
        return str(Path(path).resolve())


def _case_record(pl: CasePlan, out_dir: Path, exposure: float, mask_fraction: float) -> dict:
    cam = pl.scene.camera
    return {
        "id": pl.id, "seed": pl.seed,
        "scene": pl.scene.to_dict(),
        "camera": {"K": cam.K.tolist(), "width": cam.width, "height": cam.height, "fov_deg": cam.fov_deg},
        "object": {"name": pl.object_name, "mesh": _rel(pl.mesh_path, out_dir),
                   "recipe": pl.recipe.to_dict() if pl.recipe else None, **pl.info},
        "pose": pl.pose.to_dict(),
        "object_to_camera": pl.pose.object_to_camera(pl.info["bbox_min"], pl.info["bbox_max"]).tolist(),
        "exposure": exposure,
        "object_pixels_fraction": mask_fraction,
        "files": {key: f"cases/{pl.id}/{name}" for key, name in (
            ("image", "image.exr"), ("image_preview", "image.png"), ("depth", "depth.exr"),
            ("normals", "normals.exr"), ("albedo", "albedo.exr"), ("gt", "gt.exr"),
            ("gt_preview", "gt.png"), ("gt_depth", "gt_depth.exr"), ("object_mask", "object_mask.png"))},
    }


def write_jobs_yaml(out_dir: Path, cases: list[dict], resolution) -> Path:
    """``OUT/jobs.yaml``: one scene per case (linear EXR image + exact maps), one job per
    case with its pose and ``reference: gt.exr``; validated with zcomp's manifest loader."""
    import yaml

    from zcomp_cli.imageio import write_text_atomic

    scenes, objects, jobs = {}, {}, []
    for c in cases:
        f = c["files"]
        scenes[c["id"]] = {"image": f["image"], "fov_deg": round(float(c["camera"]["fov_deg"]), 6),
                           "depth": f["depth"], "normals": f["normals"], "albedo": f["albedo"]}
        objects.setdefault(c["object"]["name"], {"mesh": c["object"]["mesh"]})
        pose = c["pose"]
        jobs.append({"scene": c["id"], "object": c["object"]["name"],
                     "pose": {"position": [round(v, 6) for v in pose["position"]],
                              "quaternion": [round(v, 8) for v in pose["quaternion"]],
                              "height": round(float(pose["height"]), 6)},
                     "reference": f["gt"]})
    doc = {"version": 1,
           "defaults": {"renderer": "physical", "resolution": [int(resolution[0]), int(resolution[1])],
                        "shading_radius": 1.0, "seed": DEFAULT_SEED},
           "scenes": scenes, "objects": objects, "jobs": jobs}
    path = out_dir / "jobs.yaml"
    header = ("# Written by `zcomp make-benchmark`: one scene and one job per case; each job's\n"
              "# reference is the ground truth rendered by Cycles with the object in the scene.\n")
    write_text_atomic(path, header + yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=120))
    validate_jobs_yaml(path)
    return path


def validate_jobs_yaml(path) -> None:
    """Load ``path`` with zcomp's manifest loader (files checked); raise its error."""
    from zcomp_cli.pipeline.manifest import load_manifest

    load_manifest(path, check_files=True)
