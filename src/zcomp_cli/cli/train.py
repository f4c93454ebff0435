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

    res = run(load_config(config), progress=not no_progress)
    click.echo(f"trained to step {res.step}; last checkpoint: {res.last_checkpoint}")
