"""`zcomp train CONFIG.yaml`: train the ZeroComp ControlNet."""

from __future__ import annotations

import click


@click.command("train")
@click.argument("config", type=click.Path(dir_okay=False))
@click.option("--no-progress", is_flag=True, help="Disable the progress bar.")
def train(config, no_progress):
    """Train only the ControlNet from CONFIG.yaml (see docs/zerocomp.md)."""
    from zcomp_cli.training.config import load_config
    from zcomp_cli.training.trainer import train as run

    from zcomp_cli.cli.progress import StageProgress

    with StageProgress(disable=no_progress) as prog:
        res = run(load_config(config), progress=prog.update)
    click.echo(f"trained to step {res.step}; last checkpoint: {res.last_checkpoint}")
