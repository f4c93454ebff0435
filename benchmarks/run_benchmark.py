"""End-to-end benchmark (issue 4): ground truth by Cycles, every method, one table.

    python benchmarks/run_benchmark.py --out out/bench --n 20 --resolution 256 256

1. ``zcomp make-benchmark`` renders N cases (skipped if OUT/jobs.yaml exists and
   --regenerate is not given);
2. ``zcomp composite`` runs each method (naive paste, physical, and zerocomp when
   ZCOMP_CONTROLNET / ZCOMP_SD_BASE point at weights);
3. ``zcomp eval --metrics all`` scores each method against the ground truth;
4. prints a table in the paper's column order (PSNR, RMSE, si-RMSE, SSIM, MAE, LPIPS,
   FLIP), the shadow metrics (IoU and darkness error of the darkened region against the
   ground truth's), PSNR near the object (the object's box grown by its height), the
   light-direction error (median over cases lit by a sun or lamp whose ground-truth
   shadow is in frame: the generator knows the true light; a lamp counts only where it
   reaches the object's base, not blocked by a wall or box, and an area lamp's direction
   is from the object's base to the lamp; ``light_dir_err_deg`` against
   the nearest such lamp, ``dominant_light_err_deg`` against the light brightest on the floor,
   the HDR map's own sun included; ``shown_light_err_deg`` over the cases whose
   background shows a light's cast shadows (``cast_shadows_shown``: boxes in frame shadow
   the floor, more than 10 % darker), against the nearest such light, with their count;
   ``cast_shadow_err_deg`` over the cases where the
   renderer drew a cast shadow rather than a contact shadow, against the nearer of the two,
   with their count; each of the last three as "median (n)"), the share of those cases under
   10 and under 20 degrees (``dominant_under_10``, ``dominant_under_20``,
   ``shown_under_10``, ``shown_under_20``: fractions of the n of ``dominant_light_err_deg``
   and ``shown_light_err_deg``, what light-estimation papers report beside the median),
   the light scored apart from the composite (below) and the median seconds per job;
   writes OUT/table.csv, OUT/table.md and OUT/cases.csv (per case).

**The light on spheres** (``zcomp_cli.metrics.light_spheres``): when OUT/results holds
the ``physical-oracle-full`` row (its folder exists: run with ``--oracle full``, or left by
an earlier run and reused with ``--skip-composite``), each method's light (its report's
``renderer.info.light``) and the full oracle's of the same case are rendered on a
diffuse and a matte-silver sphere standing at the object's base (where lamps are seen
from), and scored by the relative scale-invariant RMSE between the two renders (0: the
same light at any strength; 1: nothing alike). ``sphere_si_rmse_diffuse`` and
``sphere_si_rmse_silver`` are the means over the cases with both lights, with their
count; n/a for a method whose report has no light (naive), ``ref`` for the oracle's own
row; per case in cases.csv. The oracle's light is the truth as the physical renderer
holds it (the HDR map's SH sky and its sources, the lamps), so this scores the
estimate, not the renderer's representation of light.

Another checkout of zcomp can be compared as an extra method, e.g. the code before a
change: ``--extra physical-before=/tmp/old/src`` runs its ``physical`` renderer with
that source tree first on PYTHONPATH.

**Oracles** (DESIGN.md section 8): ``--oracle direction,size,full`` gives the physical
renderer progressively more of the truth the generator knows, each level a row
(``physical-oracle-<level>``, ``write_oracle_jobs``); the gap between two adjacent rows is
the error of the part added between them:

* ``direction``: the true directions of the brightest light reaching the object and of
  a second one bright enough (``strength: auto``: the rest is fitted); an area lamp's
  is where it is (a lamp at its position, ``power: auto``): its light does not come
  from one direction;
* ``size``: the same, plus each light's true angular radius (a sun's; the HDR map's
  brightest source's as measured on it) or an area lamp's radius (a disc of its area);
* ``sky``: the true sky and every light where it is, their strengths fitted: ``full``'s
  light (below) with each sun's irradiance and each lamp's power ``auto``, so its
  share against the sky is the light stage's own (read off the shadows, else the
  prior). Its gap to ``size`` is the sky's shape (the HDR map against the fitted
  sky's lobes) and the HDR map's own sun (which only ``full`` and this row hold); its
  gap to ``full``, the sun/sky and lamp/sky splits of the lights the generator added;
* ``full``: everything the path tracer knew: the scene's HDR map as a probe (its
  rotation, Blender's convention, its strength), every lamp at its position with its
  power (suns with their irradiance and size), and the camera's pitch; only the
  exposure is fitted. This row is the transport's own limit;
* ``exposure``: ``full`` and the photograph's exposure: nothing is fitted. Its gap to
  ``full`` is what the light stage's fitted exposure costs.

``--true-direction`` is ``--oracle direction``. ``--oracle-renderers physical,cycles``
adds each level's row for each renderer (``cycles-oracle-full``: the path tracer on the
depth map's mesh under the full oracle; beside ``physical-oracle-full``, their gap is the
hand-written transport's error, and what ``cycles`` still misses the 2.5-D geometry's).
Besides the paper's metrics each row has PSNR near the object and on the object's own
pixels (``psnr_object``: what a viewer looks at first), and ``shadow_bias``
(``metrics.shadow.shadow_bias``): inside the ground truth's darkened region, the mean
of the composite's ratio to the background less the truth's, averaged over the cases
that have one -- the sign the darkness error does not tell (positive: too pale).
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

COLUMNS = ["psnr", "rmse", "si-rmse", "ssim", "mae", "lpips", "flip", "shadow-iou", "shadow-darkness"]
EXTRA = ["psnr_near", "psnr_object", "shadow_bias", "light_dir_err_deg",
         "dominant_light_err_deg", "dominant_under_10", "dominant_under_20",
         "shown_light_err_deg", "shown_under_10", "shown_under_20", "cast_shadow_err_deg",
         "sphere_si_rmse_diffuse", "sphere_si_rmse_silver", "median_s_per_job", "jobs_done"]
# The direction-error thresholds (degrees) whose share of cases the table reports: the
# ones light-estimation papers report beside the median (issue 37, item 9), so the rows
# compare with theirs; not tuned to anything.
UNDER_DEG = (10.0, 20.0)
# The row whose light is the reference of the sphere metric (module docstring).
SPHERE_REFERENCE = "physical-oracle-full"


def zcomp(*args: str, src: str | None = None) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "zcomp_cli", "-q", *args]
    env = None
    if src:
        env = dict(os.environ, PYTHONPATH=src + os.pathsep + os.environ.get("PYTHONPATH", ""))
    print("$ zcomp " + " ".join(args) + (f"   (PYTHONPATH={src})" if src else ""), flush=True)
    return subprocess.run(cmd, text=True, capture_output=True, env=env)


def true_lights(case: dict) -> list[dict]:
    """Every directional light of a case as the object's base sees it, brightest on the
    floor first (``benchsuite.scenes.lights_at``: the lamps and the HDR map's own sun,
    camera frame, toward the light, ``visible`` False where a wall or box blocks it)."""
    import numpy as np

    from zcomp_cli.benchsuite.scenes import BenchScene, lights_at
    from zcomp_cli.errors import InputError

    scene = BenchScene.from_dict(case["scene"])
    base = np.asarray(case["pose"]["position"], np.float64)
    try:
        return lights_at(scene, base)
    except InputError:  # no bpy (its bundled maps) here: lamps only
        return lights_at(scene, base, with_hdr=False)


def cast_shadows_shown(case: dict, bench_dir: Path, lights: list[dict]) -> list[dict]:
    """The lights of ``lights`` (``true_lights`` items) whose cast shadows the background
    shows: its boxes shadow at least ``MIN_CAST_SHADOW_PX`` floor pixels from that light
    and leave as many lit, and the shadowed floor's shading (image over albedo) is more
    than ``SHADOW_THRESHOLD`` darker than the lit floor's (medians). The evidence a
    photographer reads the light from."""
    import numpy as np

    from zcomp_cli.benchsuite.scenes import MIN_CAST_SHADOW_PX, BenchScene, cast_shadow_masks
    from zcomp_cli.conventions import REC601
    from zcomp_cli.imageio import read_image, read_map
    from zcomp_cli.metrics.shadow import SHADOW_THRESHOLD

    if not lights:
        return []
    f = case["files"]
    background = read_image(bench_dir / f["image"])
    depth = read_map(bench_dir / f["depth"], channels=1).reshape(background.shape[:2])
    albedo = read_map(bench_dir / f["albedo"], channels=3)
    shading = (background @ REC601) / np.maximum(albedo @ REC601, 1e-4)
    scene = BenchScene.from_dict(case["scene"])
    out = []
    for t, (shadowed, lit) in zip(lights, cast_shadow_masks(scene, depth, [t["lamp"] for t in lights])):
        if shadowed.sum() < MIN_CAST_SHADOW_PX or lit.sum() < MIN_CAST_SHADOW_PX:
            continue
        if np.median(shading[shadowed]) < (1.0 - SHADOW_THRESHOLD) * np.median(shading[lit]):
            out.append(t)
    return out


def case_truths(bench_dir: Path) -> dict[str, dict]:
    """Per case id, what the generator knows of its lights, the same for every method:
    ``{"lights": true_lights, "shown": cast_shadows_shown of those reaching the object}``."""
    bench = json.loads((bench_dir / "benchmark.json").read_text())
    out = {}
    for c in bench["cases"]:
        lights = true_lights(c)
        out[c["id"]] = {"lights": lights,
                        "shown": cast_shadows_shown(c, bench_dir, [t for t in lights if t["visible"]])}
    return out


def per_case(bench_dir: Path, res_dir: Path, truths: dict[str, dict] | None = None) -> list[dict]:
    """Per case: PSNR near the object, light-direction error, whether its GT shadow is in
    frame. ``truths``: ``case_truths(bench_dir)``, computed here when not given."""
    import numpy as np

    from zcomp_cli.conventions import linear_to_srgb
    from zcomp_cli.imageio import read_alpha_or_grey, read_image
    from zcomp_cli.metrics.shadow import darkened_region, shadow_bias

    bench = json.loads((bench_dir / "benchmark.json").read_text())
    truths = case_truths(bench_dir) if truths is None else truths
    rows = []
    for c in bench["cases"]:
        job = next(iter(sorted(res_dir.glob(f"*{c['id']}*"))), None)
        row = {"case": c["id"], "psnr_near": float("nan"), "psnr_object": float("nan"),
               "shadow_bias": float("nan"), "light_dir_err_deg": float("nan"),
               "shadow_in_frame": False, "lamp": "", "lamp_blocked": ""}
        lights = truths[c["id"]]["lights"]
        # a lamp counts only where it reaches the object: a sun behind a wall casts none
        # of the object's shadow (the ground truth's shadow is then the HDR map's)
        lamps = [t for t in lights if t["kind"] != "HDR-sun"]
        row["lamp"] = ",".join(t["kind"] for t in lamps if t["visible"])
        row["lamp_blocked"] = ",".join(t["kind"] for t in lamps if not t["visible"])
        if job is None or not (job / "composite.exr").is_file():
            rows.append(row)
            continue
        f = c["files"]
        bg = read_image(bench_dir / f["image"])
        gt = read_image(bench_dir / f["gt"])
        pred = read_image(job / "composite.exr")
        om = read_alpha_or_grey(bench_dir / f["object_mask"]) > 0.5
        ys, xs = np.nonzero(om)
        if len(ys):
            h = ys.max() - ys.min() + 1
            near = np.zeros(om.shape, bool)
            near[max(0, ys.min() - h // 4):ys.max() + 1 + h // 2, max(0, xs.min() - h):xs.max() + 1 + h] = True
            err2 = (linear_to_srgb(np.clip(pred, 0, None)) - linear_to_srgb(np.clip(gt, 0, None))) ** 2
            row["psnr_near"] = float(10 * np.log10(1.0 / max(float(np.mean(err2[near])), 1e-12)))
            row["psnr_object"] = float(10 * np.log10(1.0 / max(float(np.mean(err2[om])), 1e-12)))
        row["shadow_in_frame"] = bool(darkened_region(gt, bg, om).sum() >= 30)
        row["shadow_bias"] = shadow_bias(pred, gt, bg, om)
        rep = json.loads((job / "report.json").read_text())
        light = (((rep.get("renderer") or {}).get("info") or {}).get("light") or {})
        seen = [t for t in lights if t["visible"]]
        shown = truths[c["id"]]["shown"]
        row["cast_shadows_shown"] = ",".join(t["kind"] for t in shown)
        if light.get("direction") is not None and seen:
            est = np.asarray(light["direction"], float)
            est /= np.linalg.norm(est)
            ang = lambda t: float(np.degrees(np.arccos(np.clip(est @ t, -1, 1))))
            if row["lamp"]:
                row["light_dir_err_deg"] = min(ang(t["direction"]) for t in seen if t["kind"] != "HDR-sun")
            # against the brightest directional light on the floor, the HDR map's sun included
            row["dominant_light"] = seen[0]["kind"]
            row["dominant_err_deg"] = ang(seen[0]["direction"])
            row["fallback"] = light.get("fallback")
            if shown:
                row["shown_light_err_deg"] = min(ang(t["direction"]) for t in shown)
        rows.append(row)
    return rows


def _job_dir(res_dir: Path, case_id: str) -> Path | None:
    """The job folder of ``case_id`` in a results folder (as ``per_case`` finds it)."""
    return next(iter(sorted(res_dir.glob(f"*{case_id}*"))), None)


def _report_light(job: Path | None) -> dict | None:
    """A job's light as its report gives it (``renderer.info.light``, ``LightModel.to_info``),
    or None: no job, no report, or a renderer without one (naive)."""
    if job is None or not (job / "report.json").is_file():
        return None
    try:
        rep = json.loads((job / "report.json").read_text())
    except (OSError, ValueError):
        return None
    light = ((rep.get("renderer") or {}).get("info") or {}).get("light")
    return light if isinstance(light, dict) and isinstance(light.get("lights"), list) else None


def sphere_errors(bench_dir: Path, res_dir: Path, ref_dir: Path) -> dict[str, dict]:
    """Per case id, the light of ``res_dir``'s job scored against ``ref_dir``'s on the
    two spheres (``light_spheres.light_sphere_error``, module docstring), standing at the
    object's base lifted by ``LIGHT_PROBE_HEIGHT`` (where ``true_lights`` sees the lights
    from): ``{"sphere_si_rmse_diffuse", "sphere_si_rmse_silver"}``, nan where either job
    has no light (or a malformed one, with a warning)."""
    import numpy as np

    from zcomp_cli.benchsuite.scenes import LIGHT_PROBE_HEIGHT, BenchScene
    from zcomp_cli.errors import InputError
    from zcomp_cli.metrics.light_spheres import light_sphere_error

    bench = json.loads((bench_dir / "benchmark.json").read_text())
    out = {}
    for c in bench["cases"]:
        row = {"sphere_si_rmse_diffuse": float("nan"), "sphere_si_rmse_silver": float("nan")}
        out[c["id"]] = row
        est, ref = _report_light(_job_dir(res_dir, c["id"])), _report_light(_job_dir(ref_dir, c["id"]))
        if est is None or ref is None:
            continue
        up = BenchScene.from_dict(c["scene"]).up
        center = np.asarray(c["pose"]["position"], np.float64) + LIGHT_PROBE_HEIGHT * np.asarray(up, np.float64)
        try:
            r = light_sphere_error(est, ref, center=center)
        except InputError as e:
            print(f"warning: {res_dir.name} {c['id']}: light not scored on the spheres: {e}", file=sys.stderr)
            continue
        row["sphere_si_rmse_diffuse"], row["sphere_si_rmse_silver"] = r["diffuse"], r["silver"]
    return out


def _median_n(vals: list[float]) -> str | None:
    """"median (n)" of direction errors in degrees, None without any."""
    return f"{statistics.median(vals):.1f} ({len(vals)})" if vals else None


def _share_under(vals: list[float], deg: float) -> float | None:
    """The fraction of ``vals`` (degrees) under ``deg``; None without any."""
    return round(sum(v < deg for v in vals) / len(vals), 3) if vals else None


# A case's second light joins the oracle's lights when it brings at least this part of
# the dominant light's irradiance on the floor.
SECOND_TRUE_LIGHT_FRAC = 0.25


ORACLE_LEVELS = ("direction", "size", "sky", "full", "exposure")


def _true_radius_deg(t: dict, case: dict) -> float:
    """A ``true_lights`` item's angular radius (degrees) seen from the object's base: a
    sun's half its angle, an area lamp's square as a disc of its area at its distance,
    the HDR map's brightest source as measured on the map (``probe.split_probe``)."""
    import math

    import numpy as np

    lp = t["lamp"]
    if t["kind"] == "SUN":
        return 0.5 * float(lp["angle_deg"])
    if t["kind"] == "AREA":
        base = np.asarray(case["pose"]["position"], np.float64)
        dist = float(np.linalg.norm(np.asarray(lp["position"], np.float64) - base))
        return math.degrees(math.atan(float(lp["size"]) / math.sqrt(math.pi) / max(dist, 1e-6)))
    src = _hdr_sources(case)
    if not src:
        return 0.5
    return min(src, key=lambda s: -float(np.asarray(s.direction) @ np.asarray(t["direction"]))).radius_deg


def _probe_spec(case: dict) -> tuple[dict, dict]:
    """The case's HDR map as a manifest probe (Blender's convention; the yaw that puts
    its env frame where the generator's world shader had it) and the camera's tilt."""
    import math

    from zcomp_cli.benchsuite.scenes import BenchScene, bundled_hdr_path
    from zcomp_cli.worldframe import ground_frame

    scene = BenchScene.from_dict(case["scene"])
    M = scene.env_to_camera()
    fwd = ground_frame(scene.up)[2]
    f_env = M.T @ fwd
    heading = math.degrees(math.atan2(f_env[1], f_env[0]))
    rot = (heading - 90.0 + 180.0) % 360.0 - 180.0
    probe = {"type": "probe", "hdr": str(bundled_hdr_path(scene.hdr)), "convention": "blender",
             "rotation_deg": rot, "strength": float(scene.hdr_strength)}
    return probe, {"pitch_deg": -float(scene.pitch_deg), "roll_deg": 0.0}


def _hdr_sources(case: dict):
    from zcomp_cli.scene.probe import load_probe
    from zcomp_cli.worldframe import ground_frame, up_from_pitch_roll

    probe, tilt = _probe_spec(case)
    frame = ground_frame(up_from_pitch_roll(tilt["pitch_deg"], 0.0))
    return load_probe(probe["hdr"], frame, convention="blender", rotation_deg=probe["rotation_deg"]).sources


def write_oracle_jobs(bench_dir: Path, level: str) -> Path:
    """OUT/jobs_oracle_<level>.yaml: jobs.yaml with each scene given the truth of
    ``level`` (module docstring, Oracles)."""
    import math

    import numpy as np
    import yaml

    if level not in ORACLE_LEVELS:
        raise ValueError(f"unknown oracle level {level!r} (known: {', '.join(ORACLE_LEVELS)})")
    bench = json.loads((bench_dir / "benchmark.json").read_text())
    doc = yaml.safe_load((bench_dir / "jobs.yaml").read_text())
    for c in bench["cases"]:
        if c["id"] not in doc["scenes"]:
            continue
        scene = doc["scenes"][c["id"]]
        if level in ("sky", "full", "exposure"):
            from zcomp_cli.benchsuite.scenes import BenchScene, lamps_for_blender

            probe, tilt = _probe_spec(c)
            lights = [probe]
            fitted = level == "sky"  # the lights' strengths (and colours) fitted, not given
            for lp in lamps_for_blender(BenchScene.from_dict(c["scene"])):
                travel = np.asarray(lp["direction"], np.float64)
                colour = {} if fitted else {"color": [float(v) for v in lp["color"]]}
                if lp["kind"] == "SUN":
                    lights.append({"type": "sun", "direction": [float(v) for v in -travel],
                                   "angular_radius_deg": 0.5 * float(lp["angle_deg"]),
                                   **({"strength": "auto"} if fitted else {"irradiance": float(lp["strength"])}),
                                   **colour})
                else:
                    lights.append({"type": "lamp", "position": [float(v) for v in lp["position"]],
                                   "radius_m": float(lp["size"]) / math.sqrt(math.pi),
                                   "power": "auto" if fitted else float(lp["strength"]),
                                   "facing": [float(v) for v in travel], **colour})
            scene["light"] = lights
            scene.update(tilt)
            if level == "exposure":
                scene["exposure"] = float(c["exposure"])
            continue
        tl = [t for t in true_lights(c) if t["visible"]]
        if not tl:
            continue
        top = [t for t in tl[:2] if t["floor_irradiance"] >= SECOND_TRUE_LIGHT_FRAC * tl[0]["floor_irradiance"]]
        lights = []
        for t in top:
            if t["kind"] == "AREA":
                lp = t["lamp"]
                x = {"type": "lamp", "position": [float(v) for v in lp["position"]], "power": "auto",
                     "facing": [float(v) for v in lp["direction"]]}
                if level == "size":
                    x["radius_m"] = float(lp["size"]) / math.sqrt(math.pi)
            else:
                x = {"direction": [float(v) for v in t["direction"]], "strength": "auto"}
                if level == "size":
                    x["angular_radius_deg"] = float(min(_true_radius_deg(t, c), 45.0))
            lights.append(x)
        scene["light"] = lights[0] if len(lights) == 1 else lights
    path = bench_dir / f"jobs_oracle_{level}.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def median_job_seconds(out_dir: Path) -> float:
    secs = []
    for rep in out_dir.glob("*/report.json"):
        r = json.loads(rep.read_text())
        t = r.get("timings", {})
        secs.append(float(t.get("job_total_s", 0.0)))
    return statistics.median(secs) if secs else float("nan")


def jobs_done(out_dir: Path) -> str:
    """"done/all" of a composite run (its summary.json): a row's means are over its done
    jobs only, so a row with failed jobs must say so."""
    try:
        summary = json.loads((out_dir / "summary.json").read_text())
    except (OSError, ValueError):
        return "?"
    return f"{summary.get('done', 0) + summary.get('skipped', 0)}/{len(summary.get('jobs', []))}"


def read_means(eval_json: Path) -> dict:
    data = json.loads(eval_json.read_text())
    means = data.get("mean") or data.get("means") or {}
    return {k.lower(): v for k, v in means.items()}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="out/bench")
    ap.add_argument("--n", type=int, default=20)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--resolution", type=int, nargs=2, default=(256, 256))
    ap.add_argument("--samples", type=int, default=128)
    ap.add_argument("--methods", default="naive,physical", help="comma-separated renderers")
    ap.add_argument("--metrics", default="all")
    ap.add_argument("--regenerate", action="store_true")
    ap.add_argument("--extra", action="append", default=[], metavar="NAME=SRC",
                    help="also run the physical renderer of another source tree (repeatable)")
    ap.add_argument("--skip-composite", action="store_true", help="reuse results already in OUT/results")
    ap.add_argument("--true-direction", action="store_true", help="the same as --oracle direction")
    ap.add_argument("--oracle", default="", metavar="LEVELS",
                    help="comma-separated oracle levels to add as rows: direction, size, sky, full, exposure "
                         "(module docstring)")
    ap.add_argument("--oracle-renderers", default="physical", metavar="NAMES",
                    help="the renderers the oracle rows run (comma-separated; default physical)")
    args = ap.parse_args(argv)

    out = Path(args.out)
    jobs = out / "jobs.yaml"
    if args.regenerate or not jobs.is_file():
        r = zcomp("make-benchmark", str(out), "--n", str(args.n), "--seed", str(args.seed),
                  "--resolution", *map(str, args.resolution), "--samples", str(args.samples), "--overwrite")
        if r.returncode:
            print(r.stdout, r.stderr, file=sys.stderr)
            return r.returncode
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    if "zerocomp" not in methods and os.environ.get("ZCOMP_CONTROLNET") and os.environ.get("ZCOMP_SD_BASE"):
        methods.append("zerocomp")
    runs = [(m, m, None) for m in methods]
    for e in args.extra:
        name, _, src = e.partition("=")
        runs.append((name, "physical", src))
    levels = [x.strip() for x in args.oracle.split(",") if x.strip()]
    if args.true_direction and "direction" not in levels:
        levels.insert(0, "direction")
    for lv in levels:
        if lv not in ORACLE_LEVELS:
            ap.error(f"unknown oracle level {lv!r} (known: {', '.join(ORACLE_LEVELS)})")
        for rname in [x.strip() for x in args.oracle_renderers.split(",") if x.strip()]:
            runs.append((f"{rname}-oracle-{lv}", rname, None))
    rows, case_rows, scored = [], [], []
    truths = case_truths(out)
    for name, method, src in runs:
        res_dir = out / "results" / name
        if not args.skip_composite:
            import shutil

            # a fresh folder: a failed job must not leave an older run's composite to score
            shutil.rmtree(res_dir, ignore_errors=True)
            jf = (write_oracle_jobs(out, name.split("-oracle-", 1)[1]) if "-oracle-" in name else jobs)
            r = zcomp("composite", str(jf), "--out", str(res_dir), "--renderer", method, "--overwrite", src=src)
            if r.returncode not in (0, 1):
                print(r.stdout, r.stderr, file=sys.stderr)
                return r.returncode
            if r.returncode == 1:
                print(f"warning: some {name} jobs failed:\n{r.stderr[-2000:]}", file=sys.stderr)
        r = zcomp("eval", "--metrics", args.metrics, str(res_dir))
        if r.returncode not in (0, 1):
            print(r.stdout, r.stderr, file=sys.stderr)
            return r.returncode
        means = read_means(res_dir / "eval.json")
        cases = per_case(out, res_dir, truths)
        scored.append((name, res_dir))
        for c in cases:
            case_rows.append({"method": name, **c})
        import math
        near = [c["psnr_near"] for c in cases if math.isfinite(c["psnr_near"])]
        obj = [c["psnr_object"] for c in cases if math.isfinite(c["psnr_object"])]
        bias = [c["shadow_bias"] for c in cases if math.isfinite(c.get("shadow_bias", math.nan))]
        errs = [c["light_dir_err_deg"] for c in cases
                if c["lamp"] and c["shadow_in_frame"] and math.isfinite(c["light_dir_err_deg"])]
        dom = [c["dominant_err_deg"] for c in cases
               if c["lamp"] and c["shadow_in_frame"] and math.isfinite(c.get("dominant_err_deg", math.nan))]
        # the cases where the renderer drew a cast shadow (no contact-shadow fallback):
        # error against the nearest true light (the HDR map's sun included), and how many
        cast = [min(c["light_dir_err_deg"], c["dominant_err_deg"]) for c in cases
                if c["lamp"] and c["shadow_in_frame"] and c.get("fallback") is None
                and math.isfinite(c.get("dominant_err_deg", math.nan))]
        # the cases whose background shows a light's cast shadows (boxes in frame), against
        # the nearest such light, and how many: the evidence the target is about
        shown = [c["shown_light_err_deg"] for c in cases if math.isfinite(c.get("shown_light_err_deg", math.nan))]
        rows.append({"method": name, **{c: means.get(c) for c in COLUMNS},
                     "psnr_near": statistics.mean(near) if near else None,
                     "psnr_object": statistics.mean(obj) if obj else None,
                     "shadow_bias": statistics.mean(bias) if bias else None,
                     "light_dir_err_deg": statistics.median(errs) if errs else None,
                     "dominant_light_err_deg": _median_n(dom),
                     **{f"dominant_under_{d:g}": _share_under(dom, d) for d in UNDER_DEG},
                     "shown_light_err_deg": _median_n(shown),
                     **{f"shown_under_{d:g}": _share_under(shown, d) for d in UNDER_DEG},
                     "cast_shadow_err_deg": _median_n(cast),
                     "sphere_si_rmse_diffuse": None, "sphere_si_rmse_silver": None,
                     "median_s_per_job": median_job_seconds(res_dir), "jobs_done": jobs_done(res_dir)})

    # the light scored apart from the composite, against the full oracle's (module docstring)
    ref_dir = out / "results" / SPHERE_REFERENCE
    if ref_dir.is_dir():
        import math

        if SPHERE_REFERENCE not in {name for name, _ in scored}:
            print(f"note: scoring the lights on spheres against {ref_dir} (not rerun in this run)", file=sys.stderr)
        by_case = {(c["method"], c["case"]): c for c in case_rows}
        for row, (name, res_dir) in zip(rows, scored):
            if name == SPHERE_REFERENCE:
                row["sphere_si_rmse_diffuse"] = row["sphere_si_rmse_silver"] = "ref"
                continue
            errs = sphere_errors(out, res_dir, ref_dir)
            for cid, e in errs.items():
                if (name, cid) in by_case:
                    by_case[(name, cid)].update(e)
            for key in ("sphere_si_rmse_diffuse", "sphere_si_rmse_silver"):
                vals = [e[key] for e in errs.values() if math.isfinite(e[key])]
                row[key] = f"{statistics.mean(vals):.3f} ({len(vals)})" if vals else None

    def fmt(v):
        return "n/a" if v is None else (f"{v:.4f}" if isinstance(v, float) else str(v))

    def fmt_col(h, v):
        # shares of cases: two decimals are all a table of tens of cases resolves
        if h.split("_under_")[0] in ("dominant", "shown") and isinstance(v, float):
            return f"{v:.2f}"
        return fmt(v)

    header = ["method", *COLUMNS, *EXTRA]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(fmt_col(h, row[h]) for h in header) + " |" for row in rows]
    table = "\n".join(lines)
    print(f"\nBenchmark: {out} (metrics on sRGB [0, 1]; LPIPS at 256x256)\n" + table)
    (out / "table.md").write_text(table + "\n")
    with open(out / "table.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=header)
        w.writeheader()
        w.writerows(rows)
    with open(out / "cases.csv", "w", newline="") as f:
        keys = ["method", "case", "lamp", "lamp_blocked", "shadow_in_frame", "psnr_near", "psnr_object",
                "shadow_bias", "light_dir_err_deg",
                "dominant_light", "dominant_err_deg", "cast_shadows_shown", "shown_light_err_deg", "fallback",
                "sphere_si_rmse_diffuse", "sphere_si_rmse_silver"]
        w = csv.DictWriter(f, fieldnames=keys, extrasaction="ignore")
        w.writeheader()
        w.writerows(case_rows)
    groups = group_table(out, scored, case_rows)
    print("\nBy the scene's lights (PSNR near the object / on the object, shadow IoU, darkness error):\n" + groups)
    (out / "groups.md").write_text(groups + "\n")
    return 0


def scene_group(case: dict) -> str:
    """A case's group by the lights its scene holds besides the HDR map: ``sun``,
    ``area lamp`` or ``probe only``."""
    kinds = {str(lp.get("kind", "")).upper() for lp in case["scene"].get("lamps", [])}
    return "sun" if "SUN" in kinds else "area lamp" if "AREA" in kinds else "probe only"


def group_table(out: Path, scored: list, case_rows: list[dict]) -> str:
    """A markdown table: per method and group (``scene_group``) the means of PSNR near the
    object, PSNR on the object, shadow IoU and darkness error over the group's cases."""
    import math

    bench = json.loads((out / "benchmark.json").read_text())
    group = {c["id"]: scene_group(c) for c in bench["cases"]}
    names = sorted(set(group.values()), key=["sun", "area lamp", "probe only"].index)
    by_case = {(r["method"], r["case"]): r for r in case_rows}

    def mean(xs):
        xs = [float(x) for x in xs if x is not None and math.isfinite(float(x))]
        return statistics.mean(xs) if xs else math.nan

    lines = ["| method | " + " | ".join(f"{g} ({sum(v == g for v in group.values())})" for g in names) + " |",
             "|---|" + "---|" * len(names)]
    for name, res_dir in scored:
        try:
            images = json.loads((res_dir / "eval.json").read_text()).get("images", [])
        except (OSError, ValueError):
            images = []
        per = {}
        for im in images:
            cid = next((c for c in group if c in str(im.get("name", ""))), None)
            if cid is not None:
                per[cid] = im
        cells = []
        for g in names:
            cs = [c for c in group if group[c] == g]
            near = mean(by_case.get((name, c), {}).get("psnr_near") for c in cs)
            obj = mean(by_case.get((name, c), {}).get("psnr_object") for c in cs)
            iou = mean(per.get(c, {}).get("shadow-iou") for c in cs)
            dark = mean(per.get(c, {}).get("shadow-darkness") for c in cs)
            cells.append(f"{near:.2f} / {obj:.2f} / {iou:.3f} / {dark:.3f}")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
