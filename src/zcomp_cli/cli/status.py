"""``zcomp status OUT``: one summary of an output folder, over every run and shard."""

from __future__ import annotations

import click


@click.command("status")
@click.argument("out_dir", type=click.Path(file_okay=False))
@click.option("--manifest", type=click.Path(dir_okay=False), default=None,
              help="jobs.yaml: count its jobs that are in no summary yet as missing.")
@click.option("--jobs", "jobs_subset", default=None, metavar="SUBSET",
              help="With --manifest: only these jobs (as for composite).")
@click.option("--json", "as_json", is_flag=True, help="Print the merged state as JSON.")
@click.pass_context
def status(ctx, out_dir, manifest, jobs_subset, as_json):
    """Merge OUT's job reports and run/shard summaries: done, failed (with reasons)
    and missing jobs. Exit code 0 when every expected job is done, 1 otherwise."""
    import json

    from zcomp_cli.pipeline.status import folder_status

    expected = None
    if manifest is not None:
        from zcomp_cli.pipeline.manifest import load_manifest
        from zcomp_cli.pipeline.selection import select_jobs

        expected = [j.name for j in select_jobs(load_manifest(manifest).jobs, jobs_subset)]
    st = folder_status(out_dir, expected)
    if as_json:
        click.echo(json.dumps(st.to_dict(), indent=2))
    else:
        from rich.console import Console

        console = Console()
        console.print(f"{out_dir}: {len(st.done)} done, {len(st.failed)} failed, {len(st.missing)} missing")
        for k, v in st.shards.items():
            console.print(f"  shard {k}: {v}")
        for name, reason in st.failed.items():
            console.print(f"  [red]failed[/] {name}: {reason}")
        for name in st.missing[:50]:
            console.print(f"  [yellow]missing[/] {name}")
        if len(st.missing) > 50:
            console.print(f"  ... and {len(st.missing) - 50} more missing")
    if not st.complete:
        ctx.exit(1)
