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
  its start is reported apart, not charged to the batch; the workers' start is);
* ``shards-2``: ``zcomp composite --shard 0/2`` and ``--shard 1/2`` started together.

Each configuration runs ``--repeat`` times, rounds interleaved (the machine is
shared: load moves). Figures, medians with min-max: wall seconds, jobs/s, per-job
overhead (wall x workers / jobs minus the run's mean job seconds: what a job costs
beyond its own work -- process and Ray start, scheduling, scene loads) and efficiency
(jobs/s over workers x local jobs/s).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
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
    ap.add_argument("--repeat", type=int, default=3, help="rounds over all configurations")
    ap.add_argument("--configs", default="local,ray-1,ray-2,shards-2",
                    help="comma-separated configurations to run (local is always run: the reference)")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--plot", type=Path, default=None)
    ap.add_argument("--replot", type=Path, default=None, metavar="JSON",
                    help="only redraw --plot from a JSON this script wrote")
    args = ap.parse_args(argv)
    if args.replot:
        _plot(json.loads(args.replot.read_text()), args.plot)
        return 0
    sys.path.insert(0, str(SRC))
    from zcomp_cli.testing import write_floor_batch

    tmp = Path(tempfile.mkdtemp(prefix="zcomp-scaleout-"))
    ray_bin = Path(sys.executable).with_name("ray")
    runs: dict[str, list[dict]] = {}
    workers = {"local": 1, "ray-1": 1, "ray-2": 2, "shards-2": 2}
    try:
        manifest = write_floor_batch(tmp / "batch", args.jobs, n_scenes=3, size=tuple(args.size))
        cmds = {
            "local": lambda out: [_zcomp(manifest, "--out", out)],
            "ray-1": lambda out: [_zcomp(manifest, "--out", out, "--executor", "ray", "--address", "auto",
                                         "--workers", 1)],
            "ray-2": lambda out: [_zcomp(manifest, "--out", out, "--executor", "ray", "--address", "auto",
                                         "--workers", 2)],
            "shards-2": lambda out: [_zcomp(manifest, "--out", out, "--shard", f"{i}/2") for i in range(2)],
        }
        want = {"local", *(c.strip() for c in args.configs.split(",") if c.strip())}
        unknown = want - set(cmds)
        if unknown:
            raise SystemExit(f"unknown configurations {sorted(unknown)}; known: {', '.join(cmds)}")
        cmds = {k: v for k, v in cmds.items() if k in want}
        t = time.perf_counter()
        subprocess.run([str(ray_bin), "start", "--head", "--num-cpus", "2", "--include-dashboard", "false",
                        "--disable-usage-stats"], env=_env(), check=True, capture_output=True)
        ray_start = time.perf_counter() - t
        try:
            # Rounds interleave the configurations, so a change in the machine's load
            # (it is shared) spreads over all of them instead of biasing one.
            for rnd in range(args.repeat):
                for name, cmd in cmds.items():
                    out = tmp / f"out-{name}-{rnd}"
                    load = os.getloadavg()[0]
                    wall = _run(cmd(out), tmp / f"cache-{name}-{rnd}")  # fresh cache: nothing reused
                    secs = _job_seconds(out)
                    assert len(secs) == args.jobs, f"{name}: {len(secs)} of {args.jobs} jobs done"
                    run = {"wall_s": wall, "mean_job_s": sum(secs) / len(secs), "load": load,
                           # time each worker spends outside its jobs' own work, per job
                           "overhead_s": wall * workers[name] / args.jobs - sum(secs) / len(secs)}
                    runs.setdefault(name, []).append(run)
                    print(json.dumps({"round": rnd, "config": name, **{k: round(v, 3) for k, v in run.items()}}),
                          flush=True)
                    shutil.rmtree(out, ignore_errors=True)
        finally:
            subprocess.run([str(ray_bin), "stop", "--force"], env=_env(), capture_output=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)

    def med(xs):
        return statistics.median(xs)

    local_jps = args.jobs / med([r["wall_s"] for r in runs["local"]])
    rows = []
    for name, rs in runs.items():
        walls = [r["wall_s"] for r in rs]
        jps = args.jobs / med(walls)
        rows.append({"config": name, "workers": workers[name], "wall_s": round(med(walls), 2),
                     "wall_min_max_s": [round(min(walls), 2), round(max(walls), 2)],
                     "jobs_per_s": round(jps, 3),
                     "jobs_per_s_min_max": [round(args.jobs / max(walls), 3), round(args.jobs / min(walls), 3)],
                     "mean_job_s": round(med([r["mean_job_s"] for r in rs]), 3),
                     "per_job_overhead_s": round(med([r["overhead_s"] for r in rs]), 3),
                     "efficiency": round(jps / (workers[name] * local_jps), 3),
                     "load_avg": [round(r["load"], 1) for r in rs]})
    figures = {"jobs": args.jobs, "size": list(args.size), "renderer": "physical", "cpu_count": os.cpu_count(),
               "repeat": args.repeat, "ray_start_s": round(ray_start, 2),
               "load_avg_1min": [round(min(r["load"] for rs in runs.values() for r in rs), 1),
                                 round(max(r["load"] for rs in runs.values() for r in rs), 1)],
               "rows": rows}
    print(json.dumps(figures, indent=2))
    if args.json:
        args.json.write_text(json.dumps(figures, indent=2) + "\n")
    if args.plot:
        _plot(figures, args.plot)
    return 0


def _spread(rows):
    lo = [r["jobs_per_s"] - r["jobs_per_s_min_max"][0] for r in rows]
    hi = [r["jobs_per_s_min_max"][1] - r["jobs_per_s"] for r in rows]
    return [lo, hi]


def _plot(fig: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = fig["rows"]
    local = next(r for r in rows if r["config"] == "local")
    f, ax = plt.subplots(figsize=(6.4, 4.0), dpi=110)
    ray = [r for r in rows if r["config"].startswith("ray")]
    ax.errorbar([r["workers"] for r in ray], [r["jobs_per_s"] for r in ray],
                yerr=_spread(ray), fmt="o-", capsize=3, label="Ray executor")
    sh = [r for r in rows if r["config"].startswith("shards")]
    ax.errorbar([r["workers"] for r in sh], [r["jobs_per_s"] for r in sh], yerr=_spread(sh), fmt="s", ms=8,
                capsize=3, label="2 shards side by side")
    ax.errorbar([1], [local["jobs_per_s"]], yerr=_spread([local]), fmt="D", ms=7, color="k", capsize=3,
                label="local executor")
    ws = [1, 2]
    ax.plot(ws, [local["jobs_per_s"] * w for w in ws], ":", color="grey", label="ideal (local x workers)")
    for r in rows:
        left = r["config"] == "local"  # beside Ray-1 at the same x: label it on the other side
        ax.annotate(f"{r['jobs_per_s']:.2f}", (r["workers"], r["jobs_per_s"]), textcoords="offset points",
                    xytext=(-30 if left else 6, -4 if left else -12), fontsize=8)
    ax.set_xticks(ws)
    ax.set_xlim(0.6, 2.4)
    ax.set_xlabel("workers (processes)")
    ax.set_ylabel("jobs / s")
    ax.set_ylim(bottom=0)
    lo, hi = fig["load_avg_1min"]
    ax.set_title(f"{fig['jobs']} jobs, physical, {fig['size'][0]}x{fig['size'][1]}, {fig['cpu_count']} shared cores "
                 f"(load {lo:.0f}-{hi:.0f}); median of {fig['repeat']}, bars min-max", fontsize=8)
    ax.legend(fontsize=8, loc="lower right")
    ax.grid(alpha=0.3)
    f.tight_layout()
    f.savefig(path)


if __name__ == "__main__":
    sys.exit(main())
