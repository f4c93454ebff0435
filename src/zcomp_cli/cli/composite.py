"""``zcomp composite jobs.yaml --out DIR``: the product's main job."""

from __future__ import annotations

import click

from zcomp_cli.cli.options import (aovs_opt, cache_dir_opt, debug_opt, out_dir_opt, overwrite_opt, renderer_options,
                                   renderer_spec, resume_opt, seed_opt)


@click.command("composite")
@click.argument("manifest", type=click.Path(dir_okay=False))
@out_dir_opt
@renderer_options
@click.option("--jobs", "jobs_subset", default=None, metavar="SUBSET",
              help="Only these jobs: indices, ranges a-b and names, comma-separated.")
@click.option("--shard", default=None, metavar="I/N",
              help="Run only shard I of N (from 0) of the selected jobs; jobs of one scene stay together. "
                   "Shards may run side by side into one --out; `zcomp status OUT` merges them.")
@click.option("--executor", type=click.Choice(["local", "ray"]), default="local", show_default=True,
              help="Where jobs run: this process, or a Ray cluster (needs `pip install 'zcomp[ray]'`; "
                   "--out must be on a filesystem every Ray worker sees).")
@click.option("--address", default=None, metavar="auto|HOST:PORT",
              help="Ray cluster to join (default: $RAY_ADDRESS, else a local Ray started for this run).")
@click.option("--workers", type=click.IntRange(min=1), default=None,
              help="Ray: how many workers (actors, one renderer each; default: as many as the cluster's "
                   "CPUs, or GPUs for zerocomp, allow).")
@seed_opt
@resume_opt
@click.option("--redo-changed", is_flag=True,
              help="With --resume: redo the finished jobs whose inputs or settings changed (exactly "
                   "those; the unchanged ones are skipped). Without it, --resume refuses to go on.")
@overwrite_opt
@debug_opt
@aovs_opt
@cache_dir_opt
@click.pass_context
def composite(ctx, manifest, out_dir, renderer, renderer_flags, jobs_subset, shard, executor, address, workers,
              seed, resume, redo_changed, overwrite, debug, aovs, cache_dir):
    """Composite objects into scenes for every job of MANIFEST (jobs.yaml).

    Each job writes OUT/<job>/composite.png (sRGB), composite.exr (linear) and
    report.json (with --aovs also aovs.exr, the render passes); a failed job is reported
    and the batch goes on (exit code 1 at the end).
    """
    from zcomp_cli.errors import UsageError
    from zcomp_cli.pipeline.batch import run_batch
    from zcomp_cli.pipeline.manifest import load_manifest

    from zcomp_cli.pipeline.selection import parse_shard

    if resume and overwrite:
        raise UsageError("--resume and --overwrite exclude each other")
    if redo_changed and not resume:
        raise UsageError("--redo-changed goes with --resume (--overwrite redoes every job)")
    shard_ix = parse_shard(shard)
    if executor == "local" and (address is not None or workers is not None):
        raise UsageError("--address and --workers apply to --executor ray")
    runner = None
    if executor == "ray":
        from zcomp_cli.pipeline.ray_executor import RayExecutor

        runner = RayExecutor(address=address, workers=workers)
    quiet = bool(ctx.obj and ctx.obj.get("quiet"))
    m = load_manifest(manifest)
    spec = renderer_spec(m.defaults.renderer, renderer, renderer_flags)
    if seed is not None:
        for job in m.jobs:
            job.seed = seed

    from zcomp_cli.cli.progress import StageProgress

    try:
        with StageProgress(disable=quiet) as prog:
            summary = run_batch(m, out_dir, renderer_spec=spec, jobs_subset=jobs_subset, resume=resume,
                                redo_changed=redo_changed, overwrite=overwrite, debug=debug, aovs=aovs,
                                cache_dir=cache_dir, shard=shard_ix, executor=runner, progress=prog.update)
    except KeyboardInterrupt as exc:
        exc.zcomp_reported = _print_interrupted(getattr(exc, "zcomp_summary", None), out_dir)
        raise
    _print_summary(summary, out_dir, quiet)
    if not summary.ok:
        ctx.exit(1)


def _print_interrupted(doc: dict | None, out_dir) -> bool:
    """After Ctrl-C, SIGTERM or SIGHUP: what is on disk, as the rewritten summary says
    (True when said)."""
    import click

    if not doc:
        return False
    mine = doc.get("this_run") or {}
    click.echo(f"\nInterrupted. On disk in {out_dir}: {doc.get('done', 0)} done, {doc.get('failed', 0)} failed, "
               f"{doc.get('pending', 0)} pending ({mine.get('done', 0)} done and {mine.get('failed', 0)} failed by "
               f"this run); {out_dir}/summary.json lists them. `--resume` finishes the rest.", err=True)
    return True


def _print_summary(summary, out_dir, quiet: bool) -> None:
    from rich.console import Console
    from rich.table import Table

    console = Console(stderr=True)
    if not quiet:
        table = Table(title=f"zcomp composite -> {out_dir}", show_lines=False)
        table.add_column("#", justify="right")
        table.add_column("job")
        table.add_column("status")
        table.add_column("seconds", justify="right")
        table.add_column("reason", overflow="fold")
        colours = {"done": "green", "skipped": "yellow", "failed": "red"}
        for s in summary.statuses:
            table.add_row(str(s.job.index), s.job.name, f"[{colours[s.status]}]{s.status}[/]",
                          f"{s.seconds:.2f}", s.reason or "")
        console.print(table)
    line = (f"{summary.count('done')} done, {summary.count('skipped')} skipped, "
            f"{summary.count('failed')} failed in {summary.seconds:.1f} s")
    console.print(line if summary.ok else f"[red]{line}[/]")
    if not summary.ok and quiet:
        for s in summary.statuses:
            if s.status == "failed":
                console.print(f"[red]failed[/] {s.job.name}: {s.reason}")
