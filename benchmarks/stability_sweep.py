"""Numerical stability on stiff and extreme cases (issue 49): every renderer on generated
scenes pushed to the extremes a user meets, each cell finite or a clear error, its error
against a reference made at higher precision or with more samples, its time and peak
memory. Writes ``docs/stability.md``.

    python benchmarks/stability_sweep.py [--quick] [--renderers physical,naive,zerocomp,cycles]
        [--families range,geometry,stiff] [--cases NAME,...] [--out DIR] [--doc docs/stability.md]
        [--limit-s 300]

Families (``CASES``, ``SOLVER_CASES``, ``SAMPLER_CASES``):

* **range** (dynamic range): the photograph's radiance from 1e-6 to 1e6, a sun 1e5 times its
  sky, black and white albedos, a probe holding the sun in one texel;
* **geometry**: a camera 1 deg above the floor and one looking straight down, fields of
  view of 1 and 170 deg, an object of one pixel, one filling the frame, one at the
  horizon, one cut by the border, depths from 1 mm to 10 km, degenerate normals and depth
  steps;
* **stiff**: the light fit's least squares with nearly collinear columns (a sun at the
  zenith beside the sky's lobes, lamps far away: condition number, weights recovered,
  the solver's convergence), and the zerocomp sampler from 1 to 200 steps in fp32, bf16
  and fp16 (tiny random weights on the CPU) against its fp32, 200-step reference.

Every scene is a ray-cast analytic floor (``zcomp_cli.testing.floor_scene``: a floor, a
box casting a shadow, a sun and a uniform sky) and a sphere given as an object bundle,
written as files and composited by ``zcomp_cli.pipeline.batch.run_batch`` -- the user's
path: the manifest is validated, the maps read and cleaned, the light fitted, both passes
rendered and composited. A cell is:

* ``finite``: the job is done and its composite finite, its object not black;
* ``error``: the job failed or the manifest was refused with a message naming what is
  wrong (a clear error; ``internal error:`` is not one: it counts as ``crash``);
* ``NaN`` / ``black`` / ``crash`` / ``timeout``: a defect (an object drawn black in a lit
  scene, a composite with non-finite values, an exception that is zcomp's bug, a cell
  past ``--limit-s``).

The reference of a cell (column ``ref``):

* ``x k`` (radiance scaled by k): the nominal scene's composite times k -- the transport is
  linear in the light, so a photograph k times brighter must give a composite k times
  brighter; ``= nominal`` (the scene scaled in size): the nominal composite itself;
* ``converged``: the same renderer with more samples (physical: 4x the march steps, cone
  samples and light candidates; Cycles: 16x the samples; zerocomp: fp32 at 8x the steps);
* the sampler's cells: the fp32, 200-step final latent; the solver's: the weights the
  shading was made with.

``err`` is the relative RMS difference over the pixels the job changed (its region of
interest), ``time`` the cell's wall seconds (the reference's run not counted), ``peak MB``
the Python heap's peak (``tracemalloc``: numpy's arrays included, Blender's process not).
The CI slice (``--quick``; ``tests/test_stability_sweep.py``) runs the cases marked
``ci`` on physical, naive and zerocomp at 64x48.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import math
import signal
import sys
import tempfile
import time
import tracemalloc
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SIZE = (64, 48)  # every scene's working size: small enough for CI, large enough for a shadow
# The light estimate's small settings for the sweep's cells (the shipped defaults at 64x48
# work on fewer pixels than max_resolution anyway; fewer candidates keep CI under 3 min).
PHYSICAL = {"n_light_candidates": 64}
# "more samples": the physical renderer's converged reference
PHYSICAL_CONVERGED = {"n_light_candidates": 256, "march_steps": 128, "cone_samples": 32, "estimate_march_steps": 64}
CYCLES = {"samples": 8}
CYCLES_CONVERGED = {"samples": 128}
ZEROCOMP = {"steps": 2, "resolution": 32, "device": "cpu", "dtype": "fp32"}
ZEROCOMP_CONVERGED = {"steps": 16, "resolution": 32, "device": "cpu", "dtype": "fp32"}
# An object whose mean luminance is below this share of the background's, in a lit
# scene, is "black": drawn without light (the defect the issue names).
BLACK_SHARE = 1e-3
SAMPLER_STEPS = (1, 2, 5, 10, 20, 50, 100, 200)
SAMPLER_DTYPES = ("fp32", "bf16", "fp16")


# -- cases ------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Case:
    """A scene cell: ``family``, ``name``, the scene's parameters (``scene``: keyword
    arguments of ``floor_scene`` and of the object, ``build``), how its reference is made
    (``ref``: ``converged``, ``scaled`` -- radiance times ``k`` --, or ``nominal``), the
    renderers it runs on (None: all) and whether it is in the CI slice."""

    family: str
    name: str
    scene: dict = field(default_factory=dict)
    ref: str = "converged"
    k: float = 1.0
    ci: bool = False
    renderers: tuple | None = None


def _cases() -> list[Case]:
    c = []
    for k in (1e-6, 1e-3, 1e3, 1e6):
        c.append(Case("range", f"radiance x {k:g}", {"radiance": k}, ref="scaled", k=k, ci=k in (1e-6, 1e6)))
    c += [
        Case("range", "nominal", {}, ci=True),
        Case("range", "sun 1e5 x sky", {"ambient": 1e-5, "light_intensity": 1.0}, ci=True),
        Case("range", "albedo black (floor 0.02, object 0)", {"albedo": (0.02,) * 3, "object_albedo": (0.0,) * 3}),
        Case("range", "albedo 0 everywhere", {"albedo": (0.0,) * 3, "box_albedo": (0.0,) * 3}, ci=True),
        Case("range", "albedo white (1.0)", {"albedo": (1.0,) * 3, "object_albedo": (1.0,) * 3}),
        Case("range", "probe: sun in one texel", {"probe_sun": True}, ci=True, renderers=("physical", "cycles")),
        Case("geometry", "camera 1 deg above the floor", {"pitch_deg": -1.0, "camera_height": 0.3,
                                                           "object_at": (0.0, -3.0)}, ci=True),
        Case("geometry", "camera looking straight down", {"pitch_deg": -90.0, "object_at": (0.3, -0.2),
                                                           "box_center": (-0.4, 0.2)}, ci=True),
        Case("geometry", "field of view 1 deg", {"fov_deg": 1.0, "object_at": (0.0, -2.573), "radius": 0.01}, ci=True),
        Case("geometry", "field of view 170 deg", {"fov_deg": 170.0, "object_at": (0.0, -1.5), "radius": 0.3}, ci=True),
        Case("geometry", "object of one pixel", {"radius": 0.02}, ci=True),
        Case("geometry", "object filling the frame", {"radius": 0.9, "object_at": (0.0, -2.2)}),
        Case("geometry", "object at the horizon", {"pitch_deg": -3.0, "object_at": (0.0, -400.0), "radius": 2.0}),
        Case("geometry", "object cut by the border", {"object_at": (1.55, -3.0)}, ci=True),
    ]
    for k in (1e-3, 1e4):
        c.append(Case("geometry", f"depths x {k:g} ({'1 mm' if k < 1 else '10 km'} scale)", {"scale": k},
                      ref="nominal", ci=True))
    c += [
        Case("geometry", "degenerate normals (0, NaN, flipped, x5)", {"normals": "degenerate"}, ci=True),
        Case("geometry", "depth steps and holes", {"depth": "steps"}, ci=True),
        Case("stiff", "sun at the zenith", {"light_dir": (0.0, 1.0, 0.0)}, ci=True),
        Case("stiff", "lamp far away (1 km)", {"lamp_far": True}, renderers=("physical", "cycles")),
    ]
    return c


CASES = _cases()
FAMILIES = ("range", "geometry", "stiff")


def case_named(name: str) -> Case:
    for c in CASES:
        if c.name == name:
            return c
    raise KeyError(name)


# -- scenes -----------------------------------------------------------------------------------
def build_scene(case: Case, folder: Path, renderer: dict) -> Path:
    """The case's scene, object and manifest written under ``folder``; returns jobs.yaml."""
    import yaml

    from zcomp_cli.imageio import write_exr
    from zcomp_cli.testing import floor_scene, sphere_object_bundle

    p = dict(case.scene)
    k = float(p.pop("scale", 1.0))
    radiance = float(p.pop("radiance", 1.0))
    ox, oz = p.pop("object_at", (0.0, -3.0))
    radius = float(p.pop("radius", 0.25))
    obj_albedo = p.pop("object_albedo", (0.7, 0.2, 0.2))
    normals_kind, depth_kind = p.pop("normals", None), p.pop("depth", None)
    probe_sun, lamp_far = p.pop("probe_sun", False), p.pop("lamp_far", False)
    bx, bz = p.pop("box_center", (0.8, -3.5))
    kw = {"camera_height": 1.2, "pitch_deg": -25.0, **p}
    if lamp_far:
        kw.update(light_intensity=0.0, lamp=((0.0, 1000.0, -3.0), 1e6))
    s = floor_scene(*SIZE, with_box=True, box_center=(bx * k, bz * k), box_size=(0.6 * k, 0.8 * k, 0.6 * k),
                    **{**kw, "camera_height": kw["camera_height"] * k})
    image, depth, normals, albedo = s.image * radiance, s.depth.copy(), s.normals.copy(), s.albedo.copy()
    if normals_kind == "degenerate":
        normals[30:36, 20:30] = 0.0
        normals[36:40, 30:40] = np.nan
        normals[40:44, 10:20] *= -1.0
        normals[20:26, 40:50] *= 5.0
    if depth_kind == "steps":
        depth[24:30, :] *= 3.0
        depth[30:33, 5:25] = 0.0
        depth[10:12, 40:60] = 1e-9
    folder.mkdir(parents=True, exist_ok=True)
    for name, arr in (("image", image), ("depth", depth), ("normals", normals), ("albedo", albedo)):
        write_exr(folder / f"{name}.exr", np.asarray(arr, np.float32))
    center = s.world_to_camera(np.array([ox * k, radius * k, oz * k]))
    b = sphere_object_bundle(s.camera, center, radius * k, albedo=obj_albedo, floor_normal=s.up_cam)
    b.save(folder / "sphere")
    scene = {"image": "image.exr", "K": s.camera.K.tolist(), "depth": "depth.exr", "normals": "normals.exr",
             "albedo": "albedo.exr"}
    if probe_sun:
        scene["light"] = [_probe_with_sun(folder / "probe.exr", s)]
    m = {"version": 1, "defaults": {"renderer": renderer, "resolution": list(SIZE)}, "scenes": {"s": scene},
         "objects": {"ball": {"bundle": "sphere"}},
         "jobs": [{"scene": "s", "object": "ball", "pose": {"position": [0, 0, -1]}, "output": "job"}]}
    path = folder / "jobs.yaml"
    path.write_text(yaml.safe_dump(m, sort_keys=False))
    return path


def _probe_with_sun(path: Path, s) -> dict:
    """A 64x32 probe (zcomp's convention): a uniform sky of the scene's ambient and the
    scene's sun in ONE texel (its radiance that texel's share of the sun's irradiance),
    the camera's pitch given so that the probe's up is the scene's."""
    from zcomp_cli.imageio import write_exr

    W, H = 64, 32
    img = np.full((H, W, 3), s.ambient, np.float32)
    d = np.asarray(s.light_dir_cam, np.float64)
    up = s.up_cam
    el = math.asin(float(np.clip(d @ up, -1, 1)))
    fwd = np.array([0.0, 0.0, -1.0]) - up * float(np.array([0.0, 0.0, -1.0]) @ up)
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, up)
    az = math.atan2(float(d @ right), float(d @ fwd))
    col = int((az / (2 * math.pi) + 0.5) * W) % W
    row = int(np.clip((math.pi / 2 - el) / math.pi * H, 0, H - 1))
    theta0, theta1 = row * math.pi / H, (row + 1) * math.pi / H
    omega = (2 * math.pi / W) * (math.cos(theta0) - math.cos(theta1))
    img[row, col] = s.light_intensity * math.pi / omega  # E = L omega; the shading of a sun is E / pi
    write_exr(path, img)
    return {"type": "probe", "hdr": path.name}


# -- running a cell ---------------------------------------------------------------------------
@dataclass
class Cell:
    """One renderer on one case (module docstring)."""

    renderer: str
    family: str
    case: str
    outcome: str = ""
    message: str = ""
    err: float = float("nan")
    ref: str = ""
    seconds: float = float("nan")
    peak_mb: float = float("nan")
    extra: dict = field(default_factory=dict)

    def row(self) -> dict:
        return dataclasses.asdict(self)


class CellTimeout(Exception):
    pass


@contextlib.contextmanager
def time_limit(seconds: float | None):
    """Raise ``CellTimeout`` in the main thread after ``seconds`` (None: no limit)."""
    if not seconds or not hasattr(signal, "SIGALRM"):
        yield
        return

    def _raise(signum, frame):
        raise CellTimeout(f"past {seconds:g} s")

    old = signal.signal(signal.SIGALRM, _raise)
    signal.setitimer(signal.ITIMER_REAL, float(seconds))
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def renderer_spec(name: str, converged: bool, weights: tuple | None = None) -> dict:
    """The manifest's ``renderer:`` of a cell (or of its converged reference)."""
    if name == "physical":
        return {"name": "physical", **(PHYSICAL_CONVERGED if converged else PHYSICAL)}
    if name == "cycles":
        return {"name": "cycles", **(CYCLES_CONVERGED if converged else CYCLES)}
    if name == "zerocomp":
        ck, base = weights
        return {"name": "zerocomp", "controlnet": str(ck), "base": str(base),
                **(ZEROCOMP_CONVERGED if converged else ZEROCOMP)}
    return {"name": name}


def composite_of(folder: Path, manifest: Path, limit_s: float | None = None) -> tuple[dict, np.ndarray | None]:
    """Run the manifest's one job into ``folder/out``: (its outcome as a dict, the linear
    composite or None)."""
    from zcomp_cli.errors import ZcompError
    from zcomp_cli.imageio import read_image
    from zcomp_cli.pipeline.batch import run_batch
    from zcomp_cli.pipeline.manifest import load_manifest

    out = folder / "out"
    try:
        with time_limit(limit_s):
            summary = run_batch(load_manifest(manifest), out, overwrite=True)
    except CellTimeout as exc:
        return {"outcome": "timeout", "message": str(exc)}, None
    except ZcompError as exc:  # refused before any job ran: a clear error
        return {"outcome": "error", "message": f"{type(exc).__name__}: {exc}"}, None
    except Exception as exc:  # noqa: BLE001 - zcomp's own bug
        return {"outcome": "crash", "message": f"{type(exc).__name__}: {exc}"}, None
    st = summary.statuses[0]
    if st.status != "done":
        reason = str(st.reason)
        return {"outcome": "crash" if reason.startswith("internal error") else "error", "message": reason}, None
    img = read_image(out / "job" / "composite.exr")
    rep = json.loads((out / "job" / "report.json").read_text())
    return {"outcome": "done", "report": rep}, img


def classify(img: np.ndarray, folder: Path, report: dict) -> tuple[str, str]:
    """(outcome, message) of a finished job's composite: NaN, black (the object drawn
    without light in a lit scene) or finite."""
    from zcomp_cli.imageio import read_image

    if not np.all(np.isfinite(img)):
        return "NaN", f"{int((~np.isfinite(img)).sum())} non-finite values in composite.exr"
    mask = read_image(folder / "sphere" / "mask.exr")[..., 0] > 0.5 if (folder / "sphere" / "mask.exr").exists() else None
    bg = read_image(folder / "image.exr")
    lum = lambda a: a @ np.array([0.299, 0.587, 0.114], np.float32)
    alb = read_image(folder / "sphere" / "albedo.exr")
    if mask is not None and mask.any() and float(alb[mask].max()) > 0.05:
        obj = float(np.mean(lum(img)[mask]))
        level = float(np.mean(lum(bg)[~mask]))
        if level > 0 and obj < BLACK_SHARE * level:
            return "black", f"object luminance {obj:.3g} against the background's {level:.3g}"
    return "finite", ""


def rel_err(a: np.ndarray, b: np.ndarray, box) -> float:
    """Relative RMS difference of ``a`` against ``b`` over ``box`` (x0, y0, x1, y1)."""
    x0, y0, x1, y1 = box
    da, db = a[y0:y1, x0:x1].astype(np.float64), b[y0:y1, x0:x1].astype(np.float64)
    den = math.sqrt(float(np.mean(db ** 2)))
    return math.sqrt(float(np.mean((da - db) ** 2))) / den if den > 0 else float("nan")


def run_cell(case: Case, renderer: str, work: Path, *, weights=None, limit_s=None, reference=True,
             nominal: dict | None = None) -> Cell:
    """One renderer on one case (module docstring). ``nominal``: the nominal case's
    (composite, roi) per renderer, the reference of the scaled cases (filled on first use)."""
    cell = Cell(renderer, case.family, case.name)
    folder = work / f"{renderer}-{_slug(case.name)}"
    manifest = build_scene(case, folder, renderer_spec(renderer, False, weights))
    tracemalloc.start()
    t0 = time.perf_counter()
    res, img = composite_of(folder, manifest, limit_s)
    cell.seconds = time.perf_counter() - t0
    cell.peak_mb = tracemalloc.get_traced_memory()[1] / 2 ** 20
    tracemalloc.stop()
    if img is None:
        cell.outcome, cell.message = res["outcome"], res["message"]
        return cell
    rep = res["report"]
    cell.outcome, cell.message = classify(img, folder, rep)
    cell.extra["notes"] = rep.get("notes", [])
    cell.extra["stages"] = rep.get("stages")
    box = rep["roi"]["box"]
    if case.ref in ("scaled", "nominal") and nominal is not None:
        ref = nominal.get(renderer)
        if ref is None:
            nom = Case(case.family, "nominal")
            f2 = work / f"{renderer}-nominal-ref"
            _, ref_img = composite_of(f2, build_scene(nom, f2, renderer_spec(renderer, False, weights)), limit_s)
            ref = nominal[renderer] = ref_img
        if ref is not None:
            k = case.k if case.ref == "scaled" else 1.0
            cell.err, cell.ref = rel_err(img / k, ref, box), ("x k" if case.ref == "scaled" else "= nominal")
    elif reference and renderer != "naive":
        f2 = work / f"{renderer}-{_slug(case.name)}-ref"
        _, ref_img = composite_of(f2, build_scene(case, f2, renderer_spec(renderer, True, weights)), None)
        if ref_img is not None:
            cell.err, cell.ref = rel_err(img, ref_img, box), "converged"
    return cell


def _slug(name: str) -> str:
    return "".join(ch if ch.isalnum() else "_" for ch in name)[:60]


__all__ = ["CASES", "Case", "Cell", "build_scene", "run_cell", "case_named"]


def tiny_weights(folder: Path) -> tuple[Path, Path]:
    """Tiny random SD-2.1-shaped components in the official layout (the tests' own,
    ``tests/zerocomp_dummy.py``): (the ControlNet checkpoint, the base)."""
    sys.path.insert(0, str(ROOT / "tests"))
    try:
        from zerocomp_dummy import save_dummy
    finally:
        sys.path.remove(str(ROOT / "tests"))
    return save_dummy(folder, 11)
