"""Time ``zcomp import zerocomp`` on a replica of the ZeroComp archive at the archive's
size (512 x 512 per case; tests/lvsn_replica.py writes it), and the validation of the
manifest it writes. Prints seconds per case and the size of what was written.

    PYTHONPATH=src python benchmarks/bench_import.py --cases 8 --size 512
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=8)
    ap.add_argument("--size", type=int, default=512)
    args = ap.parse_args()

    import lvsn_replica as replica

    from zcomp_cli.datasets.importer import ARCHIVES, ImportOptions, run_import

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        t0 = time.perf_counter()
        replica.make_zerocomp_archive(tmp / "labo", args.cases, size=args.size)
        t_make = time.perf_counter() - t0
        bundle_mb = sum(p.stat().st_size for p in (tmp / "labo").rglob("*bundle*.exr")) / 2**20
        t1 = time.perf_counter()
        res = run_import(ARCHIVES["zerocomp"], ImportOptions(src=tmp / "labo", out=tmp / "out" / "jobs.yaml",
                                                             maps="provided"))
        t_import = time.perf_counter() - t1
        out_mb = sum(p.stat().st_size for p in res.data_dir.rglob("*") if p.is_file()) / 2**20
        print(f"replica: {args.cases} cases of {args.size}x{args.size} ({bundle_mb:.1f} MiB of bundles), "
              f"written in {t_make:.1f} s")
        print(f"import (convert, write, validate the manifest): {t_import:.2f} s, "
              f"{t_import / args.cases:.3f} s per case, {out_mb:.1f} MiB written; "
              f"{len(res.imported)} imported, {len(res.failed)} failed")


if __name__ == "__main__":
    main()
