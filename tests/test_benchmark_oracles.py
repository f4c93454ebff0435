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
