"""What estimating the background's maps costs: in quality (issue 6's figure) and in time
and memory (issue 29).

    python benchmarks/estimated_maps_benchmark.py BENCH_DIR --out OUT [--renderer physical]
    python benchmarks/estimated_maps_benchmark.py --cost [--out OUT] [--full-size] [--only NAMES]

Quality: runs ``zcomp composite`` + ``zcomp eval`` on a benchmark made by ``zcomp
make-benchmark`` three times: with the exact maps the generator rendered, with normals
and albedo estimated (normals from the exact depth, Retinex albedo), and with everything
estimated (ground-plane depth proxy from the scene's true camera height and pitch,
normals from it, Retinex albedo). Prints a table in the paper's column order.

Cost (``--cost``): each estimator once cold (the model loaded from disk, then run) and
``--repeats`` times warm (loaded), each in its own process, on scikit-image's coffee
photograph (600 x 400) at the estimator's default processing resolution (Marigold's
``default_processing_resolution``, 768, and ``default_denoising_steps``, 4, ensemble 1;
the transformers DPT's processor size). The learned models are random pipelines saved
to disk and read back as real weights are: tiny by default (what that measures is the
pipelines' own work at that resolution: resizing, VAE-sized tensors of a tiny VAE,
conversions, not the networks' FLOPs), or with ``--full-size`` Stable Diffusion 2's
UNet and VAE at their real size (the published models' compute; random weights).
Peak memory is the process's peak resident set (the kernel's high-water mark, reset after
the imports) above what it held after importing the libraries, over the cold run (the
load included) and the warm ones; with ``--device cuda`` also torch's peak GPU allocation.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

sys.path.insert(0, str(Path(__file__).parent))
from run_benchmark import COLUMNS, median_job_seconds, read_means, zcomp  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
ESTIMATORS = ("ground_plane", "normals_from_depth", "retinex", "agreement", "shift_fit",
              "dpt", "marigold-depth-v1-1", "marigold-normals-v1-1", "marigold-iid-appearance-v1-1",
              "marigold-iid-lighting-v1-1")
LEARNED = {"dpt": "depth", "marigold-depth-v1-1": "depth", "marigold-normals-v1-1": "normals",
           "marigold-iid-appearance-v1-1": "albedo", "marigold-iid-lighting-v1-1": "albedo"}


def _rss_mib() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def _reset_peak() -> None:
    """Reset the kernel's resident-set high-water mark (Linux >= 4.0), so that the peak
    read afterwards is the estimator's, not the imports'."""
    with open("/proc/self/clear_refs", "w") as f:
        f.write("5")


def _peak_mib() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024  # kB
    raise RuntimeError("no VmHWM in /proc/self/status")


def build_models(folder: Path, names, full_size: bool) -> dict:
    """Random pipelines (tests/marigold_dummy.py) and a tiny transformers DPT, saved."""
    sys.path.insert(0, str(ROOT / "tests"))
    from marigold_dummy import save_pipeline

    out = {}
    for name in names:
        d = folder / name
        if name == "dpt":
            import torch
            from transformers import DPTConfig, DPTForDepthEstimation, DPTImageProcessor

            torch.manual_seed(0)
            cfg = DPTConfig(hidden_size=16, num_hidden_layers=4, num_attention_heads=2, intermediate_size=32,
                            image_size=384, patch_size=16, backbone_out_indices=[0, 1, 2, 3],
                            neck_hidden_sizes=[8, 8, 8, 8], fusion_hidden_size=8,
                            reassemble_factors=[4, 2, 1, 0.5])
            DPTForDepthEstimation(cfg).save_pretrained(d)
            DPTImageProcessor().save_pretrained(d)  # its default: 384 x 384
        elif name in LEARNED:
            save_pipeline(d, name, full_size=full_size)
        else:
            continue
        out[name] = str(d)
    return out


def cost_one(name: str, model: str | None, repeats: int, device: str) -> dict:
    """Run one estimator cold then warm in this process; a JSON-able record."""
    import numpy as np
    from skimage import data as skdata

    from zcomp_cli.camera import Camera
    from zcomp_cli.conventions import srgb_to_linear
    from zcomp_cli.estimators.cache import EstimateCache
    from zcomp_cli.estimators.consistency import agreement, fit_shift_to_normals
    from zcomp_cli.estimators.ground_plane import GroundPlaneSpec, ground_plane_depth
    from zcomp_cli.estimators.normals_from_depth import normals_from_depth

    import torch  # noqa: F401  (counted in the baseline, as every learned estimator needs it)
    if model is not None:
        import diffusers  # noqa: F401
        import transformers  # noqa: F401

    img = srgb_to_linear(skdata.coffee().astype(np.float32) / 255.0)
    h, w = img.shape[:2]
    cam = Camera.from_fov(50, w, h)
    depth, normals = ground_plane_depth(cam, GroundPlaneSpec(0.6, pitch_deg=-35))
    settings = {} if device == "auto" else {"device": device}
    cache = EstimateCache(None)

    def run():
        if name == "ground_plane":
            return ground_plane_depth(cam, GroundPlaneSpec(0.6, pitch_deg=-35))
        if name == "normals_from_depth":
            return normals_from_depth(depth, cam)
        if name == "retinex":
            from zcomp_cli.estimators.albedo import retinex_albedo

            return retinex_albedo(img)
        if name == "agreement":
            return agreement(depth, normals, cam)
        if name == "shift_fit":
            return fit_shift_to_normals(1.0 / depth, "disparity", normals, cam)
        from zcomp_cli.estimators import learned_maps

        spec = {"model": model, **({} if name == "dpt" else settings)}
        fn = {"depth": learned_maps.learned_depth_raw, "normals": learned_maps.learned_normals,
              "albedo": learned_maps.learned_albedo}[LEARNED[name]]
        return fn(img, spec, cache=cache, img_key="bench")

    gpu = device != "cpu" and torch.cuda.is_available()
    base = _rss_mib()
    _reset_peak()
    t = time.perf_counter()
    res = run()
    cold = time.perf_counter() - t
    warm = []
    for _ in range(repeats):
        t = time.perf_counter()
        run()
        warm.append(time.perf_counter() - t)
    rec = {"estimator": name, "image": f"{w}x{h}", "cold_s": round(cold, 3),
           "warm_s": round(float(np.median(warm)), 3) if warm else None,
           "peak_rss_mib_above_imports": round(_peak_mib() - base, 1), "baseline_rss_mib": round(base, 1)}
    run_info = getattr(res, "run", None)
    if isinstance(run_info, dict):
        rec.update({k: run_info[k] for k in ("device", "dtype", "steps", "processing_resolution") if k in run_info})
    if gpu:
        rec["peak_gpu_mib"] = round(torch.cuda.max_memory_allocated() / 2**20, 1)
    return rec


def cost(args) -> int:
    names = [n for n in (args.only.split(",") if args.only else ESTIMATORS)]
    unknown = set(names) - set(ESTIMATORS)
    if unknown:
        print(f"unknown estimators {sorted(unknown)}; known: {', '.join(ESTIMATORS)}", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory() as tmp:
        models = build_models(Path(tmp), names, args.full_size)
        rows = []
        for name in names:
            cmd = [sys.executable, __file__, "--cost-one", name, "--repeats", str(args.repeats),
                   "--device", args.device]
            if name in models:
                cmd += ["--model", models[name]]
            r = subprocess.run(cmd, capture_output=True, text=True, env={**os.environ, "HF_HUB_OFFLINE": "1"})
            if r.returncode != 0:
                print(r.stdout, r.stderr, file=sys.stderr)
                return r.returncode
            rows.append(json.loads(r.stdout.strip().splitlines()[-1]))
            print(f"{name}: {rows[-1]}", file=sys.stderr)
    import torch

    size = "full-size (SD 2 UNet + VAE, random)" if args.full_size else "tiny random"
    hdr = ["estimator", "device", "dtype", "res", "steps", "cold s", "warm s", "peak RSS MiB"]
    gpu = any("peak_gpu_mib" in r for r in rows)
    if gpu:
        hdr.append("peak GPU MiB")
    lines = ["| " + " | ".join(hdr) + " |", "|" + "---|" * len(hdr)]
    for r in rows:
        cells = [r["estimator"], r.get("device", "cpu"), r.get("dtype", "fp32"), str(r.get("processing_resolution", "-")),
                 str(r.get("steps", "-")), f"{r['cold_s']:.2f}", f"{r['warm_s']:.2f}" if r["warm_s"] is not None else "-",
                 f"{r['peak_rss_mib_above_imports']:.0f}"]
        if gpu:
            cells.append(f"{r.get('peak_gpu_mib', 0):.0f}")
        lines.append("| " + " | ".join(cells) + " |")
    table = "\n".join(lines)
    head = (f"estimator cost on {rows[0]['image'] if rows else '?'} (scikit-image coffee), {size} weights, "
            f"torch {torch.__version__}, {os.cpu_count()} CPUs"
            f"{', GPU ' + torch.cuda.get_device_name() if torch.cuda.is_available() else ', no GPU'}")
    print(f"\n{head}\n{table}")
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        (out / "cost.md").write_text(head + "\n\n" + table + "\n")
        (out / "cost.json").write_text(json.dumps({"head": head, "rows": rows}, indent=1))
    return 0


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
    ap.add_argument("bench", nargs="?", help="a make-benchmark folder (the quality table)")
    ap.add_argument("--out")
    ap.add_argument("--renderer", default="physical")
    ap.add_argument("--metrics", default="all")
    ap.add_argument("--cost", action="store_true", help="time and peak memory of each estimator")
    ap.add_argument("--full-size", action="store_true", help="--cost with SD 2-sized random pipelines")
    ap.add_argument("--only", help="--cost: comma-separated estimators (default: all)")
    ap.add_argument("--repeats", type=int, default=2, help="--cost: warm runs after the cold one")
    ap.add_argument("--device", default="cpu", help="--cost: cpu, cuda or auto")
    ap.add_argument("--cost-one", help=argparse.SUPPRESS)
    ap.add_argument("--model", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.cost_one:
        print(json.dumps(cost_one(args.cost_one, args.model, args.repeats, args.device)))
        return 0
    if args.cost:
        return cost(args)
    if not args.bench or not args.out:
        ap.error("give BENCH_DIR and --out (the quality table), or --cost")
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
