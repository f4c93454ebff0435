"""Error against run time: which renderer setting is cheapest for a quality budget?

The logic behind ``benchmarks/sweep_error_vs_time.py`` (a thin script calling :func:`main`):

    python benchmarks/sweep_error_vs_time.py BENCH_DIR --out OUT [--quick] [--knobs K1,K2]
        [--values march_steps=8,16,32] [--max-jobs N] [--resume]

BENCH_DIR holds a benchmark made by ``zcomp make-benchmark`` (``jobs.yaml`` whose jobs
name their ground-truth ``reference``). One cost knob is varied at a time around the
renderer's defaults (not a grid), and every configuration is run the way a user runs it,
by the same code: a snapshot of the zcomp_cli package taken at the start
(``OUT/code``, its sha256 kept with every result; ``--live-source`` skips it):

1. write ``OUT/manifests/<config>.yaml``, a copy of the benchmark's jobs.yaml with
   absolute paths and the configuration's ``defaults: {renderer: {...}, resolution}``;
2. ``zcomp composite`` it into ``OUT/runs/<config>/`` (a fresh process per
   configuration, so the physical renderer's per-scene light cache never carries over:
   every configuration pays its own light estimation, the honest per-job cost);
3. when the working resolution is below the references', upsample each composite
   (bicubic on linear values, clamped at 0) into ``OUT/runs/<config>_upsampled/`` with
   a copy of its report.json, because the metrics need same-size images;
4. ``zcomp eval --metrics psnr,flip`` on that folder (``eval.json``'s ``mean``);
5. the median seconds per job is the median of the jobs' ``report.json``
   ``timings.job_total_s`` (object renders by Blender are cached and not part of it);
   the renderer's own ``renderer.timings`` are summed over the jobs as well.

Knobs:
* physical: working ``resolution`` (native, 3/4, 1/2, keeping the aspect),
  ``march_steps``, ``n_light_candidates``, ``max_resolution`` (of the light estimation),
  the light fit's ``cone_samples`` and ``estimate_march_steps``, and the object's rays
  (``transport.light_samples``, ``transport.sky_rays``, ``transport.bounce_rays``,
  ``gloss.reflect_rays``, ``gloss.highlight_samples``: what the path tracer's samples stand
  beside);
* zerocomp: DDIM ``steps`` at full frame and with ``crop``, only when ZCOMP_CONTROLNET
  and ZCOMP_SD_BASE name existing folders (otherwise the skip and its reason are printed);
* cycles: path ``samples`` with Open Image Denoise (``samples_denoised``) and without
  (``samples_raw``);
* naive paste: one reference point.

``--jobs-file jobs.yaml --jobs-file jobs_oracle_full.yaml`` sweeps the benchmark under
each manifest of the folder (the full oracle's light: ``benchmarks/run_benchmark.py
--oracle full`` writes it), the later manifests' series named after them, in one figure.

Outputs: ``OUT/sweep.csv`` (renderer, knob, value, psnr, flip, median_s_per_job, n_jobs,
n_failed, then default, per-image medians of PSNR and FLIP, renderer timing sums, the
composite process's wall and CPU seconds and the scored folder),
``OUT/sweep.png`` (PSNR and FLIP against median s/job, log x, one series per knob,
points labelled by value) and a printed table. ``--resume`` reuses configurations whose
row is already in ``OUT/rows/``. Job timings are wall clock: on a busy machine compare
them with the composite processes' CPU seconds before trusting small differences.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import shutil
import statistics
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

METRICS = ("psnr", "flip")
CSV_COLUMNS = ["renderer", "knob", "value", "psnr", "flip", "median_s_per_job", "n_jobs", "n_failed",
               "default", "psnr_median", "flip_median", "renderer_timings_s_sum", "composite_wall_s", "composite_cpu_s", "run_dir"]

# Knob values (one knob varied at a time; the renderer's default is added to each series).
PHYSICAL_KNOBS_FULL = {
    "resolution": [1.0, 0.75, 0.5],  # fraction of the benchmark's size
    "march_steps": [8, 16, 32, 64],
    "n_light_candidates": [64, 128, 256],
    "max_resolution": [96, 160, 256],
    # the light fit's own samples (issue 49: the stability sweep's knobs that trade
    # accuracy for time): directions per pixel over a light's cone, steps of its march
    "cone_samples": [2, 4, 8, 16],
    "estimate_march_steps": [8, 16, 32],
    # the object's rays (issue 48): over each light's disc, toward the sky, the bounce,
    # the glossy reflection (0: none; the reflection falls back to the prefiltered sky)
    "light_samples": [4, 8, 16, 32],
    "sky_rays": [8, 16, 32, 64],
    "bounce_rays": [0, 4, 16, 32],
    "reflect_rays": [0, 2, 8, 16],
    # points of each light's disc its highlight on the object sums (1: the widened lobe)
    "highlight_samples": [1, 4, 16, 32],
}
# the knobs the renderer takes inside one of its settings' groups ({group: {knob: v}})
NESTED_KNOBS = {"light_samples": "transport", "sky_rays": "transport", "bounce_rays": "transport",
                "reflect_rays": "gloss", "highlight_samples": "gloss"}
PHYSICAL_KNOBS_QUICK = {
    "resolution": [1.0, 0.5],
    "march_steps": [8, 32],
    "n_light_candidates": [64, 256],
    "max_resolution": [96, 160],
    "cone_samples": [4, 8],
    "estimate_march_steps": [8, 16],
    "light_samples": [4, 16],
    "sky_rays": [8, 32],
    "bounce_rays": [0, 16],
    "reflect_rays": [0, 8],
    "highlight_samples": [1, 16],
}
ZEROCOMP_STEPS_FULL = [1, 2, 4, 8, 20]
ZEROCOMP_STEPS_QUICK = [1, 4]
# Cycles' path samples, with Open Image Denoise (its default) and without.
CYCLES_SAMPLES_FULL = [4, 16, 32, 128]
CYCLES_SAMPLES_QUICK = [8, 32]
ALL_KNOBS = (*PHYSICAL_KNOBS_FULL, "zerocomp", "naive", "cycles")


# ----------------------------------------------------------------------------- configurations
@dataclass
class Config:
    """One run of the benchmark.

    ``key`` names its folders; ``settings`` is the manifest's renderer mapping without
    ``name``; ``resolution`` is (W, H) or None for the benchmark's own size.
    ``series`` lists the (knob, value label) rows this run stands for (the default run
    is a point of every physical knob's series).
    """

    key: str
    renderer: str
    settings: dict = field(default_factory=dict)
    resolution: tuple[int, int] | None = None
    series: list[tuple[str, str]] = field(default_factory=list)
    default: bool = False


def scaled_resolution(native: tuple[int, int], fraction: float) -> tuple[int, int]:
    """(W, H) scaled by ``fraction`` with the aspect kept: W rounds, H follows W.

    Raises ValueError for a fraction outside (0, 1], a result below 16 px (the size
    ``zcomp make-benchmark`` itself refuses), or when rounding would break the
    manifest's 1 % aspect tolerance.
    """
    W, H = int(native[0]), int(native[1])
    if not (0 < fraction <= 1) or not math.isfinite(fraction):
        raise ValueError(f"resolution fraction must be in (0, 1], got {fraction}")
    w = max(1, round(W * fraction))
    h = max(1, round(w * H / W))
    if min(w, h) < 16:
        raise ValueError(f"{W}x{H} x {fraction} = {w}x{h} is below 16 px")
    if abs(w / h - W / H) > 0.01 * (W / H):
        raise ValueError(f"{w}x{h} does not keep the aspect of {W}x{H}")
    return w, h


def physical_defaults() -> dict:
    """The physical renderer's default settings (without its name), its light stage's
    own beside them (as the renderer takes them: ``n_light_candidates=64``)."""
    from zcomp_cli.renderers.physical.renderer import PhysicalRenderer

    s = PhysicalRenderer().settings()
    s.pop("name", None)
    light = s.get("light", {})
    nested = {k: s[g][k] for k, g in NESTED_KNOBS.items() if k in s.get(g, {})}
    return {**{k: v for k, v in light.items() if not isinstance(v, dict)}, **nested, **s}


def knob_settings(knob: str, value) -> dict:
    """The renderer mapping that sets one physical ``knob``: ``{knob: value}``, or
    ``{group: {knob: value}}`` for a knob of a settings group (``NESTED_KNOBS``)."""
    group = NESTED_KNOBS.get(knob)
    return {knob: value} if group is None else {group: {knob: value}}


def zerocomp_weights() -> tuple[dict | None, str]:
    """(settings with controlnet/base, "") when ZCOMP_CONTROLNET and ZCOMP_SD_BASE name
    existing folders, else (None, why not)."""
    cn, base = os.environ.get("ZCOMP_CONTROLNET"), os.environ.get("ZCOMP_SD_BASE")
    missing = [n for n, v in (("ZCOMP_CONTROLNET", cn), ("ZCOMP_SD_BASE", base)) if not v]
    if missing:
        return None, f"{' and '.join(missing)} not set (no diffusion weights)"
    for n, v in (("ZCOMP_CONTROLNET", cn), ("ZCOMP_SD_BASE", base)):
        if not Path(v).expanduser().is_dir():
            return None, f"{n}={v} is not a folder"
    return {"controlnet": str(Path(cn).expanduser().resolve()),
            "base": str(Path(base).expanduser().resolve())}, ""


def parse_values(items) -> dict[str, list]:
    """``["march_steps=8,16", "resolution=1,0.5"]`` -> {knob: values}; ValueError on an
    unknown knob or a value that is not a number (integers for the renderer settings)."""
    out: dict[str, list] = {}
    for item in items or ():
        knob, sep, text = item.partition("=")
        knob = knob.strip()
        if not sep or knob not in PHYSICAL_KNOBS_FULL:
            raise ValueError(f"--values {item!r}: expected KNOB=v1,v2 with KNOB one of {', '.join(PHYSICAL_KNOBS_FULL)}")
        try:
            vals = [float(v) if knob == "resolution" else int(v) for v in text.split(",") if v.strip()]
        except ValueError as exc:
            raise ValueError(f"--values {item!r}: {exc}") from exc
        if not vals:
            raise ValueError(f"--values {item!r}: no values")
        out[knob] = vals
    return out


def plan_configs(native: tuple[int, int], *, quick: bool = False, knobs=ALL_KNOBS,
                 zerocomp: dict | None = None, values: dict | None = None) -> list[Config]:
    """The runs of a sweep: naive, the physical default and one physical knob at a time,
    and (when ``zerocomp`` holds the weight folders) zerocomp's steps at full frame and
    cropped. Values equal to the default share the default run. ``values`` overrides
    the knob values of the (quick or full) table, e.g. {"march_steps": [8, 16]}."""
    unknown = set(knobs) - set(ALL_KNOBS)
    if unknown:
        raise ValueError(f"unknown knob(s) {', '.join(sorted(unknown))}; choose from {', '.join(ALL_KNOBS)}")
    table = {**(PHYSICAL_KNOBS_QUICK if quick else PHYSICAL_KNOBS_FULL), **(values or {})}
    defaults = physical_defaults()
    W, H = native
    configs: list[Config] = []
    if "naive" in knobs:
        configs.append(Config("naive", "naive", series=[("baseline", "paste")]))
    phys_knobs = [k for k in table if k in knobs]
    if phys_knobs:
        default = Config("physical_default", "physical", default=True)
        configs.append(default)
        for knob in phys_knobs:
            # every series holds the default point, so each curve passes through it
            base = 1.0 if knob == "resolution" else defaults[knob]
            values = table[knob] if base in table[knob] else sorted([*table[knob], base])
            for v in values:
                if knob == "resolution":
                    res = scaled_resolution(native, float(v))
                    label = f"{res[0]}x{res[1]}"
                    if res == (W, H):
                        default.series.append((knob, label))
                        continue
                    configs.append(Config(f"physical_res{res[0]}x{res[1]}", "physical", resolution=res,
                                          series=[(knob, label)]))
                else:
                    if v == defaults[knob]:
                        default.series.append((knob, str(v)))
                        continue
                    configs.append(Config(f"physical_{knob}{v}", "physical", settings=knob_settings(knob, v),
                                          series=[(knob, str(v))]))
    if "zerocomp" in knobs and zerocomp is not None:
        for crop in (False, True):
            knob = "steps_crop" if crop else "steps_full"
            for steps in (ZEROCOMP_STEPS_QUICK if quick else ZEROCOMP_STEPS_FULL):
                configs.append(Config(f"zerocomp_{knob}{steps}", "zerocomp",
                                      settings={**zerocomp, "steps": steps, "crop": crop},
                                      series=[(knob, str(steps))], default=(steps == 20 and not crop)))
    if "cycles" in knobs:
        for denoise in (True, False):
            knob = "samples_denoised" if denoise else "samples_raw"
            for n in (CYCLES_SAMPLES_QUICK if quick else CYCLES_SAMPLES_FULL):
                configs.append(Config(f"cycles_{knob}{n}", "cycles", settings={"samples": n, "denoise": denoise},
                                      series=[(knob, str(n))], default=(denoise and n == 32)))
    return configs


# ----------------------------------------------------------------------------- manifests
def _absolute(root: Path, value):
    if isinstance(value, str) and value and not Path(value).is_absolute():
        return str((root / value).resolve())
    return value


def config_manifest(bench_jobs: Path, config: Config, max_jobs: int | None = None) -> dict:
    """The benchmark's manifest as a dict with absolute paths and ``config``'s renderer
    and working resolution in ``defaults`` (estimator mappings are kept as they are);
    only its first ``max_jobs`` jobs when given."""
    import yaml

    from zcomp_cli.pipeline.manifest import MAP_CHANNELS

    root = bench_jobs.resolve().parent
    doc = yaml.safe_load(bench_jobs.read_text())
    if not isinstance(doc, dict) or not isinstance(doc.get("jobs"), list):
        raise ValueError(f"{bench_jobs}: not a zcomp manifest (no jobs list)")
    for scene in (doc.get("scenes") or {}).values():
        for k in ("image", *MAP_CHANNELS):
            if k in scene:
                scene[k] = _absolute(root, scene[k])
    for obj in (doc.get("objects") or {}).values():
        for k in ("mesh", "bundle", "image", "mask"):
            if k in obj:
                obj[k] = _absolute(root, obj[k])
    if max_jobs is not None:
        if max_jobs < 1:
            raise ValueError(f"max_jobs must be >= 1, got {max_jobs}")
        doc["jobs"] = doc["jobs"][:max_jobs]
    for job in doc["jobs"]:
        if "reference" in job:
            job["reference"] = _absolute(root, job["reference"])
    d = dict(doc.get("defaults") or {})
    d["renderer"] = {"name": config.renderer, **config.settings}
    if config.resolution is not None:
        d["resolution"] = [int(config.resolution[0]), int(config.resolution[1])]
    doc["defaults"] = d
    return doc


def write_config_manifest(bench_jobs: Path, config: Config, path: Path, max_jobs: int | None = None) -> Path:
    import yaml

    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(config_manifest(bench_jobs, config, max_jobs), sort_keys=False, width=120))
    return path


def native_resolution(bench_jobs: Path) -> tuple[int, int]:
    """The benchmark's working size: ``defaults.resolution`` or the first scene's image."""
    from zcomp_cli.pipeline.manifest import load_manifest

    m = load_manifest(bench_jobs)
    if m.defaults.resolution is not None:
        return m.defaults.resolution
    sc = next(iter(m.scenes.values()))
    return sc.width, sc.height


# ----------------------------------------------------------------------------- running
def snapshot_source(dest: Path) -> dict:
    """Copy the zcomp_cli package in use (its Blender scripts live inside it) to ``dest/zcomp_cli``
    and return {"path", "sha256", "git_commit", "origin"}.

    Every configuration then runs this copy (PYTHONPATH=dest comes before the editable
    install), so a sweep of many minutes compares settings of ONE version of the code
    even while the working tree changes under it. ``sha256`` covers every .py file.
    """
    import zcomp_cli
    from zcomp_cli.filedigest import sources_sha256

    src = Path(zcomp_cli.__file__).resolve().parent
    if dest.exists():
        shutil.rmtree(dest)
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc")
    shutil.copytree(src, dest / "zcomp_cli", ignore=ignore)
    digest = sources_sha256(dest / "zcomp_cli", dest)
    commit = None
    try:  # read-only: which commit the working tree sits on (it may have local edits)
        r = subprocess.run(["git", "-C", str(src), "rev-parse", "HEAD"], text=True, capture_output=True, timeout=10)
        commit = r.stdout.strip() or None if r.returncode == 0 else None
    except (OSError, subprocess.SubprocessError):
        pass
    info = {"path": str(dest), "sha256": digest, "git_commit": commit, "origin": str(src)}
    (dest / "SOURCE.json").write_text(json.dumps(info, indent=1))
    return info


def child_env(code_dir: Path | None) -> dict | None:
    """Environment of the zcomp subprocesses: ``code_dir`` first on PYTHONPATH."""
    if code_dir is None:
        return None
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(code_dir), *filter(None, [env.get("PYTHONPATH")])])
    return env


def zcomp(*args: str, log: Path | None = None, env: dict | None = None) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "zcomp_cli", "-q", *args]
    print("$ zcomp " + " ".join(args), flush=True)
    r = subprocess.run(cmd, text=True, capture_output=True, env=env)
    if log is not None:
        with open(log, "a") as f:
            f.write(f"$ {' '.join(cmd)}\n[rc {r.returncode}]\n{r.stdout}\n{r.stderr}\n")
    return r


def job_reports(run_dir: Path) -> list[dict]:
    """The report.json of every finished job under ``run_dir``."""
    out = []
    for rep in sorted(run_dir.glob("*/report.json")):
        try:
            r = json.loads(rep.read_text())
        except (OSError, ValueError):
            continue
        if r.get("status") == "done":
            r["_dir"] = str(rep.parent)
            out.append(r)
    return out


def timing_summary(reports: list[dict]) -> tuple[float, dict]:
    """(median job_total_s, {renderer timing name: sum over jobs})."""
    secs = [float(r.get("timings", {}).get("job_total_s", float("nan"))) for r in reports]
    secs = [s for s in secs if math.isfinite(s)]
    sums: dict[str, float] = {}
    for r in reports:
        for k, v in ((r.get("renderer") or {}).get("timings") or {}).items():
            if isinstance(v, (int, float)) and math.isfinite(v):
                sums[k] = sums.get(k, 0.0) + float(v)
    return (statistics.median(secs) if secs else float("nan")), sums


def upsample_linear(img: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Bicubic resize of a linear H x W x 3 float image to ``size`` = (W, H), clamped at
    0 (cubic overshoot must not invent negative radiance)."""
    import cv2

    out = cv2.resize(np.asarray(img, np.float32), (int(size[0]), int(size[1])), interpolation=cv2.INTER_CUBIC)
    return np.maximum(out, 0.0).astype(np.float32)


def upsample_run(run_dir: Path, dst: Path) -> int:
    """Copy ``run_dir``'s finished jobs to ``dst`` with composites resized to their
    reference's size (composite.exr and composite.png; report.json copied, so ``zcomp
    eval`` pairs them the same way). Returns how many jobs were written."""
    from zcomp_cli.imageio import read_image, write_exr, write_png
    from zcomp_cli.imageio import image_header

    if dst.exists():
        shutil.rmtree(dst)
    n = 0
    for rep in job_reports(run_dir):
        src = Path(rep["_dir"])
        ref = rep.get("reference")
        if not ref or not (src / "composite.exr").is_file():
            continue
        w, h, _ = image_header(Path(ref))
        img = upsample_linear(read_image(src / "composite.exr"), (w, h))
        (dst / src.name).mkdir(parents=True, exist_ok=True)
        write_exr(dst / src.name / "composite.exr", img)
        write_png(dst / src.name / "composite.png", img)
        shutil.copy2(src / "report.json", dst / src.name / "report.json")
        n += 1
    return n


def eval_means(folder: Path, log: Path | None = None, env: dict | None = None) -> dict:
    """``zcomp eval --metrics psnr,flip folder`` -> its mean values (NaN when it fails)."""
    r = zcomp("eval", "--metrics", ",".join(METRICS), str(folder), log=log, env=env)
    path = folder / "eval.json"
    if r.returncode != 0 or not path.is_file():
        print(f"  eval failed (rc {r.returncode}): {r.stderr.strip()[-500:]}", file=sys.stderr)
        return {m: float("nan") for m in METRICS}
    mean = json.loads(path.read_text()).get("mean") or {}
    return {m: _json_float(mean.get(m)) for m in METRICS}


def _json_float(v) -> float:
    """A number of eval.json (which writes infinities as "inf"/"-inf"); NaN otherwise."""
    if v in ("inf", "-inf"):
        return float(v)
    return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else float("nan")


def eval_medians(folder: Path) -> dict:
    """Per-image medians of ``folder/eval.json`` (NaN when absent): one failed job can
    dominate a mean PSNR, so the median is reported beside it."""
    path = Path(folder) / "eval.json"
    if not path.is_file():
        return {m: float("nan") for m in METRICS}
    images = json.loads(path.read_text()).get("images") or []
    out = {}
    for m in METRICS:
        vals = [v for v in (_json_float(i.get(m)) for i in images) if not math.isnan(v)]
        out[m] = statistics.median(vals) if vals else float("nan")
    return out


def _children_cpu() -> float:
    """User + system CPU seconds of finished child processes (and theirs): on a shared
    machine CPU time is steadier than wall time, so it is recorded beside it."""
    import resource

    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


def run_config(config: Config, bench_jobs: Path, out: Path, native: tuple[int, int], *,
               cache_dir: str | None = None, max_jobs: int | None = None, env: dict | None = None) -> dict:
    """Run one configuration end to end; returns its result record (see ``rows_of``)."""
    manifest = write_config_manifest(bench_jobs, config, out / "manifests" / f"{config.key}.yaml", max_jobs)
    run_dir = out / "runs" / config.key
    if run_dir.exists():  # a stale report.json of an earlier sweep must not count
        shutil.rmtree(run_dir)
    log = out / "logs" / f"{config.key}.log"
    log.parent.mkdir(parents=True, exist_ok=True)
    log.write_text("")
    n_jobs = len(config_manifest(bench_jobs, config, max_jobs)["jobs"])
    args = ["composite", str(manifest), "--out", str(run_dir), "--overwrite"]
    if cache_dir:
        args += ["--cache-dir", cache_dir]
    t0, cpu0 = time.perf_counter(), _children_cpu()
    r = zcomp(*args, log=log, env=env)
    wall, cpu = time.perf_counter() - t0, _children_cpu() - cpu0
    if r.returncode not in (0, 1):
        print(f"  composite failed (rc {r.returncode}), see {log}: {r.stderr.strip()[-500:]}", file=sys.stderr)
    reports = job_reports(run_dir) if run_dir.is_dir() else []
    median_s, sums = timing_summary(reports)
    means = {m: float("nan") for m in METRICS}
    scored = run_dir
    if reports:
        if config.resolution is not None and tuple(config.resolution) != tuple(native):
            scored = out / "runs" / f"{config.key}_upsampled"
            upsample_run(run_dir, scored)
        means = eval_means(scored, log=log, env=env)
    return {"key": config.key, "renderer": config.renderer, "series": config.series, "default": config.default,
            **means, "median_s_per_job": median_s, "n_jobs": n_jobs, "n_failed": n_jobs - len(reports),
            "renderer_timings_s_sum": sums, "composite_wall_s": wall,
            "composite_cpu_s": cpu, "run_dir": str(scored)}


def rows_of(result: dict) -> list[dict]:
    """CSV rows of one result: one per (knob, value) the run stands for."""
    timings = ";".join(f"{k}={v:.3f}" for k, v in sorted(result["renderer_timings_s_sum"].items()))
    med = eval_medians(Path(result["run_dir"]))
    return [{"renderer": result["renderer"], "knob": knob, "value": value,
             **{m: result[m] for m in METRICS}, "median_s_per_job": result["median_s_per_job"],
             **{f"{m}_median": med[m] for m in METRICS},
             "n_jobs": result["n_jobs"], "n_failed": result["n_failed"], "default": result["default"],
             "renderer_timings_s_sum": timings, "composite_wall_s": round(result["composite_wall_s"], 3),
             "composite_cpu_s": round(result.get("composite_cpu_s", float("nan")), 3),
             "run_dir": result["run_dir"]} for knob, value in result["series"]]


# ----------------------------------------------------------------------------- outputs
def _fmt(v) -> str:
    if isinstance(v, float):
        return "nan" if math.isnan(v) else f"{v:.4f}"
    return str(v)


def write_csv(rows: list[dict], path: Path) -> None:
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=CSV_COLUMNS)
        w.writeheader()
        for r in rows:
            w.writerow({k: (_fmt(r[k]) if isinstance(r[k], float) else r[k]) for k in CSV_COLUMNS})


def format_table(rows: list[dict]) -> str:
    cols = ["renderer", "knob", "value", "psnr", "flip", "median_s_per_job", "n_jobs", "n_failed"]
    cells = [cols] + [[_fmt(r[c]) + ("*" if c == "value" and r["default"] else "") for c in cols] for r in rows]
    widths = [max(len(row[i]) for row in cells) for i in range(len(cols))]
    lines = ["  ".join(c.ljust(wd) for c, wd in zip(row, widths)) for row in cells]
    lines.insert(1, "  ".join("-" * wd for wd in widths))
    return "\n".join(lines) + "\n(* = the renderer's default setting; PSNR higher and FLIP lower are better)"


def plot(rows: list[dict], path: Path, title: str = "") -> None:
    """Two panels (PSNR, FLIP) against median seconds per job, log x; one series per
    (renderer, knob), each point labelled with its value."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker  # noqa: F401  (matplotlib.ticker below)

    fig, axes = plt.subplots(1, 2, figsize=(13, 5.5))
    series: dict[tuple[str, str], list[dict]] = {}
    for r in rows:
        series.setdefault((r["renderer"], r["knob"]), []).append(r)
    markers = "os^DvP<>hX*"
    for ax, metric, better in zip(axes, METRICS, ("higher is better", "lower is better")):
        placed: dict = {}
        for i, ((renderer, knob), pts) in enumerate(series.items()):
            pts = [p for p in pts if math.isfinite(p[metric]) and math.isfinite(p["median_s_per_job"])]
            if not pts:
                continue
            pts.sort(key=lambda p: p["median_s_per_job"])
            x = [max(p["median_s_per_job"], 1e-4) for p in pts]
            y = [p[metric] for p in pts]
            tag = knob[knob.index(" ["):] if " [" in knob else ""
            label = f"naive paste{tag}" if renderer == "naive" else f"{renderer}: {knob}"
            (line,) = ax.plot(x, y, marker=markers[i % len(markers)], linestyle="-" if len(pts) > 1 else "none",
                    label=label, alpha=0.85)
            for p, xi, yi in zip(pts, x, y):
                # a point several series share (the default) carries one label per
                # series: stack them
                k = placed.setdefault((round(xi, 6), round(yi, 6)), 0)
                placed[(round(xi, 6), round(yi, 6))] += 1
                dy = 4 + 8 * k
                ax.annotate(p["value"] + ("*" if p["default"] else ""), (xi, yi), textcoords="offset points",
                            xytext=(4, dy), fontsize=7, color=line.get_color())
        ax.set_xscale("log")
        # minor-tick labels of a short log range overlap each other: label majors only
        ax.xaxis.set_major_locator(matplotlib.ticker.LogLocator(subs=(1.0, 2.0, 5.0)))
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.xaxis.set_major_formatter(matplotlib.ticker.FuncFormatter(lambda v, _: f"{v:g}"))
        ax.set_xlabel("median seconds per job (log)")
        ax.set_ylabel(f"{metric.upper()} ({better})")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=8, loc="best")
    fig.suptitle(title or "zcomp: error against run time (* = default)")
    fig.tight_layout()
    from zcomp_cli.imageio import atomic_path

    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=120)
    plt.close(fig)


# ----------------------------------------------------------------------------- main
def _value_number(label: str) -> float:
    """Sort key of a value label: "192x192" -> 192, "16" -> 16, others 0."""
    try:
        return float(label.split("x")[0])
    except ValueError:
        return 0.0


def _same_run(saved: dict, cfg: Config, n_jobs: int, code_sha256: str | None = None) -> bool:
    """Whether a saved result (OUT/rows/<key>.json) ran ``cfg`` on ``n_jobs`` jobs with
    the same code (results of two versions of zcomp must not share a table)."""
    c = saved.get("config") or {}
    res = None if cfg.resolution is None else [int(v) for v in cfg.resolution]
    return (c.get("renderer") == cfg.renderer and c.get("settings") == cfg.settings
            and c.get("resolution") == res and saved.get("n_jobs") == n_jobs
            and saved.get("code_sha256") == code_sha256)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("bench_dir", type=Path, help="benchmark folder (from `zcomp make-benchmark`) with jobs.yaml")
    ap.add_argument("--out", type=Path, required=True, help="output folder")
    ap.add_argument("--quick", action="store_true", help="fewer knob values (smoke test)")
    ap.add_argument("--knobs", default=",".join(ALL_KNOBS),
                    help=f"comma-separated subset of: {', '.join(ALL_KNOBS)} (default: all)")
    ap.add_argument("--values", action="append", default=[], metavar="KNOB=V1,V2",
                    help="override a physical knob's values (resolution as fractions), repeatable")
    ap.add_argument("--cache-dir", default=None, help="passed to `zcomp composite --cache-dir`")
    ap.add_argument("--max-jobs", type=int, default=None, help="use only the benchmark's first N jobs")
    ap.add_argument("--resume", action="store_true",
                    help="reuse configurations already in OUT/rows/ (same settings, jobs and code)")
    ap.add_argument("--live-source", action="store_true",
                    help="run the working tree's zcomp_cli instead of a snapshot in OUT/code (see snapshot_source)")
    ap.add_argument("--jobs-file", action="append", default=[], metavar="NAME",
                    help="a manifest in BENCH_DIR to sweep (default jobs.yaml); repeatable: the configurations run "
                         "under each, the later ones' series named after it (jobs_oracle_full.yaml: the full "
                         "oracle's light), all in one figure")
    args = ap.parse_args(argv)

    job_files = [args.bench_dir / n for n in (args.jobs_file or ["jobs.yaml"])]
    for bench_jobs in job_files:
        if not bench_jobs.is_file():
            print(f"error: {bench_jobs} not found (make one with `zcomp make-benchmark`)", file=sys.stderr)
            return 2
    bench_jobs = job_files[0]
    knobs = [k.strip() for k in args.knobs.split(",") if k.strip()]
    if args.max_jobs is not None and args.max_jobs < 1:
        print(f"error: --max-jobs must be >= 1, got {args.max_jobs}", file=sys.stderr)
        return 2
    out: Path = args.out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    native = native_resolution(bench_jobs)
    zc, why = zerocomp_weights()
    if "zerocomp" in knobs and zc is None:
        print(f"zerocomp sweep skipped: {why}. Set ZCOMP_CONTROLNET (checkpoint folder holding "
              "controlnet/) and ZCOMP_SD_BASE (Stable Diffusion 2.1 folder) to include it.", flush=True)
    try:
        configs = plan_configs(native, quick=args.quick, knobs=knobs, zerocomp=zc,
                               values=parse_values(args.values))
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    plan = [(cfg, bench_jobs) for cfg in configs]
    for extra in job_files[1:]:
        tag = extra.stem.replace("jobs_", "")
        plan += [(Config(f"{c.key}@{tag}", c.renderer, dict(c.settings), c.resolution,
                         [(f"{k} [{tag}]", v) for k, v in c.series], c.default), extra) for c in configs]
    configs = [c for c, _ in plan]
    print(f"benchmark {bench_jobs} at {native[0]}x{native[1]}: {len(configs)} configurations", flush=True)
    if args.live_source:
        env, code_hash = None, None
        print("code: the live working tree (results may mix versions if it changes during the sweep)")
    else:
        src = snapshot_source(out / "code")
        env, code_hash = child_env(out / "code"), src["sha256"]
        print(f"code: snapshot {src['path']} of {src['origin']} (git {str(src['git_commit'])[:10]}, "
              f"sha256 {code_hash[:12]})", flush=True)

    rows: list[dict] = []
    (out / "rows").mkdir(exist_ok=True)
    t_all = time.perf_counter()
    for i, (cfg, bench_jobs) in enumerate(plan, 1):
        row_file = out / "rows" / f"{cfg.key}.json"
        result = json.loads(row_file.read_text()) if args.resume and row_file.is_file() else None
        n_jobs = len(config_manifest(bench_jobs, cfg, args.max_jobs)["jobs"])
        if result is not None and _same_run(result, cfg, n_jobs, code_hash):
            result["series"] = [tuple(s) for s in result["series"]]
            print(f"[{i}/{len(configs)}] {cfg.key}: reused", flush=True)
        else:
            print(f"[{i}/{len(configs)}] {cfg.key}", flush=True)
            result = run_config(cfg, bench_jobs, out, native, cache_dir=args.cache_dir, max_jobs=args.max_jobs,
                                env=env)
            row_file.write_text(json.dumps({**result, "config": asdict(cfg), "code_sha256": code_hash}, indent=1))
        # series of the current plan (the default run's series depend on --knobs)
        result["series"] = cfg.series
        print(f"  psnr {_fmt(result['psnr'])}  flip {_fmt(result['flip'])}  "
              f"median {_fmt(result['median_s_per_job'])} s/job  failed {result['n_failed']}/{result['n_jobs']}  "
              f"(composite {result['composite_wall_s']:.1f} s wall, "
              f"{result.get('composite_cpu_s', float('nan')):.1f} s CPU)", flush=True)
        rows.extend(rows_of(result))
    order = {k: i for i, k in enumerate(["baseline", *PHYSICAL_KNOBS_FULL, "steps_full", "steps_crop",
                                         "samples_denoised", "samples_raw"])}
    order.update({f"{k} [{f.stem.replace('jobs_', '')}]": 100 + 100 * j + v
                  for j, f in enumerate(job_files[1:]) for k, v in list(order.items())})
    rows.sort(key=lambda r: (r["renderer"] != "naive", r["renderer"], order.get(r["knob"], 99),
                             _value_number(r["value"])))
    write_csv(rows, out / "sweep.csv")
    plot(rows, out / "sweep.png",
         title=f"{args.bench_dir.resolve().name}: {native[0]}x{native[1]}, "
               f"{rows[0]['n_jobs'] if rows else 0} jobs (* = default)")
    print("\n" + format_table(rows))
    print(f"\nWrote {out / 'sweep.csv'} and {out / 'sweep.png'} ({time.perf_counter() - t_all:.0f} s)")
    ok = any(math.isfinite(r["psnr"]) for r in rows)
    return 0 if ok else 1
