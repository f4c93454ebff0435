"""Speed of `zcomp report` on a big output folder (issue 38: 10 000 jobs in 10 s or less).

Builds a synthetic output folder (zcomp_cli.report.synthetic: report.json files shaped
as the pipeline writes them, a tiny PNG per finished job, one job in ten failed, an
eval.json, the manifest the reports name) in a temporary folder, then times the Python
function and the command line, and prints the figures: seconds to write the page and
its size.

    .venv/bin/python benchmarks/bench_report.py [--jobs 10000] [--keep DIR]
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

TARGET_S = 10.0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=10_000)
    ap.add_argument("--scenes", type=int, default=20)
    ap.add_argument("--keep", type=Path, default=None, help="build the folder here and keep it")
    args = ap.parse_args()

    from zcomp_cli.report.synthetic import make_output_folder
    from zcomp_cli.report.write import write_report

    root = args.keep or Path(tempfile.mkdtemp(prefix="zcomp-bench-report-"))
    try:
        t = time.perf_counter()
        out = make_output_folder(root, args.jobs, n_scenes=args.scenes)
        print(f"synthetic folder: {args.jobs} jobs in {time.perf_counter() - t:.1f} s ({out})")

        t = time.perf_counter()
        path, col = write_report(out)
        fn_s = time.perf_counter() - t
        size_mb = path.stat().st_size / 1e6
        print(f"write_report():  {fn_s:6.2f} s  {len(col.rows)} rows "
              f"({', '.join(f'{n} {s}' for s, n in col.counts.items())}), page {size_mb:.2f} MB")

        zcomp = Path(sys.executable).with_name("zcomp")
        cmd = [str(zcomp)] if zcomp.exists() else [sys.executable, "-m", "zcomp_cli"]
        t = time.perf_counter()
        res = subprocess.run([*cmd, "report", str(out)], capture_output=True, text=True)
        cli_s = time.perf_counter() - t
        if res.returncode != 0:
            print(res.stdout, res.stderr, file=sys.stderr)
            return 1
        print(f"zcomp report:    {cli_s:6.2f} s  (the whole process: start-up and imports included)")
        print(f"target: <= {TARGET_S:.0f} s for 10 000 jobs: {'met' if max(fn_s, cli_s) <= TARGET_S else 'MISSED'}")
    finally:
        if args.keep is None:
            shutil.rmtree(root, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
