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
# The physical renderer's settings: the CI slice's fewer light candidates (at 64x48 the
# other defaults work on every pixel anyway; 64 candidates keep CI under 3 min), the full
# sweep's shipped defaults, and its "more samples" reference: 4x the light candidates,
# the march steps (of the synthesis and of the fit) and the cone samples.
PHYSICAL_QUICK = {"n_light_candidates": 64}
PHYSICAL = {}
PHYSICAL_CONVERGED = {"n_light_candidates": 1024, "march_steps": 128, "cone_samples": 32, "estimate_march_steps": 64}
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
    settings: dict = field(default_factory=dict)  # the renderer's settings for this case


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
        Case("range", "depths x 1e5 in fp16 (past 65504)", {"scale": 1e5}, ref="none", ci=True,
             renderers=("zerocomp",), settings={"dtype": "fp16"}),
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
    # (a scene k times larger is the nominal one's depths times k: floor_scene's own shadow
    # rays start 1e-4 m off their surface, which is not the same scene at every scale)
    s = floor_scene(*SIZE, with_box=True, box_center=(bx, bz), **kw)
    image, depth, normals, albedo = s.image * radiance, s.depth * k, s.normals.copy(), s.albedo.copy()
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
    center = s.world_to_camera(np.array([ox, radius, oz]))
    b = sphere_object_bundle(s.camera, center, radius, albedo=obj_albedo, floor_normal=s.up_cam)
    if k != 1.0:
        b = dataclasses.replace(b, depth=b.depth * k, footprint_depth=b.footprint_depth * k,
                                meta={**b.meta, "object_height_m": b.meta["object_height_m"] * k})
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


class PeakMemory:
    """The memory a block added at its peak, in MB: the larger of the Python heap's peak
    (``tracemalloc``: numpy's arrays included) and the process's resident high-water
    mark above its start (Linux: ``/proc/self/status`` VmHWM, reset through
    ``clear_refs``; torch's tensors are only seen there). Blender's process is not counted."""

    def __enter__(self):
        self.rss0 = _rss("VmRSS")
        with contextlib.suppress(OSError):
            Path("/proc/self/clear_refs").write_text("5")  # resets VmHWM to the current RSS
        tracemalloc.start()
        return self

    def __exit__(self, *exc):
        heap = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        hwm = _rss("VmHWM")
        self.mb = max(heap, (hwm - self.rss0) if (hwm and self.rss0) else 0) / 2 ** 20
        return False


def _rss(field_name: str) -> int | None:
    """A ``/proc/self/status`` memory field in bytes (None where there is none)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith(field_name + ":"):
                return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


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


def renderer_spec(name: str, converged: bool, weights: tuple | None = None, quick: bool = True) -> dict:
    """The manifest's ``renderer:`` of a cell (or of its converged reference; ``quick``:
    the CI slice's)."""
    if name == "physical":
        return {"name": "physical", **(PHYSICAL_CONVERGED if converged else PHYSICAL_QUICK if quick else PHYSICAL)}
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
            # (one cache for the sweep, beside its cells: a scene's light is fitted once)
            summary = run_batch(load_manifest(manifest), out, overwrite=True, cache_dir=folder.parent / "cache")
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
    composite per renderer, the reference of the scaled cases (filled on first use);
    ``reference``: the full sweep (the shipped settings, a converged reference), else the
    CI slice's."""
    cell = Cell(renderer, case.family, case.name)
    folder = work / f"{renderer}-{_slug(case.name)}"
    spec = renderer_spec(renderer, False, weights, quick=not reference)
    manifest = build_scene(case, folder, {**spec, **case.settings})
    with PeakMemory() as mem:
        t0 = time.perf_counter()
        res, img = composite_of(folder, manifest, limit_s)
        cell.seconds = time.perf_counter() - t0
    cell.peak_mb = mem.mb
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
            _, ref_img = composite_of(f2, build_scene(nom, f2, spec), limit_s)
            ref = nominal[renderer] = ref_img
        if ref is not None:
            k = case.k if case.ref == "scaled" else 1.0
            cell.err, cell.ref = rel_err(img / k, ref, box), ("x k" if case.ref == "scaled" else "= nominal")
    elif reference and renderer != "naive" and case.ref == "converged":
        f2 = work / f"{renderer}-{_slug(case.name)}-ref"
        _, ref_img = composite_of(f2, build_scene(case, f2, renderer_spec(renderer, True, weights)), None)
        if ref_img is not None:
            cell.err, cell.ref = rel_err(img, ref_img, box), "converged"
    return cell


def _slug(name: str) -> str:
    """A folder name of a case's (``1e-06`` and ``1e+06`` kept apart)."""
    return "".join(ch if ch.isalnum() or ch in "-." else "_" for ch in name.replace("+", "p"))[:60]


# -- the sweep --------------------------------------------------------------------------------
RENDERERS = ("physical", "naive", "zerocomp", "cycles")
# the cases the cycles renderer runs (each starts Blender's render of two passes: the few
# that say most about a path tracer fed zcomp's maps and light)
# the CI slice's zerocomp cases (each loads the tiny weights again: run_batch builds a renderer)
ZEROCOMP_CI = ("nominal", "radiance x 1e-06", "radiance x 1e+06", "field of view 170 deg", "object of one pixel",
               "degenerate normals (0, NaN, flipped, x5)", "depths x 1e5 in fp16 (past 65504)")
CYCLES_CASES = ("nominal", "radiance x 1e-06", "radiance x 1e+06", "sun 1e5 x sky", "probe: sun in one texel",
                "field of view 170 deg", "depths x 10000 (10 km scale)", "degenerate normals (0, NaN, flipped, x5)",
                "lamp far away (1 km)")


def scene_cells(work: Path, renderers, *, quick: bool, limit_s: float | None, names=None, families=FAMILIES,
                progress=print) -> list[Cell]:
    """Every scene case (``--quick``: those marked ``ci``) of ``families`` on each renderer
    that runs it."""
    weights = tiny_weights(work / "weights") if "zerocomp" in renderers else None
    cells = []
    for r in renderers:
        nominal: dict = {}
        for case in CASES:
            if (quick and not case.ci) or (names and case.name not in names) or case.family not in families:
                continue
            if (case.renderers and r not in case.renderers) or (r == "cycles" and case.name not in CYCLES_CASES):
                continue
            if quick and r == "zerocomp" and case.name not in ZEROCOMP_CI:
                continue
            cell = run_cell(case, r, work, weights=weights, limit_s=limit_s, reference=not quick, nominal=nominal)
            cells.append(cell)
            progress(_line(cell))
    return cells


def _line(c: Cell) -> str:
    err = "" if not math.isfinite(c.err) else f"{c.err:.3g}"
    return (f"{c.renderer:16s} {c.family:9s} {c.case:44s} {c.outcome:8s} {err:>9s} {c.ref:14s} {c.seconds:7.2f} s "
            f"{c.peak_mb:7.1f} MB  {c.message[:120]}")


DEFECTS = ("NaN", "black", "crash", "timeout")


def markdown(cells: list[Cell], *, quick: bool, seconds: float) -> str:
    """``docs/stability.md``'s tables: per renderer, the solver's and the sampler's."""
    lines = [HEADER.format(mode="--quick (the CI slice)" if quick else "the full sweep", seconds=seconds), ""]
    bad = [c for c in cells if c.outcome in DEFECTS]
    lines.append(f"**{len(cells)} cells: {sum(c.outcome == 'finite' for c in cells)} finite, "
                 f"{sum(c.outcome == 'error' for c in cells)} clear errors, {len(bad)} defects.**")
    lines.append("")
    for r in dict.fromkeys(c.renderer for c in cells):
        rows = [c for c in cells if c.renderer == r]
        lines += [f"### {r}", "", "| family | case | outcome | err | reference | time (s) | peak MB | what it says |",
                  "| --- | --- | --- | --- | --- | --- | --- | --- |"]
        for c in rows:
            err = "" if not math.isfinite(c.err) else f"{c.err:.2g}"
            msg = c.message or "; ".join(n for n in c.extra.get("notes", []) if not n.startswith("colour balance"))
            mb = f"{c.peak_mb:.0f}" if math.isfinite(c.peak_mb) else "-"
            lines.append(f"| {c.family} | {c.case} | {c.outcome} | {err} | {c.ref} | {c.seconds:.2f} | "
                         f"{mb} | {_cell_text(msg)} |")
        lines.append("")
    return "\n".join(lines)


def _cell_text(s: str, n: int = 220) -> str:
    s = s.replace("|", "/").replace("\n", " ")
    return s if len(s) <= n else s[: n - 1] + "…"


HEADER = """## The tables ({mode}, {seconds:.0f} s)

Written by `python benchmarks/stability_sweep.py --doc docs/stability.md` between the
markers below; the prose around them is kept."""
def write_doc(path: Path, tables: str, what: str = "stability tables") -> None:
    """``tables`` into ``path`` between the markers ``<!-- {what}: begin -->`` and
    ``<!-- {what}: end -->`` (the rest of the page is kept; a page without them gets them
    at its end)."""
    BEGIN, END = f"<!-- {what}: begin -->", f"<!-- {what}: end -->"
    old = path.read_text() if path.exists() else ""
    block = f"{BEGIN}\n{tables}\n{END}"
    if BEGIN in old and END in old:
        new = old[: old.index(BEGIN)] + block + old[old.index(END) + len(END):]
    else:
        new = old.rstrip("\n") + ("\n\n" if old else "") + block + "\n"
    path.write_text(new)


def sampler_figure(cells: list[Cell], path: Path) -> None:
    """The sampler's final latent against its reference, per dtype, over the steps (log-log)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.5, 3.6), dpi=120)
    for dt, marker in zip(SAMPLER_DTYPES, "osd"):
        pts = sorted((int(c.case.split()[0]), c.err) for c in cells
                     if c.renderer == "zerocomp sampler" and c.case.endswith(dt) and math.isfinite(c.err)
                     and c.err > 0)  # (the reference itself: 0 on a log axis)
        if pts:
            ax.loglog(*zip(*pts), marker=marker, label=dt)
    ax.set_xlabel("DDIM steps")
    ax.set_ylabel("final latent, relative RMS\nagainst fp32 at 200 steps")
    ax.set_title("zerocomp's sampler (tiny random weights, CPU)", fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="the CI slice: the cases marked ci, no converged reference")
    ap.add_argument("--renderers", default=",".join(RENDERERS))
    ap.add_argument("--families", default="range,geometry,stiff")
    ap.add_argument("--cases", default="", help="only these scene cases (names, '|'-separated)")
    ap.add_argument("--no-sampler", action="store_true")
    ap.add_argument("--out", type=Path, default=None, help="the cells as JSON (OUT/stability.json)")
    ap.add_argument("--doc", type=Path, default=None, help="write the tables as markdown (docs/stability.md)")
    ap.add_argument("--limit-s", type=float, default=600.0, help="a cell longer than this is 'timeout'")
    ap.add_argument("--figure", type=Path, default=None, help="the sampler's error over its steps (a PNG)")
    ap.add_argument("--from-json", type=Path, default=None,
                    help="no run: the doc and figure of a sweep's stability.json (with its seconds: --seconds)")
    ap.add_argument("--seconds", type=float, default=float("nan"))
    a = ap.parse_args(argv)
    if a.from_json is not None:
        cells = [Cell(**row) for row in json.loads(a.from_json.read_text())]
        if a.doc is not None:
            write_doc(a.doc, markdown(cells, quick=a.quick, seconds=a.seconds))
        if a.figure is not None:
            sampler_figure(cells, a.figure)
        return 0
    _quiet()
    renderers = [r for r in a.renderers.split(",") if r]
    families = set(a.families.split(","))
    names = set(a.cases.split("|")) if a.cases else None
    t0 = time.perf_counter()
    work = Path(tempfile.mkdtemp(prefix="zcomp-stability-"))
    cells = []
    try:
        cells += scene_cells(work, renderers, quick=a.quick, limit_s=a.limit_s, names=names, families=families)
        if "stiff" in families and not names:
            for c in solver_cells():
                print(_line(c))
                cells.append(c)
            if "zerocomp" in renderers and not a.no_sampler:
                steps = (1, 2, 5, 20) if a.quick else SAMPLER_STEPS
                for c in sampler_cells(work, steps=steps, ref_steps=50 if a.quick else 200):
                    print(_line(c))
                    cells.append(c)
    finally:
        import shutil

        shutil.rmtree(work, ignore_errors=True)
    seconds = time.perf_counter() - t0
    if a.out is not None:
        a.out.mkdir(parents=True, exist_ok=True)
        (a.out / "stability.json").write_text(json.dumps([c.row() for c in cells], indent=1, default=str))
    text = markdown(cells, quick=a.quick, seconds=seconds)
    if a.doc is not None:
        write_doc(a.doc, text)
    if a.figure is not None and any(c.renderer == "zerocomp sampler" for c in cells):
        sampler_figure(cells, a.figure)
    print(f"{len(cells)} cells in {seconds:.0f} s; defects: {[c.case for c in cells if c.outcome in DEFECTS]}")
    return 1 if any(c.outcome in DEFECTS for c in cells) else 0


__all__ = ["CASES", "Case", "Cell", "build_scene", "run_cell", "case_named", "scene_cells", "solver_cells",
           "sampler_cells", "main"]



# -- the light fit's stiff least squares ----------------------------------------------------
SOLVER_NOISE = 0.01
SOLVER_CASES = ("sun at 45 deg (control)", "sun at the zenith", "lamp 1 km away", "lamp 1 km away, unit scale",
                "sun at the zenith, bare floor")


def solver_cells(names=SOLVER_CASES) -> list[Cell]:
    """The light fit's robust NNLS (``light.solver.fit``) on nearly collinear columns:
    a floor's fit pixels (``light.prepare``), the sky's lobes and one light -- a sun at
    45 deg (well posed), at the zenith (its column is the uniform lobe's on a floor), a
    lamp 1 km above (its column is ~1e-6 of the others', and as flat) -- with shading made
    from known weights and 1 % noise. Per cell: the columns' condition number (each scaled to unit
    norm), the shading's and the weights' relative errors, and the reweighting's
    convergence (the weights after the solver's iterations against 50 more)."""
    import dataclasses as dc

    from zcomp_cli.light import atoms as at
    from zcomp_cli.light.config import LightConfig
    from zcomp_cli.light.prepare import prepare
    from zcomp_cli.light.solver import Atom, fit
    from zcomp_cli.testing import floor_scene

    cfg = LightConfig()
    out = []
    for name in names:
        cell = Cell("light fit", "stiff", name, ref="known weights")
        t0 = time.perf_counter()
        # a box (its faces and its shadow tell lights apart), or a bare floor (nothing does)
        s = floor_scene(*SIZE, with_box="bare" not in name, box_center=(0.8, -3.5))
        pp = prepare(s.depth, s.normals, s.shading, s.depth > 0, s.albedo, s.camera, s.up_cam, cfg, shadows=False)
        fp, up, lobes = pp.fp, s.up_cam, pp.lobe_columns
        if name.startswith("sun"):
            d = up if "zenith" in name else (up + np.cross(up, [1.0, 0, 0]) / np.linalg.norm(np.cross(up, [1.0, 0, 0])))
            col = at.sun_column(fp, d / np.linalg.norm(d), 0.265, steps=cfg.estimate_march_steps,
                                cone_samples=cfg.cone_samples)
            w_light = 1.0
        else:
            q = pp.anchor + up * 1000.0
            col = at.lamp_columns(fp, q[None], steps=cfg.estimate_march_steps)[:, 0]
            w_light = 1.0 / max(float(np.median(col)), 1e-300)  # lights the floor as a unit sun does
            if "unit scale" in name:  # the column in the solver's units: what scaling would buy
                col, w_light = col * w_light, 1.0
        X = np.concatenate([col[:, None], lobes], 1)
        w_true = np.zeros(X.shape[1])
        w_true[0], w_true[1] = w_light, 0.3 / max(float(np.median(lobes[:, 0])), 1e-12)
        clean_y = X @ w_true
        # 1 % noise (a render's, a photograph's grain): what an ill-conditioned split amplifies
        y = clean_y * (1.0 + SOLVER_NOISE * np.random.default_rng(0).standard_normal(len(clean_y)))
        atoms_ = [Atom(f"c{i}", X[:, i], direct=(i == 0)) for i in range(X.shape[1])]
        try:
            r4 = fit(atoms_, y, train=fp.train, cfg=cfg.solver)
            r50 = fit(atoms_, y, train=fp.train, cfg=dc.replace(cfg.solver, irls_iters=cfg.solver.irls_iters + 50))
        except Exception as exc:  # noqa: BLE001 - reported as the cell's crash
            cell.outcome, cell.message = "crash", f"{type(exc).__name__}: {exc}"
            out.append(cell)
            continue
        w4 = np.array([w[0] for w in r4.weights])
        w50 = np.array([w[0] for w in r50.weights])
        norms = np.linalg.norm(X, axis=0)
        cond = float(np.linalg.cond(X / np.maximum(norms, 1e-300)))
        cell.seconds = time.perf_counter() - t0
        finite = np.all(np.isfinite(w4))
        cell.outcome = "finite" if finite else "NaN"
        cell.err = float(np.linalg.norm(X @ w4 - clean_y) / np.linalg.norm(clean_y))
        light_err = abs(w4[0] - w_true[0]) / w_true[0]
        step = float(np.linalg.norm(w4 - w50) / max(np.linalg.norm(w50), 1e-300))
        # how far the light's column lies from the sky's span (sin of the angle): 0 = collinear
        proj = lobes @ np.linalg.lstsq(lobes, col, rcond=None)[0]
        sep = float(np.linalg.norm(col - proj) / max(np.linalg.norm(col), 1e-300))
        cell.extra.update(cond=cond, light_weight_err=float(light_err), irls_step=step, separation=sep)
        cell.message = (f"cond {cond:.3g}; the light off the sky's span by {sep:.2g}; its weight "
                        f"{100 * light_err:.3g} % off; {cfg.solver.irls_iters} iterations against "
                        f"{cfg.solver.irls_iters + 50}: {step:.2g}")
        out.append(cell)
    return out


# -- the zerocomp sampler ---------------------------------------------------------------------
def sampler_cells(work: Path, steps=SAMPLER_STEPS, dtypes=SAMPLER_DTYPES, ref_steps: int = 200) -> list[Cell]:
    """The zerocomp sampler (``renderers.zerocomp.pipeline.run_pipeline``: DDIM, trailing
    spacing, v-prediction) on tiny random weights on the CPU, one job's two passes, from
    1 to 200 steps in each dtype: its final latent against the fp32, ``ref_steps``-step
    one (relative RMS); a dtype the CPU cannot run, or an overflow, is the clear error
    the renderer gives (``NumericalError`` names the step and the dtype)."""
    import torch

    from zcomp_cli.errors import ZcompError
    from zcomp_cli.renderers.zerocomp.conditioning import build_conditioning
    from zcomp_cli.renderers.zerocomp.loading import load_models
    from zcomp_cli.renderers.zerocomp.pipeline import run_pipeline

    _quiet()
    torch.set_num_threads(1)  # (two threads on a shared 2-core machine ran 60 times slower)
    ck, base = tiny_weights(work / "weights")
    req = _zerocomp_request()
    cond = np.stack([build_conditioning(req, 11, 32)] * 2)
    types = {"fp32": torch.float32, "bf16": torch.bfloat16, "fp16": torch.float16}
    models32 = load_models(ck, base, device="cpu", dtype=torch.float32)
    ref = run_pipeline(models32, cond, steps=ref_steps, seed=469, device="cpu", dtype=torch.float32).latents
    out = []
    for dt in dtypes:
        models = models32 if dt == "fp32" else load_models(ck, base, device="cpu", dtype=types[dt])
        for n in steps:
            cell = Cell("zerocomp sampler", "stiff", f"{n} steps, {dt}", ref=f"fp32, {ref_steps} steps")
            with PeakMemory() as mem:
                t0 = time.perf_counter()
                try:
                    lat = run_pipeline(models, cond, steps=n, seed=469, device="cpu", dtype=types[dt]).latents
                    cell.outcome = "finite" if np.all(np.isfinite(lat)) else "NaN"
                    cell.err = float(np.sqrt(np.mean((lat - ref) ** 2)) / np.sqrt(np.mean(ref ** 2)))
                except ZcompError as exc:
                    cell.outcome, cell.message = "error", f"{type(exc).__name__}: {exc}"
                except Exception as exc:  # noqa: BLE001
                    cell.outcome, cell.message = "crash", f"{type(exc).__name__}: {exc}"
                cell.seconds = time.perf_counter() - t0
            cell.peak_mb = mem.mb
            out.append(cell)
    return out


def _zerocomp_request():
    """A floor scene's composite request (the nominal case's maps, its shading masked
    around the sphere) at SIZE."""
    from zcomp_cli.maps import SceneMaps
    from zcomp_cli.renderers.base import RenderRequest
    from zcomp_cli.testing import floor_scene, insert_bundle, sphere_object_bundle

    s = floor_scene(*SIZE, with_box=True, box_center=(0.8, -3.5))
    b = sphere_object_bundle(s.camera, s.world_to_camera([0.0, 0.25, -3.0]), 0.25, albedo=(0.7, 0.2, 0.2),
                             floor_normal=s.up_cam)
    d, n, a, sel = insert_bundle(s.depth, s.normals, s.albedo, b)
    known = ~sel
    known[18:40, 20:44] = False
    return RenderRequest(SceneMaps(d, n, a), s.shading, known, s.camera, roi=(16, 14, 48, 44), image=s.image)


def _quiet() -> None:
    """diffusers' and transformers' progress bars and advice off (the table is the output)."""
    import logging
    import os

    os.environ.setdefault("HF_HUB_DISABLE_PROGRESS_BARS", "1")
    for name in ("diffusers", "transformers", "huggingface_hub"):
        logging.getLogger(name).setLevel(logging.ERROR)
    try:
        from diffusers.utils import logging as dl

        dl.set_verbosity_error()
        dl.disable_progress_bar()
        from transformers.utils import logging as tl

        tl.set_verbosity_error()
        tl.disable_progress_bar()
    except Exception:  # noqa: BLE001 - only noise
        pass


def tiny_weights(folder: Path) -> tuple[Path, Path]:
    """Tiny random SD-2.1-shaped components in the official layout (the tests' own,
    ``tests/zerocomp_dummy.py``): (the ControlNet checkpoint, the base)."""
    sys.path.insert(0, str(ROOT / "tests"))
    try:
        from zerocomp_dummy import save_dummy
    finally:
        sys.path.remove(str(ROOT / "tests"))
    return save_dummy(folder, 11)


if __name__ == "__main__":
    sys.exit(main())
