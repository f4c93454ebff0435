"""End-to-end benchmark (issue 4): ground truth by Cycles, every method, one table.

    python benchmarks/run_benchmark.py --out out/bench --n 20 --resolution 256 256

1. ``zcomp make-benchmark`` renders N cases (skipped if OUT/jobs.yaml exists and
   --regenerate is not given);
2. ``zcomp composite`` runs each method (naive paste, physical, and zerocomp when
   ZCOMP_CONTROLNET / ZCOMP_SD_BASE point at weights);
3. ``zcomp eval --metrics all`` scores each method against the ground truth;
4. prints a table in the paper's column order (PSNR, RMSE, si-RMSE, SSIM, MAE, LPIPS,
   FLIP) with the median seconds per job, and writes OUT/table.csv and OUT/table.md.
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

COLUMNS = ["psnr", "rmse", "si-rmse", "ssim", "mae", "lpips", "flip"]


def zcomp(*args: str) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "zcomp_cli", "-q", *args]
    print("$ zcomp " + " ".join(args), flush=True)
    return subprocess.run(cmd, text=True, capture_output=True)


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
    rows = []
    for method in methods:
        res_dir = out / "results" / method
        r = zcomp("composite", str(jobs), "--out", str(res_dir), "--renderer", method, "--overwrite")
        if r.returncode not in (0, 1):
            print(r.stdout, r.stderr, file=sys.stderr)
            return r.returncode
        if r.returncode == 1:
            print(f"warning: some {method} jobs failed:\n{r.stderr[-2000:]}", file=sys.stderr)
        r = zcomp("eval", "--metrics", args.metrics, str(res_dir))
        if r.returncode not in (0, 1):
            print(r.stdout, r.stderr, file=sys.stderr)
            return r.returncode
        means = read_means(res_dir / "eval.json")
        rows.append({"method": method, **{c: means.get(c) for c in COLUMNS},
                     "median_s_per_job": median_job_seconds(res_dir)})

    def fmt(v):
        return "n/a" if v is None else (f"{v:.4f}" if isinstance(v, float) else str(v))

    header = ["method", *COLUMNS, "median_s_per_job"]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(fmt(row[h]) for h in header) + " |" for row in rows]
    table = "\n".join(lines)
    print(f"\nBenchmark: {out} (metrics on sRGB [0, 1]; LPIPS at 256x256)\n" + table)
    (out / "table.md").write_text(table + "\n")
    with open(out / "table.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=header)
        w.writeheader()
        w.writerows(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
