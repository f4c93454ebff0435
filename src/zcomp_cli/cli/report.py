"""``zcomp report OUT``: one self-contained HTML page for an output folder."""

from __future__ import annotations

import click


@click.command("report")
@click.argument("out_dir", metavar="OUT", type=click.Path(file_okay=True, dir_okay=True))
@click.option("--title", default=None, help="The page's title (default: zcomp report: <folder name>).")
@click.option("--page-size", type=click.IntRange(min=1), default=100, show_default=True,
              help="Rows per page when the page opens (the page can change it).")
@click.option("--name", default="report.html", show_default=True,
              help="File name of the page, written inside OUT.")
@click.option("--manifest", type=click.Path(dir_okay=False), default=None,
              help="jobs.yaml: list its jobs that are not in OUT as missing (as `zcomp status --manifest`).")
@click.option("--eval", "eval_file", type=click.Path(dir_okay=False), default=None,
              help="The eval.json (or eval.csv) whose metrics to show (default: OUT/eval.json when there is one).")
@click.option("--verify", is_flag=True,
              help="Check the outputs' sha256, as `zcomp status` does (default: sizes only, faster).")
@click.pass_context
def report(ctx, out_dir, title, page_size, name, manifest, eval_file, verify):
    """Write OUT/report.html: every job of the output folder OUT with its composite and
    background thumbnails, status and failure reason, the light's summary, the metrics
    `zcomp eval` wrote and the time it took, in a table sortable by any column,
    filterable by status and text, paginated; the preview sheets of
    `zcomp preview-light` (OUT/preview/*.png) when there are some. No server and no
    network: open the file in a browser. Images are relative links, so the page works
    while OUT and the scenes' photographs stay where they are."""
    from zcomp_cli.report.write import write_report

    path, col = write_report(out_dir, name=name, title=title, page_size=page_size, manifest=manifest,
                             eval_file=eval_file, verify=verify)
    counts = ", ".join(f"{n} {s}" for s, n in col.counts.items()) or "no jobs"
    extra = []
    if col.metrics:
        extra.append(f"metrics {', '.join(col.metrics)}")
    if col.previews:
        extra.append(f"{len(col.previews)} preview sheet{'s' if len(col.previews) != 1 else ''}")
    n = len(col.rows)
    click.echo(f"Wrote {path}: {n} job{'s' if n != 1 else ''} ({counts})" + (f"; {'; '.join(extra)}" if extra else ""))
    if col.notes and not (ctx.obj or {}).get("quiet"):
        click.secho(f"{len(col.notes)} note{'s' if len(col.notes) != 1 else ''} (listed on the page), e.g. "
                    f"{col.notes[0]}", fg="yellow", err=True)
