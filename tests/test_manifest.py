"""jobs.yaml validation: every problem reported at once, with its line and location."""

import numpy as np
import pytest

from zcomp_cli.errors import ManifestError
from zcomp_cli.imageio import write_exr, write_png
from zcomp_cli.scene.lightparams import Param
from zcomp_cli.pipeline.manifest import load_manifest


@pytest.fixture
def scene_dir(tmp_path):
    (tmp_path / "scenes").mkdir()
    (tmp_path / "objects").mkdir()
    write_png(tmp_path / "scenes/room.png", np.full((30, 40, 3), 0.5, np.float32))
    write_exr(tmp_path / "scenes/depth.exr", np.full((30, 40), 2.0, np.float32))
    write_exr(tmp_path / "scenes/normals.exr", np.tile(np.float32([0, 1, 0]), (30, 40, 1)))
    write_exr(tmp_path / "scenes/albedo.exr", np.full((30, 40, 3), 0.5, np.float32))
    write_exr(tmp_path / "scenes/small_albedo.exr", np.full((10, 40, 3), 0.5, np.float32))
    (tmp_path / "objects/chair.glb").write_bytes(b"glTF")
    return tmp_path


GOOD = """\
version: 1
defaults: {renderer: physical, shading_radius: 1.0, seed: 469}
scenes:
  room:
    image: scenes/room.png
    fov_deg: 50
    depth: scenes/depth.exr
    normals: scenes/normals.exr
    albedo: scenes/albedo.exr
objects:
  chair: {mesh: objects/chair.glb}
jobs:
  - {scene: room, object: chair, pose: {position: [0.1, -0.9, -3.0], rotation_deg: [0, 35, 0], height: 0.9}}
  - {scene: room, object: chair, placement: {pixel: [20, 25], yaw_deg: 20, height: 0.9}, output: placed}
"""


def test_good_manifest(scene_dir):
    p = scene_dir / "jobs.yaml"
    p.write_text(GOOD)
    m = load_manifest(p)
    assert list(m.scenes) == ["room"] and m.scenes["room"].width == 40 and m.scenes["room"].height == 30
    assert m.scenes["room"].maps["depth"] == (scene_dir / "scenes/depth.exr").resolve()
    assert m.jobs[0].name == "000_room_chair" and m.jobs[1].name == "placed"
    assert m.jobs[0].pose.height == 0.9
    np.testing.assert_allclose(m.jobs[0].pose.position, [0.1, -0.9, -3.0])
    assert m.jobs[1].placement.pixel == (20.0, 25.0)
    assert m.defaults.seed == 469 and m.defaults.renderer.name == "physical"


def test_all_problems_reported_with_lines(scene_dir):
    bad = GOOD.replace("albedo: scenes/albedo.exr", "albedo: scenes/small_albedo.exr")
    bad = bad.replace("fov_deg: 50", "fov_deg: 50\n    colour: red")
    bad = bad.replace("objects/chair.glb", "objects/missing.glb")
    bad = bad.replace("position: [0.1, -0.9, -3.0]", "position: [0.1, -0.9]")
    bad = bad.replace("pixel: [20, 25]", "pixel: [200, 25]")
    p = scene_dir / "jobs.yaml"
    p.write_text(bad)
    with pytest.raises(ManifestError) as ei:
        load_manifest(p)
    msg = str(ei.value)
    probs = ei.value.problems
    assert len(probs) == 5, msg
    assert any("scenes.room.colour" in x and "unknown key" in x and "jobs.yaml:7" in x for x in probs), msg
    assert any("scenes.room.albedo" in x and "40x10" in x for x in probs), msg
    assert any("objects.chair.mesh" in x and "file not found" in x for x in probs), msg
    assert any("jobs[0].pose.position" in x for x in probs), msg
    assert any("jobs[1].placement.pixel" in x and "outside" in x for x in probs), msg
    assert ei.value.exit_code == 2


@pytest.mark.parametrize(
    "text, needle",
    [
        ("version: 1\nscenes: {}\nobjects: {}\njobs: []\n", "non-empty"),
        ("- a\n- b\n", "must be a mapping"),
        ("version: 2\n" + GOOD.split("\n", 1)[1], "unsupported manifest version"),
        (GOOD.replace("scene: room, object: chair, pose", "scene: kitchen, object: chair, pose"), "unknown scene"),
        (GOOD.replace(", output: placed", ", output: 000_room_chair"), "also used by"),
        (GOOD + "  - {scene: room, object: chair}\n", "exactly one of 'pose'"),
        (GOOD.replace("seed: 469", "seed: abc"), "defaults.seed"),
        ("version: 1\nscenes: [\n", "invalid YAML"),
        (GOOD.replace("fov_deg: 50", "fov_deg: 50\n    K: [[1,0,0],[0,1,0],[0,0,1]]"), "not both"),
        (GOOD.replace("defaults: {", "defaults: {resolution: [64, 64], "), "aspect ratio"),
    ],
)
def test_manifest_problems(scene_dir, text, needle):
    p = scene_dir / "jobs.yaml"
    p.write_text(text)
    with pytest.raises(ManifestError) as ei:
        load_manifest(p)
    assert needle in str(ei.value)


def test_missing_manifest(tmp_path):
    with pytest.raises(ManifestError, match="file not found"):
        load_manifest(tmp_path / "nope.yaml")


def test_scene_light_parsed(scene_dir):
    p = scene_dir / "jobs.yaml"
    p.write_text(GOOD.replace("fov_deg: 50", "fov_deg: 50\n    light: {azimuth_deg: 135, elevation_deg: 40, "
                                              "angular_radius_deg: 2, strength: 3}"))
    light = load_manifest(p).scenes["room"].light.suns[0]
    assert light.angles == (135, 40) and light.share == 3 and not light.irradiance.frozen
    assert light.radius_deg == Param.given(2.0) and not light.direction.frozen and light.direction_given
    p.write_text(GOOD.replace("fov_deg: 50", "fov_deg: 50\n    light: {direction: [0, 2, 0]}"))
    light = load_manifest(p).scenes["room"].light.suns[0]
    # no strength: measured from the photo (free); no size: the Sun's unless the pixels tell (free)
    assert light.direction == Param.given((0.0, 1.0, 0.0)) and light.share is None
    assert not light.irradiance.frozen and not light.radius_deg.frozen
    # the camera's tilt rides with the light tree (the light itself then estimated)
    p.write_text(GOOD.replace("fov_deg: 50", "fov_deg: 50\n    pitch_deg: -20\n    roll_deg: 4"))
    tree = load_manifest(p).scenes["room"].light
    assert tree.tilt == {"pitch_deg": -20.0, "roll_deg": 4.0} and not tree.given


def test_scene_light_problems_name_field_and_line(scene_dir):
    p = scene_dir / "jobs.yaml"
    p.write_text(GOOD.replace("fov_deg: 50", "fov_deg: 50\n    light:\n      direction: [0, 0]\n"
                                              "      strength: -1\n      colour: warm"))
    with pytest.raises(ManifestError) as ei:
        load_manifest(p)
    probs = ei.value.problems
    assert any("scenes.room.light.direction" in x and "jobs.yaml:8" in x for x in probs), probs
    assert any("scenes.room.light.strength" in x and "jobs.yaml:9" in x for x in probs), probs
    assert any("scenes.room.light.colour" in x and "unknown key" in x for x in probs), probs
    p.write_text(GOOD.replace("fov_deg: 50", "fov_deg: 50\n    light: {elevation_deg: 95}"))
    with pytest.raises(ManifestError) as ei:
        load_manifest(p)
    assert any("scenes.room.light" in x and "azimuth_deg" in x for x in ei.value.problems)


def test_scene_light_probe(scene_dir):
    write_exr(scene_dir / "scenes/probe.exr", np.full((8, 16, 3), 0.5, np.float32))
    p = scene_dir / "jobs.yaml"
    p.write_text(GOOD.replace("fov_deg: 50", "fov_deg: 50\n    light: {type: probe, hdr: scenes/probe.exr, "
                                              "rotation_deg: 30}"))
    probe = load_manifest(p).scenes["room"].light.probe
    assert probe.rotation_deg == 30 and probe.convention == "zcomp"
    assert probe.hdr == str((scene_dir / "scenes/probe.exr").resolve())
    p.write_text(GOOD.replace("fov_deg: 50", "fov_deg: 50\n    light: {type: probe, hdr: scenes/nope.exr}"))
    with pytest.raises(ManifestError) as ei:
        load_manifest(p)
    assert any("scenes.room.light.hdr" in x and "file not found" in x and "jobs.yaml:7" in x
               for x in ei.value.problems), ei.value.problems


def test_scene_light_strength_auto(scene_dir):
    p = scene_dir / "jobs.yaml"
    p.write_text(GOOD.replace("fov_deg: 50", "fov_deg: 50\n    light: {direction: [0, 1, 0], strength: auto}"))
    light = load_manifest(p).scenes["room"].light.suns[0]
    assert not light.irradiance.frozen and light.share is None and not light.radius_deg.frozen
    p.write_text(GOOD.replace("fov_deg: 50", "fov_deg: 50\n    light: {direction: [0, 1, 0], strength: bright}"))
    with pytest.raises(ManifestError) as ei:
        load_manifest(p)
    assert any("scenes.room.light.strength" in x and "'auto'" in x for x in ei.value.problems), ei.value.problems


def test_scene_light_list(scene_dir):
    p = scene_dir / "jobs.yaml"
    p.write_text(GOOD.replace("fov_deg: 50", "fov_deg: 50\n    light:\n"
                              "      - {azimuth_deg: 30, elevation_deg: 45, strength: 3}\n"
                              "      - {direction: [-1, 1, 0], strength: 1, angular_radius_deg: 4}"))
    light = load_manifest(p).scenes["room"].light
    assert len(light.suns) == 2
    assert light.suns[1].radius_deg.value == 4 and light.suns[0].share == 3
    # one item is that light
    p.write_text(GOOD.replace("fov_deg: 50", "fov_deg: 50\n    light: [{direction: [0, 1, 0]}]"))
    assert len(load_manifest(p).scenes["room"].light.suns) == 1
    bad = {
        "[{direction: [0, 1, 0]}, {type: lamp, position: [0, 1, -2], power: 50}, {direction: [1, 1, 0], strength: 2}]":
            ("scenes.room.light", "cannot stand beside"),
        "[{direction: [0, 1, 0]}, {type: spot}]": ("scenes.room.light[1].type", "unsupported light type"),
        "[{direction: [0, 1, 0]}, {direction: [0, 0, 0]}]": ("scenes.room.light[1].direction", "not all 0"),
        "[]": ("scenes.room.light", "at least one light"),
    }
    for text, (field, words) in bad.items():
        p.write_text(GOOD.replace("fov_deg: 50", f"fov_deg: 50\n    light: {text}"))
        with pytest.raises(ManifestError) as ei:
            load_manifest(p)
        assert any(field in x and words in x for x in ei.value.problems), (text, ei.value.problems)
