"""Fit the light estimate's two calibrated constants on the development seeds
(``seeds.DEVELOPMENT``), and print how each was chosen:

* ``estimate.PRIOR_SKY_SHARE``: the sky's share of the support's light where the photo
  does not fix the split: the median, over the development cases, of the true share of
  the floor's irradiance at the object's base that the HDR map's sky brings (its sun and
  the lamps being the lights), from the generator's own description of each case.
* ``estimate.MIN_GAIN``: the least held-out gain for which the estimate draws a light's
  cast shadow: the threshold that best separates (balanced accuracy) the cases whose
  background shows a light's cast shadows (``run_benchmark.cast_shadows_shown``) from
  the others, on the gains a ``physical`` run reported (``report.json``).

    python benchmarks/fit_light_constants.py BENCH_1618 BENCH_7777 [...]

Each BENCH is a ``make-benchmark`` folder on which ``run_benchmark.py --methods physical``
has run (``results/physical``).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))


def true_sky_share(case: dict) -> float:
    """The HDR sky's share of the floor's irradiance at the case object's base."""
    import numpy as np

    from zcomp_cli.benchsuite.scenes import BenchScene, hdr_lights, lamp_rays, lamps_for_blender

    sc = BenchScene.from_dict(case["scene"])
    h = hdr_lights(sc)
    base = np.asarray(case["pose"]["position"], np.float64)
    lamps = 0.0
    for lp in lamps_for_blender(sc):
        d, _, e = lamp_rays(lp, base[None])
        lamps += float(e[0]) * max(float(d[0] @ sc.up), 0.0)
    sky, sun = h["sky_floor_irradiance"], h["sun_floor_irradiance"] + lamps
    return sky / max(sky + sun, 1e-12)


def gains_and_truth(bench: Path):
    """[(held-out gain, whether the background shows cast shadows)] of a benchmark's
    physical run."""
    from run_benchmark import case_truths

    truths = case_truths(bench)
    out = []
    for cid, t in sorted(truths.items()):
        rep = next((bench / "results" / "physical").glob(f"*{cid}*/report.json"), None)
        if rep is None:
            continue
        light = json.loads(rep.read_text())["renderer"]["info"]["light"]
        out.append((float(light["fit"]["held_out_gain"]), bool(t["shown"])))
    return out


def best_threshold(pairs):
    """(threshold, balanced accuracy) separating True from False by gain >= threshold."""
    pos = [g for g, s in pairs if s]
    neg = [g for g, s in pairs if not s]
    best = (0.0, 0.0)
    for t in sorted({g for g, _ in pairs}):
        tpr = sum(g >= t for g in pos) / max(len(pos), 1)
        tnr = sum(g < t for g in neg) / max(len(neg), 1)
        acc = 0.5 * (tpr + tnr)
        if acc > best[1]:
            best = (t, acc)
    return best


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("benches", nargs="+", type=Path)
    args = ap.parse_args(argv)
    shares, pairs = [], []
    for b in args.benches:
        cases = json.loads((b / "benchmark.json").read_text())["cases"]
        s = [true_sky_share(c) for c in cases]
        shares += s
        p = gains_and_truth(b)
        pairs += p
        print(f"{b}: {len(cases)} cases, true sky share median {statistics.median(s):.3f}; "
              f"{sum(x for _, x in p)} show cast shadows")
    print(f"PRIOR_SKY_SHARE = {statistics.median(shares):.2f}  (median of {len(shares)} cases)")
    if pairs:
        t, acc = best_threshold(pairs)
        print(f"MIN_GAIN = {t:.3g}  (balanced accuracy {acc:.2f} over {len(pairs)} cases: "
              "cast shadows shown vs not)")
        for g, sh in sorted(pairs):
            print(f"  gain {g:8.3f}  {'shown' if sh else '-'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
