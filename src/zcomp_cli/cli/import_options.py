"""Options shared by the ``zcomp import`` commands (validated in callbacks)."""

from __future__ import annotations

import functools

import click


def _check_depth_model(ctx, param, value):
    if value is None:
        return None
    from zcomp_cli.errors import WeightsError
    from zcomp_cli.estimators.learned import check_model_dir

    try:
        return check_model_dir(value)
    except WeightsError as exc:
        raise click.BadParameter(str(exc), ctx=ctx, param=param) from exc


def import_options(f):
    """--out, --maps, --depth-model, --limit, --cases, --overwrite, --bundle-normals."""

    @click.option("--out", "out", type=click.Path(dir_okay=False), required=True, metavar="JOBS.yaml",
                  help="The manifest to write; the converted cases go to JOBS_data/ beside it.")
    @click.option("--maps", type=click.Choice(["paper", "provided", "estimated"]), default="paper",
                  show_default=True,
                  help="Background maps: paper (depth from --depth-model, i.e. ZoeDepth, as the paper; the "
                       "archive's normals and albedo), provided (all from the archive), estimated (zcomp's "
                       "estimators: depth from --depth-model, normals from depth, Retinex albedo).")
    @click.option("--depth-model", type=click.Path(file_okay=False), default=None, callback=_check_depth_model,
                  metavar="DIR", help="A local transformers depth model for --maps paper/estimated "
                                      "(the paper: ZoeDepth NK, Intel/zoedepth-nyu-kitti).")
    @click.option("--limit", type=click.IntRange(min=1), default=None, metavar="N",
                  help="Only the first N cases (in name order, after --cases).")
    @click.option("--cases", "cases", default=None, metavar="GLOB",
                  help="Only the cases whose name matches GLOB (e.g. '9C4A*').")
    @click.option("--bundle-normals", type=click.Choice(["blender-camera", "opengl"]), default=None,
                  help="Read the bundles' normals in this frame instead of the official loader's "
                       "(blender-camera: z negated).")
    @click.option("--overwrite", is_flag=True, help="Replace an earlier import at --out.")
    @functools.wraps(f)
    def wrapper(*args, **kwargs):
        return f(*args, **kwargs)

    return wrapper


def run_and_report(ctx, archive_key: str, src, **kw) -> None:
    """Run one import with a progress bar, print what was imported and what failed,
    exit 1 when a case failed (the manifest then holds the others)."""
    from pathlib import Path

    from rich.console import Console
    from rich.markup import escape

    from zcomp_cli.cli.progress import StageProgress
    from zcomp_cli.datasets.importer import ARCHIVES, ImportOptions, run_import
    from zcomp_cli.limits import printable

    opts = ImportOptions(src=Path(src), out=Path(kw.pop("out")), **kw)
    quiet = bool(ctx.obj and ctx.obj.get("quiet"))
    with StageProgress(disable=quiet) as prog:
        res = run_import(ARCHIVES[archive_key], opts,
                         progress=lambda i, n, label: prog.update("cases", i, n, printable(label)), warn=prog.warn)
    console = Console(stderr=True, soft_wrap=True)  # paths stay whole, copy-pasteable
    for name, why in res.failed.items():
        console.print(f"[red]failed[/] {escape(printable(name))}: {escape(why)}", highlight=False)
    n = len(res.imported)
    line = (f"{n} case{'s' * (n != 1)} imported ({res.jobs} job{'s' * (res.jobs != 1)}), {len(res.failed)} failed, "
            f"from {printable(res.root)}: wrote {printable(res.manifest)} and {printable(res.data_dir)}/")
    console.print(line if not res.failed else f"[yellow]{line}[/]", highlight=False)
    if res.failed:
        ctx.exit(1)
