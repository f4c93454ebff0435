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
   shadow is in frame: the generator knows the true light; ``light_dir_err_deg`` against
   the nearest lamp, ``dominant_light_err_deg`` against the light brightest on the floor,
   the HDR map's own sun included; ``cast_shadow_err_deg`` over the cases where the
   renderer drew a cast shadow rather than a contact shadow, against the nearer of the two,
   with their count) and the median seconds per job; writes OUT/table.csv, OUT/table.md and OUT/cases.csv (per case).

Another checkout of zcomp can be compared as an extra method, e.g. the code before a
change: ``--extra physical-before=/tmp/old/src`` runs its ``physical`` renderer with
that source tree first on PYTHONPATH. ``--true-direction`` adds physical-true-dir: each
lamp-lit scene given the true directions of its dominant light and of a second one
bright enough (``write_true_direction_jobs``; ``strength: auto``), what the renderer
reaches with the directions right.
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
EXTRA = ["psnr_near", "light_dir_err_deg", "dominant_light_err_deg", "cast_shadow_err_deg", "median_s_per_job"]


def zcomp(*args: str, src: str | None = None) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "zcomp_cli", "-q", *args]
    env = None
    if src:
        env = dict(os.environ, PYTHONPATH=src + os.pathsep + os.environ.get("PYTHONPATH", ""))
    print("$ zcomp " + " ".join(args) + (f"   (PYTHONPATH={src})" if src else ""), flush=True)
    return subprocess.run(cmd, text=True, capture_output=True, env=env)


def true_light_dirs(case: dict) -> list:
    """Camera-frame unit directions TOWARD each lamp of a benchmark case."""
    import numpy as np

    pitch = float(case["scene"]["pitch_deg"])
    a = np.deg2rad(pitch)
    R = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    out = []
    for lp in case["scene"].get("lamps", []):
        d = -(R @ np.asarray(lp["direction"], float))
        out.append(d / np.linalg.norm(d))
    return out


def true_lights(case: dict) -> list[dict]:
    """Every directional light of a case, brightest on the floor first: the lamps and
    the HDR map's own sun (``benchsuite.scenes.hdr_lights``), each ``{"kind",
    "direction" (camera frame, toward it), "floor_irradiance"}``. Area lamps count
    ``strength / (pi d^2)`` at the floor target."""
    import math

    import numpy as np

    from zcomp_cli.benchsuite.scenes import BenchScene, hdr_lights

    scene = BenchScene.from_dict(case["scene"])
    up = scene.up
    out = []
    for lp, d in zip(case["scene"].get("lamps", []), true_light_dirs(case)):
        e = float(lp["strength"]) if lp["kind"] == "SUN" else float(lp["strength"]) / (math.pi * float(lp["distance"]) ** 2)
        out.append({"kind": lp["kind"], "direction": d, "floor_irradiance": e * max(float(d @ up), 0.0)})
    try:
        h = hdr_lights(scene)
        out.append({"kind": "HDR-sun", "direction": np.asarray(h["sun_direction"]),
                    "floor_irradiance": h["sun_floor_irradiance"]})
    except Exception:  # no bpy (its bundled maps) here: lamps only
        pass
    return sorted(out, key=lambda x: -x["floor_irradiance"])


def per_case(bench_dir: Path, res_dir: Path) -> list[dict]:
    """Per case: PSNR near the object, light-direction error, whether its GT shadow is in frame."""
    import numpy as np

    from zcomp_cli.conventions import linear_to_srgb
    from zcomp_cli.imageio import read_alpha_or_grey, read_image
    from zcomp_cli.metrics.shadow import darkened_region

    bench = json.loads((bench_dir / "benchmark.json").read_text())
    rows = []
    for c in bench["cases"]:
        job = next(iter(sorted(res_dir.glob(f"*{c['id']}*"))), None)
        row = {"case": c["id"], "psnr_near": float("nan"), "light_dir_err_deg": float("nan"),
               "shadow_in_frame": False, "lamp": ",".join(lp["kind"] for lp in c["scene"].get("lamps", []))}
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
            mse = np.mean((linear_to_srgb(np.clip(pred, 0, None)) - linear_to_srgb(np.clip(gt, 0, None)))[near] ** 2)
            row["psnr_near"] = float(10 * np.log10(1.0 / max(mse, 1e-12)))
        row["shadow_in_frame"] = bool(darkened_region(gt, bg, om).sum() >= 30)
        rep = json.loads((job / "report.json").read_text())
        light = (((rep.get("renderer") or {}).get("info") or {}).get("light") or {})
        true = true_light_dirs(c)
        if light.get("direction") is not None and true:
            est = np.asarray(light["direction"], float)
            est /= np.linalg.norm(est)
            ang = lambda t: float(np.degrees(np.arccos(np.clip(est @ t, -1, 1))))
            row["light_dir_err_deg"] = min(ang(t) for t in true)
            # against the brightest directional light on the floor, the HDR map's sun included
            dom = true_lights(c)[0]
            row["dominant_light"] = dom["kind"]
            row["dominant_err_deg"] = ang(dom["direction"])
            row["fallback"] = light.get("fallback")
        rows.append(row)
    return rows


# A case's second light joins the oracle's lights when it brings at least this part of
# the dominant light's irradiance on the floor.
SECOND_TRUE_LIGHT_FRAC = 0.25


def write_true_direction_jobs(bench_dir: Path) -> Path:
    """OUT/jobs_true_dir.yaml: jobs.yaml with each lamp-lit scene's ``light:`` set to
    the true directions of its dominant light and, when it brings at least
    SECOND_TRUE_LIGHT_FRAC of that on the floor, the next one (``true_lights``: a lamp
    or the HDR map's sun), the strengths measured (``auto``)."""
    import yaml

    bench = json.loads((bench_dir / "benchmark.json").read_text())
    doc = yaml.safe_load((bench_dir / "jobs.yaml").read_text())
    for c in bench["cases"]:
        if c["scene"].get("lamps") and c["id"] in doc["scenes"]:
            tl = true_lights(c)
            top = [t for t in tl[:2] if t["floor_irradiance"] >= SECOND_TRUE_LIGHT_FRAC * tl[0]["floor_irradiance"]]
            lights = [{"direction": [float(v) for v in t["direction"]], "strength": "auto"} for t in top or tl[:1]]
            doc["scenes"][c["id"]]["light"] = lights[0] if len(lights) == 1 else lights
    path = bench_dir / "jobs_true_dir.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def median_job_seconds(out_dir: Path) -> float:
    secs = []
    for rep in out_dir.glob("*/report.json"):
        r = json.loads(rep.read_text())
        t = r.get("timings", {})
        secs.append(float(t.get("job_total_s", 0.0)))
    return statistics.median(secs) if secs else float("nan")


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
    ap.add_argument("--true-direction", action="store_true",
                    help="also run physical-true-dir: each lamp-lit scene given its true light direction "
                         "(manifest light, strength auto): what the estimate would reach with the direction right")
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
    if args.true_direction:
        runs.append(("physical-true-dir", "physical", None))
    rows, case_rows = [], []
    for name, method, src in runs:
        res_dir = out / "results" / name
        if not args.skip_composite:
            jf = write_true_direction_jobs(out) if name == "physical-true-dir" else jobs
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
        cases = per_case(out, res_dir)
        for c in cases:
            case_rows.append({"method": name, **c})
        import math
        near = [c["psnr_near"] for c in cases if math.isfinite(c["psnr_near"])]
        errs = [c["light_dir_err_deg"] for c in cases
                if c["lamp"] and c["shadow_in_frame"] and math.isfinite(c["light_dir_err_deg"])]
        dom = [c["dominant_err_deg"] for c in cases
               if c["lamp"] and c["shadow_in_frame"] and math.isfinite(c.get("dominant_err_deg", math.nan))]
        # the cases where the renderer drew a cast shadow (no contact-shadow fallback):
        # error against the nearest true light (the HDR map's sun included), and how many
        cast = [min(c["light_dir_err_deg"], c["dominant_err_deg"]) for c in cases
                if c["lamp"] and c["shadow_in_frame"] and c.get("fallback") is None
                and math.isfinite(c.get("dominant_err_deg", math.nan))]
        rows.append({"method": name, **{c: means.get(c) for c in COLUMNS},
                     "psnr_near": statistics.mean(near) if near else None,
                     "light_dir_err_deg": statistics.median(errs) if errs else None,
                     "dominant_light_err_deg": statistics.median(dom) if dom else None,
                     "cast_shadow_err_deg": (f"{statistics.median(cast):.1f} ({len(cast)})" if cast else None),
                     "median_s_per_job": median_job_seconds(res_dir)})

    def fmt(v):
        return "n/a" if v is None else (f"{v:.4f}" if isinstance(v, float) else str(v))

    header = ["method", *COLUMNS, *EXTRA]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(fmt(row[h]) for h in header) + " |" for row in rows]
    table = "\n".join(lines)
    print(f"\nBenchmark: {out} (metrics on sRGB [0, 1]; LPIPS at 256x256)\n" + table)
    (out / "table.md").write_text(table + "\n")
    with open(out / "table.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=header)
        w.writeheader()
        w.writerows(rows)
    with open(out / "cases.csv", "w", newline="") as f:
        keys = ["method", "case", "lamp", "shadow_in_frame", "psnr_near", "light_dir_err_deg", "dominant_light",
                "dominant_err_deg", "fallback"]
        w = csv.DictWriter(f, fieldnames=keys, extrasaction="ignore")
        w.writeheader()
        w.writerows(case_rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
