"""Which colour-constancy estimate gives the plate's white balance (``PLATE_WHITE_BALANCE``
in ``estimators/albedo.py``).

    .venv/bin/python benchmarks/fit_plate_white_balance.py BENCH [BENCH ...] [--json docs/plate_white_balance.json]

(docs/plate_white_balance.json: the development seeds 1618, 8191, 2719, 3301 and 4441, 112 cases)

Each BENCH is a ``zcomp make-benchmark`` folder of a development seed
(``benchmarks/seeds.py``). A case's true light colour, as its camera recorded it, is
the mean over the frame of its true shading, ``image / albedo`` per channel (the
generator's albedo pass; pixels whose albedo is below 0.02 in a channel are left out:
there the ratio is noise). Each candidate reads the light's colour off the plate alone
(``estimators.white_balance.plate_illuminant``): grey ``(1, 1, 1)`` (what Retinex alone
assumes), shades of grey at ``p`` in 1, 2, 4, 6, 8, 12 and the maximum, and the grey-edge
form at the same orders. The score is the angle between the estimate and the truth
(median, mean and 90th percentile over cases, degrees); the script prints them and names
the candidate with the lowest mean (the expected error).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

CANDIDATES = [("grey", None, False)] + [(f"{'edge' if e else 'pixels'} p={p}", p, e)
                                        for e in (False, True) for p in (1, 2, 4, 6, 8, 12, math.inf)]
ALBEDO_FLOOR = 0.02  # below it, image / albedo is the noise of a dark pixel


def _true_colour(image: np.ndarray, albedo: np.ndarray) -> np.ndarray | None:
    ok = np.isfinite(image).all(-1) & np.isfinite(albedo).all(-1) & (albedo > ALBEDO_FLOOR).all(-1)
    if ok.sum() < 16:
        return None
    return (image[ok] / albedo[ok]).mean(0)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("benches", nargs="+", type=Path)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    from zcomp_cli.estimators.white_balance import angular_error_deg, plate_illuminant
    from zcomp_cli.imageio import read_image

    errors = {name: [] for name, _, _ in CANDIDATES}
    cases = []
    for bench in args.benches:
        desc = json.loads((bench / "benchmark.json").read_text())
        for case in desc["cases"]:
            folder = bench / "cases" / case["id"]
            image = read_image(str(folder / "image.exr"))[..., :3].astype(np.float64)
            albedo = read_image(str(folder / "albedo.exr"))[..., :3].astype(np.float64)
            truth = _true_colour(image, albedo)
            if truth is None:
                continue
            row = {"bench": bench.name, "case": case["id"], "truth": (truth / truth.sum()).round(4).tolist()}
            for name, p, edges in CANDIDATES:
                est = np.ones(3) if p is None else plate_illuminant(image, p=p, edges=edges)
                errors[name].append(angular_error_deg(est, truth))
                row[name] = round(errors[name][-1], 2)
            cases.append(row)
    print(f"{len(cases)} cases from {', '.join(str(b) for b in args.benches)}")
    print(f"{'candidate':<16} {'median':>7} {'mean':>7} {'p90':>7}  (angular error, degrees)")
    summary = {}
    for name, _, _ in CANDIDATES:
        e = np.asarray(errors[name])
        summary[name] = {"median": float(np.median(e)), "mean": float(e.mean()), "p90": float(np.percentile(e, 90))}
        print(f"{name:<16} {summary[name]['median']:7.2f} {summary[name]['mean']:7.2f} {summary[name]['p90']:7.2f}")
    best = min(summary, key=lambda k: summary[k]["mean"])
    print(f"lowest mean: {best}")
    if args.json:
        args.json.write_text(json.dumps({"benches": [str(b) for b in args.benches], "cases": len(cases),
                                         "summary": summary, "best": best, "per_case": cases}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
