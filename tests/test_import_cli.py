"""``zcomp import zerocomp|spotlight`` on replicas of the official archives
(tests/lvsn_replica.py), then ``zcomp composite`` (physical and naive) and ``zcomp eval``
end to end; bad and partial trees reported per case while the others go on."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

import lvsn_replica as replica
from zcomp_cli.cli import cli
from zcomp_cli.imageio import read_alpha_or_grey, read_image, read_map


def run(*args):
    return CliRunner().invoke(cli, list(map(str, args)), catch_exceptions=False)


@pytest.fixture(scope="module")
def labo(tmp_path_factory):
    """Three cases; the third's bundle lacks its normals layer; plus a case folder
    without a bundle (a partial tree)."""
    root = tmp_path_factory.mktemp("labo") / "labo"
    cases = replica.make_zerocomp_archive(root, 3, broken={2: ("normals",)})
    partial = root / "GT_emission_envmap" / "ZZpartial"
    partial.mkdir()
    (partial / "ZZpartial_bg_diffuse.png").write_bytes(b"")
    return root, cases


@pytest.fixture(scope="module")
def imported(labo, tmp_path_factory):
    root, cases = labo
    out = tmp_path_factory.mktemp("imp") / "labo" / "jobs.yaml"
    r = run("import", "zerocomp", root, "--out", out, "--maps", "provided")
    return out, r, cases


@pytest.fixture
def no_lpips(tmp_path, monkeypatch):
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "torch"))
    monkeypatch.setenv("ZCOMP_LPIPS_BACKBONE", str(tmp_path / "missing_alexnet.pth"))


def _manifest(path: Path) -> dict:
    return yaml.safe_load(path.read_text())


def test_import_reports_the_bad_cases_and_goes_on(imported):
    out, r, cases = imported
    assert r.exit_code == 1, r.output  # a case failed: the others are imported
    assert "failed 9C4A0002-crop_B02" in r.output and "missing layer normals" in r.output
    assert "failed ZZpartial" in r.output and "no *_bundle*.exr" in r.output
    assert "2 cases imported (2 jobs), 2 failed" in r.output
    rep = json.loads((out.parent / "jobs_data" / "import.json").read_text())
    assert rep["imported"] == [cases[0].name, cases[1].name]
    assert set(rep["failed"]) == {cases[2].name, "ZZpartial"}
    assert not (out.parent / "jobs_data" / cases[2].name).exists()  # nothing left of a failed case


def test_manifest_carries_the_paper_settings(imported):
    out, _, cases = imported
    m = _manifest(out)
    assert m["defaults"] == {"renderer": {"name": "zerocomp", "window": "center", "steps": 20,
                                          "dtype": "fp16-autocast"}, "seed": 469, "shading_radius": 1.0}
    assert list(m["scenes"]) == [cases[0].name, cases[1].name]
    sc = m["scenes"][cases[0].name]
    assert sc["fov_deg"] == 50.0
    for key in ("image", "depth", "normals", "albedo", "roughness"):
        assert (out.parent / sc[key]).is_file()
    job = m["jobs"][0]
    assert job["output"] == cases[0].name and m["objects"][job["object"]]["bundle"].endswith("/object")
    assert (out.parent / job["reference"]).name == "reference.exr"
    info = json.loads((out.parent / job["reference"]).with_name("case.json").read_text())
    assert info["dataset"] == "zerocomp-labo" and info["checks"]["normals_frame"] == "blender-camera"


def test_every_map_lands_in_zcomp_conventions(imported):
    out, _, cases = imported
    c = cases[0]
    d = out.parent / "jobs_data" / c.name
    sc, b = c.scene, c.bundle
    np.testing.assert_allclose(read_image(d / "background.exr"), c.background, atol=1e-6)
    np.testing.assert_allclose(read_image(d / "reference.exr"), c.composite, atol=1e-6)
    np.testing.assert_allclose(read_map(d / "depth.exr"), sc.depth, atol=1e-5)
    alb = read_map(d / "albedo.exr", channels=3)
    np.testing.assert_allclose(alb, np.round(sc.albedo * 255) / 255, atol=1e-6)  # linear, not sRGB-decoded
    n = read_map(d / "normals.exr", channels=3)
    valid = np.linalg.norm(sc.normals, axis=-1) > 0
    cosang = (n * sc.normals).sum(-1)[valid]
    assert cosang.min() > 0.999  # StableNormal's x flip undone (8-bit quantisation only)
    np.testing.assert_allclose(read_alpha_or_grey(d / "object_mask.png"), b.mask, atol=1 / 65535)
    obj = d / "object"
    m = b.mask > 0
    np.testing.assert_allclose(read_map(obj / "depth.exr")[m], b.depth[m], rtol=1e-5)  # un-premultiplied
    on = read_map(obj / "normals.exr", channels=3)
    assert ((on * b.normals).sum(-1)[b.mask > 0.01]).min() > 0.999  # z negation undone
    np.testing.assert_allclose(read_map(obj / "albedo.exr", channels=3)[b.mask > 0.01], b.albedo[b.mask > 0.01],
                               atol=1e-5)
    np.testing.assert_allclose(read_map(obj / "footprint_depth.exr"), b.footprint_depth, atol=1e-5)
    meta = json.loads((obj / "meta.json").read_text())
    assert meta["object_height_m"] == pytest.approx(0.6, abs=0.08)  # the sphere's diameter


def _paper_rows(tmp_path) -> Path:
    p = tmp_path / "rows.yaml"
    p.write_text(yaml.safe_dump({"dataset": "zerocomp-labo", "source": "a test table", "rows": [
        {"name": "Method A", "region": "full", "psnr": 31.5, "mae": 0.0123},
        {"name": "Method A", "region": "object-crop", "psnr": 21.25}]}))
    return p


@pytest.mark.parametrize("renderer", ["naive", "physical"])
def test_import_composite_eval_end_to_end(imported, tmp_path, no_lpips, renderer):
    out, _, cases = imported
    res = tmp_path / renderer
    r = run("composite", out, "--out", res, "--renderer", renderer)
    assert r.exit_code == 0, r.output
    r = run("eval", res, "--paper-rows", _paper_rows(tmp_path))
    assert r.exit_code == 0, r.output
    assert "paper protocol, gamma 2.2, full, zerocomp-labo" in r.output
    assert "paper: Method A" in r.output and "31.5" in r.output
    full = json.loads((res / "eval.json").read_text())
    assert full["metrics"] == ["psnr", "rmse", "si-rmse", "ssim", "mae", "lpips", "flip"]
    assert full["protocol"]["encoding"] == "gamma2.2" and full["protocol"]["dataset"] == "zerocomp-labo"
    assert [i["name"] for i in full["images"]] == [cases[0].name, cases[1].name]
    assert "lpips" in full["unavailable"]
    r = run("eval", res, "--region", "object-crop", "--out", tmp_path / "crop")
    assert r.exit_code == 0, r.output
    # the supplementary's object-crop table is bundled: printed beside the run's
    assert "paper: ZeroComp OpenRooms" in r.output and "24.4" in r.output and "paper: Garon et al. 2019" in r.output
    crop = json.loads((tmp_path / "crop.json").read_text())
    assert crop["protocol"]["region"] == "object-crop"
    for name in ("psnr", "mae", "si-rmse", "ssim"):
        assert np.isfinite(full["mean"][name]) and np.isfinite(crop["mean"][name])
    # outside the object and its shadow the composite is the background the ground truth
    # shares, so the whole image scores far better than the crop around the object
    assert full["mean"]["psnr"] > crop["mean"]["psnr"] + 3
    assert full["mean"]["mae"] < crop["mean"]["mae"]
    r = run("eval", res, "--protocol", "zcomp", "--metrics", "psnr", "--out", tmp_path / "srgb")
    assert r.exit_code == 0, r.output
    srgb = json.loads((tmp_path / "srgb.json").read_text())
    assert srgb["protocol"]["encoding"] == "srgb" and srgb["mean"]["psnr"] != pytest.approx(full["mean"]["psnr"])


def test_limit_and_cases(labo, tmp_path):
    root, cases = labo
    r = run("import", "zerocomp", root, "--out", tmp_path / "a.yaml", "--maps", "provided", "--limit", "1")
    assert r.exit_code == 0, r.output
    assert list(_manifest(tmp_path / "a.yaml")["scenes"]) == [cases[0].name]
    r = run("import", "zerocomp", root, "--out", tmp_path / "b.yaml", "--maps", "provided", "--cases", "*B01")
    assert r.exit_code == 0, r.output
    assert list(_manifest(tmp_path / "b.yaml")["scenes"]) == [cases[1].name]
    r = run("import", "zerocomp", root, "--out", tmp_path / "c.yaml", "--maps", "provided", "--cases", "nope*")
    assert r.exit_code == 2 and "no case" in r.output and not (tmp_path / "c.yaml").exists()


def test_usage_errors_write_nothing(labo, tmp_path):
    root, _ = labo
    out = tmp_path / "x" / "jobs.yaml"
    r = run("import", "zerocomp", root, "--out", out)  # --maps paper needs the depth model
    assert r.exit_code == 2 and "--depth-model" in r.output and "ZoeDepth" in r.output
    assert not out.parent.exists()
    r = run("import", "zerocomp", tmp_path, "--out", out, "--maps", "provided")
    assert r.exit_code == 2 and "no case found" in r.output
    r = run("import", "zerocomp", root, "--out", tmp_path / "jobs.txt", "--maps", "provided")
    assert r.exit_code == 2 and ".yaml" in r.output


def test_overwrite(labo, tmp_path):
    root, cases = labo
    out = tmp_path / "jobs.yaml"
    assert run("import", "zerocomp", root, "--out", out, "--maps", "provided", "--limit", "1").exit_code == 0
    r = run("import", "zerocomp", root, "--out", out, "--maps", "provided")
    assert r.exit_code == 2 and "--overwrite" in r.output
    assert list(_manifest(out)["scenes"]) == [cases[0].name]
    r = run("import", "zerocomp", root, "--out", out, "--maps", "provided", "--cases", "*B01", "--overwrite")
    assert r.exit_code == 0, r.output
    assert list(_manifest(out)["scenes"]) == [cases[1].name]
    assert not (tmp_path / "jobs_data" / cases[0].name).exists()  # the earlier import is replaced
    assert not list(tmp_path.glob(".jobs_data*"))  # no temporary folder left


def _fake_depth_model(folder: Path) -> Path:
    """Only the files ``check_model_dir`` looks for: the importer writes the manifest
    and never loads the model (composite would)."""
    folder.mkdir(parents=True, exist_ok=True)
    for f in ("config.json", "preprocessor_config.json"):
        (folder / f).write_text("{}")
    # a well-formed, empty safetensors file (a 2-byte one is refused as truncated)
    (folder / "model.safetensors").write_bytes((2).to_bytes(8, "little") + b"{}")
    return folder


def test_paper_and_estimated_maps(labo, tmp_path):
    root, cases = labo
    model = _fake_depth_model(tmp_path / "zoedepth")
    out = tmp_path / "p.yaml"
    r = run("import", "zerocomp", root, "--out", out, "--depth-model", model, "--limit", "1")
    assert r.exit_code == 0, r.output
    sc = _manifest(out)["scenes"][cases[0].name]
    assert sc["depth"] == {"model": str(model.resolve())}
    assert sc["normals"].endswith("normals.exr") and sc["albedo"].endswith("albedo.exr")
    out = tmp_path / "e.yaml"
    r = run("import", "zerocomp", root, "--out", out, "--maps", "estimated", "--depth-model", model, "--limit", "1")
    assert r.exit_code == 0, r.output
    sc = _manifest(out)["scenes"][cases[0].name]
    assert set(sc) == {"image", "fov_deg", "depth"}
    r = run("import", "zerocomp", root, "--out", tmp_path / "q.yaml", "--depth-model", tmp_path)
    assert r.exit_code == 2 and "config.json" in r.output


def test_every_case_broken(tmp_path):
    root = tmp_path / "labo"
    replica.make_zerocomp_archive(root, 1, broken={0: ("mask", "depth")})
    out = tmp_path / "o" / "jobs.yaml"
    r = run("import", "zerocomp", root, "--out", out, "--maps", "provided")
    assert r.exit_code == 1 and "missing layers depth, mask" in r.output
    assert not out.parent.exists()


def test_missing_background_map_names_the_file(tmp_path):
    root = tmp_path / "labo"
    cases = replica.make_zerocomp_archive(root, 2)
    (root / "GT_emission_envmap" / cases[1].name / f"{cases[1].name}_bg_normal.png").unlink()
    r = run("import", "zerocomp", root, "--out", tmp_path / "jobs.yaml", "--maps", "provided")
    assert r.exit_code == 1
    assert f"failed {cases[1].name}" in r.output and f"{cases[1].name}_bg_normal.png not found" in r.output
    assert list(_manifest(tmp_path / "jobs.yaml")["scenes"]) == [cases[0].name]


# ------------------------------------------------------------------ SpotLight
@pytest.fixture(scope="module")
def spot(tmp_path_factory):
    data = tmp_path_factory.mktemp("spot") / "data"
    cases = replica.make_spotlight_archive(data, 2)
    return data / "rendered_2024-10-20_19-07-58_control", cases


def _expected_lamp(case, v) -> np.ndarray:
    c_true = case.scene.world_to_camera([0.25 * int(case.name[4:8]) - 0.1, 0.3, -3.0])
    return np.asarray(c_true) + 10.0 * np.array([v[0], v[2], -v[1]])


def test_spotlight_cases_carry_their_lamps(spot, tmp_path):
    from zcomp_cli.datasets.importer import ARCHIVES, ImportOptions, _import_case
    from zcomp_cli.datasets.layouts import list_cases

    root, cases = spot
    files = list_cases(root, maps_dir=root.parent / "WACV_bg_estimates", light=True,
                       shadows_dir=root.parent / "shadows")
    assert [f.name for f in files] == [c.name for c in cases]
    assert len(files[0].shadows) == 2
    opts = ImportOptions(src=root, out=tmp_path / "j.yaml", maps="provided")
    e = _import_case(ARCHIVES["spotlight"], opts, files[0], "c0", tmp_path / "c0", "j_data", {"c0"})
    lamp = e["scenes"]["c0"]["light"][0]
    assert set(lamp) == {"type", "position", "radius_m", "power"}
    assert lamp["type"] == "lamp" and lamp["radius_m"] == 1.0 and lamp["power"] == "auto"
    # the lamp sits 10 m from the object's centre along (v_x, v_z, -v_y); the centre is
    # estimated from the footprint and the visible surface: a few cm off the sphere's
    np.testing.assert_allclose(lamp["position"], _expected_lamp(cases[0], replica.GT_LIGHT), atol=0.08)
    assert e["jobs"][0]["reference"].endswith("reference.exr")
    info = json.loads((tmp_path / "c0" / "case.json").read_text())
    assert info["dataset"] == "spotlight" and info["checks"]["normals_frame"] == "opengl"
    assert info["light"]["alignment"]["mode"] in ("affine", "shift")
    e = _import_case(ARCHIVES["spotlight"], ImportOptions(src=root, out=tmp_path / "j.yaml", maps="provided",
                                                          lights="all"), files[1], "c1", tmp_path / "c1", "j_data",
                     {"c1"})
    assert list(e["scenes"]) == ["c1_light0000", "c1_lightgt_dir"]
    refs = {j["scene"]: j.get("reference") for j in e["jobs"]}
    assert refs["c1_light0000"] is None and refs["c1_lightgt_dir"].endswith("reference.exr")
    np.testing.assert_allclose(e["scenes"]["c1_light0000"]["light"][0]["position"],
                               _expected_lamp(cases[1], replica.PATH_LIGHT), atol=0.08)


def test_spotlight_end_to_end_light_estimated(spot, tmp_path, no_lpips):
    root, cases = spot
    out = tmp_path / "sl" / "jobs.yaml"
    r = run("import", "spotlight", root, "--out", out, "--maps", "provided", "--lights", "none")
    assert r.exit_code == 0, r.output
    m = _manifest(out)
    assert m["defaults"]["shading_radius"] == 0.5  # SpotLight's configs/default.yaml
    assert all("light" not in s for s in m["scenes"].values())
    res = tmp_path / "res"
    assert run("composite", out, "--out", res, "--renderer", "naive").exit_code == 0
    r = run("eval", res, "--metrics", "psnr,mae")
    assert r.exit_code == 0 and "spotlight" in r.output
    assert "none bundled" in r.output  # no published figure for this set: said, not invented
    data = json.loads((res / "eval.json").read_text())
    assert len(data["images"]) == 2 and np.isfinite(data["mean"]["psnr"])


def test_spotlight_end_to_end_with_lamps(spot, tmp_path, no_lpips):
    root, _ = spot
    out = tmp_path / "sl" / "jobs.yaml"
    r = run("import", "spotlight", root, "--out", out, "--maps", "provided")
    assert r.exit_code == 0, r.output
    res = tmp_path / "res"
    r = run("composite", out, "--out", res, "--renderer", "physical")
    assert r.exit_code == 0, r.output
    assert run("eval", res, "--metrics", "psnr").exit_code == 0
    # the case's light is the manifest's lamp, frozen in the fit (its power fitted)
    import json

    rep = json.loads(next(res.glob("*/report.json")).read_text())
    light = rep["renderer"]["info"]["light"]
    assert light["source"] == "manifest" and light["lights"][0]["kind"] == "lamp"
    assert light["lights"][0]["position_from"] == "given in the manifest"


def test_spotlight_needs_its_estimates(spot, tmp_path):
    root, _ = spot
    lone = tmp_path / "lone"
    shutil.copytree(root, lone / "rendered")
    r = run("import", "spotlight", lone / "rendered", "--out", tmp_path / "j.yaml", "--maps", "provided")
    assert r.exit_code == 2 and "WACV_bg_estimates" in r.output
    r = run("import", "zerocomp", root, "--out", tmp_path / "k.yaml", "--maps", "provided", "--lights", "all")
    assert r.exit_code == 2


def test_eval_protocol_errors(imported, tmp_path, no_lpips):
    out, _, _ = imported
    res = tmp_path / "naive"
    assert run("composite", out, "--out", res, "--renderer", "naive").exit_code == 0
    other = tmp_path / "spot.yaml"
    other.write_text(yaml.safe_dump({"dataset": "spotlight", "rows": [{"name": "x", "psnr": 1.0}]}))
    r = run("eval", res, "--paper-rows", other)
    assert r.exit_code == 2 and "'spotlight'" in r.output
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump({"rows": [{"name": "x", "psnr": "high"}]}))
    r = run("eval", res, "--paper-rows", bad)
    assert r.exit_code == 2 and "rows[0].psnr" in r.output
    # issue 39, defect 13: a 528-byte alias bomb took 4.3 GB and wrote a 1.4 GB eval.json
    bomb = tmp_path / "bomb.yaml"
    lines = ['a0: &a0 ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    lines += [f"a{i}: &a{i} [{', '.join(['*a' + str(i - 1)] * 9)}]" for i in range(1, 9)]
    lines += ["rows: [{name: x, psnr: 1.0, pad: *a8}]"]
    bomb.write_text("\n".join(lines) + "\n")
    r = run("eval", res, "--paper-rows", bomb, "--out", tmp_path / "bomb_eval")
    assert r.exit_code == 2 and "alias bomb" in r.output, r.output
    assert not (tmp_path / "bomb_eval.json").exists()
    many = tmp_path / "many.yaml"
    many.write_text(yaml.safe_dump({"rows": [{"name": f"r{i}", "psnr": 1.0} for i in range(1001)]}))
    r = run("eval", res, "--paper-rows", many)
    assert r.exit_code == 2 and "1001 rows" in r.output
    r = run("eval", res, "--protocol", "paper", "--linear")
    assert r.exit_code == 2 and "--linear" in r.output
    r = run("eval", res, "--linear", "--metrics", "mae", "--out", tmp_path / "lin")  # auto: zcomp's, linear
    assert r.exit_code == 0 and json.loads((tmp_path / "lin.json").read_text())["protocol"]["encoding"] == "linear"
    # shadow metrics on the crop: the background (the manifest's scene photo) is cut like the images
    r = run("eval", res, "--metrics", "shadow-iou,shadow-darkness", "--region", "object-crop",
            "--out", tmp_path / "sh")
    assert r.exit_code == 0, r.output
    sh = json.loads((tmp_path / "sh.json").read_text())["mean"]
    assert 0 <= sh["shadow-iou"] <= 1 and np.isfinite(sh["shadow-darkness"])
    # two plain folders: no object masks, nothing to crop
    a, b = tmp_path / "a", tmp_path / "b"
    for d in (a, b):
        d.mkdir()
        shutil.copy(res / next(iter(_manifest(out)["scenes"])) / "composite.png", d / "x.png")
    r = run("eval", a, b, "--region", "object-crop", "--metrics", "mae")
    assert r.exit_code == 2 and "object_mask.png" in r.output
