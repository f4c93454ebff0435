"""``zcomp import``: the official evaluation sets as zcomp manifests (one sub-command
per archive, each in its own module)."""

from __future__ import annotations

import click

from zcomp_cli.cli.import_spotlight import import_spotlight
from zcomp_cli.cli.import_zerocomp import import_zerocomp


@click.group("import")
def import_group():
    """Import an official evaluation set as a manifest (jobs with their ground truth)."""


import_group.add_command(import_zerocomp)
import_group.add_command(import_spotlight)
