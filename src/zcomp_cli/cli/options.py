"""Option decorators shared by several commands (the rasterio ``rio`` way)."""

from __future__ import annotations

import functools

import click

def check_writable_dir(path, what: str = "--out") -> str | None:
    """Why ``path`` cannot be used as an output folder (None when it can): it, or its
    first existing ancestor, must be a folder where a file can be created. Probes by
    creating (and removing) a file: permission bits lie to root and on /proc or
    read-only mounts. Leaves nothing behind."""
    import os
    import tempfile
    from pathlib import Path

    p = Path(path).absolute()
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
            # The folder itself is made by the command. Probe with a private folder of
            # our own: creating and removing ``p`` here would race with a second run
            # (a shard) starting into the same new --out.
            os.rmdir(tempfile.mkdtemp(prefix=".zcomp-probe.", dir=probe_dir))
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
def _check_fov(ctx, param, value):
    import math

    if value is not None and not (math.isfinite(value) and 0 < value < 180):
        raise click.BadParameter(f"expected degrees in (0, 180), got {value}", ctx=ctx, param=param)
    return value


def _check_resolution(ctx, param, value):
    """[W, H]: at least MIN_RENDER_SIDE pixels a side (Blender's smallest image) and
    within the pixel budget -- refused here, before Blender starts."""
    if value is None:
        return value
    from zcomp_cli.errors import UsageError
    from zcomp_cli.limits import pixel_budget_problem
    from zcomp_cli.pipeline.manifest import MIN_RENDER_SIDE

    w, h = value
    if min(w, h) < MIN_RENDER_SIDE:
        raise click.BadParameter(f"{w}x{h} is too small: Blender renders at least {MIN_RENDER_SIDE}x"
                                 f"{MIN_RENDER_SIDE} pixels", ctx=ctx, param=param)
    try:
        budget = pixel_budget_problem(w, h)
    except UsageError as exc:  # a bad $ZCOMP_MAX_PIXELS
        raise click.BadParameter(str(exc), ctx=ctx, param=param) from None
    if budget:
        raise click.BadParameter(budget, ctx=ctx, param=param)
    return value


fov_opt = click.option(
    "--fov-deg",
    type=float,
    default=None,
    callback=_check_fov,
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
    callback=_check_resolution,
    help="Image size in pixels.",
)
seed_opt = click.option("--seed", type=click.IntRange(min=0), default=None,
                        help="Override every job's seed (default: the manifest's, else 469).")
def _check_cache(ctx, param, value):
    """The cache root (--cache-dir, else $ZCOMP_CACHE_DIR, else ~/.cache/zcomp) must be
    writable: otherwise every job would fail one by one on the same cause."""
    from zcomp_cli.cache import ENV_VAR, cache_root

    root = cache_root(value)
    problem = check_writable_dir(root, "cache")
    if problem:
        source = "--cache-dir" if value is not None else (f"${ENV_VAR}" if ENV_VAR in __import__("os").environ
                                                          else "the default cache folder")
        raise click.BadParameter(f"{problem.split(': ', 1)[1]} (set by {source}; give a writable --cache-dir)",
                                 ctx=ctx, param=param)
    return value


cache_dir_opt = click.option(
    "--cache-dir",
    type=click.Path(file_okay=False),
    default=None,
    callback=_check_cache,
    help="Cache root for object renders and estimates (default $ZCOMP_CACHE_DIR or ~/.cache/zcomp).",
)
debug_opt = click.option(
    "--debug", is_flag=True, help="Also write intermediate maps and a debug grid."
)
aovs_opt = click.option(
    "--aovs", is_flag=True,
    help="Also write OUT/<job>/aovs.exr: the render passes as layers (composite, background, shadow, "
         "object, render_bg, render_comp) that recombine into the composite in Nuke or Blender.",
)


def parse_K(text: str | None):
    """Parse ``--K 'fx,fy,cx,cy'`` into a 3x3 matrix (``camera.K_from_value``), or None."""
    if text is None:
        return None
    from zcomp_cli.camera import K_from_value

    try:
        return K_from_value([float(v) for v in text.split(",")])
    except ValueError as exc:
        raise click.BadParameter(f"expected 'fx,fy,cx,cy': {exc}", param_hint="--K") from exc


# Flags of the commands that take renderer flags: a plugin renderer's option may not
# take one of these names.
COMMAND_FLAGS = {"out", "renderer", "jobs", "shard", "executor", "address", "workers", "seed", "resume",
                 "redo-changed", "overwrite", "debug", "aovs", "cache-dir", "help", "h", "version", "verbose", "quiet"}


def _renderer_flags():
    """{flag: (RendererOption, [renderer names offering it])} over ``RENDERERS``. A
    plugin's flag that is a command's own, or that another renderer offers with another
    type, is left out (with a warning): it would break the command line."""
    import logging

    from zcomp_cli.renderers.registry import RENDERERS

    flags: dict[str, tuple] = {}
    for name, entry in RENDERERS.items():
        for opt in entry.options:
            plugin = entry.source != "zcomp"
            if plugin and (opt.flag in COMMAND_FLAGS or (opt.flag in flags and flags[opt.flag][0].type != opt.type)):
                logging.getLogger(__name__).warning(
                    "renderer %r: option --%s clashes with zcomp's own; left out", name, opt.flag)
                continue
            flags.setdefault(opt.flag, (opt, []))[1].append(name)
    return flags


def renderer_options(f):
    """``--renderer NAME`` plus every renderer's own flags, from the one table
    ``renderers.registry.RENDERERS`` (plugins included). The command receives
    ``renderer`` (a name or None) and ``renderer_flags`` ({flag: value} for the flags
    given); :func:`renderer_spec` turns them into the settings of the chosen renderer."""
    from zcomp_cli.renderers.registry import RENDERERS

    first = _renderer_flags()
    params = {flag: f"rflag_{flag.replace('-', '_')}" for flag in first}

    @functools.wraps(f)
    def wrapper(*args, **kwargs):
        kwargs["renderer_flags"] = {flag: kwargs.pop(p) for flag, p in params.items() if kwargs.get(p) is not None}
        for p in params.values():
            kwargs.pop(p, None)
        return f(*args, **kwargs)

    for flag in reversed(list(first)):
        opt, owners = first[flag]
        wrapper = click.option(f"--{flag}", params[flag], type=opt.type, default=None, metavar=opt.metavar,
                               help=f"{', '.join(owners)}: {opt.help}.")(wrapper)
    summary = "; ".join(f"{n} = {e.summary}" for n, e in RENDERERS.items())
    return click.option("--renderer", type=click.Choice(list(RENDERERS)), default=None,
                        help=f"Override the manifest's renderer ({summary}).")(wrapper)


def renderer_spec(manifest_spec, renderer: str | None, flags: dict):
    """The renderer a run uses: the manifest's, or ``--renderer`` (then with no manifest
    settings), with the renderer's command-line flags applied. A flag that the chosen
    renderer does not offer is a UsageError naming it."""
    from zcomp_cli.errors import UsageError
    from zcomp_cli.pipeline.manifest import RendererSpec

    spec = manifest_spec
    if renderer is not None and renderer != spec.name:
        spec = RendererSpec(renderer, {})
    from zcomp_cli.renderers.registry import RENDERERS

    table = _renderer_flags()
    own = RENDERERS[spec.name].options if spec.name in RENDERERS else ()
    offered = {o.flag: o for o in own if spec.name in table.get(o.flag, (None, []))[1]}
    settings = dict(spec.settings)
    for flag, value in flags.items():
        if flag not in offered:
            takers = table.get(flag, (None, []))[1]
            raise UsageError(f"--{flag} applies to --renderer {' or '.join(takers)}, not {spec.name!r}")
        settings[offered[flag].setting] = value
    return RendererSpec(spec.name, settings)
