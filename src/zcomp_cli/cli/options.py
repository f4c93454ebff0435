"""Option decorators shared by several commands (the rasterio ``rio`` way)."""

from __future__ import annotations

import click

def check_writable_dir(path, what: str = "--out") -> str | None:
    """Why ``path`` cannot be used as an output folder (None when it can): it, or its
    first existing ancestor, must be a folder where a file can be created. Probes by
    creating (and removing) a file: permission bits lie to root and on /proc or
    read-only mounts. Leaves nothing behind."""
    import os
    import tempfile
    from pathlib import Path

    p = Path(path)
    try:
        if p.exists():
            if not p.is_dir():
                return f"{what}: {p} exists and is not a folder"
            probe_dir = p
        else:
            probe_dir = next((a for a in p.absolute().parents if a.exists()), None)
            if probe_dir is None or not probe_dir.is_dir():
                return f"{what}: no existing folder above {p}"
        fd, tmp = tempfile.mkstemp(prefix=".zcomp-probe.", dir=probe_dir)
        os.close(fd)
        os.unlink(tmp)
        if not p.exists():
            # A folder can be created in some file systems where files cannot (/proc).
            p.mkdir(parents=True)
            created = [p, *[a for a in p.parents if a != probe_dir and probe_dir in a.parents]]
            for d in created:
                d.rmdir()
    except OSError as exc:
        return f"{what}: cannot write in {p}: {exc.strerror or exc}"
    return None


def _check_out(ctx, param, value):
    if value is None:
        return value
    problem = check_writable_dir(value)
    if problem:
        raise click.BadParameter(problem.split(": ", 1)[1], ctx=ctx, param=param)
    return value


out_dir_opt = click.option(
    "--out",
    "out_dir",
    type=click.Path(file_okay=False),
    required=True,
    callback=_check_out,
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
