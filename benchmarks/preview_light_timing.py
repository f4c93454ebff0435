"""Seconds per scene of ``zcomp preview-light`` (issue 38's target: <= 5 s a scene on the
2-core machine after Blender's start), with where they go.

    python benchmarks/preview_light_timing.py [MANIFEST] [--repeat N] [--map-resolution R ...]

Runs the preview of every scene of MANIFEST (default: the shipped example) in one
process, as the command does, ``--repeat`` times (each a fresh renderer and Blender
process), and prints per scene: the seconds in all, Blender's start (the first scene
only), the light fit, the scene mesh, the two Cycles passes, the balls alone. With
several ``--map-resolution`` values (the world's importance map, ``CyclesSettings``;
0 = Cycles' automatic) it compares them.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("manifest", nargs="?", default=str(ROOT / "examples" / "jobs.yaml"))
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--map-resolution", type=int, action="append", default=None)
    args = ap.parse_args(argv)

    import zcomp_cli.preview.run as R
    from zcomp_cli.pipeline.manifest import load_manifest

    m = load_manifest(args.manifest)
    print(f"preview-light on {args.manifest}: {len(m.scenes)} scenes, {args.repeat} runs each")
    for res in args.map_resolution or [R.WORLD_MAP_RESOLUTION]:
        R.WORLD_MAP_RESOLUTION = res
        rows = {}
        for _ in range(args.repeat):
            with tempfile.TemporaryDirectory() as out:
                for r in R.preview_light(m, out, overwrite=True):
                    if r.error:
                        print(f"  scene {r.scene} failed: {r.error}")
                        continue
                    t = r.info["timings"]
                    start = r.info.get("blender_startup_s") or 0.0
                    rows.setdefault(r.scene, []).append(
                        (r.seconds - start, start, t["estimate"], t["build"], t["blender"], t["alone_s"]))
        print(f"world importance map {res or 'automatic'}: seconds per scene (median of runs)")
        print(f"  {'scene':<12} {'after start':>11} {'Blender start':>13} {'light fit':>9} {'mesh':>6} "
              f"{'2 passes':>8} {'alone':>6}")
        for scene, vals in rows.items():
            med = [statistics.median(v[k] for v in vals) for k in range(6)]
            print(f"  {scene:<12} {med[0]:>11.2f} {med[1]:>13.2f} {med[2]:>9.2f} {med[3]:>6.2f} {med[4]:>8.2f} "
                  f"{med[5]:>6.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
