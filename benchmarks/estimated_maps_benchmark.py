"""What estimating the background's maps costs in quality (issue 6's figure).

    python benchmarks/estimated_maps_benchmark.py BENCH_DIR --out OUT [--renderer physical]

Runs ``zcomp composite`` + ``zcomp eval`` on a benchmark made by ``zcomp make-benchmark``
three times: with the exact maps the generator rendered, with normals and albedo
estimated (normals from the exact depth, Retinex albedo), and with everything
estimated (ground-plane depth proxy from the scene's true camera height and pitch,
normals from it, Retinex albedo). Prints a table in the paper's column order.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import yaml

sys.path.insert(0, str(Path(__file__).parent))
from run_benchmark import COLUMNS, median_job_seconds, read_means, zcomp  # noqa: E402


def variant(manifest: dict, bench: dict, mode: str, root: Path) -> dict:
    m = json.loads(json.dumps(manifest))
    cases = {c["id"]: c for c in bench["cases"]}
    for name, s in m["scenes"].items():
        for k in ("image", "depth", "normals", "albedo"):
            if k in s:
                s[k] = str((root / s[k]).resolve())
        if mode in ("estimated_normals_albedo", "all_estimated"):
            s.pop("normals", None)
            s.pop("albedo", None)
        if mode == "all_estimated":
            sc = cases[name]["scene"]
            s["depth"] = {"proxy": "ground_plane", "camera_height": float(sc["camera_height"]),
                          "pitch_deg": -float(sc["pitch_deg"])}
    for o in m["objects"].values():
        o["mesh"] = str((root / o["mesh"]).resolve())
    for j in m["jobs"]:
        if "reference" in j:
            j["reference"] = str((root / j["reference"]).resolve())
    return m


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("bench")
    ap.add_argument("--out", required=True)
    ap.add_argument("--renderer", default="physical")
    ap.add_argument("--metrics", default="all")
    args = ap.parse_args(argv)
    root = Path(args.bench).resolve()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    manifest = yaml.safe_load((root / "jobs.yaml").read_text())
    bench = json.loads((root / "benchmark.json").read_text())
    rows = []
    for mode in ("exact", "estimated_normals_albedo", "all_estimated"):
        jobs = out / f"jobs_{mode}.yaml"
        jobs.write_text(yaml.safe_dump(variant(manifest, bench, mode, root)))
        res = out / mode
        r = zcomp("composite", str(jobs), "--out", str(res), "--renderer", args.renderer, "--overwrite")
        if r.returncode not in (0, 1):
            print(r.stdout, r.stderr, file=sys.stderr)
            return r.returncode
        r = zcomp("eval", "--metrics", args.metrics, str(res))
        if r.returncode not in (0, 1):
            print(r.stdout, r.stderr, file=sys.stderr)
            return r.returncode
        means = read_means(res / "eval.json")
        rows.append({"maps": mode, **{c: means.get(c) for c in COLUMNS}, "median_s_per_job": median_job_seconds(res)})
    header = ["maps", *COLUMNS, "median_s_per_job"]
    fmt = lambda v: "n/a" if v is None else (f"{v:.4f}" if isinstance(v, float) else str(v))  # noqa: E731
    table = "\n".join(["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
                      + ["| " + " | ".join(fmt(r[h]) for h in header) + " |" for r in rows])
    print(f"\n{args.renderer} renderer on {root}\n{table}")
    (out / "table.md").write_text(table + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
