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


def _bench(tmp_path, exposure):
    from zcomp_cli.benchsuite.scenes import sample_scene

    scene = sample_scene(np.random.default_rng(11), 64, 48)
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
