"""``zcomp import spotlight DIR --out jobs.yaml``: SpotLight's test set, with its lights."""

from __future__ import annotations

import click

from zcomp_cli.cli.import_options import import_options, run_and_report


@click.command("spotlight")
@click.argument("src", type=click.Path(exists=True, file_okay=False), metavar="DIR")
@import_options
@click.option("--lights", type=click.Choice(["gt", "all", "none"]), default="gt", show_default=True,
              help="gt: each case lit by its ground-truth light frame (gt_dir) as a lamp; all: one job per "
                   "light frame (only gt_dir has a reference); none: the light is estimated.")
@click.option("--estimates", type=click.Path(exists=True, file_okay=False), default=None, metavar="DIR",
              help="SpotLight's WACV_bg_estimates folder (default: found beside DIR).")
@click.option("--shadows", type=click.Path(exists=True, file_okay=False), default=None, metavar="DIR",
              help="SpotLight's shadows folder (recorded in case.json; default: found beside DIR).")
@click.pass_context
def import_spotlight(ctx, src, **kw):
    """Import SpotLight's test set (DIR: rendered_<date>_control, holding
    <case>/<case>_bundle0001.exr and <case>_light_path_dto.json); see docs/reproduce.md."""
    for key in ("estimates", "shadows"):
        if kw.get(key) is not None:
            from pathlib import Path

            kw[key] = Path(kw[key])
    run_and_report(ctx, "spotlight", src, **kw)
