"""``zcomp preview-light jobs.yaml --out DIR``: see the light before a batch."""

from __future__ import annotations

import click

from zcomp_cli.cli.options import cache_dir_opt, out_dir_opt, overwrite_opt
from zcomp_cli.renderers.cycles.settings import MAX_SAMPLES


@click.command("preview-light")
@click.argument("manifest", type=click.Path(dir_okay=False))
@out_dir_opt
@click.option("--scene", "scenes", multiple=True, metavar="NAME",
              help="Only this scene (repeatable; default: every scene of the manifest).")
@click.option("--pixel", type=(float, float), default=None, metavar="X Y",
              help="Where the balls stand, in the photograph's pixels (default: the scene's first job's "
                   "placement).")
@click.option("--diameter", type=float, default=None, metavar="M",
              help="Each ball's diameter in metres (default: the row spans a quarter of the frame).")
@click.option("--samples", type=click.IntRange(min=1, max=MAX_SAMPLES), default=None,
              help="Cycles samples per pixel, denoised (default 16).")
@overwrite_opt
@cache_dir_opt
@click.pass_context
def preview_light(ctx, manifest, out_dir, scenes, pixel, diameter, samples, overwrite, cache_dir):
    """Render the light of each scene of MANIFEST on three balls (grey, silver, mirror).

    Writes OUT/preview/<scene>.png -- the photograph with the balls composited in, their
    shadows included, beside the balls alone, with the light's numbers (direction as
    azimuth/elevation, size, sun/sky split, uncertainty, where each came from) -- and
    <scene>.json. The light is the one `zcomp composite` will use: given in the manifest
    or estimated. Runs Blender's Cycles (one process for all scenes).
    """
    from rich.console import Console

    from zcomp_cli.cli.progress import StageProgress
    from zcomp_cli.pipeline.manifest import load_manifest
    from zcomp_cli.preview.run import DEFAULT_SAMPLES, preview_light as run

    quiet = bool(ctx.obj and ctx.obj.get("quiet"))
    m = load_manifest(manifest)
    with StageProgress(disable=quiet) as prog:
        results = run(m, out_dir, scenes=list(scenes) or None, pixel_native=pixel, diameter=diameter,
                      samples=samples or DEFAULT_SAMPLES, overwrite=overwrite, cache_dir=cache_dir,
                      progress=prog.update)
    console = Console(stderr=True)
    for r in results:
        if r.error:
            console.print(f"[red]failed[/] scene {r.scene}: {r.error}")
        elif not quiet:
            console.print(f"scene {r.scene}: {r.sheet} ({r.seconds:.1f} s)")
            for line in r.info.get("lines", [])[:4]:
                console.print(f"    {line}", markup=False, highlight=False)
    failed = sum(1 for r in results if r.error)
    console.print(f"{len(results) - failed} sheets written, {failed} failed")
    if failed:
        ctx.exit(1)
