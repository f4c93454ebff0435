"""`zcomp composite --renderer zerocomp --weights DIR` with tiny random weights on disk."""

import json

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from zerocomp_dummy import save_dummy

pytestmark = [pytest.mark.blender, pytest.mark.slow]


def test_composite_cli_zerocomp(tmp_path, small_example):
    from zcomp_cli.cli import cli
    from zcomp_cli.imageio import read_image

    ck, base = save_dummy(tmp_path / "w", 11)
    manifest = small_example(tmp_path, jobs=[0])
    m = yaml.safe_load(manifest.read_text())
    m["defaults"]["renderer"] = {"name": "zerocomp", "resolution": 32, "device": "cpu"}
    manifest.write_text(yaml.safe_dump(m))
    out = tmp_path / "out"
    r = CliRunner().invoke(cli, ["composite", str(manifest), "--out", str(out), "--renderer",
                                 "zerocomp", "--weights", str(ck), "--base", str(base),
                                 "--steps", "2"], catch_exceptions=False)
    assert r.exit_code == 0, r.output
    d = next(p for p in out.iterdir() if p.is_dir())
    rep = json.loads((d / "report.json").read_text())
    assert rep["status"] == "done", rep
    assert rep["renderer"]["settings"]["name"] == "zerocomp"
    img = read_image(d / "composite.exr")
    assert np.isfinite(img).all() and img.max() > 0


def test_composite_cli_zerocomp_batches_equal_singles(tmp_path, small_example):
    # two jobs in one GPU batch (--batch-size 2) == one job per batch (--batch-size 1, the
    # executor then prepares the second job on a thread while the first renders); the batch
    # size is a speed setting: --resume with another one skips the finished jobs
    from zcomp_cli.cli import cli
    from zcomp_cli.imageio import read_image

    ck, base = save_dummy(tmp_path / "w", 11)
    manifest = small_example(tmp_path, jobs=[0, 2])
    m = yaml.safe_load(manifest.read_text())
    m["defaults"]["renderer"] = {"name": "zerocomp", "resolution": 32, "device": "cpu"}
    manifest.write_text(yaml.safe_dump(m))
    args = ["composite", str(manifest), "--weights", str(ck), "--base", str(base), "--steps", "2"]
    outs = {}
    for bs in (2, 1):
        out = tmp_path / f"out{bs}"
        r = CliRunner().invoke(cli, args + ["--out", str(out), "--batch-size", str(bs)],
                               catch_exceptions=False)
        assert r.exit_code == 0, r.output
        outs[bs] = out
    dirs = sorted(p.name for p in outs[2].iterdir() if p.is_dir())
    assert len(dirs) == 2
    for name in dirs:
        reps = [json.loads((outs[bs] / name / "report.json").read_text()) for bs in (2, 1)]
        assert [rep["renderer"]["info"]["jobs_in_call"] for rep in reps] == [2, 1]
        req = reps[0]["renderer"]["info"]["requests"][0]
        assert req["window"] == "auto" and req["box"][2] - req["box"][0] == 192  # 256 x 192 frame
        a, b = (read_image(outs[bs] / name / "composite.exr") for bs in (2, 1))
        np.testing.assert_allclose(a, b, atol=1e-5)
    r = CliRunner().invoke(cli, args + ["--out", str(outs[2]), "--batch-size", "1", "--resume"],
                           catch_exceptions=False)
    assert r.exit_code == 0 and "2 skipped" in r.output, r.output
