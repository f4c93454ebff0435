"""``zcomp estimate`` and an end-to-end composite from a real photograph with only
``image:`` and a ground-plane line."""

import json

import numpy as np
from click.testing import CliRunner

from zcomp_cli.cli import cli


def test_estimate_writes_maps_and_preview(tmp_path, photo_manifest):
    photo_manifest(tmp_path, "naive")
    r = CliRunner().invoke(cli, ["estimate", str(tmp_path / "jobs.yaml"), "--out", str(tmp_path / "out"),
                                 "--cache-dir", str(tmp_path / "cache"), "--native"])
    assert r.exit_code == 0, r.output
    from zcomp_cli.imageio import read_map

    d = tmp_path / "out" / "table"
    depth = read_map(d / "depth.exr", channels=1)
    normals = read_map(d / "normals.exr", channels=3)
    albedo = read_map(d / "albedo.exr", channels=3)
    shading = read_map(d / "shading.exr", channels=3)
    for a in (depth, normals, albedo, shading):
        assert a.shape[:2] == (120, 160) and np.isfinite(a).all()
    assert depth.min() > 0 and depth[-1].max() < depth[0].min()  # floor nearer at the bottom
    assert 0 <= albedo.min() and albedo.max() <= 1
    src = json.loads((d / "sources.json").read_text())["sources"]
    assert src == {"depth": "ground_plane", "normals": "ground_plane", "albedo": "retinex"}
    from PIL import Image

    prev = np.asarray(Image.open(d / "preview.png"))
    assert prev.shape == (120, 5 * 160, 3)
    assert any((tmp_path / "cache" / "estimates").iterdir())


def test_estimate_writes_every_scene_of_the_manifest(tmp_path, photo_manifest):
    """Each scene of a manifest gets its maps (the second one used to crash: a loop
    variable shadowed the manifest)."""
    m = photo_manifest(tmp_path, "naive")
    m.write_text(m.read_text().replace(
        "objects:", "  table2:\n    image: photo.png\n    fov_deg: 50\n"
        "    depth: {proxy: ground_plane, camera_height: 0.6, pitch_deg: -30}\nobjects:"))
    r = CliRunner().invoke(cli, ["estimate", str(m), "--out", str(tmp_path / "out"),
                                 "--cache-dir", str(tmp_path / "cache"), "--native"])
    assert r.exit_code == 0, r.output
    for name in ("table", "table2"):
        assert (tmp_path / "out" / name / "sources.json").is_file()
        assert (tmp_path / "out" / name / "preview.png").is_file()


def test_estimate_unknown_scene_is_usage_error(tmp_path, photo_manifest):
    photo_manifest(tmp_path, "naive")
    r = CliRunner().invoke(cli, ["estimate", str(tmp_path / "jobs.yaml"), "--out", str(tmp_path / "o"),
                                 "--scenes", "nope"])
    assert r.exit_code == 2


def _composite(tmp_path, photo_manifest, renderer, *extra):
    photo_manifest(tmp_path, renderer)
    r = CliRunner().invoke(cli, ["composite", str(tmp_path / "jobs.yaml"), "--out", str(tmp_path / "out"),
                                 "--cache-dir", str(tmp_path / "cache"), *extra])
    assert r.exit_code == 0, r.output
    from zcomp_cli.imageio import read_image

    out = read_image(next((tmp_path / "out").glob("*/composite.exr")))
    bg = read_image(tmp_path / "photo.png")
    return out, bg


def test_composite_from_photo_with_image_only(tmp_path, photo_manifest):
    out, bg = _composite(tmp_path, photo_manifest, "naive")
    assert out.shape == bg.shape and np.isfinite(out).all()
    assert np.abs(out - bg).max() > 0.05  # the object is there


def test_composite_from_photo_casts_a_floor_shadow(tmp_path, photo_manifest):
    out, bg = _composite(tmp_path, photo_manifest, "physical", "--debug")
    assert np.isfinite(out).all()
    from scipy.ndimage import binary_dilation

    from zcomp_cli.imageio import read_map

    job = next(p for p in (tmp_path / "out").glob("*/") if (p / "report.json").is_file())
    m = read_map(job / "debug" / "object_mask.exr") > 0
    lum = lambda x: x @ np.array([0.299, 0.587, 0.114])  # noqa: E731
    ratio = lum(out) / np.maximum(lum(bg), 1e-4)
    # The object darkens the table around it (a cast shadow or, where the photo does not
    # fix the light's direction, a contact shadow), and the report says which.
    ring = binary_dilation(m, iterations=6) & ~m
    assert (ratio[ring] < 0.9).sum() >= 5
    far = ~binary_dilation(m, iterations=30)
    assert np.array_equal(out[far], bg[far])  # far pixels untouched
    rep = json.loads((job / "report.json").read_text())
    light = rep["renderer"]["info"]["light"]
    assert light["shadow"] in ("cast shadow", "contact shadow only")
    # a direction the photo does not fix is said, with how uncertain it is
    if light["fallback"]:
        assert "within" in light["fallback"] and light["fit"]["direction_uncertainty_deg"] > 0


def test_estimate_never_writes_into_a_folder_holding_the_scenes_maps(tmp_path, examples_dir):
    """Issue 39, defect 12: ``--out`` pointed at the folder holding a scene's maps, with
    ``--overwrite``, replaced the input maps with working-size copies. A scene folder
    holding files estimate did not write is refused (exit 2), --overwrite or not, and
    nothing in it changes."""
    import shutil

    import yaml

    proj = tmp_path / "proj"
    shutil.copytree(examples_dir / "scenes", proj / "scenes")
    m = yaml.safe_load((examples_dir / "jobs.yaml").read_text())
    m["scenes"] = {"room": m["scenes"]["room"]}
    m["objects"] = {k: {"mesh": str(examples_dir / v["mesh"])} for k, v in m["objects"].items()}
    m["jobs"] = [j for j in m["jobs"] if j["scene"] == "room"][:1]
    m["jobs"][0].pop("reference", None)
    (proj / "jobs.yaml").write_text(yaml.safe_dump(m))
    before = {p.name: p.read_bytes() for p in (proj / "scenes" / "room").iterdir() if p.is_file()}
    for extra in ([], ["--overwrite"]):
        r = CliRunner().invoke(cli, ["estimate", str(proj / "jobs.yaml"), "--out", str(proj / "scenes"), *extra])
        assert r.exit_code == 2, r.output
        assert "did not write" in r.output and "room" in r.output
    after = {p.name: p.read_bytes() for p in (proj / "scenes" / "room").iterdir() if p.is_file()}
    assert after == before
