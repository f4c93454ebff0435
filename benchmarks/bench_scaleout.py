"""Benchmark scale-out: jobs/s of one batch run locally, on Ray with 1 and 2 workers, and
as 2 shards side by side.

    .venv/bin/python benchmarks/bench_scaleout.py [--jobs 24] [--size 128 96] \
        [--json docs/scaleout.json] [--plot docs/scaleout.png]

The batch is mesh-free (``zcomp_cli.testing.write_floor_batch``: 3 analytic scenes given
as maps, a 2D card object, physical renderer), so no Blender and no estimation are
timed. Every configuration runs the real CLI in a subprocess into a fresh --out:

* ``local``: ``zcomp composite``;
* ``ray-W``: ``zcomp composite --executor ray --address auto --workers W`` against a
  Ray started once with ``ray start --head --num-cpus 2`` (a cluster is long-lived, so
  its start is reported apart, not charged to the batch);
* ``shards-2``: ``zcomp composite --shard 0/2`` and ``--shard 1/2`` started together.

Figures: wall seconds, jobs/s, per-job overhead (wall x workers / jobs minus the mean
job seconds of the local run: what each job costs beyond its own work) and efficiency
(jobs/s over workers x local jobs/s).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src"


def _env() -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = f"{SRC}{os.pathsep}{env.get('PYTHONPATH', '')}".rstrip(os.pathsep)
    return env


def _zcomp(*args) -> list[str]:
    return [sys.executable, "-m", "zcomp_cli", "-q", "composite", *map(str, args)]


def _run(cmds: list[list[str]], cache: Path) -> float:
    """Start every command at once, wait for all; return the wall seconds."""
    env = _env()
    env["ZCOMP_CACHE_DIR"] = str(cache)
    t0 = time.perf_counter()
    procs = [subprocess.Popen(c, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
             for c in cmds]
    for p in procs:
        _, err = p.communicate()
        if p.returncode != 0:
            raise SystemExit(f"{' '.join(p.args)} failed ({p.returncode}):\n{err[-2000:]}")
    return time.perf_counter() - t0


def _job_seconds(out: Path) -> list[float]:
    secs = []
    for f in out.glob("summary*.json"):
        secs += [j["seconds"] for j in json.loads(f.read_text())["jobs"] if j["status"] == "done"]
    return secs


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=24)
    ap.add_argument("--size", type=int, nargs=2, default=(128, 96), metavar=("W", "H"))
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--plot", type=Path, default=None)
    args = ap.parse_args(argv)
    sys.path.insert(0, str(SRC))
    from zcomp_cli.testing import write_floor_batch

    tmp = Path(tempfile.mkdtemp(prefix="zcomp-scaleout-"))
    ray_bin = Path(sys.executable).with_name("ray")
    rows = []
    try:
        manifest = write_floor_batch(tmp / "batch", args.jobs, n_scenes=3, size=tuple(args.size))

        def measure(name: str, workers: int, cmds_for) -> dict:
            out = tmp / f"out-{name}"
            wall = _run(cmds_for(out), tmp / f"cache-{name}")  # a fresh cache: nothing reused
            row = {"config": name, "workers": workers, "wall_s": round(wall, 2),
                   "jobs_per_s": round(args.jobs / wall, 3), "mean_job_s": None}
            secs = _job_seconds(out)
            assert len(secs) == args.jobs, f"{name}: {len(secs)} of {args.jobs} jobs done"
            row["mean_job_s"] = round(sum(secs) / len(secs), 3)
            rows.append(row)
            print(json.dumps(row), flush=True)
            return row

        load0 = os.getloadavg()[0]
        local = measure("local", 1, lambda out: [_zcomp(manifest, "--out", out)])
        t = time.perf_counter()
        subprocess.run([str(ray_bin), "start", "--head", "--num-cpus", "2", "--include-dashboard", "false",
                        "--disable-usage-stats"], env=_env(), check=True, capture_output=True)
        ray_start = time.perf_counter() - t
        try:
            for w in (1, 2):
                measure(f"ray-{w}", w, lambda out, w=w: [_zcomp(manifest, "--out", out, "--executor", "ray",
                                                                "--address", "auto", "--workers", w)])
        finally:
            subprocess.run([str(ray_bin), "stop", "--force"], env=_env(), capture_output=True)
        measure("shards-2", 2, lambda out: [_zcomp(manifest, "--out", out, "--shard", f"{i}/2")
                                            for i in range(2)])
        load1 = os.getloadavg()[0]
    finally:
        shutil.rmtree(tmp, ignore_errors=True)

    base = local["jobs_per_s"]
    for r in rows:
        r["per_job_overhead_s"] = round(r["wall_s"] * r["workers"] / args.jobs - local["mean_job_s"], 3)
        r["efficiency"] = round(r["jobs_per_s"] / (r["workers"] * base), 3)
    figures = {"jobs": args.jobs, "size": list(args.size), "renderer": "physical", "cpu_count": os.cpu_count(),
               "ray_start_s": round(ray_start, 2), "load_avg_1min": [round(load0, 2), round(load1, 2)],
               "rows": rows}
    print(json.dumps(figures, indent=2))
    if args.json:
        args.json.write_text(json.dumps(figures, indent=2) + "\n")
    if args.plot:
        _plot(figures, args.plot)
    return 0


def _plot(fig: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = fig["rows"]
    local = next(r for r in rows if r["config"] == "local")
    f, ax = plt.subplots(figsize=(6.4, 4.0), dpi=110)
    ray = [r for r in rows if r["config"].startswith("ray")]
    ax.plot([r["workers"] for r in ray], [r["jobs_per_s"] for r in ray], "o-", label="Ray executor")
    sh = [r for r in rows if r["config"].startswith("shards")]
    ax.plot([r["workers"] for r in sh], [r["jobs_per_s"] for r in sh], "s", ms=9, label="2 shards side by side")
    ax.plot([1], [local["jobs_per_s"]], "D", ms=8, color="k", label="local executor")
    ws = [1, 2]
    ax.plot(ws, [local["jobs_per_s"] * w for w in ws], ":", color="grey", label="ideal (local x workers)")
    for r in rows:
        ax.annotate(f"{r['jobs_per_s']:.2f}", (r["workers"], r["jobs_per_s"]), textcoords="offset points",
                    xytext=(6, -12), fontsize=8)
    ax.set_xticks(ws)
    ax.set_xlabel("workers (processes)")
    ax.set_ylabel("jobs / s")
    ax.set_ylim(bottom=0)
    ax.set_title(f"{fig['jobs']} jobs, physical renderer, {fig['size'][0]}x{fig['size'][1]}, "
                 f"{fig['cpu_count']} shared cores (load {fig['load_avg_1min'][0]:.0f})", fontsize=9)
    ax.legend(fontsize=8, loc="lower right")
    ax.grid(alpha=0.3)
    f.tight_layout()
    f.savefig(path)


if __name__ == "__main__":
    sys.exit(main())
