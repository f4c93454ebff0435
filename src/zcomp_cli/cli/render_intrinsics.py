"""``zcomp render-intrinsics``: object intrinsics bundles rendered by headless Blender.

Two forms::

    zcomp render-intrinsics --mesh chair.glb --position 0 -1 -3 --rotation-deg 0 30 0 \\
        --height 0.9 --fov-deg 50 --resolution 512 512 --out out/chair
    zcomp render-intrinsics objects.yaml --out out/intrinsics

The YAML form is parsed by ``pipeline.objects_manifest``. Exit codes: 0 all rendered, 1
some item failed (each named with its reason), 2 usage or manifest errors (every
problem listed with its file and line, nothing rendered).
"""

from __future__ import annotations

from pathlib import Path

import click

from zcomp_cli.blender import DEFAULT_SAMPLES
from zcomp_cli.cli.options import (K_opt, cache_dir_opt, fov_opt, out_dir_opt, overwrite_opt, parse_K,
                                   resolution_opt)

def _single_job(mesh, position, rotation_deg, quaternion, scale, height, fov_deg, K_text, resolution):
    from zcomp_cli.errors import UsageError
    from zcomp_cli.pipeline.objects_manifest import DEFAULT_RESOLUTION, RenderItem, camera_from_spec
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
    camera, err = camera_from_spec(fov_deg, K, resolution or DEFAULT_RESOLUTION,
                                   where="--resolution" if resolution else "camera")
    if err:
        raise UsageError(err)  # a bad flag: refused before Blender starts
    return RenderItem(name=Path(mesh).stem, mesh=Path(mesh), pose=pose, camera=camera, error=err)


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
@click.option("--samples", type=click.IntRange(min=1), default=None,
              help=f"Cycles samples of the anti-aliased pass (default {DEFAULT_SAMPLES}).")
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
        from zcomp_cli.pipeline.objects_manifest import load_objects_manifest

        jobs = load_objects_manifest(manifest)
    else:
        jobs = _single_job(mesh, position, rotation_deg, quaternion, scale, height, fov_deg, K, resolution)
        jobs = [jobs]
    out = Path(out_dir)
    from zcomp_cli.pipeline.outguard import check_inside

    for j in jobs:  # every folder written must stay inside --out
        check_inside(out, out / j.name, f"renders: {j.name}")
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


def run_jobs(jobs: list, out: Path, *, samples, use_cache, cache_dir, quiet) -> int:
    """Render ``jobs`` with a progress bar, print a summary; returns the failure count."""
    from rich.console import Console
    from rich.markup import escape
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from zcomp_cli.blender.intrinsics import IntrinsicsRequest, render_object_intrinsics

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
