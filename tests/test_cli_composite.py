"""`zcomp composite` end to end on the shipped example (Blender renders the objects)."""

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from zcomp_cli.cli import cli
from zcomp_cli.imageio import read_image

pytestmark = [pytest.mark.blender]


def _run(*args):
    return CliRunner().invoke(cli, list(args), catch_exceptions=False)


def test_naive_batch_outputs_resume_overwrite(tmp_path, small_example):
    manifest = small_example(tmp_path, jobs=[0, 2])
    out = tmp_path / "out"
    r = _run("composite", str(manifest), "--out", str(out), "--renderer", "naive", "--debug")
    assert r.exit_code == 0, r.output
    jobs = sorted(p.name for p in out.iterdir() if (p / "report.json").is_file())
    assert len(jobs) == 2
    for name in jobs:
        d = out / name
        for f in ("composite.png", "composite.exr", "report.json", "grid.png", "debug/f_bg.exr"):
            assert (d / f).is_file(), f
        rep = json.loads((d / "report.json").read_text())
        assert rep["status"] == "done" and rep["renderer"]["settings"]["name"] == "naive"
        assert set(rep["timings"]) >= {"align_s", "shading_mask_s", "render_s", "compositor_s"}
        img = read_image(d / "composite.exr")
        assert img.shape == (192, 256, 3) and np.all(np.isfinite(img))
    assert not list(out.rglob("*.tmp*")), "temporary files left behind"
    summary = json.loads((out / "summary.json").read_text())
    assert summary["done"] == 2 and summary["failed"] == 0

    # Existing outputs are never replaced silently.
    r = _run("composite", str(manifest), "--out", str(out), "--renderer", "naive")
    assert r.exit_code == 2 and "--resume" in r.output
    # --resume skips both.
    r = _run("composite", str(manifest), "--out", str(out), "--renderer", "naive", "--resume")
    assert r.exit_code == 0 and "2 skipped" in r.output
    # --overwrite redoes them.
    r = _run("composite", str(manifest), "--out", str(out), "--renderer", "naive", "--overwrite", "--jobs", "1")
    assert r.exit_code == 0 and "1 done" in r.output


def test_failed_job_does_not_stop_batch(tmp_path, small_example):
    manifest = small_example(tmp_path, jobs=[0, 1])
    m = yaml.safe_load(manifest.read_text())
    bad = tmp_path / "broken.glb"
    bad.write_bytes(b"this is not a glb file")
    m["objects"]["broken"] = {"mesh": str(bad)}
    m["jobs"].insert(1, {"scene": "room", "object": "broken", "pose": {"position": [0, -0.5, -3]}})
    # an object fully outside the frame
    m["jobs"].append({"scene": "room", "object": "vase", "pose": {"position": [40, 0, -3]}, "output": "outside"})
    manifest.write_text(yaml.safe_dump(m))
    out = tmp_path / "out"
    r = _run("composite", str(manifest), "--out", str(out), "--renderer", "naive")
    assert r.exit_code == 1, r.output
    summary = json.loads((out / "summary.json").read_text())
    st = {j["name"]: j for j in summary["jobs"]}
    assert summary["done"] == 2 and summary["failed"] == 2
    assert "broken" in st["001_room_broken"]["reason"]
    assert st["outside"]["status"] == "failed" and "outside" in st["outside"]["reason"].lower()
    assert not (out / "001_room_broken" / "report.json").exists()


def test_usage_errors(tmp_path, small_example):
    manifest = small_example(tmp_path, jobs=[0])
    r = _run("composite", str(manifest), "--out", str(tmp_path / "o"), "--jobs", "7")
    assert r.exit_code == 2 and "out of range" in r.output
    r = _run("composite", str(manifest), "--out", str(tmp_path / "o"), "--resume", "--overwrite")
    assert r.exit_code == 2
    r = _run("composite", str(manifest), "--out", str(tmp_path / "o"), "--weights", str(tmp_path))
    assert r.exit_code == 2 and "zerocomp" in r.output


@pytest.mark.slow
def test_physical_example_casts_shadow_far_pixels_unchanged(tmp_path, small_example):
    """The shipped example with the default renderer at low resolution."""
    from scipy.ndimage import binary_dilation

    from zcomp_cli.imageio import read_map

    manifest = small_example(tmp_path, jobs=[0])
    out = tmp_path / "out"
    r = _run("composite", str(manifest), "--out", str(out), "--debug")
    assert r.exit_code == 0, r.output
    job = next(p for p in out.iterdir() if (p / "report.json").is_file())
    img = read_image(job / "composite.exr")
    rep = json.loads((job / "report.json").read_text())
    from zcomp_cli.pipeline.manifest import load_manifest
    from zcomp_cli.pipeline.scene import load_scene

    m_ = load_manifest(manifest)
    bg = load_scene(m_.scenes["room"], m_.defaults.resolution).image
    m = read_map(job / "debug" / "object_mask.exr") > 0
    lum = lambda x: x @ np.array([0.299, 0.587, 0.114])  # noqa: E731
    ratio = lum(img) / np.maximum(lum(bg), 1e-6)
    near = binary_dilation(m, iterations=12) & ~m
    assert (ratio[near] < 0.85).sum() >= 10, "no cast shadow beside the object"
    info = rep["renderer"]["info"]
    # the object casts its shadow, as the report says, from a sun or lamp the fit placed;
    # the report says how well the photograph fixes its direction, and where it does not
    # (the example's sunlit vase: one vague shadow), the note says it is drawn as the
    # posterior's likeliest lights, which the report lists, each at the light's own size
    assert info["shadow"] == "cast shadow" and info["light"]["lights"][0]["kind"] in ("sun", "lamp")
    fit = info["light"]["fit"]
    assert 0.0 < fit["direction_uncertainty_deg"] < 180.0 and fit["shadow_blocks"] >= 0.0
    assert bool(info["light"]["fallback"]) == fit["unfixed"]
    direct = [x for x in info["light"]["lights"] if x["kind"] in ("sun", "lamp")]
    assert len(fit["modes"]) == len(direct) and (len(fit["modes"]) > 1) == fit["unfixed"]
    if fit["unfixed"]:
        assert "likeliest lights" in fit["note"]
        radii = {x["angular_radius_deg"] for x in direct if x["kind"] == "sun"}
        assert len(radii) <= 1, radii  # one light's size, whatever its direction's doubt
    x0, y0, x1, y1 = rep["roi"]["box"]
    far = np.ones(m.shape, bool)
    far[y0:y1, x0:x1] = False
    assert np.array_equal(img[far], bg[far])
    # the object is reshaded: its two halves facing toward / away from the light differ
    light = np.asarray(rep["renderer"]["info"]["light"]["direction"])
    normals = read_map(job / "debug" / "comp_normals.exr", channels=3)
    facing = (normals @ light) > 0.3
    away = (normals @ light) < -0.1
    shade = read_map(job / "debug" / "f_comp.exr", channels=3)
    alb = read_map(job / "debug" / "comp_albedo.exr", channels=3)
    s_lum = lum(shade) / np.maximum(lum(alb), 1e-4)
    assert (m & facing).sum() > 5 and (m & away).sum() > 5
    assert np.median(s_lum[m & facing]) > 1.2 * np.median(s_lum[m & away])


def test_a_cached_object_render_shadows_with_this_manifests_mesh(tmp_path, small_example):
    """The object's render is cached by its mesh's content; the cached bundle names the
    file it was first rendered from. A second manifest of the same mesh elsewhere, the
    first file gone, still casts the object's shadow from its mesh (it fell back to the
    bundle's maps, extruded: other shadows, up to 65 of 255 apart in the demo)."""
    import shutil

    reports = []
    for name in ("first", "second"):
        d = tmp_path / name
        d.mkdir()
        manifest = small_example(d, jobs=[0])
        m = yaml.safe_load(manifest.read_text())
        for o in m["objects"].values():
            copy = d / Path(o["mesh"]).name
            shutil.copy2(o["mesh"], copy)
            o["mesh"] = str(copy)
        manifest.write_text(yaml.safe_dump(m))
        r = _run("composite", str(manifest), "--out", str(d / "out"), "--renderer", "naive")
        assert r.exit_code == 0, r.output
        reports += [json.loads(p.read_text()) for p in (d / "out").glob("*/report.json")]
        for o in m["objects"].values():
            Path(o["mesh"]).unlink()  # the first checkout's file, gone
    assert len(reports) == 2
    assert [r["occluder"] for r in reports] == ["mesh", "mesh"]
