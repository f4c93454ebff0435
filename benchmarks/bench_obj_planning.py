"""1000 jobs on one large OBJ (issue 39, defect 10): planning in seconds, not minutes.

    .venv/bin/python benchmarks/bench_obj_planning.py [--jobs 1000] [--subdivisions 8] [--keep DIR]

Writes a large OBJ (a trimesh icosphere: subdivisions 8 is 655k vertices, 1.3M faces,
about 50 MB) with an MTL beside it, and a manifest of N jobs placing it in the shipped
example's room. Times, in this process:

* validating the manifest (``load_manifest``: the mesh checked once per object);
* every job's input fingerprint (what ``composite --resume`` and ``zcomp status
  --manifest`` plan with): the OBJ's side files and content hash were found by reading
  the whole OBJ again for every job;
* posing the object's mesh for 20 jobs (``load_posed_mesh``, what each job's shadow
  uses): the OBJ was parsed again for every job.

Prints the figures; no assertion (timings depend on the machine).
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--jobs", type=int, default=1000)
    ap.add_argument("--subdivisions", type=int, default=8)
    ap.add_argument("--keep", type=Path, default=None)
    args = ap.parse_args(argv)

    import numpy as np
    import trimesh
    import yaml

    from zcomp_cli.pipeline.fingerprint import job_fingerprint
    from zcomp_cli.pipeline.manifest import load_manifest
    from zcomp_cli.pipeline.outguard import DigestCache
    from zcomp_cli.posed_mesh import load_posed_mesh

    root = args.keep or Path(tempfile.mkdtemp(prefix="zcomp-bench-obj-"))
    root.mkdir(parents=True, exist_ok=True)
    try:
        obj = root / "big.obj"
        if not obj.exists():
            t = time.perf_counter()
            m = trimesh.creation.icosphere(subdivisions=args.subdivisions, radius=0.5)
            lines = ["mtllib big.mtl", "usemtl grey"]
            lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in m.vertices]
            lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in m.faces]
            obj.write_text("\n".join(lines) + "\n")
            (root / "big.mtl").write_text("newmtl grey\nKd 0.5 0.5 0.5\n")
            print(f"wrote {obj.name}: {len(m.vertices)} vertices, {len(m.faces)} faces, "
                  f"{obj.stat().st_size / 2**20:.0f} MB in {time.perf_counter() - t:.1f} s")
        ex = yaml.safe_load((ROOT / "examples" / "jobs.yaml").read_text())
        room = ex["scenes"]["room"]
        scene = {k: str(ROOT / "examples" / room[k]) for k in ("image", "depth", "normals", "albedo")}
        scene["fov_deg"] = room["fov_deg"]
        jobs = [{"scene": "room", "object": "big",
                 "pose": {"position": [-0.5 + 0.001 * i, -0.3, -3.0], "rotation_deg": [0, i % 360, 0],
                          "height": 0.4}} for i in range(args.jobs)]
        manifest = root / "jobs.yaml"
        manifest.write_text(yaml.safe_dump({"version": 1, "defaults": {"renderer": "physical"},
                                            "scenes": {"room": scene}, "objects": {"big": {"mesh": str(obj)}},
                                            "jobs": jobs}))
        t = time.perf_counter()
        man = load_manifest(manifest)
        t_load = time.perf_counter() - t
        digests = DigestCache(None)
        from zcomp_cli.pipeline.manifest import RendererSpec

        t = time.perf_counter()
        fps = {job_fingerprint(man, j, RendererSpec("physical"), 16, digests) for j in man.jobs}
        t_fp = time.perf_counter() - t
        meta = {"mesh": str(obj), "object_to_camera": np.eye(4).tolist()}
        t = time.perf_counter()
        first = load_posed_mesh(meta)
        t_first = time.perf_counter() - t
        t = time.perf_counter()
        for _ in range(20):
            load_posed_mesh(meta)
        t_more = (time.perf_counter() - t) / 20
        print(f"{args.jobs} jobs on one {obj.stat().st_size / 2**20:.0f} MB OBJ ({len(first.faces)} faces):")
        print(f"  validate the manifest:       {t_load:6.2f} s")
        print(f"  every job's fingerprint:     {t_fp:6.2f} s ({1000 * t_fp / args.jobs:.1f} ms a job; "
              f"{len(fps)} distinct)")
        print(f"  pose the mesh, first job:    {t_first:6.2f} s; each later job {t_more:.3f} s")
    finally:
        if args.keep is None:
            shutil.rmtree(root, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
