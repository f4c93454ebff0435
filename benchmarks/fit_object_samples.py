"""How many Cycles samples the object's anti-aliased pass needs (``blender.DEFAULT_SAMPLES``).

    .venv/bin/python benchmarks/fit_object_samples.py BENCH [BENCH ...] [--samples 16,32,64,128,256]
        [--renderer physical] [--json docs/object_samples.json]

The object's coverage (the alpha of ``render_intrinsics``' appearance pass) is the
share of a pixel's filter samples that hit the object: at ``N`` samples its error is at
most binomial, ``sqrt(m (1 - m) / N)`` (a sphere's edge: 0.047 rms at 16 samples, 0.016
at 64, against 1024), and the compositor blends the object into the photograph by it, so
a silhouette against a bright background shows that error times the contrast, pixel by
pixel: a ragged edge.
The ground truth's edge is Cycles' own film at 64 samples, denoised.

For each BENCH (a ``zcomp make-benchmark`` folder, development seeds only:
``benchmarks/seeds.py``), each sample count runs the renderer on the benchmark's
exposure-oracle jobs (``jobs_oracle_exposure.yaml``, written by ``run_benchmark.py
--oracle exposure``: the light and the exposure given, so the object's transport and
its edge are what is scored; else ``jobs.yaml``) with the manifest's ``defaults.samples``
set, into a cache of its own (the object passes rendered afresh, timed), and prints per
count: the object's PSNR (the mean over cases, sRGB, the ground truth's object mask),
the same on the mask's outer two-pixel band (the edge) and inside it, and the median
seconds of the object passes per job (the Blender batch's ``render_s``).

Measured (issue 48; development seeds 2719 and 3301, 16 cases each, 256x256,
physical renderer): see ``docs/object_samples.json`` and docs/calibration-record.md.
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np


def _scores(bench: Path, results: Path) -> dict:
    from scipy import ndimage

    from zcomp_cli.conventions import linear_to_srgb
    from zcomp_cli.imageio import read_alpha_or_grey, read_image

    desc = json.loads((bench / "benchmark.json").read_text())
    rows = {"object": [], "edge": [], "interior": []}
    for case in desc["cases"]:
        files = case["files"]
        got = sorted(glob.glob(str(results / f"*{case['id']}*" / "composite.exr")))
        if not got:
            continue
        gt = read_image(str(bench / files["gt"]))[..., :3]
        mask = read_alpha_or_grey(str(bench / files["object_mask"])) > 0.5
        inner = ndimage.binary_erosion(mask, iterations=2)
        err = (linear_to_srgb(np.clip(read_image(got[0])[..., :3], 0, None))
               - linear_to_srgb(np.clip(gt, 0, None))) ** 2
        for key, m in (("object", mask), ("edge", mask & ~inner), ("interior", inner)):
            if m.any():
                rows[key].append(10 * np.log10(1.0 / max(float(err[m].mean()), 1e-12)))
    return {k: float(np.mean(v)) if v else float("nan") for k, v in rows.items()} | {"cases": len(rows["object"])}


def run(bench: Path, samples: int, renderer: str, work: Path) -> dict:
    import yaml

    src = bench / "jobs_oracle_exposure.yaml"
    if not src.exists():
        src = bench / "jobs.yaml"
    jobs = yaml.safe_load(src.read_text())
    jobs.setdefault("defaults", {})["samples"] = int(samples)
    manifest = bench / f".fit_object_samples_{samples}.yaml"  # beside the jobs: their paths are relative
    manifest.write_text(yaml.safe_dump(jobs))
    out = work / f"{bench.name}_{renderer}_s{samples}"
    env = dict(os.environ, ZCOMP_CACHE_DIR=str(work / f"cache_s{samples}_{bench.name}"))
    try:
        subprocess.run([sys.executable, "-m", "zcomp_cli", "-q", "composite", str(manifest), "--out", str(out),
                        "--renderer", renderer, "--overwrite"], check=True, env=env)
    finally:
        manifest.unlink(missing_ok=True)
    summary = json.loads((out / "summary.json").read_text())
    render_s = [float(s) for s in (summary.get("blender") or {}).get("render_s") or []]
    return _scores(bench, out) | {"samples": int(samples), "object_pass_s": statistics.median(render_s)
                                  if render_s else float("nan")}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("bench", nargs="+", type=Path)
    ap.add_argument("--samples", default="16,32,64,128,256")
    ap.add_argument("--renderer", default="physical")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    counts = [int(s) for s in args.samples.split(",")]
    table = []
    with tempfile.TemporaryDirectory(prefix="zcomp_samples_") as tmp:
        for bench in args.bench:
            for n in counts:
                row = run(bench.resolve(), n, args.renderer, Path(tmp)) | {"bench": bench.name}
                table.append(row)
                print(f"{bench.name:24s} samples {n:4d}: object {row['object']:.2f} dB, edge {row['edge']:.2f}, "
                      f"interior {row['interior']:.2f} ({row['cases']} cases); object passes "
                      f"{row['object_pass_s']:.2f} s a job", flush=True)
    print("\nmean over the benchmarks:")
    for n in counts:
        rows = [r for r in table if r["samples"] == n]
        print(f"samples {n:4d}: object {np.mean([r['object'] for r in rows]):.2f} dB, edge "
              f"{np.mean([r['edge'] for r in rows]):.2f}, interior {np.mean([r['interior'] for r in rows]):.2f}, "
              f"object passes {np.mean([r['object_pass_s'] for r in rows]):.2f} s a job")
    if args.json:
        args.json.write_text(json.dumps({"renderer": args.renderer, "rows": table}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
