"""A real output folder for the `zcomp report` tests: `zcomp composite` (physical
renderer, mesh-free floor scenes of zcomp_cli.testing, so no Blender) on a few jobs,
one of which fails at run time (an object bundle with a damaged depth map), then
`zcomp eval` on it, and preview sheets where `zcomp preview-light` writes them."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import yaml
from click.testing import CliRunner

from zcomp_cli.cli import cli
from zcomp_cli.testing import floor_scene, sphere_object_bundle, write_floor_batch

# A job name and a failure reason made to break a page that pastes text into HTML.
HOSTILE_NAME = "</script><script>window.__pwned=1</script><!--"
HOSTILE_REASON = "<img src=x onerror=\"window.__pwned=2\"> & 'quotes' \"too\" </td></tr></table>"


def make_output(root: Path, *, n_jobs: int = 5, size=(160, 120)) -> tuple[Path, Path]:
    """Write a project under ``root/project`` and composite it into ``root/out``;
    return (manifest, out). ``job_ball`` fails; the others are done and scored by
    ``zcomp eval --metrics psnr,mae`` (their reference is the scene's photograph)."""
    proj, out = Path(root) / "project", Path(root) / "out"
    manifest = write_floor_batch(proj, n_jobs, n_scenes=3, size=size)
    doc = yaml.safe_load(manifest.read_text())
    for j in doc["jobs"]:
        j["reference"] = doc["scenes"][j["scene"]]["image"]
    sc = floor_scene(*size, with_box=False)
    ball = sphere_object_bundle(sc.camera, center=sc.world_to_camera([0.0, 0.3, -3.0]), radius=0.3,
                                floor_normal=sc.up_cam, supersample=2)
    ball.save(proj / "ball")
    (proj / "ball" / "depth.exr").write_bytes(b"broken")  # read at run time: the job fails
    doc["objects"]["ball"] = {"bundle": "ball"}
    doc["jobs"].insert(1, {"output": "job_ball", "scene": "s0", "object": "ball",
                           "pose": {"position": [0.0, -1.2, -3.0]}})
    manifest.write_text(yaml.safe_dump(doc, sort_keys=False))
    runner = CliRunner()
    r = runner.invoke(cli, ["-q", "composite", str(manifest), "--out", str(out)])
    assert r.exit_code == 1 and "job_ball" in r.output, r.output  # one job failed, the others done
    r = runner.invoke(cli, ["-q", "eval", "--metrics", "psnr,mae", str(out)])
    assert r.exit_code == 0, r.output
    return manifest, out


def add_previews(out: Path, manifest: Path) -> list[str]:
    """``OUT/preview/<scene>.png`` and ``.json``, as `zcomp preview-light` writes them (the
    scene's photograph stands in for the sheet; the light is the one its jobs used)."""
    doc = yaml.safe_load(Path(manifest).read_text())
    (out / "preview").mkdir(exist_ok=True)
    lights = {}
    for rep in sorted(out.glob("*/report.json")):
        r = json.loads(rep.read_text())
        lights.setdefault(r["job"]["scene"], r["renderer"]["info"]["light"])
    for name, s in doc["scenes"].items():
        shutil.copy(Path(manifest).parent / s["image"], out / "preview" / f"{name}.png")
        (out / "preview" / f"{name}.json").write_text(json.dumps({"scene": name, "light": lights.get(name)}))
    return sorted(doc["scenes"])


def add_hostile_failure(out: Path) -> None:
    """A failed job named ``HOSTILE_NAME`` failing with ``HOSTILE_REASON``, in the
    summary (as a run that failed it before making its folder leaves it)."""
    p = out / "summary.json"
    doc = json.loads(p.read_text())
    doc["jobs"].append({"index": len(doc["jobs"]), "name": HOSTILE_NAME, "status": "failed",
                        "reason": HOSTILE_REASON, "seconds": 0.5, "this_run": "failed"})
    p.write_text(json.dumps(doc, indent=2))


# Text that becomes an event handler wherever it lands inside a tag (issue 50, defect 1).
HANDLER = " onload=window.__pwned=3 onerror=window.__pwned=4 "
SLOTS = ("%DATA%", "%JS%", "%CSS%", "%HEAD%", "%TITLE%", "%PREVIEWS%", "%NONCE%")


def make_slot_named_output(root: Path) -> Path:
    """An output folder whose names and texts aim at the page's template: preview
    sheets named after its slots (``%DATA%.png``...), failed jobs whose name, scene,
    renderer and failure reason hold ``HANDLER`` (a mesh named ``a onload=... b.obj``
    gives such a reason), and an eval.json whose metric name holds it too."""
    from zcomp_cli.report.synthetic import tiny_png

    out = Path(root) / "out"
    (out / "preview").mkdir(parents=True)
    for k, slot in enumerate(SLOTS):
        (out / "preview" / f"{slot}.png").write_bytes(tiny_png((40 * k % 255, 90, 200)))
        (out / "preview" / f"{slot}.json").write_text(json.dumps({"scene": slot}))
    jobs = [{"index": i, "name": name, "status": "failed", "seconds": 0.1, "this_run": "failed",
             "reason": f"cannot read the mesh 'a{HANDLER}b.obj': {slot}\"'<>"}
            for i, (name, slot) in enumerate([(f"job{HANDLER}", "%DATA%"), ('q"uote' + HANDLER, "%JS%"),
                                              ("plain", "%TITLE%")])]
    (out / "summary.json").write_text(json.dumps({"jobs": jobs}))
    ev = {"metrics": [f"psnr{HANDLER}"], "images": [{"name": "plain", f"psnr{HANDLER}": 3.0}],
          "mean": {f"psnr{HANDLER}": 3.0}}
    (out / "eval.json").write_text(json.dumps(ev))
    return out
