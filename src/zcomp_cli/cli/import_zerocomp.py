"""``zcomp import zerocomp DIR --out jobs.yaml``: ZeroComp's test set (labo.zip)."""

from __future__ import annotations

import click

from zcomp_cli.cli.import_options import import_options, run_and_report


@click.command("zerocomp")
@click.argument("src", type=click.Path(exists=True, file_okay=False), metavar="DIR")
@import_options
@click.pass_context
def import_zerocomp(ctx, src, **kw):
    """Import ZeroComp's test set (DIR: the unzipped labo archive, or its folder of
    <case>/<case>_bundle0001.exr) with the paper's settings; see docs/reproduce.md."""
    run_and_report(ctx, "zerocomp", src, **kw)
