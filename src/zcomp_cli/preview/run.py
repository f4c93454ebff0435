"""``zcomp preview-light``: the light zcomp will use, seen on three balls, before a batch.

Per scene (numbered as the pipeline's steps):

1. **Where**: the balls stand on the surface seen at a pixel -- the user's, else the
   scene's first job's placement (a pose's position, projected), else the frame's centre
   two thirds down -- in a row along the ground's right direction, the row spanning
   ``ROW_SHARE`` of the frame's width at that depth (or ``diameter`` metres each).
2. **The balls as an object**: their intrinsic maps drawn analytically
   (``balls.ball_bundle``), their mesh and materials a glTF (``balls.write_balls_glb``).
3. **The light**: the scene's light as the batch will use it -- given (a probe, a chrome
   ball, suns, lamps) or estimated -- fitted once per scene (the physical renderer's fit,
   the same seed as the scene's first job).
4. **Blender**: Cycles renders the balls into the photograph through the pipeline's own
   steps (background and composite passes, then the shadow-opacity compositor: their
   shadows included), then the balls alone with the same light on transparent film,
   zoomed. One Blender process for every scene.
5. **The sheet**: both pictures and the light's numbers (``summary``), written atomically
   as ``OUT/preview/<scene>.png``, the numbers also as ``<scene>.json``.
"""

from __future__ import annotations

import math
import shutil
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from zcomp_cli.errors import GeometryError, RenderError, UsageError, ZcompError

# the row of three balls spans this share of the frame's width at their depth (a
# judgement: large enough to read the light on, small enough to leave the floor around
# them and their shadows in the frame)
ROW_SHARE = 0.25
# where the balls stand when the scene has no job: the frame's centre column, two thirds
# down (on most photographs' floor)
DEFAULT_PIXEL_SHARE = (0.5, 2.0 / 3.0)
# the balls alone are rendered this many pixels tall at least (zoomed from the frame, at
# most ``MAX_ZOOM`` times): enough to see a sun's highlight on the silver ball
ALONE_MIN_PX = 192
MAX_ZOOM = 8.0
# Cycles samples per pixel of a preview (denoised): the error-against-time sweep's knee
# is 16-32 (docs/error_vs_time_cycles.png); 16 keeps a scene within seconds
DEFAULT_SAMPLES = 16
SUBDIR = "preview"
# A ball is drawn at least this many pixels across (the grey ball's shading and the
# chrome ball's reflection read over a few pixels at least), and the row of balls fits
# the frame: a --diameter outside these is named as too small or too large.
MIN_BALL_PX = 4.0
# The surface the balls stand on is at most this far (metres): beyond it Cycles' single
# floats lose the balls (a depth of 1e30 made a blank sheet). 1e5 m: 100 km, past any
# photograph's ground and still ~1e-2 m float resolution.
MAX_BALL_DEPTH_M = 1e5
WORK_PREFIX = "zcomp-preview-"  # + pid: a later run sweeps the folder of a killed one
# the world's importance map a preview builds on every pass (``CyclesSettings``): 256
# instead of a 1024-wide probe's own width saves 0.7 s a pass (a preview's three renders
# are otherwise mostly this map; benchmarks/preview_light_timing.py)
WORLD_MAP_RESOLUTION = 256


@dataclass
class PreviewResult:
    """One scene's preview: its sheet and numbers (paths), or why it failed."""

    scene: str
    sheet: Path | None = None
    numbers: Path | None = None
    seconds: float = 0.0
    error: str | None = None
    info: dict = field(default_factory=dict)


def sheet_paths(out_dir, scene: str) -> tuple[Path, Path]:
    # (a scene's name is a safe file name: the manifest checks it as a job folder's)
    base = Path(out_dir) / SUBDIR / scene
    return base.with_suffix(".png"), base.with_suffix(".json")


def choose_pixel(manifest, scene_name: str, camera, pixel_native=None) -> tuple[tuple[float, float], str]:
    """(x, y) in working pixels where the balls stand, and where it came from."""
    spec = manifest.scenes[scene_name]
    sx, sy = camera.width / float(spec.width), camera.height / float(spec.height)
    if pixel_native is not None:
        x, y = (float(v) for v in pixel_native)
        if not (0 <= x < spec.width and 0 <= y < spec.height):
            raise UsageError(f"--pixel {x:g} {y:g} is outside scene {scene_name!r}'s {spec.width}x{spec.height} "
                             "photograph")
        return (x * sx, y * sy), "--pixel"
    for job in manifest.jobs:
        if job.scene != scene_name:
            continue
        if job.placement is not None:
            return tuple(job.placement.pixel), f"job {job.name}'s placement"
        if job.pose is not None:
            px, z = camera.project(np.asarray(job.pose.position, np.float64)[None])
            if z[0] > 0 and np.all(np.isfinite(px[0])):
                x, y = float(px[0][0]), float(px[0][1])
                if 0 <= x < camera.width and 0 <= y < camera.height:
                    return (x, y), f"job {job.name}'s pose"
    return ((DEFAULT_PIXEL_SHARE[0] * camera.width, DEFAULT_PIXEL_SHARE[1] * camera.height),
            "the frame's centre, two thirds down")


def ball_pose(scene, pixel, diameter: float | None) -> tuple[np.ndarray, float]:
    """(4, 4) object-to-camera matrix of the balls' row standing at ``pixel`` (its x axis
    the camera's right on the surface, y the surface's normal), and the ball diameter."""
    from zcomp_cli.pipeline.manifest import Placement
    from zcomp_cli.pipeline.placement import pose_from_placement

    cam = scene.camera
    pose = pose_from_placement(Placement(pixel=tuple(pixel)), scene.maps.depth, scene.maps.normals, cam)
    P = np.asarray(pose.position, np.float64)
    up = np.asarray(pose.rotation, np.float64)[:, 1]
    x = np.array([1.0, 0.0, 0.0]) - up[0] * up
    if np.linalg.norm(x) < 1e-6:  # a surface facing sideways: its own horizontal
        x = np.cross(up, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    z = np.cross(x, up)
    M = np.eye(4)
    M[:3, 0], M[:3, 1], M[:3, 2], M[:3, 3] = x, up, z, P
    if diameter is None:
        from zcomp_cli.preview.balls import BALLS, SPACING

        depth = -P[2]
        frame_w = depth * cam.width / float(cam.K[0, 0])
        row = SPACING * (len(BALLS) - 1) + 1.0  # the row's width in diameters
        diameter = ROW_SHARE * frame_w / row
    return M, float(diameter)


def check_ball_size(camera, M, diameter: float, given: bool) -> None:
    """Refuse (``GeometryError``: the scene fails, naming the scene and what to give) balls the sheet cannot
    show: a surface beyond ``MAX_BALL_DEPTH_M``, balls under ``MIN_BALL_PX`` across, or a
    row wider or taller than the frame. ``given``: the diameter came from --diameter."""
    from zcomp_cli.preview.balls import BALLS, SPACING

    depth = -float(M[2, 3])
    f = float(camera.K[0, 0])
    where = "the surface the balls stand on"
    if not (math.isfinite(depth) and 0 < depth <= MAX_BALL_DEPTH_M):
        raise GeometryError(f"{where} is {depth:.3g} m away (its depth map), beyond the {MAX_BALL_DEPTH_M:g} m a "
                         f"preview draws at; give --pixel on a nearer surface")
    px = diameter * f / depth
    row = (SPACING * (len(BALLS) - 1) + 1.0) * px
    opt = "--diameter" if given else "the default diameter"
    if px < MIN_BALL_PX:
        raise GeometryError(f"{where} is {depth:.3g} m away: balls {diameter:.3g} m across ({opt}) are "
                         f"{px:.2g} pixels there, too small to see; give --diameter "
                         f"{MIN_BALL_PX * depth / f:.3g} or more")
    if row > camera.width or px > camera.height:
        raise GeometryError(f"{where} is {depth:.3g} m away: balls {diameter:.3g} m across ({opt}) make a row "
                         f"{row:.0f} pixels wide, {px:.0f} tall, larger than the {camera.width}x{camera.height} "
                         f"frame; give --diameter {min(camera.width / row, camera.height / px) * diameter:.3g} "
                         f"or less")


def preview_scene(manifest, scene_name: str, renderer, *, out_dir, work: Path, pixel_native=None,
                  diameter: float | None = None, cache_dir=None, lights=None) -> PreviewResult:
    """Steps 1-5 for one scene (module docstring); raises ZcompError on failure.
    ``lights``: the light stage (``pipeline.stages.LightStore``; None: one for this call)."""
    from zcomp_cli.cache import cache_dir as cache_folder
    from zcomp_cli.pipeline.job import finish_job, prepare_job, roi_around
    from zcomp_cli.pipeline.scene import load_scene
    from zcomp_cli.preview.balls import ball_bundle, write_balls_glb
    from zcomp_cli.preview.sheet import make_sheet
    from zcomp_cli.preview.summary import light_lines

    t0 = time.perf_counter()
    spec = manifest.scenes[scene_name]
    scene = load_scene(spec, manifest.defaults.resolution, cache_dir=cache_folder("estimates", cache_dir))
    # 1. where
    pixel, pixel_from = choose_pixel(manifest, scene_name, scene.camera, pixel_native)
    M, d = ball_pose(scene, pixel, diameter)
    check_ball_size(scene.camera, M, d, diameter is not None)
    # 2. the balls as an object
    glb = work / f"balls_{d:.6g}.glb"
    if not glb.is_file():
        write_balls_glb(glb, d)
    bundle = ball_bundle(scene.camera, M, d, mesh_path=glb)
    seed = next((j.seed for j in manifest.jobs if j.scene == scene_name), manifest.defaults.seed)
    # 3. the light: the batch's light stage (its cache shared with `zcomp composite`)
    if lights is None:
        from zcomp_cli.pipeline.stages import LightStore

        lights = LightStore(renderer.light_config(), cache_folder("lights", cache_dir), Path(out_dir))
    fitted = lights.get(scene, seed)
    model = fitted.model
    prep = prepare_job(scene, bundle, shading_radius=manifest.defaults.shading_radius, seed=seed,
                       fitted_light=fitted)
    # 4. Blender
    t = time.perf_counter()
    out = renderer.render(prep.requests, seed=seed)
    res = finish_job(prep, out, renderer.name, renderer.settings())
    cover = bundle.mask > 0
    box = roi_around(cover, max(4, int(0.1 * cover.any(0).sum())))
    bh = max(1, box[3] - box[1])
    zoom = float(np.clip(ALONE_MIN_PX / bh, 1.0, MAX_ZOOM))
    ta = time.perf_counter()
    # (in the photograph's units, as finish_job gives the composite: ``Scene.working_scale``)
    alone = renderer.render_alone(prep.requests[1], seed, box=box, zoom=zoom)
    alone[..., :3] *= np.float32(scene.working_scale)
    alone_s = time.perf_counter() - ta
    if not (alone[..., 3] > 0).any():
        raise RenderError(f"Blender drew no ball (the balls {d:.3g} m across at "
                         f"{-M[2, 3]:.3g} m); no sheet written")
    render_s = time.perf_counter() - t
    startup = next((p.get("blender_startup_s") for p in out.info.get("passes", []) if p.get("blender_startup_s")),
                   None)
    # 5. the sheet
    lines = light_lines(model, getattr(scene.light, "probe", None) if scene.light is not None else None)
    lines.append(f"balls: {d:.3g} m across at pixel [{pixel[0]:.0f}, {pixel[1]:.0f}] ({pixel_from}); grey 18%, "
                 f"satin silver, chrome mirror; rendered by Cycles, {renderer.settings().get('samples')} samples")
    sheet = make_sheet(res.image, alone, lines, f"zcomp preview-light: scene {scene_name}")
    png, js = sheet_paths(out_dir, scene_name)
    seconds = time.perf_counter() - t0
    info = {"scene": scene_name, "pixel": list(pixel), "pixel_from": pixel_from, "ball_diameter_m": d,
            "object_to_camera": M.tolist(),
            "seed": seed, "light": model.to_info(), "lines": lines, "seconds": seconds, "render_s": render_s,
            "blender_startup_s": startup, "timings": {**{k: float(v) for k, v in out.timings.items()},
                                                      "alone_s": float(alone_s)},
            "renderer": renderer.settings(), "notes": res.report.get("notes", [])}
    write_pair(png, sheet, js, info)
    return PreviewResult(scene_name, png, js, seconds, None, info)


def write_pair(png: Path, sheet: np.ndarray, js: Path, info: dict) -> None:
    """The sheet (uint8 RGB) and its numbers, each atomically, and the two together: an
    interrupt between them waits for the second (a SIGTERM there left a PNG without its
    JSON), and a JSON that cannot be written takes its new PNG away."""
    from zcomp_cli.imageio import write_json_atomic, write_png
    from zcomp_cli.interrupts import deferred

    with deferred():
        write_png(png, sheet.astype(np.float32) / 255.0, srgb_encode=False)
        try:
            write_json_atomic(js, info)
        except BaseException:
            png.unlink(missing_ok=True)
            raise


def preview_light(manifest, out_dir, *, scenes=None, pixel_native=None, diameter: float | None = None,
                  samples: int = DEFAULT_SAMPLES, overwrite: bool = False, cache_dir=None,
                  progress=None) -> list[PreviewResult]:
    """Preview sheets for ``scenes`` (default: every scene of the manifest, in order; a
    scene named twice once). Refuses (``UsageError``, before anything is written) an
    unknown scene, a bad ``diameter``, a preview folder that is a symbolic link, a
    second run into the same folder at the same time, or sheets that exist without
    ``overwrite``. A scene that fails is reported in its result and the rest go on.
    ``progress(stage, done, total, label)``."""
    from zcomp_cli.pipeline.outguard import check_inside, held_or_refused
    from zcomp_cli.renderers.cycles import CyclesRenderer

    names = list(manifest.scenes) if not scenes else list(dict.fromkeys(scenes))  # a repeated --scene once
    unknown = [n for n in names if n not in manifest.scenes]
    if unknown:
        raise UsageError(f"--scene: no scene {', '.join(map(repr, unknown))} in {manifest.path.name} "
                         f"(scenes: {', '.join(manifest.scenes)})")
    if diameter is not None and not (math.isfinite(diameter) and 0 < diameter <= 1e3):
        raise UsageError(f"--diameter: expected metres in (0, 1000], got {diameter!r}")
    if pixel_native is not None:
        x, y = (float(v) for v in pixel_native)
        for n in names:
            sp = manifest.scenes[n]
            if not (0 <= x < sp.width and 0 <= y < sp.height):
                raise UsageError(f"--pixel {x:g} {y:g} is outside scene {n!r}'s {sp.width}x{sp.height} photograph")
    from zcomp_cli.pipeline.batch import check_renderer_budget

    check_renderer_budget(manifest, names, "cycles")
    from zcomp_cli.knobs import as_dict
    from zcomp_cli.pipeline.stages import light_config_of

    # the light the batch will fit: the manifest's renderer's light config
    renderer = CyclesRenderer(samples=int(samples), world_map_resolution=WORLD_MAP_RESOLUTION,
                              light=as_dict(light_config_of(manifest.defaults.renderer)))
    renderer.check()
    out_dir = Path(out_dir)
    folder = out_dir / SUBDIR
    check_inside(out_dir, folder, "--out")  # a linked preview/ would take the sheets outside --out
    for n in names:
        for p in sheet_paths(out_dir, n):
            check_inside(out_dir, p, "--out")
    folder.mkdir(parents=True, exist_ok=True)
    # one run at a time writes a folder's sheets: two would replace each other's
    with held_or_refused(folder / ".zcomp-preview.lock", "zcomp preview-light"):
        if not overwrite:
            there = [str(p) for n in names for p in sheet_paths(out_dir, n) if p.exists()]
            if there:
                raise UsageError(f"{there[0]} exists (and {len(there) - 1} more); give --overwrite to replace them")
        return _preview_scenes(manifest, renderer, out_dir, names, pixel_native=pixel_native, diameter=diameter,
                               cache_dir=cache_dir, progress=progress)


def _preview_scenes(manifest, renderer, out_dir, names, *, pixel_native, diameter, cache_dir,
                    progress) -> list[PreviewResult]:
    import os

    from zcomp_cli.cache import cache_dir as cache_folder
    from zcomp_cli.pipeline.outguard import sweep_dead_temporaries
    from zcomp_cli.pipeline.stages import LightStore

    lights = LightStore(renderer.light_config(), cache_folder("lights", cache_dir), Path(out_dir))
    sweep_dead_temporaries()  # what killed runs left in /tmp (a preview's work folder among them)
    work = Path(tempfile.mkdtemp(prefix=f"{WORK_PREFIX}{os.getpid()}-"))
    results = []
    try:
        for k, name in enumerate(names):
            if progress:
                progress("scenes", k, len(names), name)
            t = time.perf_counter()
            try:
                results.append(preview_scene(manifest, name, renderer, out_dir=out_dir, work=work,
                                             pixel_native=pixel_native, diameter=diameter, cache_dir=cache_dir,
                                             lights=lights))
            except ZcompError as exc:
                results.append(PreviewResult(name, seconds=time.perf_counter() - t, error=str(exc)))
        if progress:
            progress("scenes", len(names), len(names), "")
    finally:
        renderer.close()
        shutil.rmtree(work, ignore_errors=True)
    return results


__all__ = ["PreviewResult", "preview_light", "preview_scene", "choose_pixel", "ball_pose", "sheet_paths",
           "ROW_SHARE", "DEFAULT_SAMPLES"]
