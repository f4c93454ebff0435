"""Option decorators shared by several commands (the rasterio ``rio`` way)."""

from __future__ import annotations

import click

out_dir_opt = click.option(
    "--out",
    "out_dir",
    type=click.Path(file_okay=False),
    required=True,
    help="Output directory.",
)
overwrite_opt = click.option(
    "--overwrite", is_flag=True, help="Replace outputs that already exist."
)
resume_opt = click.option(
    "--resume", is_flag=True, help="Skip items whose outputs are already complete."
)
fov_opt = click.option(
    "--fov-deg",
    type=float,
    default=None,
    help="Horizontal field of view in degrees (default 50).",
)
K_opt = click.option(
    "--K",
    "K",
    type=str,
    default=None,
    help="Intrinsics as 'fx,fy,cx,cy' in pixels (overrides --fov-deg).",
)
resolution_opt = click.option(
    "--resolution",
    type=(int, int),
    default=None,
    metavar="W H",
    help="Image size in pixels.",
)
seed_opt = click.option("--seed", type=int, default=None, help="Random seed (default 469).")
debug_opt = click.option(
    "--debug", is_flag=True, help="Also write intermediate maps and a debug grid."
)


def parse_K(text: str | None):
    """Parse 'fx,fy,cx,cy' into a 3x3 list, or None."""
    if text is None:
        return None
    try:
        fx, fy, cx, cy = (float(v) for v in text.split(","))
    except ValueError as exc:
        raise click.BadParameter("expected 'fx,fy,cx,cy'", param_hint="--K") from exc
    return [[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]
