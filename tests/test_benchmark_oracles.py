"""The benchmark's oracle levels (``benchmarks/run_benchmark.py``, DESIGN.md section 8):
each gives the renderer more of the truth the generator knew."""

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest
import yaml

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "run_benchmark.py"


@pytest.fixture(scope="module")
def rb():
    spec = importlib.util.spec_from_file_location("run_benchmark_under_test", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _bench(tmp_path, exposure, seed=11):
    from zcomp_cli.benchsuite.scenes import sample_scene

    scene = sample_scene(np.random.default_rng(seed), 64, 48)
    case = {"id": "case_0000", "scene": scene.to_dict(), "exposure": exposure}
    (tmp_path / "benchmark.json").write_text(json.dumps({"cases": [case]}))
    jobs = {"version": 1, "scenes": {"case_0000": {"image": "cases/case_0000/image.exr", "fov_deg": 45.0}},
            "jobs": [{"scene": "case_0000", "object": "o"}]}
    (tmp_path / "jobs.yaml").write_text(yaml.safe_dump(jobs, sort_keys=False))
    return tmp_path


def test_the_exposure_level_is_the_full_light_and_the_photographs_exposure(rb, tmp_path):
    bench = _bench(tmp_path, 0.4321)
    full = yaml.safe_load(rb.write_oracle_jobs(bench, "full").read_text())["scenes"]["case_0000"]
    exp = yaml.safe_load(rb.write_oracle_jobs(bench, "exposure").read_text())["scenes"]["case_0000"]
    assert "exposure" not in full  # the full oracle fits the exposure
    assert exp["exposure"] == pytest.approx(0.4321)
    assert exp["light"] == full["light"] and exp["pitch_deg"] == full["pitch_deg"]
    assert (bench / "jobs_oracle_exposure.yaml").is_file()
    with pytest.raises(ValueError, match="unknown oracle level 'sun'"):
        rb.write_oracle_jobs(bench, "sun")


@pytest.mark.parametrize("seed,kind", [(11, "lamp"), (14, "sun")])
def test_the_sky_level_is_the_full_light_with_the_lights_strengths_fitted(rb, tmp_path, seed, kind):
    """``sky``: the HDR map as a probe at its strength, every lamp and sun where it is and
    at its size, as ``full`` gives them; only their strengths (and colours) are left to
    the fit: the gap to ``full`` is the split alone."""
    from zcomp_cli.pipeline.lightspec import parse_light

    bench = _bench(tmp_path, 0.5, seed)
    full = yaml.safe_load(rb.write_oracle_jobs(bench, "full").read_text())["scenes"]["case_0000"]
    sky = yaml.safe_load(rb.write_oracle_jobs(bench, "sky").read_text())["scenes"]["case_0000"]
    assert sky["pitch_deg"] == full["pitch_deg"] and "exposure" not in sky
    assert sky["light"][0] == full["light"][0] and sky["light"][0]["type"] == "probe"
    direct = [(f, s) for f, s in zip(full["light"][1:], sky["light"][1:])]
    assert len(sky["light"]) == len(full["light"]) and [f["type"] for f, _ in direct] == [kind]
    strength = {"sun": ("irradiance", "strength"), "lamp": ("power", "power")}
    for f, s in direct:
        given, fitted = strength[kind]
        assert isinstance(f[given], float) and s[fitted] == "auto" and "color" in f and "color" not in s
        same = {k: v for k, v in f.items() if k not in ("irradiance", "power", "color")}
        assert {k: v for k, v in s.items() if k in same} == same  # where it is, and its size
    problems = []
    parse_light(sky["light"], "scenes.case_0000.light", lambda *a: problems.append(a))
    assert problems == []  # a manifest zcomp takes: an auto strength may stand beside a probe


def test_the_shadow_bias_is_the_composites_ratio_less_the_truths_inside_the_true_shadow(rb, tmp_path):
    """``shadow_bias`` per case: the sign the darkness error does not tell. The truth
    halves the floor's light in a square, the composite takes a quarter off it: +0.25
    (too pale); a composite darker than the truth, below 0; no true shadow: nan."""
    from zcomp_cli.imageio import write_exr, write_image

    H, W = 32, 48
    bg = np.full((H, W, 3), 0.5, np.float32)
    gt = bg.copy()
    gt[8:16, 8:16] *= 0.5
    om = np.zeros((H, W), np.float32)
    om[20:28, 30:40] = 1.0  # the object, off the shadow
    cases = []
    for i, (truth, k) in enumerate(((gt, 0.75), (gt, 0.25), (bg, 0.75))):
        cid = f"case_{i:04d}"
        d = tmp_path / "cases" / cid
        d.mkdir(parents=True)
        write_image(d / "image.exr", bg)
        write_image(d / "gt.exr", truth)
        write_exr(d / "object_mask.exr", om)
        pred = bg.copy()
        pred[8:16, 8:16] *= k
        job = tmp_path / "res" / f"{i:03d}_{cid}_o"
        job.mkdir(parents=True)
        write_image(job / "composite.exr", pred)
        (job / "report.json").write_text(json.dumps({"renderer": {"info": {}}}))
        cases.append({"id": cid, "files": {"image": f"cases/{cid}/image.exr", "gt": f"cases/{cid}/gt.exr",
                                           "object_mask": f"cases/{cid}/object_mask.exr"}})
    (tmp_path / "benchmark.json").write_text(json.dumps({"cases": cases}))
    truths = {c["id"]: {"lights": [], "shown": []} for c in cases}
    rows = rb.per_case(tmp_path, tmp_path / "res", truths)
    assert rows[0]["shadow_bias"] == pytest.approx(0.25, abs=1e-6)
    assert rows[1]["shadow_bias"] == pytest.approx(-0.25, abs=1e-6)
    assert np.isnan(rows[2]["shadow_bias"])
