"""``zcomp render-intrinsics``: object intrinsics bundles rendered by headless Blender.

Two forms::

    zcomp render-intrinsics --mesh chair.glb --position 0 -1 -3 --rotation-deg 0 30 0 \\
        --height 0.9 --fov-deg 50 --resolution 512 512 --out out/chair
    zcomp render-intrinsics objects.yaml --out out/intrinsics

The YAML form (mesh paths relative to the YAML file)::

    objects:                      # name -> mesh path (or {mesh: path})
      chair: meshes/chair.glb
    cameras:                      # name -> fov_deg or K, and resolution [W, H]
      main: {fov_deg: 50, resolution: [512, 512]}
      calib: {K: [[500, 0, 320], [0, 500, 240], [0, 0, 1]], resolution: [640, 480]}
    renders:                      # one bundle each, written to OUT/<name>/
      - object: chair
        camera: main
        pose: {position: [0, -1, -3], rotation_deg: [0, 30, 0], height: 0.9}
        name: chair_front         # optional; default <object>_<index>

Exit codes: 0 all rendered, 1 some item failed (each named with its reason), 2 usage
or manifest errors (every problem listed with its location, nothing rendered).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import click

from zcomp_cli.cli.options import (K_opt, cache_dir_opt, fov_opt, out_dir_opt, overwrite_opt, parse_K,
                                   resolution_opt)

_TOP_KEYS = {"objects", "cameras", "renders"}
_CAMERA_KEYS = {"fov_deg", "K", "resolution"}
_RENDER_KEYS = {"object", "camera", "pose", "name"}


@dataclass
class _Job:
    """One output folder to produce; ``error`` set when it cannot even be requested."""

    name: str
    mesh: Path | None = None
    pose: object = None
    camera: object = None
    error: str | None = None


def _camera_from_spec(fov_deg, K, resolution, where: str):
    """Build a Camera; returns (camera, None) or (None, message naming ``where``)."""
    import numpy as np

    from zcomp_cli.camera import DEFAULT_FOV_DEG, Camera
    from zcomp_cli.conventions import K_from_fov

    try:
        w, h = (int(v) for v in resolution)
        if w <= 0 or h <= 0:
            return None, f"{where}: resolution must be positive, got {w}x{h}"
        if K is not None:
            K = np.asarray(K, dtype=np.float64)
            if K.shape == (4,):
                fx, fy, cx, cy = K
                K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]], dtype=np.float64)
            return Camera(K, w, h), None
        fov = DEFAULT_FOV_DEG if fov_deg is None else float(fov_deg)
        return Camera(K_from_fov(fov, w, h), w, h), None
    except (TypeError, ValueError) as exc:
        return None, f"{where}: invalid camera: {exc}"


def _is_vec(v, n) -> bool:
    return isinstance(v, (list, tuple)) and len(v) == n and all(
        isinstance(x, (int, float)) and not isinstance(x, bool) for x in v)


def load_manifest(path) -> list[_Job]:
    """Parse and validate an objects YAML. Structural problems (missing or unknown keys,
    wrong types, unknown references, invalid poses, repeated names) are collected and
    raised together as one ManifestError; value problems that concern one item (a
    zero-size resolution, a missing mesh file) become that item's error instead, so
    the other items still render."""
    from zcomp_cli.errors import ManifestError
    from zcomp_cli.pose import Pose
    from zcomp_cli.yamlloc import load_yaml

    path = Path(path)
    src = str(path)
    doc = load_yaml(path)  # ManifestError naming the file (and the line of a syntax error)
    if not isinstance(doc, dict):
        raise ManifestError("top level must be a mapping with objects, cameras, renders", source=src)
    problems: list[str] = []
    for k in doc:
        if k not in _TOP_KEYS:
            problems.append(f"{k}: unknown key (expected {sorted(_TOP_KEYS)})")
    for k in ("objects", "cameras"):
        if not isinstance(doc.get(k), dict) or not doc.get(k):
            problems.append(f"{k}: required, a non-empty mapping of name -> entry")
    if not isinstance(doc.get("renders"), list) or not doc.get("renders"):
        problems.append("renders: required, a non-empty list")
    objects = doc.get("objects") if isinstance(doc.get("objects"), dict) else {}
    cameras = doc.get("cameras") if isinstance(doc.get("cameras"), dict) else {}
    renders = doc.get("renders") if isinstance(doc.get("renders"), list) else []

    meshes: dict[str, Path] = {}
    for name, entry in objects.items():
        where = f"objects.{name}"
        if isinstance(entry, dict):
            unknown = [k for k in entry if k != "mesh"]
            problems += [f"{where}.{k}: unknown key (expected ['mesh'])" for k in unknown]
            entry = entry.get("mesh")
        if not isinstance(entry, str) or not entry:
            problems.append(f"{where}: expected a mesh path (or {{mesh: path}})")
            continue
        p = Path(entry).expanduser()
        meshes[str(name)] = p if p.is_absolute() else (path.parent / p)

    cams: dict[str, tuple] = {}
    for name, entry in cameras.items():
        where = f"cameras.{name}"
        if not isinstance(entry, dict):
            problems.append(f"{where}: expected a mapping with fov_deg or K, and resolution")
            continue
        problems += [f"{where}.{k}: unknown key (expected {sorted(_CAMERA_KEYS)})"
                     for k in entry if k not in _CAMERA_KEYS]
        if "fov_deg" in entry and "K" in entry:
            problems.append(f"{where}: give fov_deg or K, not both")
        if not _is_vec(entry.get("resolution"), 2) or not all(float(v).is_integer() for v in entry["resolution"]):
            problems.append(f"{where}.resolution: required, [width, height] in pixels")
            continue
        K = entry.get("K")
        if K is not None and not (_is_vec(K, 4) or (isinstance(K, list) and len(K) == 3
                                                   and all(_is_vec(r, 3) for r in K))):
            problems.append(f"{where}.K: expected [[fx,0,cx],[0,fy,cy],[0,0,1]] or [fx, fy, cx, cy]")
            continue
        fov = entry.get("fov_deg")
        if fov is not None and (isinstance(fov, bool) or not isinstance(fov, (int, float))):
            problems.append(f"{where}.fov_deg: expected a number of degrees")
            continue
        cams[str(name)] = (fov, K, entry["resolution"])

    jobs: list[_Job] = []
    names: dict[str, int] = {}
    for i, r in enumerate(renders):
        where = f"renders[{i}]"
        if not isinstance(r, dict):
            problems.append(f"{where}: expected a mapping with object, camera, pose")
            continue
        problems += [f"{where}.{k}: unknown key (expected {sorted(_RENDER_KEYS)})"
                     for k in r if k not in _RENDER_KEYS]
        obj, cam = r.get("object"), r.get("camera")
        if obj is None:
            problems.append(f"{where}.object: required")
        elif str(obj) not in objects:
            problems.append(f"{where}.object: unknown object {obj!r} (known: {sorted(map(str, objects))})")
        if cam is None:
            problems.append(f"{where}.camera: required")
        elif str(cam) not in cameras:
            problems.append(f"{where}.camera: unknown camera {cam!r} (known: {sorted(map(str, cameras))})")
        pose = None
        if "pose" not in r:
            problems.append(f"{where}.pose: required")
        else:
            try:
                pose = Pose.from_dict(r["pose"], where=f"{where}.pose")
            except ManifestError as exc:
                problems += exc.problems
        name = str(r.get("name") or f"{obj}_{i:03d}")
        if "/" in name or "\\" in name or name in (".", ".."):
            problems.append(f"{where}.name: {name!r} is not a plain folder name")
        if name in names:
            problems.append(f"{where}.name: {name!r} already used by renders[{names[name]}]")
        names.setdefault(name, i)
        if obj is None or str(obj) not in meshes or cam is None or str(cam) not in cams or pose is None:
            continue
        camera, err = _camera_from_spec(*cams[str(cam)], where=f"cameras.{cam}")
        jobs.append(_Job(name=name, mesh=meshes[str(obj)], pose=pose, camera=camera,
                         error=f"{where}: {err}" if err else None))
    if problems:
        raise ManifestError(problems, source=src)
    return jobs


def _single_job(mesh, position, rotation_deg, quaternion, scale, height, fov_deg, K_text, resolution) -> _Job:
    from zcomp_cli.errors import UsageError
    from zcomp_cli.pose import Pose, euler_deg_to_matrix, quaternion_to_matrix

    if position is None:
        raise UsageError("--position X Y Z is required with --mesh (camera frame, metres; in front: Z < 0)")
    if rotation_deg is not None and quaternion is not None:
        raise UsageError("give --rotation-deg or --quaternion, not both")
    try:
        R = quaternion_to_matrix(quaternion) if quaternion is not None else euler_deg_to_matrix(*(rotation_deg or (0, 0, 0)))
        pose = Pose(position=tuple(position), rotation=R, scale=scale, height=height)
    except ValueError as exc:
        raise UsageError(f"invalid pose: {exc}") from exc
    K = parse_K(K_text)
    res = resolution or (512, 512)
    name = Path(mesh).stem
    camera, err = _camera_from_spec(fov_deg, K, res, where="camera")
    return _Job(name=name, mesh=Path(mesh), pose=pose, camera=camera, error=err)


@click.command("render-intrinsics")
@click.argument("manifest", required=False, type=click.Path(dir_okay=False))
@click.option("--mesh", type=click.Path(dir_okay=False), default=None, help="One mesh (OBJ, GLB/GLTF, PLY, STL) instead of a YAML.")
@click.option("--position", type=(float, float, float), default=None, metavar="X Y Z",
              help="Base point of the object in the camera frame, metres (x right, y up, in front: z < 0).")
@click.option("--rotation-deg", type=(float, float, float), default=None, metavar="RX RY RZ",
              help="Rotation about the camera's x, then y, then z axes, degrees.")
@click.option("--quaternion", type=(float, float, float, float), default=None, metavar="W X Y Z",
              help="Rotation as a quaternion (instead of --rotation-deg).")
@click.option("--scale", type=float, default=1.0, show_default=True, help="Uniform scale of the mesh.")
@click.option("--height", type=float, default=None, help="Scale the mesh so its vertical extent is this many metres.")
@fov_opt
@K_opt
@resolution_opt
@out_dir_opt
@click.option("--samples", type=click.IntRange(min=1), default=None, help="Cycles samples of the anti-aliased pass (default 16).")
@click.option("--no-cache", is_flag=True, help="Render everything and leave the cache alone.")
@cache_dir_opt
@overwrite_opt
@click.pass_context
def render_intrinsics(ctx, manifest, mesh, position, rotation_deg, quaternion, scale, height, fov_deg, K,
                      resolution, out_dir, samples, no_cache, cache_dir, overwrite):
    """Render object intrinsics (depth, normals, albedo, mask, footprint) with Blender.

    MANIFEST is an objects YAML (objects, cameras, renders); or give one object with
    --mesh and its pose. Each bundle goes to OUT/<name>/.
    """
    from zcomp_cli.errors import UsageError

    quiet = bool((ctx.obj or {}).get("quiet"))
    if (manifest is None) == (mesh is None):
        raise UsageError("give either an objects YAML or --mesh (not both)")
    if manifest is not None:
        used = [n for n, v in (("--position", position), ("--rotation-deg", rotation_deg),
                               ("--quaternion", quaternion), ("--height", height), ("--fov-deg", fov_deg),
                               ("--K", K), ("--resolution", resolution)) if v is not None]
        if used:
            raise UsageError(f"{', '.join(used)} only apply with --mesh; the YAML sets poses and cameras")
        jobs = load_manifest(manifest)
    else:
        jobs = _single_job(mesh, position, rotation_deg, quaternion, scale, height, fov_deg, K, resolution)
        jobs = [jobs]
    out = Path(out_dir)
    existing = [j.name for j in jobs if (out / j.name / "meta.json").exists()]
    if existing and not overwrite:
        raise UsageError(f"outputs already exist for {', '.join(existing[:5])}"
                         f"{' ...' if len(existing) > 5 else ''} in {out}; pass --overwrite to replace them")
    failures = run_jobs(jobs, out, samples=samples, use_cache=not no_cache, cache_dir=cache_dir, quiet=quiet)
    if failures:
        from zcomp_cli.errors import RenderError

        # A typed error, not ctx.exit(1): zcomp's main() runs click with
        # standalone_mode=False, which swallows click's Exit codes.
        raise RenderError(f"{failures} of {len(jobs)} item(s) failed (see above)")


def run_jobs(jobs: list[_Job], out: Path, *, samples, use_cache, cache_dir, quiet) -> int:
    """Render ``jobs`` with a progress bar, print a summary; returns the failure count."""
    from rich.console import Console
    from rich.markup import escape
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from zcomp_cli.blender.intrinsics import DEFAULT_SAMPLES, IntrinsicsRequest, render_object_intrinsics

    console = Console(stderr=True)
    failed = [(j.name, j.error) for j in jobs if j.error]
    todo = [j for j in jobs if not j.error]
    requests = [IntrinsicsRequest(j.name, j.mesh, j.pose, j.camera, out / j.name) for j in todo]
    results = []
    if requests:
        with Progress(TextColumn("render-intrinsics"), BarColumn(), MofNCompleteColumn(),
                      TextColumn("{task.fields[item]}"), TimeElapsedColumn(),
                      console=console, disable=quiet, transient=True) as bar:
            task = bar.add_task("render", total=len(requests), item="")
            results = render_object_intrinsics(
                requests, cache_dir=cache_dir, samples=samples or DEFAULT_SAMPLES, use_cache=use_cache,
                progress=lambda done, total, iid: bar.update(task, completed=done, item=iid))
    n_cached = sum(1 for r in results if r.ok and r.cached)
    n_done = sum(1 for r in results if r.ok)
    failed += [(r.id, r.error) for r in results if not r.ok]
    out_console = Console()
    out_console.print(f"render-intrinsics: {n_done} done ({n_cached} from cache), {len(failed)} failed -> {out}",
                      soft_wrap=True, highlight=False)
    for name, err in failed:
        console.print(f"[red]failed[/red] {escape(str(name))}: {escape(str(err))}", highlight=False, soft_wrap=True)
    return len(failed)
