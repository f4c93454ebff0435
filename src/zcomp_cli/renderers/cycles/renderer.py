"""The ``cycles`` renderer: Blender's path tracer as the transport (issue 35).

Per request (numbered as the pipeline's steps):

1. **The light**: the scene's fitted light (``RenderRequest.fitted_light``, the light
   stage's, ``zcomp_cli.light``; or that stage run here for a caller who gives none) --
   the manifest's lights with their strengths fitted to the photograph, or the whole
   light estimated -- in zcomp's shading units (``scene``: Blender's are the same, so no
   exposure of its own). A given probe is the world itself (its rotation and
   convention, ``docs/lights.md``); an estimated sky is drawn into a small world map;
   suns and lamps are Blender's.
2. **The geometry**: the request's depth map as a mesh (``scene.depthmesh``:
   discontinuities cut, occluders extruded backwards, the walls beyond the frame), its
   albedo as each vertex's diffuse colour so bounce light has the photograph's colours;
   on the composite request, the pixels the object covers are left out of that mesh and
   the object is its own file at its pose with its own materials (``PosedMesh.source``),
   or, for an object given as maps, its extruded surface with its mean material.
3. **The window**: only the re-shaded pixels (the unknown ones, grown along a given
   light's shadow, ``renderers.lighting.request_reach``) and a margin are path traced (Blender's
   render border); every known pixel is ``albedo x shading``, the photograph, exactly
   (the renderer contract), so the compositor's guarantees hold as they are.
4. **Blender**: one process per renderer (``blender.runner.BlenderSession``, the
   script ``blender/scripts/render_cycles.py``), kept for every job of a worker; the
   scene mesh is rebuilt only when its content changes; a crash fails that job alone
   and the next job starts a fresh process.

Both passes use the job's seed, so their noise agrees wherever the object changes
nothing and the compositor's ratio is 1 there.
"""

from __future__ import annotations

import atexit
import hashlib
import math
import os
import shutil
import tempfile
import time
from pathlib import Path
from typing import Sequence

import numpy as np

from zcomp_cli.conventions import DEFAULT_SEED, REC601, luminance
from zcomp_cli.errors import InputError, RenderError, UsageError
from zcomp_cli.renderers.base import Renderer, RenderOutput, RenderRequest
from zcomp_cli.renderers.cycles import scene as sc
from zcomp_cli.renderers.cycles.settings import CyclesSettings

SCRIPT = "render_cycles.py"
WORK_PREFIX = "zcomp-cycles-"
# world maps kept in the work folder (a few scenes' jobs interleave in a worker's batch;
# each map is a few MB, so the folder stays small whatever the manifest's size)
KEEP_WORLDS = 4


class CyclesRenderer(Renderer):
    """Blender Cycles on a mesh of the photograph's depth (module docstring). Settings:
    ``CyclesSettings`` (its ``light``: the light stage's config, a mapping)."""

    name = "cycles"
    uses_light = True

    def __init__(self, **settings):
        from zcomp_cli.light.stage import SceneLight

        self._settings = CyclesSettings.from_kwargs(**settings)
        # the light stage for a caller who gives no fitted light (memory only)
        self._lights = SceneLight(self._settings.light)
        self._session = None
        self._work: Path | None = None
        self._meshes: dict = {}
        self._worlds: dict = {}  # inputs' key -> the world's rows (its EXR in the work folder), oldest first

    def settings(self) -> dict:
        return {"name": self.name, **self._settings.as_dict()}

    def light_config(self):
        return self._settings.light

    def check(self) -> None:
        import importlib.util

        if importlib.util.find_spec("bpy") is None:
            raise UsageError("renderer cycles needs Blender's Python module: pip install bpy (DESIGN.md section 7 "
                             "has the version that resolves with zcomp's pins)")

    # -- Blender -------------------------------------------------------------------
    def _blender(self):
        from zcomp_cli.blender.runner import BlenderSession

        if self._session is None:
            self._work = Path(tempfile.mkdtemp(prefix=f"{WORK_PREFIX}{os.getpid()}-"))
            self._session = BlenderSession(SCRIPT, item_timeout_s=self._settings.item_timeout_s)
            atexit.register(self.close)
        return self._session

    def close(self) -> None:
        """End the Blender process and remove the work folder."""
        if self._session is not None:
            self._session.close()
            self._session = None
        if self._work is not None:
            shutil.rmtree(self._work, ignore_errors=True)
            self._work = None
            self._worlds = {}

    def __del__(self):  # noqa: D105 - a dropped renderer ends its Blender
        try:
            self.close()
        except Exception:  # noqa: BLE001 - interpreter shutdown
            pass

    # -- the passes ----------------------------------------------------------------
    def render(self, requests: Sequence[RenderRequest], *, seed: int = DEFAULT_SEED) -> RenderOutput:
        if not requests:
            raise UsageError("cycles renderer needs at least one request")
        from zcomp_cli.renderers.lighting import request_reach

        timings = {"estimate": 0.0, "build": 0.0, "blender": 0.0}
        t0 = time.perf_counter()
        model = self.light(requests[0], seed)
        timings["estimate"] = time.perf_counter() - t0
        # where a given light's shadow falls beyond the mask (every light-drawing renderer's rule)
        grown, reach = request_reach(requests, model, self._settings.light)
        images, passes, layers = [], [], {}
        for k, req in enumerate(requests):
            im, info, aov = self._render_one(req, model, seed, reach, timings)
            images.append(im)
            passes.append(info)
            tag = "bg" if k == 0 else "comp" if k == 1 else f"pass{k}"
            layers.update({f"cycles_{tag}_{name}": a for name, a in aov.items()})
        light = model.to_info()
        info = {"light": light, "fallback": light["fallback"], "shadow": str(model.shadows),
                "settings": self.settings(), "passes": passes}
        return RenderOutput(images=images, info=info, timings=timings, shading_mask=grown, aov_layers=layers)

    def _render_one(self, req: RenderRequest, model, seed: int, reach, timings: dict):
        from zcomp_cli.blender.intrinsics import blender_camera_from_K
        from zcomp_cli.blender.passes import get_pass

        H, W = req.camera.height, req.camera.width
        albedo = np.clip(np.nan_to_num(np.asarray(req.maps.albedo, np.float64)), 0.0, 1.0)
        shading = np.clip(np.nan_to_num(np.asarray(req.shading, np.float64), nan=0.0, posinf=0.0), 0.0, 1e6)
        if albedo.shape != (H, W, 3) or shading.shape != (H, W, 3) or np.shape(req.known) != (H, W):
            raise InputError(f"cycles renderer: maps of shape {albedo.shape}, shading {shading.shape}, "
                             f"known {np.shape(req.known)}; expected {(H, W)}")
        out = (albedo * shading).astype(np.float32)
        todo = ~np.asarray(req.known, bool)
        if reach is not None:
            todo |= reach
        if req.roi is not None:
            x0, y0, x1, y1 = req.roi
            inside = np.zeros((H, W), bool)
            inside[y0:y1, x0:x1] = True
            if reach is not None:
                inside |= reach
            todo &= inside
        if not todo.any():
            return out, {"rendered_pixels": 0}, {}
        ys, xs = np.nonzero(todo)
        m = self._settings.margin_px
        box = (max(0, int(xs.min()) - m), max(0, int(ys.min()) - m), min(W, int(xs.max()) + 1 + m),
               min(H, int(ys.max()) + 1 + m))

        t = time.perf_counter()
        self._blender()
        item, arrays = self._describe(req, model, seed, box)
        item.update(width=W, height=H, camera=blender_camera_from_K(req.camera.K, W, H), clip=clip_range(req.maps.depth))
        timings["build"] += time.perf_counter() - t
        ch, ev, res = self._run(item, arrays, timings)
        rgb = np.nan_to_num(get_pass(ch, "Combined", "RGB"), nan=0.0, posinf=0.0, neginf=0.0)
        aov = _light_passes(ch, box, (H, W)) if req.aovs else {}
        x0, y0, x1, y1 = box
        if rgb.shape[:2] != (y1 - y0, x1 - x0):
            raise RenderError(f"Cycles rendered a {rgb.shape[1]}x{rgb.shape[0]} window, expected "
                              f"{x1 - x0}x{y1 - y0}")
        rgb = np.maximum(rgb, 0.0)
        scale = 1.0
        win_known = ~todo[y0:y1, x0:x1] & (np.asarray(req.maps.depth)[y0:y1, x0:x1] > 0)
        ref = luminance(out[y0:y1, x0:x1], REC601)[win_known]
        got = luminance(rgb, REC601)[win_known]
        ok = (got > 1e-6) & (ref > 1e-6)
        # (None: too few known pixels in the window to tell)
        ratio = float(np.median(ref[ok] / got[ok])) if ok.sum() >= 16 else None
        if self._settings.exposure == "render" and ratio is not None and np.isfinite(ratio):
            scale = ratio
        win = out[y0:y1, x0:x1]
        sel = todo[y0:y1, x0:x1]
        win[sel] = (scale * rgb[sel]).astype(np.float32)
        first = res.startup_s[0] if res.startup_s else None
        aov = {k: v * np.float32(scale) if not k.endswith("_color") else v for k, v in aov.items()}
        return out, {"rendered_pixels": int(sel.sum()), "window": list(box), "scale": scale,
                     "photo_over_render": ratio, "blender_startup_s": first,
                     "render_s": float(ev.get("render_s", float("nan"))),
                     "blender_build_s": float(ev.get("build_s", float("nan"))),
                     "object": item["object"] and ("file" if "mesh" in item["object"] else "maps")}, aov

    def _run(self, item: dict, arrays: dict, timings: dict | None = None):
        """One item in the worker's Blender process: its arrays written beside it, Cycles'
        EXR read back, both scratch files removed whatever happens. Returns (the EXR's
        channels, Blender's event for the item, the run's ``BatchResult``); raises
        ``RenderError`` with Cycles' reason when the item failed. ``timings``: "build"
        and "blender" seconds are added to it."""
        from zcomp_cli.blender.passes import read_multilayer_exr

        t = time.perf_counter()
        arrays_path = self._work / f"{item['id']}.npz"
        out = self._work / f"{item['id']}.exr"
        try:
            np.savez(arrays_path, **arrays)
            item.update(arrays=str(arrays_path), out=str(out))
            if timings is not None:
                timings["build"] += time.perf_counter() - t
            t = time.perf_counter()
            res = self._session.run([item])
            if timings is not None:
                timings["blender"] += time.perf_counter() - t
            ev = res.results.get(item["id"], {})
            if ev.get("event") != "done":
                raise RenderError(f"Cycles failed: {ev.get('error', 'no answer from Blender')}")
            return read_multilayer_exr(str(out)), ev, res
        finally:
            for p in (arrays_path, out):
                p.unlink(missing_ok=True)

    def _world_file(self, key: str, make) -> tuple[Path, np.ndarray]:
        """The world map (``make() -> (image, rows)``) as an EXR in the work folder, made
        and written once per ``key`` (the inputs it is made from: a scene's every pass
        looks it up); the last few kept. Returns (its path, its rows)."""
        from zcomp_cli.imageio import write_exr

        path = self._work / f"world_{key}.exr"
        if key not in self._worlds or not path.is_file():
            image, rows = make()
            write_exr(path, image)
            self._worlds[key] = np.asarray(rows, np.float64)
        self._worlds[key] = self._worlds.pop(key)  # most recently used last
        while len(self._worlds) > KEEP_WORLDS:
            old = next(iter(self._worlds))
            del self._worlds[old]
            (self._work / f"world_{old}.exr").unlink(missing_ok=True)
        return path, self._worlds[key]

    def fitted_light(self, req: RenderRequest, seed: int = DEFAULT_SEED):
        """The scene's fitted light (``renderers.lighting.request_light``)."""
        from zcomp_cli.renderers.lighting import request_light

        return request_light(req, self._lights, seed)

    def light(self, req: RenderRequest, seed: int = DEFAULT_SEED):
        """The scene's light model (``fitted_light``'s)."""
        return self.fitted_light(req, seed).model

    def render_alone(self, req: RenderRequest, seed: int = DEFAULT_SEED, *, box, zoom: float = 1.0,
                     samples: int | None = None) -> np.ndarray:
        """The request's object under the scene's light with nothing of the scene around
        it (no depth mesh: no floor, no shadow, no bounce from the photograph), on
        transparent film: a look at the light itself, as a look-development turntable
        shows it. Seen by the request's camera ``zoom`` times finer, in the window
        ``box`` (x0, y0, x1, y1) of the request's pixels.

        Returns (h, w, 4) float32 linear RGB and alpha of the window (``zoom`` x box).
        """
        from zcomp_cli.blender.intrinsics import blender_camera_from_K

        if req.occluder is None or getattr(req.occluder, "source", None) is None:
            raise UsageError("render_alone needs a request whose occluder is a mesh file (PosedMesh.source)")
        H, W = req.camera.height, req.camera.width
        z = float(zoom)
        if not (math.isfinite(z) and 1.0 <= z <= 16.0):
            raise UsageError(f"render_alone: zoom must be in [1, 16], got {zoom!r}")
        Wz, Hz = max(1, round(W * z)), max(1, round(H * z))
        x0, y0, x1, y1 = (int(v) for v in box)
        bz = (max(0, math.floor(x0 * z)), max(0, math.floor(y0 * z)), min(Wz, math.ceil(x1 * z)),
              min(Hz, math.ceil(y1 * z)))
        if bz[2] <= bz[0] or bz[3] <= bz[1]:
            raise UsageError(f"render_alone: empty window {list(box)}")
        model = self.light(req, seed)
        self._blender()
        item, arrays = self._describe(req, model, seed, bz, with_scene=False)
        K = np.asarray(req.camera.K, np.float64).copy()
        K[:2] *= z
        item.update(width=Wz, height=Hz, transparent=True, camera=blender_camera_from_K(K, Wz, Hz))
        if samples is not None:
            item["samples"] = int(samples)
        ch, _, _ = self._run(item, arrays)
        rgba = np.stack([ch[f"Combined.{c}"] for c in "RGBA"], -1)
        return np.clip(np.nan_to_num(rgba, nan=0.0, posinf=0.0, neginf=0.0), 0.0, None).astype(np.float32)

    def _describe(self, req: RenderRequest, model, seed: int, box, *, with_scene: bool = True) -> tuple[dict, dict]:
        """The Blender item and its arrays for one request (``scene``); without the
        scene's mesh when not ``with_scene`` (``render_alone``)."""
        from zcomp_cli.scene.depthmesh import has_geometry
        from zcomp_cli.scene.lightmodel import ShadowKind

        s = self._settings
        d = np.nan_to_num(np.asarray(req.maps.depth, np.float64), nan=0.0, posinf=0.0, neginf=0.0)
        n = np.nan_to_num(np.asarray(req.maps.normals, np.float64))
        albedo = np.clip(np.nan_to_num(np.asarray(req.maps.albedo, np.float64)), 0.0, 1.0)
        cover = None if req.coverage is None else np.asarray(req.coverage, np.float64) > 0
        valid = has_geometry(d, n)
        if not with_scene:
            valid[:] = False
        if cover is not None and with_scene:
            valid &= ~cover
            d, n, albedo, valid = sc.fill_behind(d, n, albedo, valid, cover, req.camera, model.up)
        # the scene mesh, cached by its content (a scene's background request is the same
        # for every job)
        h = hashlib.sha256()
        for a in (d, n, albedo, valid, np.asarray(model.up, np.float64),
                  np.float64(model.specular_roughness)):
            h.update(np.ascontiguousarray(a).tobytes())
        h.update(repr(([w.to_info() for w in model.walls], sc.mesh_regions(d.shape, box))).encode())
        key = h.hexdigest()[:24] if with_scene else None
        arrays = self._meshes.get(key) if with_scene else {}
        if arrays is None:  # (a large frame: meshed finely only around the window)
            arrays = sc.scene_arrays(d, n, albedo, valid, req.camera, model, box, cfg=s.light.mesh)
            # the last few scenes' meshes (a job's two passes): memory flat in the scenes
            self._meshes = {**dict(list(self._meshes.items())[-3:]), key: arrays}
        arrays = dict(arrays)
        probe = model.probe.params if model.probe is not None and s.world == "probe" else None
        up = np.asarray(model.up, np.float64)
        if probe is not None:
            scale = model.probe.scale
            wkey = repr(("probe", probe.to_dict(), scale, up.tolist(), s.probe_width))
            make = lambda: sc.probe_image(probe, up, scale, s.probe_width)  # noqa: E731
        else:
            wkey = repr(("sky", model.sky.radiance_sh.tolist(), model.sky.ground.tolist(), up.tolist(), s.sky_width))
            make = lambda: sc.sky_image(model.sky, s.sky_width)  # noqa: E731
        world_path, rows = self._world_file(hashlib.sha256(wkey.encode()).hexdigest()[:24], make)
        lamps = sc.lamps_of(model, skip_probe_sources=probe is not None)
        for lp in lamps:
            lp["shadow"] = model.shadows is ShadowKind.CAST
        obj = None
        occ = req.occluder
        if occ is not None and getattr(occ, "source", None) and getattr(occ, "source_to_camera", None) is not None:
            from zcomp_cli.blender.meshes import mesh_format

            obj = {"mesh": str(occ.source), "format": mesh_format(occ.source),
                   "matrix": np.asarray(occ.source_to_camera, np.float64).tolist()}
        elif occ is not None and cover is not None and cover.any():
            def mean_of(a, default):
                a = None if a is None else np.asarray(a, np.float64)
                return default if a is None or a.shape[:2] != cover.shape else np.nan_to_num(a[cover]).mean(0)

            obj = {"arrays": True, "color": np.clip(albedo[cover].mean(0), 0, 1).tolist(),
                   "roughness": float(np.clip(mean_of(getattr(req.maps, "roughness", None), 0.5), 0, 1)),
                   "metallic": float(np.clip(mean_of(getattr(req.maps, "metallic", None), 0.0), 0, 1))}
            arrays["object_vertices"] = np.asarray(occ.vertices, np.float32)
            arrays["object_faces"] = np.asarray(occ.faces, np.int32)
        item = {"id": hashlib.sha256(f"{key}-{seed}-{time.monotonic_ns()}".encode()).hexdigest()[:16],
                "mesh_key": key, "border": list(box), "samples": s.samples, "seed": int(seed) % (2 ** 31),
                "denoise": s.denoise, "max_bounces": s.max_bounces, "threads": s.threads,
                "light_passes": bool(req.aovs),
                "world": {"rows": rows.tolist(), "image": str(world_path), "map_resolution": s.world_map_resolution},
                "lamps": lamps, "object": obj}
        return item, arrays


def _light_passes(channels: dict, box, shape) -> dict[str, np.ndarray]:
    """Cycles' light passes of a rendered window (every ``<pass>.R/G/B`` but Combined) as
    full-frame (H, W, 3) float32 layers, 0 outside the window; names lower-case with
    ``_`` (``Diffuse Direct`` -> ``diffuse_direct``)."""
    import re

    x0, y0, x1, y1 = box
    out = {}
    for name in sorted({k.rsplit(".", 1)[0] for k in channels if k.endswith(".R")}):
        if name == "Combined" or f"{name}.G" not in channels or f"{name}.B" not in channels:
            continue
        key = re.sub(r"[^a-z0-9]+", "_", name.lower()).strip("_")[:40]
        full = np.zeros((*shape, 3), np.float32)
        win = np.stack([channels[f"{name}.{c}"] for c in "RGB"], -1)
        full[y0:y1, x0:x1] = np.nan_to_num(win, nan=0.0, posinf=0.0, neginf=0.0)
        out[key] = full
    return out


__all__ = ["CyclesRenderer"]


# The camera's clipping range in Blender: at least Blender's own defaults for a scene in
# metres, and always wide enough for the scene's depths (a pixel's ray, 85 deg off the
# axis in a 170 deg view, is 11.5 times its depth): with a fixed 10 km, a scene 10 km
# deep was clipped away and the path tracer saw the world where its floor was (issue 49).
CLIP_RANGE_M = (1e-3, 1e4)
CLIP_DEPTHS = 100.0


def clip_range(depth) -> list[float]:
    """[clip_start, clip_end] of the camera for a scene of ``depth`` (H, W) z-depths (0 or
    non-finite: none): ``CLIP_RANGE_M`` widened to half the nearest depth and
    ``CLIP_DEPTHS`` times the farthest."""
    d = np.asarray(depth, np.float64)
    d = d[np.isfinite(d) & (d > 0)]
    lo, hi = CLIP_RANGE_M
    if d.size:
        lo, hi = min(lo, 0.5 * float(d.min())), max(hi, CLIP_DEPTHS * float(d.max()))
    return [lo, hi]
