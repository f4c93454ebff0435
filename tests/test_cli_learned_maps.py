"""The manifest keys ``depth/normals/albedo: {model: DIR}`` end to end: tiny random Marigold
pipelines saved on disk, read through ``zcomp composite`` and ``zcomp estimate``; errors
for a missing folder, a bad key and a missing weights file."""

import json
import shutil

import numpy as np
from click.testing import CliRunner

from zcomp_cli.cli import cli

MANIFEST = """version: 1
defaults: {{renderer: {renderer}}}
scenes:
  table:
    image: photo.png
    fov_deg: 50
    depth: {depth}
    normals: {{model: {normals}, steps: 1, processing_resolution: 32}}
    albedo: {{model: {albedo}, steps: 1, processing_resolution: 32, seed: 3}}
objects:
  card: {{image: obj.png, mask: mask.png}}
jobs:
  - {{scene: table, object: card, placement: {{pixel: [70, 100], height: 0.12}}}}
"""
GROUND = "{proxy: ground_plane, camera_height: 0.6, pitch_deg: -30}"


def _write(folder, dirs, *, renderer="physical", depth=GROUND, normals=None, albedo=None):
    from PIL import Image
    from skimage import data as skdata

    Image.fromarray(skdata.coffee()).resize((160, 120)).save(folder / "photo.png")
    m = np.zeros((60, 30), np.uint8)
    m[4:56, 4:26] = 255
    Image.fromarray(m).save(folder / "mask.png")
    Image.fromarray(np.full((60, 30, 3), 200, np.uint8)).save(folder / "obj.png")
    text = MANIFEST.format(renderer=renderer, depth=depth,
                           normals=normals or dirs["marigold-normals-v1-1"],
                           albedo=albedo or dirs["marigold-iid-appearance-v1-1"])
    (folder / "jobs.yaml").write_text(text)
    return folder / "jobs.yaml"


def _invoke(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def test_composite_with_learned_normals_albedo_and_depth(tmp_path, marigold_dirs):
    depth = ("{model: %s, camera_height: 0.6, pitch_deg: -30, steps: 1, processing_resolution: 32}"
             % marigold_dirs["marigold-depth-v1-1"])
    jobs = _write(tmp_path, marigold_dirs, depth=depth)
    r = _invoke("composite", jobs, "--out", tmp_path / "out", "--cache-dir", tmp_path / "cache")
    assert r.exit_code == 0, r.output
    job = next(p for p in (tmp_path / "out").glob("*/") if (p / "report.json").is_file())
    rep = json.loads((job / "report.json").read_text())
    src = rep["scene"]["sources"]
    for m in ("depth", "normals", "albedo", "roughness", "metallic"):
        assert src[m].startswith("learned:"), (m, src)
    assert "normals vs depth: median" in src["notes"]
    from zcomp_cli.imageio import read_image

    out = read_image(job / "composite.exr")
    assert np.isfinite(out).all() and out.shape == (120, 160, 3)
    # The estimates are cached: a second run (another output) runs no model.
    cached = list((tmp_path / "cache" / "estimates").iterdir())
    assert any(p.name.startswith("normals-") for p in cached) and any(p.name.startswith("intrinsics_") for p in cached)


def test_estimate_writes_every_map_and_its_preview(tmp_path, marigold_dirs):
    jobs = _write(tmp_path, marigold_dirs, renderer="naive")
    r = _invoke("estimate", jobs, "--out", tmp_path / "est", "--cache-dir", tmp_path / "cache", "--native")
    assert r.exit_code == 0, r.output
    d = tmp_path / "est" / "table"
    from zcomp_cli.imageio import read_map

    for name, ch in (("depth", 1), ("normals", 3), ("albedo", 3), ("shading", 3), ("roughness", 1),
                     ("metallic", 1), ("agreement", 1)):
        a = read_map(d / f"{name}.exr", channels=ch)
        assert a.shape[:2] == (120, 160) and np.isfinite(a).all(), name
    agree = read_map(d / "agreement.exr", channels=1)
    assert ((agree == -1) | ((agree >= 0) & (agree <= 180))).all()  # degrees; -1 = not compared
    from PIL import Image

    prev = np.asarray(Image.open(d / "preview.png"))
    assert prev.shape == (120, 8 * 160, 3)  # image, depth, normals, albedo, shading, rough, metal, agreement
    info = json.loads((d / "sources.json").read_text())
    assert info["fits"]["agreement"]["pixels"] > 0
    assert info["fits"]["normals_model"]["runner"] == "MarigoldNormalsPipeline"
    assert info["fits"]["albedo_model"]["seed"] == 3


def test_manifest_errors_name_the_field_before_anything_runs(tmp_path, marigold_dirs):
    jobs = _write(tmp_path, marigold_dirs, normals=tmp_path / "nowhere")
    text = jobs.read_text().replace("seed: 3", "seed: 3, ensemble_size: 0, colour: red")
    jobs.write_text(text)
    r = _invoke("composite", jobs, "--out", tmp_path / "out")
    assert r.exit_code == 2, r.output
    assert "scenes.table.normals.model: model folder not found" in r.output
    assert "jobs.yaml:8" in r.output  # the line of the normals mapping
    assert "scenes.table.albedo.ensemble_size" in r.output and "scenes.table.albedo.colour: unknown key" in r.output
    assert not (tmp_path / "out").exists()


def test_missing_weights_file_is_named_before_anything_runs(tmp_path, marigold_dirs):
    broken = tmp_path / "normals"
    shutil.copytree(marigold_dirs["marigold-normals-v1-1"], broken)
    (broken / "vae" / "diffusion_pytorch_model.safetensors").unlink()
    (broken / "tokenizer" / "tokenizer.json").unlink()
    jobs = _write(tmp_path, marigold_dirs, renderer="naive", normals=broken)
    r = _invoke("composite", jobs, "--out", tmp_path / "out", "--cache-dir", tmp_path / "cache")
    assert r.exit_code == 2, r.output
    flat = " ".join(r.output.split())
    assert "scenes.table.normals.model" in flat
    assert str(broken / "vae" / "diffusion_pytorch_model.safetensors") in flat
    assert str(broken / "tokenizer" / "tokenizer.json") in flat
    assert not (tmp_path / "out").exists()
