"""``zcomp eval`` end to end on tiny PNG/EXR folders."""

import json

import numpy as np
import pytest
from click.testing import CliRunner

from zcomp_cli.cli import cli
from zcomp_cli.imageio import write_exr, write_png


def _img(seed, h=16, w=20):
    return np.random.default_rng(seed).random((h, w, 3)).astype(np.float32)


@pytest.fixture
def folders(tmp_path, monkeypatch):
    # No LPIPS weights anywhere: LPIPS must be reported unavailable, the rest must run.
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "torch"))
    monkeypatch.setenv("ZCOMP_LPIPS_BACKBONE", str(tmp_path / "missing_alexnet.pth"))
    pred, ref = tmp_path / "pred", tmp_path / "ref"
    write_png(pred / "a.png", _img(0))
    write_png(ref / "a.png", _img(0))  # identical
    write_exr(pred / "sub" / "b.exr", _img(1) * 3)
    write_exr(ref / "sub" / "b.exr", _img(2) * 3)
    return pred, ref


def run(*args):
    return CliRunner().invoke(cli, list(map(str, args)), catch_exceptions=False)


def test_two_folders_all_metrics(folders):
    pred, ref = folders
    r = run("eval", "--metrics", "all", pred, ref)
    assert r.exit_code == 0, r.output
    assert "lpips unavailable" in r.output and "missing_alexnet.pth" in r.output
    data = json.loads((pred / "eval.json").read_text())
    assert [i["name"] for i in data["images"]] == ["a", "sub/b"]
    a, b = data["images"]
    assert a["psnr"] == "inf" and a["rmse"] == 0 and a["ssim"] == pytest.approx(1.0)
    assert a["flip"] == pytest.approx(0.0, abs=1e-7)
    assert b["rmse"] > 0 and np.isfinite(b["psnr"]) and 0 < b["flip"]
    assert "lpips" in data["unavailable"] and "lpips" not in data["mean"]
    assert data["mean"]["rmse"] == pytest.approx((a["rmse"] + b["rmse"]) / 2)
    lines = (pred / "eval.csv").read_text().splitlines()
    assert lines[0] == "name,pred,ref,psnr,rmse,si-rmse,ssim,mae,flip"
    assert lines[-1].startswith("mean,") and len(lines) == 4


def test_out_prefix_and_linear_and_mask(folders, tmp_path):
    pred, ref = folders
    masks = tmp_path / "masks"
    m = np.zeros((16, 20, 3), np.float32)
    m[:, :10] = 1
    write_png(masks / "a.png", m, srgb_encode=False)
    write_png(masks / "sub" / "b.png", m, srgb_encode=False)
    out = tmp_path / "o" / "res"
    r = run("eval", "--metrics", "mae,rmse", "--linear", "--mask", masks, "--out", out, pred, ref)
    assert r.exit_code == 0, r.output
    data = json.loads((tmp_path / "o" / "res.json").read_text())
    assert data["colour_space"] == "linear" and data["metrics"] == ["mae", "rmse"]
    b = data["images"][1]
    want = np.abs(_img(1)[:, :10] * 3 - _img(2)[:, :10] * 3).mean()
    assert b["mae"] == pytest.approx(want, rel=1e-5)
    assert (tmp_path / "o" / "res.csv").is_file()


def test_size_mismatch_names_files(folders):
    """A pair of another size is listed as unscored (named, with both files), the rest
    is scored (issue 30: it used to abort the whole evaluation)."""
    pred, ref = folders
    write_png(ref / "a.png", _img(0, 17, 20))
    r = run("eval", "--metrics", "psnr", pred, ref)
    assert r.exit_code == 0, r.output
    assert "size mismatch" in r.output and str(pred / "a.png") in r.output and str(ref / "a.png") in r.output
    d = json.loads((pred / "eval.json").read_text())
    assert "a" in d["unscored"] and "a" not in [i["name"] for i in d["images"]] and d["images"]
    write_exr(ref / "sub" / "b.exr", _img(2, 17, 20))
    r = run("eval", "--metrics", "psnr", pred, ref)
    assert r.exit_code == 1 and "no pair could be scored" in r.output


def test_missing_pair_and_nan(folders):
    pred, ref = folders
    write_png(pred / "c.png", _img(3))
    r = run("eval", "--metrics", "psnr", pred, ref)
    assert r.exit_code == 1 and "c" in r.output and "no reference" in r.output
    (pred / "c.png").unlink()
    bad = _img(1) * 3
    bad[0, 0, 0] = np.nan
    write_exr(pred / "sub" / "b.exr", bad)
    r = run("eval", "--metrics", "psnr", pred, ref)
    assert r.exit_code == 1 and "non-finite" in r.output and "b.exr" in r.output


def test_unknown_metric_is_usage_error(folders):
    pred, ref = folders
    r = run("eval", "--metrics", "psnr,bogus", pred, ref)
    assert r.exit_code == 2 and "bogus" in r.output


def test_composite_output_folder(tmp_path, monkeypatch):
    monkeypatch.setenv("ZCOMP_LPIPS_BACKBONE", str(tmp_path / "missing.pth"))
    out, refs = tmp_path / "out", tmp_path / "refs"
    write_png(refs / "job1.png", _img(5))
    write_png(refs / "job2.png", _img(6))
    for job, seed in (("job1", 5), ("job2", 7)):
        write_png(out / job / "composite.png", _img(seed))
        write_exr(out / job / "composite.exr", _img(seed))
        mask = np.ones((16, 20, 3), np.float32)
        write_png(out / job / "shading_mask.png", mask, srgb_encode=False)
        (out / job / "report.json").write_text(json.dumps({"reference": str(refs / f"{job}.png")}))
    r = run("eval", "--metrics", "psnr,mae", "--mask", "shading_mask.png", out)
    assert r.exit_code == 0, r.output
    data = json.loads((out / "eval.json").read_text())
    assert [i["name"] for i in data["images"]] == ["job1", "job2"]
    assert data["images"][0]["psnr"] == "inf" and data["images"][1]["mae"] > 0
    assert data["images"][0]["pred"].endswith("composite.png")
    assert data["images"][0]["mask"].endswith("shading_mask.png")
    # --refs matches job folders by name, whatever report.json says.
    for job in ("job1", "job2"):
        (out / job / "report.json").write_text("{}")
    r = run("eval", "--metrics", "mae", "--refs", refs, out)
    assert r.exit_code == 0, r.output
    # Without a reference anywhere: a clear error naming the job.
    r = run("eval", "--metrics", "mae", out)
    assert r.exit_code == 1 and "job1" in r.output and "--refs" in r.output


def test_shadow_metrics_with_background(tmp_path):
    bg = np.full((16, 20, 3), 0.5, np.float32)
    ref_img, pred_img = bg.copy(), bg.copy()
    ref_img[4:8, 2:10] *= 0.3
    pred_img[4:8, 6:14] *= 0.6
    write_exr(tmp_path / "pred" / "a.exr", pred_img)
    write_exr(tmp_path / "ref" / "a.exr", ref_img)
    write_exr(tmp_path / "bg.exr", bg)
    r = run("eval", "--metrics", "shadow-iou,shadow-darkness", tmp_path / "pred", tmp_path / "ref")
    assert r.exit_code == 0 and "unavailable" in r.output and "--background" in r.output
    r = run("eval", "--metrics", "shadow-iou,shadow-darkness", "--background", tmp_path / "bg.exr",
            tmp_path / "pred", tmp_path / "ref")
    assert r.exit_code == 0, r.output
    a = json.loads((tmp_path / "pred" / "eval.json").read_text())["images"][0]
    assert a["shadow-iou"] == pytest.approx(16 / 48)
    assert a["shadow-darkness"] == pytest.approx((16 * 0.3 + 16 * 0.7 + 16 * 0.4) / 48, abs=1e-4)
