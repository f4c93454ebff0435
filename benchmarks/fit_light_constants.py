"""Fit the light estimate's two calibrated constants on the development seeds
(``seeds.DEVELOPMENT``), and print how each was chosen:

* ``estimate.PRIOR_SKY_SHARE``: the sky's share of the support's light where the photo
  does not fix the split: the median, over the development cases, of the true share of
  the floor's irradiance at the object's base that the HDR map's sky brings (its sun and
  the lamps being the lights), from the generator's own description of each case.
* ``estimate.MIN_GAIN``: the least held-out gain for which the estimate keeps a light
  (and so draws its cast shadow rather than the contact shadow): among ``--grid``, the
  value whose physical composites have the highest mean PSNR near the object over the
  development cases (each value a run of the renderer with it, through
  ``run_benchmark.py --extra`` on a copy of ``src/``), the shadow IoU breaking ties
  within 0.05 dB. (How well the first light's gain tells the cases whose background
  shows cast shadows is printed too: a light is also fixed by shading on several
  orientations, without a cast shadow in frame.)

    python benchmarks/fit_light_constants.py BENCH_1618 BENCH_7777 [...] [--grid 0.05,0.2,0.6]

Each BENCH is a ``make-benchmark`` folder (the shares need only its description; the
gain table a ``run_benchmark.py --methods physical`` run in ``results/physical``).
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


def gains_by_case(bench: Path) -> dict:
    """{case id: the first light's held-out gain} of a benchmark's physical run."""
    out = {}
    for rep in (bench / "results" / "physical").glob("*/report.json"):
        r = json.loads(rep.read_text())
        light = r["renderer"]["info"]["light"]
        name = "case_" + rep.parent.name.split("case_")[1][:4]
        out[name] = float(light["fit"]["held_out_gain"])
    return out


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


def grid_run(bench: Path, value: float) -> str:
    """results/physical-gain-<value>: the physical renderer with MIN_GAIN = value."""
    import re
    import shutil
    import subprocess
    import tempfile

    root = Path(__file__).resolve().parents[1]
    tmp = Path(tempfile.mkdtemp(prefix="zcomp-gain-"))
    shutil.copytree(root / "src", tmp / "src")
    est = tmp / "src/zcomp_cli/renderers/physical/estimate.py"
    text, n = re.subn(r"^MIN_GAIN = .*$", f"MIN_GAIN = {value!r}", est.read_text(), count=1, flags=re.M)
    if n != 1:
        raise SystemExit("MIN_GAIN not found in estimate.py")
    est.write_text(text)
    name = f"physical-gain-{value:g}"
    subprocess.run([sys.executable, str(root / "benchmarks/run_benchmark.py"), "--out", str(bench), "--methods", "",
                    "--extra", f"{name}={tmp / 'src'}", "--metrics", "psnr,shadow-iou"], check=True,
                   stdout=subprocess.DEVNULL)
    shutil.rmtree(tmp, ignore_errors=True)
    return name


def mean_iou(bench: Path, method: str) -> list:
    data = json.loads((bench / "results" / method / "eval.json").read_text())
    return [float(r["shadow-iou"]) for r in data["images"] if r.get("shadow-iou") is not None]


def near_psnr(bench: Path, method: str, truths=None) -> dict:
    """{case id: PSNR near the object} of ``results/<method>`` (run_benchmark.per_case)."""
    import math

    from run_benchmark import per_case

    return {r["case"]: r["psnr_near"] for r in per_case(bench, bench / "results" / method, truths)
            if math.isfinite(r["psnr_near"])}


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
    ap.add_argument("--grid", default="0.05,0.2,0.6", help="MIN_GAIN values to run (comma-separated)")
    args = ap.parse_args(argv)
    grid = [float(x) for x in args.grid.split(",") if x.strip()]
    shares, pairs = [], []
    near = {g: [] for g in grid}
    iou = {g: [] for g in grid}
    for b in args.benches:
        from run_benchmark import case_truths

        truths = case_truths(b)
        for g in grid:
            name = grid_run(b, g)
            near[g] += list(near_psnr(b, name, truths).values())
            iou[g] += mean_iou(b, name)
        cases = json.loads((b / "benchmark.json").read_text())["cases"]
        s = [true_sky_share(c) for c in cases]
        shares += s
        p = gains_and_truth(b) if (b / "results" / "physical").is_dir() else []
        pairs += p
        print(f"{b}: {len(cases)} cases, true sky share median {statistics.median(s):.3f}; "
              f"{sum(x for _, x in p)} show cast shadows")
    print(f"PRIOR_SKY_SHARE = {statistics.median(shares):.2f}  (median of {len(shares)} cases)")
    scored = [(statistics.mean(near[g]), statistics.mean(iou[g]) if iou[g] else float("nan"), g) for g in grid]
    top = max(m for m, _, _ in scored)
    best = max((x for x in scored if x[0] >= top - 0.05), key=lambda x: (x[1], x[0]))
    for m, i, g in scored:
        print(f"  MIN_GAIN {g:g}: mean PSNR near the object {m:.3f} dB, shadow IoU {i:.3f}")
    print(f"MIN_GAIN = {best[2]:g}")
    if pairs:
        t, acc = best_threshold(pairs)
        print(f"(the gain tells the cases showing cast shadows at best with balanced accuracy {acc:.2f}, "
              f"threshold {t:.3g})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
