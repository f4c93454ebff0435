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
