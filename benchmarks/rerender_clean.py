"""A benchmark's chosen backgrounds rendered again, clean: to ask what the photograph does to a fit.

The generator's photographs (``zcomp make-benchmark``) are Cycles renders at 32-64
samples through Open Image Denoise, lit by an HDR map and, in most cases, a lamp. A
fit's preference read off them (``size_oracle_models.py``: a wide light where the truth
is the Sun's size) may be the photograph's (the denoiser's smear of a faint shadow
edge, the map's sky in the shadow) or the model's. This script copies BENCH to OUT and
renders the backgrounds of ``--cases`` again, the same scene and the same draw
(``generate.plan_benchmark`` at the benchmark's own seed), with ``--samples`` samples
and **no denoiser**, the map's radiance scaled by ``--sky-scale`` (1: as generated;
0.1: the lamp's light with a tenth of the sky). Each is exposed by the generator's own
rule (``generate.exposure_scale``); its depth, normals and albedo are the original's
(the same scene). Only the backgrounds are rendered: OUT's ground truths are BENCH's,
so OUT is for diagnostics of the light's fit, not for scoring composites.

    PYTHONPATH=src python benchmarks/rerender_clean.py CALIB/4242 OUT/4242-clean --cases 4,7,19,21 \\
        [--samples 512] [--sky-scale 1]

Then, e.g., ``size_oracle_models.py OUT/4242-clean``. An existing OUT is reused (its
chosen cases rendered again); nothing is written outside OUT (Blender's log:
``OUT/rerender_blender.log``).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import shutil
import sys
import tempfile
from pathlib import Path

BENCHMARK_FILE = "benchmark.json"


def parse_cases(text: str) -> list[int]:
    """``"4,7,19"`` -> [4, 7, 19] (case indices, each >= 0)."""
    try:
        out = sorted({int(x) for x in text.split(",") if x.strip()})
    except ValueError:
        raise SystemExit(f"--cases: comma-separated case indices, got {text!r}")
    if not out or out[0] < 0:
        raise SystemExit(f"--cases: comma-separated case indices >= 0, got {text!r}")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("bench", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--cases", required=True, type=parse_cases, help="case indices, e.g. 4,7,19")
    ap.add_argument("--samples", type=int, default=512, help="Cycles samples per render (no denoiser)")
    ap.add_argument("--sky-scale", type=float, default=1.0, help="the HDR map's radiance times this")
    args = ap.parse_args(argv)
    if args.samples < 1 or not args.sky_scale >= 0:
        raise SystemExit("--samples must be >= 1 and --sky-scale >= 0")
    src = args.bench / BENCHMARK_FILE
    if not src.is_file():
        raise SystemExit(f"{args.bench}: no {BENCHMARK_FILE} (not a `zcomp make-benchmark` folder)")
    bench = json.loads(src.read_text())
    by_id = {c["id"]: c for c in bench["cases"]}

    from zcomp_cli.benchsuite.generate import BenchmarkSettings, exposure_scale, plan_benchmark, render_items
    from zcomp_cli.benchsuite.render import render_scenes
    from zcomp_cli.imageio import write_exr, write_json_atomic, write_png

    st = bench["settings"]
    n = max(args.cases) + 1
    if n > int(st["n"]):
        raise SystemExit(f"--cases: {args.bench} has {st['n']} cases (0..{int(st['n']) - 1})")
    if not args.out.exists():
        shutil.copytree(args.bench, args.out)
    settings = BenchmarkSettings(n=n, seed=int(st["seed"]), resolution=tuple(st["resolution"]),
                                 samples=args.samples, denoise=False)
    with tempfile.TemporaryDirectory(prefix="zcomp-rerender-") as tmp:
        # the plan draws each case from its own seed: the first n are the benchmark's
        plans = [p for i, p in enumerate(plan_benchmark(settings, tmp)) if i in args.cases]
        items = []
        for p in plans:
            if p.id not in by_id:
                raise SystemExit(f"{args.bench}: the plan's {p.id} is not among its cases (another generator version?)")
            scene = dataclasses.replace(p.scene, hdr_strength=p.scene.hdr_strength * args.sky_scale)
            items.append(render_items(dataclasses.replace(p, scene=scene), settings, tmp)[0])  # the background
        maps = render_scenes(items, threads=0, log_path=args.out / "rerender_blender.log",
                             on_event=lambda ev: print(f"{ev.get('event')} {ev.get('id') or ''}", flush=True)
                             if ev.get("event") in ("done", "error") else None)
        out_bench = json.loads((args.out / BENCHMARK_FILE).read_text())
        out_cases = {c["id"]: c for c in out_bench["cases"]}
        for p in plans:
            image = maps[f"{p.id}/bg"].image
            scale = exposure_scale(image, settings.exposure_key)
            case_dir = args.out / "cases" / p.id
            write_exr(case_dir / "image.exr", image * scale)
            write_png(case_dir / "image.png", image * scale)
            out_cases[p.id]["exposure"] = float(scale)
            out_cases[p.id]["rerendered"] = {"samples": args.samples, "denoise": False, "sky_scale": args.sky_scale,
                                             "ground_truth": "the original's (not rendered again)"}
            print(f"{p.id}: background written", flush=True)
        write_json_atomic(args.out / BENCHMARK_FILE, out_bench)
    return 0


if __name__ == "__main__":
    sys.exit(main())
