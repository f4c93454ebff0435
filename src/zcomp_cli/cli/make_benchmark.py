"""``zcomp make-benchmark``: test cases with ground truth rendered physically by Cycles.

    zcomp make-benchmark OUT --n 20 --seed 0 --resolution 512 512 --samples 128 \\
        --objects my_chair.glb --objects lamp.obj

Writes ``OUT/cases/<id>/`` (background image and its exact maps, ground-truth
composite), ``OUT/objects/``, ``OUT/jobs.yaml`` (ready for ``zcomp composite``, each job
with ``reference:`` = its ground truth) and ``OUT/benchmark.json``.
"""

from __future__ import annotations

import click


@click.command("make-benchmark")
@click.argument("out", type=click.Path(file_okay=False))
@click.option("--n", "n", type=int, default=10, show_default=True, help="Number of cases.")
@click.option("--seed", type=int, default=0, show_default=True, help="Master seed (same seed, same benchmark).")
@click.option("--resolution", type=(int, int), default=(512, 512), show_default=True, metavar="W H",
              help="Image size in pixels.")
@click.option("--samples", type=int, default=128, show_default=True, help="Cycles samples per render.")
@click.option("--denoise/--no-denoise", default=True, show_default=True,
              help="OpenImageDenoise on the renders (background and ground truth alike).")
@click.option("--objects", "objects", multiple=True, type=click.Path(exists=True, dir_okay=False),
              help="A mesh (GLB/glTF/OBJ/PLY/STL, metres, Y-up) added to the procedural shapes; repeatable.")
@click.option("--no-procedural", is_flag=True, help="Use only the meshes given with --objects.")
@click.option("--lights", type=click.Choice(["mixed", "probe"]), default="mixed", show_default=True,
              help="mixed: an HDR map with a sun or an area lamp or neither; probe: the same scenes lit by "
                   "their HDR map alone.")
@click.option("--threads", type=int, default=0, show_default=True, help="Cycles CPU threads (0 = all).")
@click.option("--overwrite", is_flag=True, help="Replace a benchmark already in OUT.")
@click.pass_context
def make_benchmark(ctx, out, n, seed, resolution, samples, denoise, objects, no_procedural, lights, threads,
                   overwrite):
    """Build a benchmark in OUT with physically rendered ground truth."""
    from zcomp_cli.benchsuite.generate import BenchmarkSettings, generate_benchmark
    from zcomp_cli.benchsuite.objects import SHAPES
    from zcomp_cli.cli.progress import StageProgress

    settings = BenchmarkSettings(n=n, seed=seed, resolution=tuple(resolution), samples=samples,
                                 denoise=denoise, object_paths=tuple(objects),
                                 shapes=() if no_procedural else SHAPES, threads=threads, lights=lights)
    quiet = bool((ctx.obj or {}).get("quiet"))
    with StageProgress(disable=quiet) as prog:
        result = generate_benchmark(out, settings, overwrite=overwrite,
                                    on_progress=lambda d, t, label: prog.update("render", d, t, label))
    click.echo(f"{len(result.cases)} cases written to {result.out_dir} "
               f"(jobs: {result.jobs_yaml}, description: {result.benchmark_json})")
