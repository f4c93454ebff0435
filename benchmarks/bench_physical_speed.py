"""Speed of the embedded physical renderer (targets on 2 cores):

* per-scene light estimate <= 0.5 s at 512x384 (issue 28);
* per-job shading synthesis (background + composite pass) <= 0.3 s at 512x512.

    PYTHONPATH=src python benchmarks/bench_physical_speed.py [--repeats 3]

Analytic scenes (zcomp_cli.testing, the sky hidden by what stands in it): a floor, a box
casting a shadow (under a sun, and under a lamp near the scene for a second estimate
timing), a sphere inserted with a shading mask of twice its size. Prints the median
wall time of each stage; no assertion (timings depend on the machine and its load).
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np


def _requests(W, H, lamp=None):
    from zcomp_cli.maps import SceneMaps
    from zcomp_cli.renderers.base import RenderRequest
    from zcomp_cli.testing import floor_scene, insert_bundle, sphere_object_bundle

    if lamp is None:
        s = floor_scene(W, H, with_box=True, light_dir=(0.7, 1.0, 0.2), ambient=0.3, box_center=(-0.4, -3.2),
                        sky_occlusion=True)
    else:  # a lamp near the scene, no sun (the fit's lamp candidates)
        s = floor_scene(W, H, with_box=True, light_intensity=0.0, ambient=0.3, box_center=(-0.4, -3.2),
                        lamp=lamp, sky_occlusion=True)
    c = s.world_to_camera([0.4, 0.3, -2.6])
    b = sphere_object_bundle(s.camera, c, 0.3, (0.7, 0.7, 0.7), floor_normal=s.up_cam, supersample=1)
    d, n, a, sel = insert_bundle(s.depth, s.normals, s.albedo, b)
    ys, xs = np.nonzero(sel)
    h = ys.max() - ys.min()
    mask = np.zeros(sel.shape, bool)
    mask[max(0, ys.min() - h // 2):ys.max() + h, max(0, xs.min() - h):xs.max() + h] = True
    known = ~mask
    roi = (max(0, xs.min() - h - 20), max(0, ys.min() - h // 2 - 20), xs.max() + h + 20, ys.max() + h + 20)
    bg = RenderRequest(SceneMaps(s.depth, s.normals, s.albedo), s.shading, known, s.camera, roi=roi, scene_key="s")
    comp = RenderRequest(SceneMaps(d, n, a), s.shading, known, s.camera, roi=roi, scene_key="s")
    return bg, comp, s


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)
    from zcomp_cli.renderers.physical import PhysicalRenderer

    est_t = []
    bg, comp, s = _requests(512, 384)
    for _ in range(args.repeats):
        r = PhysicalRenderer()
        t = time.perf_counter()
        e = r.light(bg)
        est_t.append(time.perf_counter() - t)
    err = np.degrees(np.arccos(np.clip(e.key_direction @ s.light_dir_cam, -1, 1)))
    lamp_t = []
    bg_l, _, s_l = _requests(512, 384, lamp=((1.0, 2.5, -4.0), 4.0))
    for _ in range(args.repeats):
        r = PhysicalRenderer()
        t = time.perf_counter()
        e_l = r.light(bg_l)
        lamp_t.append(time.perf_counter() - t)
    syn_t = []
    bg, comp, s = _requests(512, 512)
    r = PhysicalRenderer()
    r.light(bg)  # cached: only synthesis is timed below
    for _ in range(args.repeats):
        out = r.render([bg, comp])
        syn_t.append(out.timings["synthesis"])
    kinds = lambda m: ", ".join([f"sun {x.radius_deg:g} deg" for x in m.suns] + ["lamp" for _ in m.lamps]) or "none"
    print(f"light estimate, 512x384: median {statistics.median(est_t):.3f} s "
          f"(runs: {', '.join(f'{t:.3f}' for t in est_t)}); direction error {err:.1f} deg, "
          f"lights: {kinds(e)}, shadow evidence {e.fit.shadow_blocks:.2f} blocks")
    print(f"light estimate, 512x384, a lamp near the scene: median {statistics.median(lamp_t):.3f} s "
          f"(runs: {', '.join(f'{t:.3f}' for t in lamp_t)}); lights: {kinds(e_l)}")
    # the path of a bundle rendered by Blender: its posed mesh occludes (the object's
    # shadow from a shadow map, its sky occlusion from area elements, its silhouette)
    import dataclasses

    import trimesh

    from zcomp_cli.posed_mesh import PosedMesh

    sph = trimesh.creation.icosphere(subdivisions=5, radius=0.3)
    mesh = PosedMesh(np.asarray(sph.vertices) + s.world_to_camera([0.4, 0.3, -2.6]), np.asarray(sph.faces))
    # (a fresh mesh each time, as each job poses its own: what the renderer keeps on a
    # mesh between its uses in one render must not carry over to the next)
    fresh = lambda m: PosedMesh(m.vertices.copy(), m.faces.copy())  # noqa: E731
    mesh_t = []
    for _ in range(args.repeats):
        out = r.render([bg, dataclasses.replace(comp, occluder=fresh(mesh))])
        mesh_t.append(out.timings["synthesis"])
    # a dense mesh (a scan, a sculpt): its cost should grow with the pixels, not the faces
    big = trimesh.creation.icosphere(subdivisions=7, radius=0.3)
    big_m = PosedMesh(np.asarray(big.vertices) + s.world_to_camera([0.4, 0.3, -2.6]), np.asarray(big.faces))
    big_t = []
    for _ in range(args.repeats):
        out = r.render([bg, dataclasses.replace(comp, occluder=fresh(big_m))])
        big_t.append(out.timings["synthesis"])
    print(f"synthesis (bg + composite pass), 512x512, roi {bg.roi}: median {statistics.median(syn_t):.3f} s "
          f"(runs: {', '.join(f'{t:.3f}' for t in syn_t)})")
    print(f"synthesis with the posed mesh ({len(mesh.faces)} faces): median {statistics.median(mesh_t):.3f} s "
          f"(runs: {', '.join(f'{t:.3f}' for t in mesh_t)})")
    print(f"synthesis with a dense posed mesh ({len(big.faces)} faces): median {statistics.median(big_t):.3f} s "
          f"(runs: {', '.join(f'{t:.3f}' for t in big_t)})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
