"""Benchmark ``render_object_intrinsics``: seconds per object-pose in one Blender batch
(excluding Blender start-up) and the start-up cost itself.

    .venv/bin/python benchmarks/bench_render_intrinsics.py [--n 20] [--res 512] [--samples 16]

The mesh is generated (an icosphere, a torus and a base slab from trimesh primitives,
~27k triangles, random vertex colours, saved as GLB), so the benchmark needs no data. The cache is bypassed (``use_cache=False``). Start-up is the time
from process launch to bpy imported and reset, as reported by the script's ``ready``
event; per-item time is the batch wall time minus start-up, divided by the item count
(it includes the parent's EXR conversion and bundle writing, which overlap Blender).
Also printed: CPU seconds per item of Blender and of the parent (steadier than wall
time on a shared machine) and the median per-render split the script reports.

Measured (2 shared cores, 27k triangles, 512x512, 16 samples): 1.23 CPU-s per item
before the static-scene rewrite, 0.34 after; wall 1.23 -> 0.31-0.38 s/item at load ~4.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path


def make_mesh(path: Path) -> int:
    import numpy as np
    import trimesh

    parts = [
        trimesh.creation.icosphere(subdivisions=5, radius=0.5),
        trimesh.creation.torus(major_radius=0.6, minor_radius=0.15, major_sections=96, minor_sections=32),
        trimesh.creation.box(extents=(1.4, 0.1, 1.4)),
    ]
    parts[0].apply_translation((0, 0.6, 0))
    parts[1].apply_translation((0, 0.6, 0))
    parts[2].apply_translation((0, 0.05, 0))
    mesh = trimesh.util.concatenate(parts)
    rng = np.random.default_rng(0)
    mesh.visual.vertex_colors = (rng.random((len(mesh.vertices), 4)) * 255).astype(np.uint8)
    mesh.export(path)
    return len(mesh.faces)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=20, help="object-poses in the batch")
    ap.add_argument("--res", type=int, default=512, help="square resolution")
    ap.add_argument("--samples", type=int, default=16)
    ap.add_argument("--json", type=str, default=None, help="also write the figures here")
    args = ap.parse_args(argv)

    from zcomp_cli.blender.intrinsics import IntrinsicsRequest, render_object_intrinsics
    from zcomp_cli.camera import Camera
    from zcomp_cli.pose import Pose, euler_deg_to_matrix

    with tempfile.TemporaryDirectory(prefix="zcomp-bench-") as tmp:
        tmp = Path(tmp)
        faces = make_mesh(tmp / "bench.glb")
        cam = Camera.from_fov(50.0, args.res, args.res)
        reqs = []
        for i in range(args.n):
            pose = Pose(position=(0.3 * ((i % 5) - 2) / 2, -0.6, -3.0 - 0.1 * i),
                        rotation=euler_deg_to_matrix(0, 360.0 * i / args.n, 0), height=1.0)
            reqs.append(IntrinsicsRequest(f"item{i:02d}", tmp / "bench.glb", pose, cam, tmp / "out" / f"{i:02d}"))
        stats: dict = {}
        import resource

        ru0s, ru0c = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.monotonic()
        res = render_object_intrinsics(reqs, samples=args.samples, use_cache=False, stats=stats)
        wall = time.monotonic() - t0
        ru1s, ru1c = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
        # CPU seconds hold up better than wall time on a machine shared with others.
        cpu_blender = (ru1c.ru_utime + ru1c.ru_stime) - (ru0c.ru_utime + ru0c.ru_stime)
        cpu_parent = (ru1s.ru_utime + ru1s.ru_stime) - (ru0s.ru_utime + ru0s.ru_stime)
        # Where Blender's time goes, per item (the script reports it in each bundle's meta).
        parts: dict[str, list[float]] = {}
        for r in res:
            if r.ok:
                meta = json.loads((Path(r.bundle_dir) / "meta.json").read_text())
                for k, v in (meta.get("render_timings") or {}).items():
                    parts.setdefault(k, []).append(float(v))
    failed = [r for r in res if not r.ok]
    if failed:
        print(f"{len(failed)} items failed, e.g. {failed[0].id}: {failed[0].error}", file=sys.stderr)
        return 1
    startup = sum(stats.get("startup_s", [])) or float("nan")
    figures = {
        "items": args.n,
        "resolution": args.res,
        "samples": args.samples,
        "mesh_faces": faces,
        "batch_wall_s": round(wall, 3),
        "blender_startup_s": round(startup, 3),
        "seconds_per_item_excl_startup": round((wall - startup) / args.n, 3),
        "median_item_seconds_reported": round(statistics.median(r.seconds for r in res), 3),
        "cpu_s_per_item_blender": round(cpu_blender / args.n, 3),
        "cpu_s_per_item_parent": round(cpu_parent / args.n, 3),
        "blender_median_s": {k: round(statistics.median(v), 4) for k, v in parts.items()},
        "blender_first_item_s": {k: round(v[0], 4) for k, v in parts.items()},
        "load_avg_1min": round(os.getloadavg()[0], 2),
        "cpu_count": os.cpu_count(),
        "machine": platform.processor() or platform.machine(),
    }
    print(json.dumps(figures, indent=2))
    if args.json:
        Path(args.json).write_text(json.dumps(figures, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
