"""``zcomp estimate jobs.yaml --out DIR``: precompute a manifest's missing scene maps.

Writes, per scene, ``OUT/<scene>/{depth,normals,albedo,shading}.exr`` (and
``roughness.exr``/``metallic.exr`` when an appearance model predicted them,
``agreement.exr`` — degrees between the normals and the depth's normals — when they come
from different sources), ``sources.json`` (which map came from where, the fits, the
model runs), ``preview.png`` (the maps side by side) and ``light.yaml`` (the scene's
light as the light stage fits it for the manifest's renderer, in the manifest's own
``light:`` syntax: ``docs/lights.md``). Estimates and lights land in the cache shared
with ``zcomp composite``.
"""

from __future__ import annotations

import click

from zcomp_cli.cli.options import cache_dir_opt, out_dir_opt, overwrite_opt

# What estimate writes per scene (an existing one is replaced only with --overwrite).
OUTPUTS = ("depth.exr", "normals.exr", "albedo.exr", "shading.exr", "preview.png", "sources.json")
# ... and when the maps exist (a scene folder holding anything else is not estimate's)
OPTIONAL_OUTPUTS = ("roughness.exr", "metallic.exr", "agreement.exr", "light.yaml")


def foreign_files(folder) -> list[str]:
    """Entries of a scene's output folder that ``estimate`` does not write (its hidden
    temporaries excepted): such a folder is someone else's -- the scene's own maps,
    with ``--out`` pointed at the folder holding them -- and is never written into."""
    import os

    try:
        names = sorted(os.listdir(folder))
    except (FileNotFoundError, NotADirectoryError):
        return []
    ours = set(OUTPUTS) | set(OPTIONAL_OUTPUTS)
    return [n for n in names if n not in ours and not (n.startswith(".") and ".tmp" in n)]

AGREEMENT_DISPLAY_MAX_DEG = 90.0  # the agreement tile's colour scale: 0 .. 90 degrees


def preview_sheet(image, depth, normals, albedo, shading, *, roughness=None, metallic=None, agreement=None):
    """(H, N*W, 3) float32 display sheet in [0, 1] (already display-encoded), tiles left to
    right: sRGB image, turbo-coloured inverse depth, normals * 0.5 + 0.5, sRGB albedo,
    sRGB shading normalised by its 99th percentile; then, when given, roughness and
    metallic (grey, value as is) and the normals/depth agreement (viridis, 0 to 90
    degrees, black where not compared)."""
    import numpy as np
    from matplotlib import colormaps

    from zcomp_cli.conventions import linear_to_srgb, valid_depth_mask

    valid = valid_depth_mask(depth)
    inv = np.zeros(depth.shape, np.float64)
    inv[valid] = 1.0 / depth[valid]
    if valid.any():
        lo, hi = np.percentile(inv[valid], [1, 99])
        inv = np.clip((inv - lo) / max(hi - lo, 1e-12), 0, 1)
    dep = colormaps["turbo"](inv)[..., :3]
    dep[~valid] = 0
    sh = np.nan_to_num(shading)
    ref = float(np.percentile(sh, 99)) if sh.size else 1.0
    tiles = [linear_to_srgb(image), dep, np.clip(np.nan_to_num(normals) * 0.5 + 0.5, 0, 1),
             linear_to_srgb(albedo), linear_to_srgb(sh / max(ref, 1e-12))]
    for m in (roughness, metallic):
        if m is not None:
            tiles.append(np.repeat(np.clip(np.nan_to_num(m), 0, 1)[..., None], 3, axis=-1))
    if agreement is not None:
        a = np.asarray(agreement, np.float64)
        ok = np.isfinite(a)
        t = colormaps["viridis"](np.clip(np.where(ok, a, 0) / AGREEMENT_DISPLAY_MAX_DEG, 0, 1))[..., :3]
        t[~ok] = 0
        tiles.append(t)
    return np.concatenate([np.asarray(t, np.float32) for t in tiles], axis=1)


@click.command("estimate")
@click.argument("manifest", type=click.Path(dir_okay=False))
@out_dir_opt
@click.option("--scenes", "scene_names", default=None, metavar="NAMES",
              help="Only these scenes (comma-separated names).")
@click.option("--native", is_flag=True, help="Estimate at each image's own size, not the manifest's resolution.")
@overwrite_opt
@cache_dir_opt
@click.pass_context
def estimate(ctx, manifest, out_dir, scene_names, native, overwrite, cache_dir):
    """Estimate the missing depth, normals and albedo of MANIFEST's scenes.

    Provided maps are copied through unchanged; missing ones come from the estimators
    named in the manifest (e.g. depth: {proxy: ground_plane, camera_height: 1.5,
    pitch_deg: -10}). Writes OUT/<scene>/*.exr, sources.json and preview.png; an
    existing scene folder is replaced only with --overwrite.
    """
    from pathlib import Path

    import numpy as np

    from zcomp_cli.cache import cache_dir as cache_folder
    from zcomp_cli.compositing.shading import shading_from_image
    from zcomp_cli.errors import UsageError, ZcompError
    from zcomp_cli.imageio import write_exr, write_json_atomic, write_png
    from zcomp_cli.pipeline.manifest import load_manifest
    from zcomp_cli.pipeline.scene import load_scene

    m = load_manifest(manifest)
    names = list(m.scenes)
    if scene_names:
        want = [s.strip() for s in scene_names.split(",") if s.strip()]
        unknown = [s for s in want if s not in m.scenes]
        if unknown:
            raise UsageError(f"unknown scenes {unknown}; the manifest has {names}")
        names = want
    cache = cache_folder("estimates", cache_dir)
    out = Path(out_dir)
    from zcomp_cli.pipeline.outguard import check_inside

    for name in names:  # every folder written must stay inside --out
        check_inside(out, out / name, f"scenes.{name}")
    for name in names:  # nothing estimate did not write is replaced, even with --overwrite
        d = out / name
        if d.exists() and not d.is_dir():
            raise UsageError(f"--out: {d} (scene {name!r}'s folder) is a file, not a folder")
        theirs = foreign_files(d)
        inputs = [p for p in [m.scenes[name].image, *m.scenes[name].maps.values()]
                  if p is not None and Path(p).resolve().parent == d.resolve()]
        if theirs or inputs:
            shown = ", ".join((theirs or [Path(p).name for p in inputs])[:5])
            raise UsageError(f"--out: {d} (scene {name!r}'s folder) holds files zcomp estimate did not write "
                             f"({shown}{' ...' if len(theirs) > 5 else ''}): point --out at a folder of its own "
                             "(the scene's input maps are never replaced)")
    existing = [n for n in names if any((out / n / f).exists() for f in OUTPUTS)]
    if existing and not overwrite:  # the rule of every command: nothing replaced unasked
        raise UsageError(f"estimates already exist for scene(s) {', '.join(existing[:5])}"
                         f"{' ...' if len(existing) > 5 else ''} in {out}; pass --overwrite to replace them")
    quiet = bool(ctx.obj and ctx.obj.get("quiet"))
    from zcomp_cli.pipeline.stages import LightStore, light_config_of

    lights = LightStore(light_config_of(m.defaults.renderer), cache_folder("lights", cache_dir), out,
                        path_of=lambda name: out / name / "light.yaml")  # (beside the scene's maps)
    seed_of = {j.scene: j.seed for j in reversed(m.jobs)}  # (a scene's first job's seed, as composite fits it)
    for name in names:
        spec = m.scenes[name]
        scene = load_scene(spec, None if native else m.defaults.resolution, cache_dir=cache)
        mp = scene.maps
        shading = shading_from_image(scene.image, mp.albedo)
        d = out / name
        d.mkdir(parents=True, exist_ok=True)
        write_exr(d / "depth.exr", mp.depth)
        write_exr(d / "normals.exr", mp.normals)
        write_exr(d / "albedo.exr", mp.albedo)
        write_exr(d / "shading.exr", shading)
        est = scene.estimated or {}
        agree = est.get("agreement")
        for key, arr in (("roughness", mp.roughness), ("metallic", mp.metallic), ("agreement", agree)):
            if arr is not None:
                write_exr(d / f"{key}.exr", np.nan_to_num(arr, nan=-1.0) if key == "agreement" else arr)
        write_png(d / "preview.png", preview_sheet(scene.image, mp.depth, mp.normals, mp.albedo, shading,
                                                   roughness=mp.roughness, metallic=mp.metallic,
                                                   agreement=agree), srgb_encode=False)
        try:
            lights.get(scene, seed_of.get(name, m.defaults.seed))  # writes light.yaml
        except ZcompError as exc:
            click.echo(f"{name}: the light could not be fitted: {exc}", err=True)
        write_json_atomic(d / "sources.json", {"scene": name, "sources": scene.sources,
                                               "notes": list(scene.notes),
                                               "fits": est.get("fits", {}),
                                               "timings_s": scene.timings,
                                               "K": scene.camera.K.tolist(),
                                               "resolution": [scene.camera.width, scene.camera.height]})
        if not quiet:
            src = ", ".join(f"{k}: {v}" for k, v in scene.sources.items())
            click.echo(f"{name}: {src} -> {d}")
