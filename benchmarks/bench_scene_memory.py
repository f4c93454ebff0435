"""Peak memory of one batch against its number of scenes (issue 30: a scene's maps are
freed after its last job, so the peak must stay flat in the number of scenes).

    .venv/bin/python benchmarks/bench_scene_memory.py [--scenes 10 60] [--size 512 384] \
        [--renderer naive] [--src SRC]

For each scene count N, a mesh-free batch of N distinct analytic scenes given as maps
(``zcomp_cli.testing.write_floor_batch``, one 2D card job per scene, the scenes taken in
turn) runs through the CLI in a subprocess; its peak resident memory (``ru_maxrss`` of
that process, from ``os.wait4``) and wall time are printed, with the growth per scene.
``--src`` runs another source tree (e.g. an export of an older commit) for a before /
after comparison.
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


def peak_rss_mb(cmd: list[str], env: dict) -> tuple[float, float, int]:
    """(peak RSS in MB, wall seconds, exit code) of ``cmd``."""
    t = time.perf_counter()
    p = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    _, status, usage = os.wait4(p.pid, 0)
    p.returncode = os.waitstatus_to_exitcode(status)
    return usage.ru_maxrss / 1024.0, time.perf_counter() - t, p.returncode


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", type=int, nargs="+", default=[10, 60])
    ap.add_argument("--size", type=int, nargs=2, default=(512, 384), metavar=("W", "H"))
    ap.add_argument("--renderer", default="naive")
    ap.add_argument("--src", type=Path, default=SRC, help="the zcomp source tree to run (default: this one)")
    args = ap.parse_args(argv)
    sys.path.insert(0, str(SRC))
    from zcomp_cli.testing import write_floor_batch

    env = dict(os.environ, PYTHONPATH=str(args.src))
    tmp = Path(tempfile.mkdtemp(prefix="zcomp-scene-memory-"))
    rows = []
    try:
        for n in args.scenes:
            manifest = write_floor_batch(tmp / f"b{n}", n, n_scenes=n, size=tuple(args.size), renderer=args.renderer)
            mb, wall, rc = peak_rss_mb([sys.executable, "-m", "zcomp_cli", "-q", "composite", str(manifest),
                                        "--out", str(tmp / f"out{n}"), "--cache-dir", str(tmp / "cache")], env)
            if rc != 0:
                raise SystemExit(f"{n} scenes: zcomp exited with {rc}")
            rows.append({"scenes": n, "peak_rss_mb": round(mb, 1), "wall_s": round(wall, 2)})
            print(json.dumps(rows[-1]), flush=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    if len(rows) > 1:
        a, b = rows[0], rows[-1]
        per = (b["peak_rss_mb"] - a["peak_rss_mb"]) / (b["scenes"] - a["scenes"])
        print(json.dumps({"src": str(args.src), "size": list(args.size), "renderer": args.renderer,
                          "rows": rows, "mb_per_extra_scene": round(per, 2)}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
