"""Given lights that cannot light what the camera sees (issue 39, defect 9): refused at
validation when world up is known, else the job fails with the reason -- never an
exposure of 1e9 and a white object reported done; colours bounded."""

from __future__ import annotations

import json

import pytest
import yaml
from click.testing import CliRunner

from zcomp_cli.cli import cli


def _manifest(tmp_path, examples_dir, light, *, pitch=True):
    m = yaml.safe_load((examples_dir / "jobs.yaml").read_text())
    sc = dict(m["scenes"]["room_lit"])
    for k in ("image", "depth", "normals", "albedo"):
        sc[k] = str(examples_dir / sc[k])
    if not pitch:
        sc.pop("pitch_deg")
    sc["light"] = light
    mm = {"version": 1, "defaults": {"renderer": "physical", "resolution": [128, 96]}, "scenes": {"room": sc},
          "objects": {"vase": {"mesh": str(examples_dir / "objects/vase.glb")}},
          "jobs": [{"scene": "room", "object": "vase", "placement": {"pixel": [200, 300], "height": 0.3}}]}
    p = tmp_path / "jobs.yaml"
    p.write_text(yaml.safe_dump(mm))
    return p


@pytest.mark.parametrize("light, field, words", [
    ({"type": "sun", "direction": [0, -1, 0], "irradiance": 3.0}, "scenes.room.light.direction", "below the horizon"),
    ({"type": "sun", "azimuth_deg": 10, "elevation_deg": 40, "color": [1e30, 1, 1]}, "scenes.room.light.color",
     "[0, 1000]"),
])
def test_an_impossible_light_is_refused_before_anything_is_written(tmp_path, examples_dir, light, field, words):
    out = tmp_path / "out"
    r = CliRunner().invoke(cli, ["composite", str(_manifest(tmp_path, examples_dir, light)), "--out", str(out)])
    assert r.exit_code == 2, r.output
    assert field in r.output and words in r.output, r.output
    assert not out.exists()


@pytest.mark.parametrize("light, words", [
    ({"type": "sun", "direction": [0, -1, 0], "irradiance": 3.0}, "below the horizon"),
    ({"type": "lamp", "position": [0.0, -6.0, -3.0], "power": 60}, "below the floor"),
])
def test_a_light_that_reaches_no_visible_pixel_fails_its_job(tmp_path, examples_dir, light, words):
    """Without pitch_deg world up is read off the support at render time: the job fails
    with the reason (exit 1), where it used to be fitted with an exposure of 1e9, drawn
    white and reported done."""
    out = tmp_path / "out"
    r = CliRunner().invoke(cli, ["composite", str(_manifest(tmp_path, examples_dir, light, pitch=False)),
                                 "--out", str(out)])
    assert r.exit_code == 1, r.output
    job = json.loads((out / "summary.json").read_text())["jobs"][0]
    assert job["status"] == "failed" and words in job["reason"], job
    assert not (out / "000_room_vase" / "composite.png").exists()


def test_a_lamp_inside_the_object_is_noted(tmp_path, examples_dir):
    """A given lamp at the object's centre lights it from within (its outside drawn
    unlit): the job runs, its report says so (there was no note)."""
    import numpy as np

    from zcomp_cli.pose import Pose

    out = tmp_path / "out"
    m = _manifest(tmp_path, examples_dir, {"type": "lamp", "position": [0.0, 1.0, -2.0], "power": 60})
    assert CliRunner().invoke(cli, ["composite", str(m), "--out", str(out)]).exit_code == 0
    rep = json.loads((out / "000_room_vase" / "report.json").read_text())
    assert not any("inside the object" in n for n in rep["notes"])
    pose = Pose.from_dict(rep["pose"])
    centre = np.asarray(pose.position) + pose.up * (rep["pose"]["height"] / 2)
    m = _manifest(tmp_path, examples_dir, {"type": "lamp", "position": centre.tolist(), "power": 60})
    r = CliRunner().invoke(cli, ["composite", str(m), "--out", str(tmp_path / "out2")])
    assert r.exit_code == 0, r.output
    notes = json.loads((tmp_path / "out2" / "000_room_vase" / "report.json").read_text())["notes"]
    assert any("light: lamp 0 at" in n and "is inside the object" in n for n in notes), notes
