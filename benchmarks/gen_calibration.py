"""Generate the light estimate's calibration cases in the background, resumably.

    python benchmarks/gen_calibration.py OUT [--seeds 1618,7777,...] [--n 28]
        [--resolution 192 192] [--samples 32]

One ``zcomp make-benchmark`` per seed (``OUT/<seed>/``: Cycles ground truth, each case's
generator description in ``benchmark.json``), seed after seed; a seed whose
``benchmark.json`` exists is done and skipped, so an interrupted run resumes where it
stopped (the seed it was in is made again). The default seeds are the development seeds
and those earlier versions reported (``seeds.py``: a reported seed may serve
development, never the report again); the report seed is never among them.

The cases carry their generator families in ``benchmark.json`` -- the HDR map, the lamp
kinds, the objects -- so that ``fit_light_constants.py`` can hold whole families out of
a fit and check it on them.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from seeds import DEVELOPMENT, REPORT, REPORTED  # noqa: E402

# The default calibration seeds: every seed development may look at (12: at least 10,
# 300 cases and more at the default --n).
DEFAULT_SEEDS = tuple(dict.fromkeys(DEVELOPMENT + REPORTED))[:12]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("out", type=Path)
    ap.add_argument("--seeds", default=",".join(map(str, DEFAULT_SEEDS)))
    ap.add_argument("--n", type=int, default=28, help="cases per seed")
    ap.add_argument("--resolution", type=int, nargs=2, default=(192, 192))
    ap.add_argument("--samples", type=int, default=32)
    args = ap.parse_args(argv)
    seeds = [int(s) for s in args.seeds.split(",") if s.strip()]
    if REPORT in seeds:
        ap.error(f"seed {REPORT} is the report seed: it is never generated for calibration")
    args.out.mkdir(parents=True, exist_ok=True)
    for k, seed in enumerate(seeds):
        folder = args.out / str(seed)
        if (folder / "benchmark.json").is_file():
            print(f"[{k + 1}/{len(seeds)}] seed {seed}: done", flush=True)
            continue
        t0 = time.perf_counter()
        cmd = [sys.executable, "-m", "zcomp_cli", "-q", "make-benchmark", str(folder), "--n", str(args.n),
               "--seed", str(seed), "--resolution", *map(str, args.resolution), "--samples", str(args.samples),
               "--overwrite"]
        r = subprocess.run(cmd)
        if r.returncode != 0:
            print(f"[{k + 1}/{len(seeds)}] seed {seed}: make-benchmark failed ({r.returncode})", flush=True)
            return r.returncode
        print(f"[{k + 1}/{len(seeds)}] seed {seed}: {args.n} cases in {time.perf_counter() - t0:.0f} s", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
