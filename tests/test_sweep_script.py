"""zcomp_cli.benchsuite.sweep (behind benchmarks/sweep_error_vs_time.py): the plan of configurations, the per-configuration
manifest, timing summaries, upsampling and outputs (fast), and a --quick sweep over a
2-case Blender benchmark (slow)."""

from __future__ import annotations

import csv
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "benchmarks" / "sweep_error_vs_time.py"


@pytest.fixture(scope="module")
def sweep():
    import zcomp_cli.benchsuite.sweep as mod

    return mod


# -- resolution -----------------------------------------------------------------------------
def test_scaled_resolution_keeps_aspect(sweep):
    assert sweep.scaled_resolution((256, 256), 0.75) == (192, 192)
    assert sweep.scaled_resolution((256, 256), 0.5) == (128, 128)
    assert sweep.scaled_resolution((64, 48), 0.5) == (32, 24)
    assert sweep.scaled_resolution((640, 480), 1.0) == (640, 480)
    w, h = sweep.scaled_resolution((1000, 563), 0.5)
    assert abs(w / h - 1000 / 563) <= 0.01 * 1000 / 563


@pytest.mark.parametrize("frac", [0.0, -0.5, 1.5, float("nan")])
def test_scaled_resolution_rejects_bad_fractions(sweep, frac):
    with pytest.raises(ValueError):
        sweep.scaled_resolution((256, 256), frac)


def test_scaled_resolution_rejects_tiny_sizes(sweep):
    with pytest.raises(ValueError, match="16"):
        sweep.scaled_resolution((40, 30), 0.25)


# -- plan -----------------------------------------------------------------------------------
def test_plan_varies_one_knob_at_a_time(sweep):
    defaults = sweep.physical_defaults()
    configs = sweep.plan_configs((256, 256), quick=False)
    keys = [c.key for c in configs]
    assert len(keys) == len(set(keys))
    assert [c.key for c in configs if c.renderer == "naive"] == ["naive"]
    default = [c for c in configs if c.renderer == "physical" and c.default]
    assert len(default) == 1 and default[0].settings == {} and default[0].resolution is None
    # the default run is a point of every physical series
    assert {k for k, _ in default[0].series} == set(sweep.PHYSICAL_KNOBS_FULL)
    for c in configs:
        if c.renderer != "physical" or c.default:
            continue
        # exactly one knob differs from the default
        changed = len(c.settings) + (c.resolution is not None)
        assert changed == 1, c
        for k, v in c.settings.items():
            assert v != defaults[k]
    res = sorted(c.resolution for c in configs if c.resolution is not None)
    assert res == [(128, 128), (192, 192)]
    n_series = sum(len(c.series) for c in configs if c.renderer == "physical")
    assert n_series == sum(len(v) for v in sweep.PHYSICAL_KNOBS_FULL.values())
    assert not any(c.renderer == "zerocomp" for c in configs)


def test_plan_quick_is_smaller_and_knobs_select(sweep):
    full = sweep.plan_configs((64, 48))
    quick = sweep.plan_configs((64, 48), quick=True)
    assert len(quick) < len(full)
    only = sweep.plan_configs((64, 48), quick=True, knobs=["march_steps"])
    assert [c.key for c in only] == ["physical_default", "physical_march_steps8"]
    assert only[0].series == [("march_steps", "32")]
    with pytest.raises(ValueError, match="unknown knob"):
        sweep.plan_configs((64, 48), knobs=["bogus"])


def test_plan_adds_default_value_missing_from_a_series(sweep, monkeypatch):
    monkeypatch.setitem(sweep.PHYSICAL_KNOBS_QUICK, "march_steps", [8, 16])
    plan = sweep.plan_configs((64, 48), quick=True, knobs=["march_steps"])
    assert ("march_steps", "32") in plan[0].series
    assert len(plan) == 3


def test_plan_zerocomp_only_with_weights(sweep):
    zc = {"controlnet": "/w/cn", "base": "/w/sd"}
    plan = sweep.plan_configs((256, 256), quick=True, knobs=["zerocomp"], zerocomp=zc)
    assert {c.renderer for c in plan} == {"zerocomp"}
    assert sorted((c.settings["crop"], c.settings["steps"]) for c in plan) == [
        (False, 1), (False, 4), (True, 1), (True, 4)]
    assert all(c.settings["controlnet"] == "/w/cn" for c in plan)
    assert sweep.plan_configs((256, 256), knobs=["zerocomp"], zerocomp=None) == []


def test_zerocomp_weights_reasons(sweep, monkeypatch, tmp_path):
    monkeypatch.delenv("ZCOMP_CONTROLNET", raising=False)
    monkeypatch.delenv("ZCOMP_SD_BASE", raising=False)
    got, why = sweep.zerocomp_weights()
    assert got is None and "ZCOMP_CONTROLNET" in why and "ZCOMP_SD_BASE" in why
    monkeypatch.setenv("ZCOMP_CONTROLNET", str(tmp_path / "missing"))
    monkeypatch.setenv("ZCOMP_SD_BASE", str(tmp_path))
    got, why = sweep.zerocomp_weights()
    assert got is None and "not a folder" in why
    (tmp_path / "cn").mkdir()
    monkeypatch.setenv("ZCOMP_CONTROLNET", str(tmp_path / "cn"))
    got, why = sweep.zerocomp_weights()
    assert why == "" and Path(got["controlnet"]) == (tmp_path / "cn").resolve()


# -- manifest -------------------------------------------------------------------------------
def test_config_manifest_absolute_paths_and_settings(sweep, tmp_path):
    doc = {"version": 1, "defaults": {"renderer": "physical", "resolution": [64, 48], "seed": 7},
           "scenes": {"s": {"image": "cases/s/image.exr", "fov_deg": 50, "depth": "cases/s/depth.exr",
                            "normals": {"from_depth": True}, "albedo": "/abs/albedo.exr"}},
           "objects": {"o": {"mesh": "objects/o.glb"}},
           "jobs": [{"scene": "s", "object": "o", "pose": {"position": [0, 0, -2]}, "reference": "cases/s/gt.exr"}]}
    jobs = tmp_path / "bench" / "jobs.yaml"
    jobs.parent.mkdir()
    jobs.write_text(yaml.safe_dump(doc))
    cfg = sweep.Config("x", "physical", settings={"march_steps": 8}, resolution=(32, 24))
    out = sweep.config_manifest(jobs, cfg)
    root = jobs.parent.resolve()
    assert out["scenes"]["s"]["image"] == str(root / "cases/s/image.exr")
    assert out["scenes"]["s"]["depth"] == str(root / "cases/s/depth.exr")
    assert out["scenes"]["s"]["albedo"] == "/abs/albedo.exr"
    assert out["scenes"]["s"]["normals"] == {"from_depth": True}  # estimator spec kept
    assert out["objects"]["o"]["mesh"] == str(root / "objects/o.glb")
    assert out["jobs"][0]["reference"] == str(root / "cases/s/gt.exr")
    assert out["defaults"] == {"renderer": {"name": "physical", "march_steps": 8}, "resolution": [32, 24], "seed": 7}
    # native: the benchmark's resolution is kept
    out2 = sweep.config_manifest(jobs, sweep.Config("n", "naive"))
    assert out2["defaults"]["resolution"] == [64, 48] and out2["defaults"]["renderer"] == {"name": "naive"}
    assert len(sweep.config_manifest(jobs, cfg, max_jobs=1)["jobs"]) == 1
    with pytest.raises(ValueError, match="max_jobs"):
        sweep.config_manifest(jobs, cfg, max_jobs=0)
    # the source manifest is untouched and the written copy parses as YAML
    assert yaml.safe_load(jobs.read_text()) == doc
    p = sweep.write_config_manifest(jobs, cfg, tmp_path / "m" / "x.yaml")
    assert yaml.safe_load(p.read_text()) == out


def test_config_manifest_rejects_non_manifest(sweep, tmp_path):
    p = tmp_path / "jobs.yaml"
    p.write_text("just: text\n")
    with pytest.raises(ValueError, match="no jobs"):
        sweep.config_manifest(p, sweep.Config("x", "naive"))


# -- timings, upsampling, outputs -----------------------------------------------------------
def _report(d: Path, total, timings, status="done"):
    d.mkdir(parents=True)
    (d / "report.json").write_text(json.dumps(
        {"status": status, "timings": {"job_total_s": total}, "renderer": {"timings": timings}}))


def test_timing_summary_median_and_sums(sweep, tmp_path):
    _report(tmp_path / "a", 1.0, {"estimate": 0.5, "synthesis": 0.25})
    _report(tmp_path / "b", 5.0, {"estimate": 4.0, "synthesis": 0.5})
    _report(tmp_path / "c", 2.0, {"estimate": 1.5, "synthesis": float("nan")})
    _report(tmp_path / "d", 100.0, {"estimate": 99.0}, status="failed")  # not finished: ignored
    reps = sweep.job_reports(tmp_path)
    assert len(reps) == 3
    med, sums = sweep.timing_summary(reps)
    assert med == 2.0
    assert sums == {"estimate": 6.0, "synthesis": 0.75}
    assert math.isnan(sweep.timing_summary([])[0])


def test_upsample_linear_shape_constant_and_nonnegative(sweep):
    const = np.full((12, 16, 3), 0.37, np.float32)
    up = sweep.upsample_linear(const, (32, 24))
    assert up.shape == (24, 32, 3) and up.dtype == np.float32
    np.testing.assert_allclose(up, 0.37, atol=1e-6)
    edge = np.zeros((12, 16, 3), np.float32)
    edge[:, 8:] = 1e4  # HDR step: bicubic overshoot must not go negative
    up = sweep.upsample_linear(edge, (32, 24))
    assert up.min() >= 0 and np.isfinite(up).all()


def test_eval_medians_resist_one_outlier(sweep, tmp_path):
    (tmp_path / "eval.json").write_text(json.dumps({"mean": {"psnr": 20.0, "flip": 0.2}, "images": [
        {"name": "a", "psnr": 30.0, "flip": 0.05}, {"name": "b", "psnr": "inf", "flip": 0.0},
        {"name": "c", "psnr": 1.0, "flip": 0.9}]}))
    med = sweep.eval_medians(tmp_path)
    assert med == {"psnr": 30.0, "flip": 0.05}
    assert all(math.isnan(v) for v in sweep.eval_medians(tmp_path / "none").values())


def test_csv_table_and_plot(sweep, tmp_path):
    base = {"n_jobs": 2, "n_failed": 0, "renderer_timings_s_sum": {"estimate": 1.0}, "composite_wall_s": 3.0,
            "composite_cpu_s": 2.5, "run_dir": "r"}
    results = [
        {"renderer": "naive", "series": [("baseline", "paste")], "default": False, "psnr": 20.0, "flip": 0.1,
         "median_s_per_job": 0.01, **base},
        {"renderer": "physical", "series": [("march_steps", "32"), ("resolution", "64x48")], "default": True,
         "psnr": 25.0, "flip": 0.05, "median_s_per_job": 2.0, **base},
        {"renderer": "physical", "series": [("march_steps", "8")], "default": False, "psnr": float("nan"),
         "flip": float("nan"), "median_s_per_job": float("nan"), **{**base, "n_failed": 2}},
    ]
    rows = [r for res in results for r in sweep.rows_of(res)]
    assert len(rows) == 4
    sweep.write_csv(rows, tmp_path / "s.csv")
    with open(tmp_path / "s.csv") as f:
        got = list(csv.DictReader(f))
    assert list(got[0])[:8] == ["renderer", "knob", "value", "psnr", "flip", "median_s_per_job", "n_jobs", "n_failed"]
    assert got[1]["knob"] == "march_steps" and float(got[1]["psnr"]) == 25.0
    assert got[3]["psnr"] == "nan" and got[3]["n_failed"] == "2"
    assert got[0]["psnr_median"] == "nan"  # no eval.json in run_dir "r"
    table = sweep.format_table(rows)
    assert "32*" in table and "paste" in table
    sweep.plot(rows, tmp_path / "s.png")
    assert (tmp_path / "s.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_missing_benchmark_is_a_clear_error(tmp_path):
    r = subprocess.run([sys.executable, str(SCRIPT), str(tmp_path), "--out", str(tmp_path / "o")],
                       text=True, capture_output=True)
    assert r.returncode == 2 and "jobs.yaml not found" in r.stderr


# -- end to end on a tiny Blender benchmark ---------------------------------------------------
@pytest.mark.blender
@pytest.mark.slow
def test_quick_sweep_on_tiny_benchmark(tmp_path, monkeypatch):
    monkeypatch.delenv("ZCOMP_CONTROLNET", raising=False)
    monkeypatch.delenv("ZCOMP_SD_BASE", raising=False)
    bench = tmp_path / "bench"
    r = subprocess.run([sys.executable, "-m", "zcomp_cli", "-q", "make-benchmark", str(bench), "--n", "2",
                        "--seed", "5", "--resolution", "64", "48", "--samples", "4", "--no-denoise"],
                       text=True, capture_output=True)
    assert r.returncode == 0, r.stderr
    out = tmp_path / "sweep"
    r = subprocess.run([sys.executable, str(SCRIPT), str(bench), "--out", str(out), "--quick",
                        "--knobs", "naive,resolution,march_steps,zerocomp"],
                       text=True, capture_output=True)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert "zerocomp sweep skipped" in r.stdout
    with open(out / "sweep.csv") as f:
        rows = list(csv.DictReader(f))
    got = {(row["renderer"], row["knob"], row["value"]) for row in rows}
    assert got == {("naive", "baseline", "paste"), ("physical", "resolution", "64x48"),
                   ("physical", "resolution", "32x24"), ("physical", "march_steps", "32"),
                   ("physical", "march_steps", "8")}
    for row in rows:
        assert row["n_jobs"] == "2" and row["n_failed"] == "0"
        psnr, flip, secs = float(row["psnr"]), float(row["flip"]), float(row["median_s_per_job"])
        assert math.isfinite(psnr) and 5 < psnr < 80
        assert math.isfinite(flip) and 0 <= flip <= 1
        assert math.isfinite(secs) and secs > 0
    # the half-resolution run was scored on composites upsampled to the references' size
    half = next(row for row in rows if row["value"] == "32x24")
    assert half["run_dir"].endswith("_upsampled")
    ev = json.loads((Path(half["run_dir"]) / "eval.json").read_text())
    assert len(ev["images"]) == 2
    man = yaml.safe_load((out / "manifests" / "physical_res32x24.yaml").read_text())
    assert man["defaults"]["resolution"] == [32, 24]
    assert (out / "sweep.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_resume_reuses_only_the_same_run(sweep):
    cfg = sweep.Config("physical_res32x24", "physical", resolution=(32, 24))
    saved = {"n_jobs": 2, "config": {"renderer": "physical", "settings": {}, "resolution": [32, 24]}}
    assert sweep._same_run(saved, cfg, 2)
    assert not sweep._same_run(saved, cfg, 1)  # another --max-jobs
    assert not sweep._same_run(saved, sweep.Config("x", "physical", resolution=(48, 36)), 2)
    assert not sweep._same_run(saved, sweep.Config("x", "physical", {"march_steps": 8}, (32, 24)), 2)
    assert not sweep._same_run({"n_jobs": 2}, cfg, 2)
    # another version of the code: rerun
    assert not sweep._same_run(saved, cfg, 2, "abc")
    assert sweep._same_run({**saved, "code_sha256": "abc"}, cfg, 2, "abc")


def test_snapshot_source_is_a_complete_importable_copy(sweep, tmp_path):
    info = sweep.snapshot_source(tmp_path / "code")
    pkg = tmp_path / "code" / "zcomp_cli"
    assert (pkg / "renderers" / "physical" / "renderer.py").is_file()
    assert (pkg / "blender" / "scripts" / "render_intrinsics.py").is_file()
    assert not list(pkg.rglob("__pycache__"))
    assert len(info["sha256"]) == 64
    assert json.loads((tmp_path / "code" / "SOURCE.json").read_text())["sha256"] == info["sha256"]
    # the same tree gives the same hash (so --resume can match it)
    again = sweep.snapshot_source(tmp_path / "code2")
    assert again["sha256"] == info["sha256"]
    env = sweep.child_env(tmp_path / "code")
    assert env["PYTHONPATH"].split(":")[0] == str(tmp_path / "code")
    r = subprocess.run([sys.executable, "-c", "import zcomp_cli; print(zcomp_cli.__file__)"],
                       text=True, capture_output=True, env=env)
    assert r.returncode == 0 and Path(r.stdout.strip()).parent == pkg
    assert sweep.child_env(None) is None


def test_values_override_the_table(sweep):
    vals = sweep.parse_values(["march_steps=8,16", "resolution=1,0.5"])
    assert vals == {"march_steps": [8, 16], "resolution": [1.0, 0.5]}
    plan = sweep.plan_configs((256, 256), knobs=["march_steps"], values=vals)
    assert sorted(c.key for c in plan) == ["physical_default", "physical_march_steps16", "physical_march_steps8"]
    for bad in (["bogus=1"], ["march_steps"], ["march_steps=a"], ["march_steps="]):
        with pytest.raises(ValueError):
            sweep.parse_values(bad)


def test_the_objects_ray_knobs_are_set_inside_their_settings_group(sweep):
    cs = sweep.plan_configs((64, 48), quick=True, knobs=("bounce_rays", "reflect_rays", "highlight_samples",
                                                          "march_steps"))
    by = {c.key: c.settings for c in cs}
    assert by["physical_bounce_rays0"] == {"transport": {"bounce_rays": 0}}
    assert by["physical_reflect_rays0"] == {"gloss": {"reflect_rays": 0}}
    assert by["physical_highlight_samples1"] == {"gloss": {"highlight_samples": 1}}
    assert by["physical_march_steps8"] == {"march_steps": 8}
    d = sweep.physical_defaults()
    from zcomp_cli.renderers.physical.settings import PhysicalSettings

    ps = PhysicalSettings()
    assert d["bounce_rays"] == ps.transport.bounce_rays and d["reflect_rays"] == ps.gloss.reflect_rays
    assert d["highlight_samples"] == ps.gloss.highlight_samples
    # the renderer takes each as it is written into the manifest
    from zcomp_cli.renderers.physical.renderer import PhysicalRenderer

    for c in cs:
        r = PhysicalRenderer(**c.settings)
        for group, vals in c.settings.items():
            got = r.settings()[group] if isinstance(vals, dict) else {group: r.settings()[group]}
            for k, v in (vals.items() if isinstance(vals, dict) else [(group, vals)]):
                assert got[k] == v


def test_cycles_sweep_plans_samples_with_and_without_the_denoiser():
    from zcomp_cli.benchsuite.sweep import plan_configs

    configs = plan_configs((64, 48), quick=True, knobs=("cycles",))
    assert [c.renderer for c in configs] == ["cycles"] * 4
    assert {(c.settings["samples"], c.settings["denoise"]) for c in configs} == {(8, True), (32, True), (8, False),
                                                                                 (32, False)}
    assert [c.key for c in configs if c.default] == ["cycles_samples_denoised32"]
