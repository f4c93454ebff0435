"""Figures of the README and docs/physical.md (issue 10).

    PYTHONPATH=src python docs/make_figures.py demo OUT_DEMO            # docs/demo.png
    PYTHONPATH=src python docs/make_figures.py cases BENCH IDS [METHOD [OUT]]  # docs/benchmark_cases.png
    PYTHONPATH=src python docs/make_figures.py coffee OUT_COFFEE        # docs/coffee_known_light.png
    PYTHONPATH=src python docs/make_figures.py coffee_estimated OUT_EST OUT_MAPS OUT_COFFEE
                                                                        # docs/coffee_estimated.png

``demo``: OUT_DEMO is ``zcomp composite examples/jobs.yaml --out OUT_DEMO`` (``make demo``);
top row background / job 0 (the light estimated) / job 4 (the same, the light given) /
their Cycles reference, bottom row jobs 1-3.
``cases``: BENCH is a ``make-benchmark`` folder whose ``results/METHOD`` (default
``physical``) holds the composites; IDS comma-separated case ids; one row per case:
background, the method's composite, GT; written to OUT (default
``docs/benchmark_cases.png``).
``coffee``: OUT_COFFEE is the composite output of ``docs/coffee/jobs.yaml``: the
photograph and the composite, side by side.
``coffee_estimated``: OUT_EST is the composite output of ``docs/coffee/jobs_estimated.yaml``
(nothing but the photograph and a ground-plane line), OUT_MAPS its ``zcomp estimate``
output, OUT_COFFEE that of ``docs/coffee/jobs.yaml`` (the light given).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from zcomp_cli.imageio import read_image, write_png


def _pad(im, p=3):
    return np.pad(im, ((p, p), (p, p), (0, 0)), constant_values=1.0)


def _row(ims):
    h = max(i.shape[0] for i in ims)
    ims = [np.pad(i, ((0, h - i.shape[0]), (0, 0), (0, 0)), constant_values=1.0) for i in ims]
    return np.concatenate([_pad(i) for i in ims], 1)


def _resize(im, w):
    import cv2

    h = int(round(im.shape[0] * w / im.shape[1]))
    return cv2.resize(im, (w, h), interpolation=cv2.INTER_AREA)


def demo(out_dir: Path):
    jobs = sorted(d for d in out_dir.iterdir() if (d / "report.json").is_file())
    root = Path("examples")
    bg = read_image(root / "scenes/room/image.png")
    comp = [read_image(j / "composite.exr") for j in jobs]
    ref = read_image(root / "refs/vase_pose.exr")
    top = _row([bg, comp[0], comp[4], ref])
    bottom = _row([_resize(c, bg.shape[1] * 4 // 3) for c in comp[1:4]])
    bottom = np.pad(bottom, ((0, 0), (0, max(0, top.shape[1] - bottom.shape[1])), (0, 0)), constant_values=1.0)
    write_png("docs/demo.png", np.concatenate([top, bottom[:, :top.shape[1]]], 0))


def cases(bench: Path, ids: list[str], method: str = "physical", out: str = "docs/benchmark_cases.png"):
    b = json.loads((bench / "benchmark.json").read_text())
    by_id = {c["id"]: c for c in b["cases"]}
    rows = []
    for cid in ids:
        c = by_id[cid]
        job = next(iter(sorted((bench / "results" / method).glob(f"*{cid}*"))))
        rows.append(_row([read_image(bench / c["files"]["image"]), read_image(job / "composite.exr"),
                          read_image(bench / c["files"]["gt"])]))
    half = (len(rows) + 1) // 2
    left, right = np.concatenate(rows[:half], 0), np.concatenate(rows[half:], 0)
    right = np.pad(right, ((0, left.shape[0] - right.shape[0]), (0, 0), (0, 0)), constant_values=1.0)
    write_png(out, np.concatenate([left, np.ones((left.shape[0], 12, 3)), right], 1))


def _first_job(out_dir: Path) -> Path:
    return next(d for d in sorted(out_dir.iterdir()) if (d / "report.json").is_file())


def coffee(out_dir: Path):
    job = _first_job(out_dir)
    rep = json.loads((job / "report.json").read_text())
    bg = read_image(Path(rep["job"]["manifest"]).parent / "coffee.png")
    write_png("docs/coffee_known_light.png", _row([bg, read_image(job / "composite.exr")]))


def coffee_estimated(est_out: Path, maps_out: Path, known_out: Path):
    """Top: the photograph, the weight-free composite (light estimated), the same with the
    light given. Bottom: what the weight-free estimators see (zcomp estimate's preview
    sheet without its image tile: inverse depth, normals, albedo, shading)."""
    job = _first_job(est_out)
    rep = json.loads((job / "report.json").read_text())
    bg = read_image(Path(rep["job"]["manifest"]).parent / "coffee.png")
    top = _row([bg, read_image(job / "composite.exr"), read_image(_first_job(known_out) / "composite.exr")])
    sheet = read_image(maps_out / "table" / "preview.png")  # decoded as sRGB, re-encoded on writing
    w = bg.shape[1]
    tiles = [sheet[:, i * w:(i + 1) * w] for i in range(1, 5)]
    bottom = _row([_resize(t, top.shape[1] // 4 - 6) for t in tiles])
    bottom = np.pad(bottom, ((0, 0), (0, top.shape[1] - bottom.shape[1]), (0, 0)), constant_values=1.0)
    write_png("docs/coffee_estimated.png", np.concatenate([top, bottom], 0))


if __name__ == "__main__":
    what = sys.argv[1]
    if what == "demo":
        demo(Path(sys.argv[2]))
    elif what == "cases":
        cases(Path(sys.argv[2]), sys.argv[3].split(","), *(sys.argv[4:6]))
    elif what == "coffee":
        coffee(Path(sys.argv[2]))
    elif what == "coffee_estimated":
        coffee_estimated(Path(sys.argv[2]), Path(sys.argv[3]), Path(sys.argv[4]))
    else:
        raise SystemExit(__doc__)
