"""A mirror-ball photograph as the light (``chromeball``, ``light: {type: chrome_ball}``):
known values of the unwrap, the manifest's checks, and the round trip through Blender
(a mirror ball rendered in Cycles under a known probe, unwrapped, gives the probe's sun)."""

from __future__ import annotations

import json
import math
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from zcomp_cli import chromeball, equirect
from zcomp_cli.worldframe import ground_frame

FRAME = ground_frame(np.array([0.0, 1.0, 0.0]))  # a level camera: right, up, forward = x, y, -z


def _angle(a, b) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    return math.degrees(math.acos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1, 1)))


def _sun_probe(sun, h=128, sky=0.05, peak=500.0, radius_deg=2.0):
    sun = np.asarray(sun, float) / np.linalg.norm(sun)
    d = equirect.pixel_directions(h, 2 * h, FRAME)
    img = np.full((h, 2 * h, 3), sky)
    img[d @ sun > math.cos(math.radians(radius_deg))] = peak
    return img


def _photograph_ball(probe, size=241, center=(120.5, 120.5), radius=100.0, reflectance=1.0):
    """The orthographic photograph of a mirror ball under ``probe`` (zcomp convention in
    FRAME), by the reflection law -- the unwrap's forward model, written independently."""
    ys, xs = np.mgrid[0:size, 0:size] + 0.5
    nx, ny = (xs - center[0]) / radius, -(ys - center[1]) / radius
    inside = nx ** 2 + ny ** 2 < 1
    nz = np.sqrt(np.clip(1 - nx ** 2 - ny ** 2, 0, 1))
    n = np.stack([nx, ny, nz], -1)
    i = np.array([0.0, 0.0, -1.0])
    d = i - 2 * (n @ i)[..., None] * n
    u, v = equirect.direction_to_uv(d.reshape(-1, 3), FRAME)
    H, W = probe.shape[:2]
    px = probe[np.clip((v * H).astype(int), 0, H - 1), np.clip((u * W).astype(int), 0, W - 1)]
    img = np.zeros((size, size, 3))
    img[inside] = reflectance * px.reshape(size, size, 3)[inside]
    return img


def _brightest(img):
    h, w = img.shape[:2]
    d = equirect.pixel_directions(h, w, FRAME)
    lum = img.mean(-1)
    return d.reshape(-1, 3)[np.argmax(lum)]


@pytest.mark.parametrize("sun", [(0.3, 0.6, 0.74), (-0.8, 0.3, 0.52), (0.9, 0.1, -0.42)])
def test_the_unwrap_finds_the_sun_the_ball_reflects(sun):
    """A ball photographed under a probe holding a 2 deg sun (toward the camera, to the
    side, half behind the ball): the unwrapped probe's brightest texel is the sun's
    direction within 2 deg, and the sky's level is read back (reflectance undone)."""
    sun = np.asarray(sun) / np.linalg.norm(sun)
    probe = _sun_probe(sun)
    photo = _photograph_ball(probe, reflectance=0.6)
    img, info = chromeball.unwrap(photo, (120.5, 120.5), 100.0, FRAME, reflectance=0.6)
    assert img.shape == (200, 400, 3)
    assert _angle(_brightest(img), sun) < 2.0
    assert np.median(img) == pytest.approx(0.05, rel=0.05)
    assert info.blind_deg == pytest.approx(chromeball.blind_degrees(100.0))


def test_the_blind_spot_is_the_last_pixel_ring_and_is_filled_evenly():
    # known values: a 100 px ball's last ring reflects the 16.2 deg about straight behind
    assert chromeball.blind_degrees(100.0) == pytest.approx(16.2, abs=0.05)
    assert chromeball.blind_degrees(1000.0) == pytest.approx(5.12, abs=0.01)
    assert chromeball.blind_degrees(1.0) == 180.0
    sun = np.array([0.0, 0.6, 0.8])
    img, info = chromeball.unwrap(_photograph_ball(_sun_probe(sun)), (120.5, 120.5), 100.0, FRAME, reflectance=1.0)
    h, w = img.shape[:2]
    d = equirect.pixel_directions(h, w, FRAME).reshape(-1, 3)
    spot = d @ np.array([0.0, 0.0, -1.0]) > math.cos(math.radians(info.blind_deg))
    assert spot.any()
    vals = img.reshape(-1, 3)[spot]
    assert np.ptp(vals, axis=0).max() == 0.0  # one fill value
    assert vals[0] == pytest.approx([0.05] * 3, rel=0.05)
    assert np.isfinite(img).all()


def test_hostile_photographs_give_finite_probes_or_clear_errors():
    photo = _photograph_ball(_sun_probe(np.array([0.0, 0.6, 0.8])))
    photo[10:20, 10:200] = np.nan
    photo[100, 100] = np.inf
    img, _ = chromeball.unwrap(photo, (120.5, 120.5), 100.0, FRAME, reflectance=1.0)
    assert np.isfinite(img).all() and (img >= 0).all()
    with pytest.raises(ValueError, match="outside"):
        chromeball.unwrap(photo, (200.0, 120.0), 100.0, FRAME)
    with pytest.raises(ValueError, match="under 2 pixels"):
        chromeball.unwrap(photo, (120.0, 120.0), 1.0, FRAME)
    with pytest.raises(ValueError, match="reflectance"):
        chromeball.unwrap(photo, (120.5, 120.5), 100.0, FRAME, reflectance=0.0)
    with pytest.raises(ValueError, match="finite"):
        chromeball.unwrap(photo, (float("nan"), 120.0), 100.0, FRAME)


def test_an_ldr_ball_says_its_sun_is_clipped(tmp_path):
    from zcomp_cli.imageio import write_png

    photo = _photograph_ball(_sun_probe(np.array([0.3, 0.6, 0.74])))
    path = tmp_path / "ball.png"
    write_png(path, np.clip(photo, 0, 1))
    img, info = chromeball.ball_probe(path, (120.5, 120.5), 100.0, FRAME)
    assert not info.hdr and info.clipped > 0
    assert any("LDR" in w and "clipped" in w for w in info.warnings())
    assert any("behind the ball" in w for w in info.warnings())


# -- the manifest -------------------------------------------------------------------

def _manifest(tmp_path, light: dict, ball_size=(241, 241)):
    import yaml

    from zcomp_cli.imageio import write_exr

    from pathlib import Path

    ex = Path(__file__).resolve().parents[1] / "examples"
    ball = tmp_path / "ball.exr"
    write_exr(ball, np.full((ball_size[1], ball_size[0], 3), 0.3, np.float32))
    room = {k: str(ex / "scenes" / "room" / f) for k, f in
            (("image", "image.png"), ("depth", "depth.exr"), ("normals", "normals.exr"), ("albedo", "albedo.exr"))}
    m = {"version": 1, "defaults": {"renderer": "physical", "resolution": [128, 96]},
         "scenes": {"kitchen": {**room, "fov_deg": 55.0, "light": light}},
         "objects": {"vase": {"mesh": str(ex / "objects" / "vase.glb")}},
         "jobs": [{"scene": "kitchen", "object": "vase", "placement": {"pixel": [60, 80], "height": 0.3}}]}
    p = tmp_path / "jobs.yaml"
    p.write_text(yaml.safe_dump(m))
    return p


def test_a_chrome_ball_light_is_parsed_into_a_probe(tmp_path):
    from zcomp_cli.pipeline.manifest import load_manifest

    p = _manifest(tmp_path, {"type": "chrome_ball", "image": "ball.exr", "center": [120.5, 120.5],
                             "radius": [100, 101], "reflectance": 0.55})
    light = load_manifest(p).scenes["kitchen"].light
    pr = light.probe
    assert pr.is_ball and pr.ball_center == (120.5, 120.5) and pr.ball_radius == pytest.approx(100.5)
    assert pr.reflectance == 0.55 and pr.hdr.endswith("ball.exr")
    assert light.given
    assert pr.to_dict()["type"] == "chrome_ball"


@pytest.mark.parametrize("light, field, words", [
    ({"center": [200, 120], "radius": 100}, "center", "outside"),
    ({"center": [120, 120], "radius": 300}, "center", "outside"),
    ({"center": [120, 120], "radius": [100, 80]}, "radius", "not round"),
    ({"center": [120, 120]}, "radius", "needs 'radius'"),
    ({"center": [120], "radius": 10}, "center", "needs 'center'"),
    ({"image": "missing.exr", "center": [120, 120], "radius": 10}, "image", "not found"),
    ({"center": [120, 120], "radius": 10, "reflectance": 2}, "reflectance", "[0.001, 1]"),
])
def test_a_bad_chrome_ball_names_the_scene_and_the_field(tmp_path, light, field, words):
    from zcomp_cli.errors import ManifestError
    from zcomp_cli.pipeline.manifest import load_manifest

    p = _manifest(tmp_path, {"type": "chrome_ball", "image": "ball.exr", **light})
    with pytest.raises(ManifestError) as exc:
        load_manifest(p)
    msg = str(exc.value)
    assert f"scenes.kitchen.light.{field}" in msg and words in msg, msg
    assert exc.value.exit_code == 2


def test_a_bad_chrome_ball_stops_composite_before_anything_is_written(tmp_path):
    from click.testing import CliRunner

    from zcomp_cli.cli import cli

    p = _manifest(tmp_path, {"type": "chrome_ball", "image": "ball.exr", "center": [10, 10], "radius": 50})
    out = tmp_path / "out"
    r = CliRunner().invoke(cli, ["composite", str(p), "--out", str(out)])
    assert r.exit_code == 2, r.output
    assert "scenes.kitchen.light.center" in r.output and "outside" in r.output
    assert not out.exists()


# -- through Blender ----------------------------------------------------------------

_BLENDER_BALL = r'''
import bpy, math, sys
import numpy as np
bpy.ops.wm.read_factory_settings(use_empty=True)
sc = bpy.context.scene
sc.render.engine = "CYCLES"
sc.cycles.device = "CPU"
sc.cycles.samples = 16
sc.cycles.use_denoising = False
sc.cycles.max_bounces = 2
sc.cycles.seed = 0
sc.render.resolution_x = sc.render.resolution_y = @SIZE@
sc.render.resolution_percentage = 100
sc.view_settings.view_transform = "Standard"
sc.render.image_settings.file_format = "OPEN_EXR"
sc.render.image_settings.color_depth = "32"
wd = bpy.data.worlds.new("w"); sc.world = wd; wd.use_nodes = True
nt = wd.node_tree
env = nt.nodes.new("ShaderNodeTexEnvironment")
env.image = bpy.data.images.load(@PROBE@)
nt.links.new(env.outputs["Color"], nt.nodes["Background"].inputs["Color"])
bpy.ops.mesh.primitive_uv_sphere_add(radius=1.0, segments=128, ring_count=64)
bpy.ops.object.shade_smooth()
m = bpy.data.materials.new("chrome"); m.use_nodes = True
p = m.node_tree.nodes["Principled BSDF"]
p.inputs["Base Color"].default_value = (1, 1, 1, 1)
p.inputs["Metallic"].default_value = 1.0
p.inputs["Roughness"].default_value = 0.0
bpy.context.object.data.materials.append(m)
cam = bpy.data.cameras.new("c"); cam.type = "ORTHO"; cam.ortho_scale = @ORTHO@
co = bpy.data.objects.new("c", cam); sc.collection.objects.link(co)
co.location = (0, -10, 0); co.rotation_euler = (math.pi / 2, 0, 0)  # looks along world +Y
sc.camera = co
sc.render.filepath = @OUT@
bpy.ops.render.render(write_still=True)
'''


@pytest.mark.blender
def test_a_ball_rendered_by_blender_under_a_probe_gives_back_the_probes_sun(tmp_path):
    """Cycles renders a mirror sphere (metallic, roughness 0, white) under an
    equirectangular probe in Blender's own mapping holding a 2 deg sun; seen by an
    orthographic camera from the camera's position. Unwrapped, then split as any given
    probe is (``probe.load_given_probe``), its strongest source lies within 3 deg of the
    probe's own -- for a sun toward the camera and one to the side."""
    from zcomp_cli.imageio import read_image, write_exr
    from zcomp_cli.scene.lightparams import ProbeParams
    from zcomp_cli.scene.probe import load_given_probe

    size, ortho = 240, 2.4  # the ball: radius 100 px about the image's centre
    ph, pw = 256, 512
    v, u = np.mgrid[0:ph, 0:pw]
    phi = (0.5 - (u + 0.5) / pw) * 2 * math.pi  # Blender's mapping
    el = (0.5 - (v + 0.5) / ph) * math.pi
    d = np.stack([np.cos(el) * np.cos(phi), np.cos(el) * np.sin(phi), np.sin(el)], -1)
    for k, (sun_phi, sun_el) in enumerate(((250.0, 35.0), (10.0, 20.0))):
        s = np.array([math.cos(math.radians(sun_el)) * math.cos(math.radians(sun_phi)),
                      math.cos(math.radians(sun_el)) * math.sin(math.radians(sun_phi)), math.sin(math.radians(sun_el))])
        img = np.full((ph, pw, 3), 0.05, np.float32)
        img[d @ s > math.cos(math.radians(2.0))] = 400.0
        probe = tmp_path / f"probe{k}.exr"
        write_exr(probe, img)
        out = tmp_path / f"ball{k}.exr"
        script = tmp_path / f"ball{k}.py"
        script.write_text(textwrap.dedent(_BLENDER_BALL).replace("@SIZE@", str(size))
                          .replace("@ORTHO@", str(ortho)).replace("@PROBE@", repr(str(probe)))
                          .replace("@OUT@", repr(str(out))))
        r = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=600)
        assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
        photo = read_image(out)
        # the camera frame: x = world X, y = world Z, z = -world Y
        s_cam = np.array([s[0], s[2], -s[1]])
        params = ProbeParams(hdr=str(out), ball_center=(size / 2, size / 2), ball_radius=size / ortho,
                             reflectance=1.0)
        lights = load_given_probe(params, FRAME)
        err = _angle(lights.sources[0].direction, s_cam)
        print(f"sun at azimuth {sun_phi} elevation {sun_el}: unwrapped {err:.2f} deg off")
        assert err < 3.0, (sun_phi, sun_el)
        unwrapped, info = chromeball.unwrap(photo, (size / 2, size / 2), size / ortho, FRAME, reflectance=1.0)
        # away from the sun and the blind spot, the sky's radiance comes back
        assert np.median(unwrapped) == pytest.approx(0.05, rel=0.1)
        json.dumps(info.to_dict())


def test_a_chrome_ball_lights_a_composite_as_its_probe_does(tmp_path, examples_dir):
    """The shipped example's room lit by a probe holding a 2 deg sun, given once as the
    equirectangular file and once as a mirror ball photographed (by the reflection law)
    from the camera under it: both composites' light models put the probe's sun in the
    same direction (within 3 deg; the manifest's scene frame, pitch included, carries the
    ball to the world), and the report names the ball."""
    import yaml
    from click.testing import CliRunner

    from zcomp_cli.cli import cli
    from zcomp_cli.imageio import write_exr
    from zcomp_cli.worldframe import direction_from_angles, up_from_pitch_roll

    m = yaml.safe_load((examples_dir / "jobs.yaml").read_text())
    room = m["scenes"]["room_lit"]
    up = up_from_pitch_roll(room["pitch_deg"], 0.0)
    frame = ground_frame(up)
    sun = direction_from_angles(150.0, 40.0, up)  # left and behind the balls, well lit
    h = 256
    dirs = equirect.pixel_directions(h, 2 * h, frame)
    probe = np.full((h, 2 * h, 3), 0.3, np.float32)
    probe[dirs @ sun > math.cos(math.radians(2.0))] = 800.0
    write_exr(tmp_path / "probe.exr", probe)
    # the ball, photographed from the camera (camera frame: its view ray is -z)
    size, c, r = 401, 200.5, 180.0
    ys, xs = np.mgrid[0:size, 0:size] + 0.5
    nx, ny = (xs - c) / r, -(ys - c) / r
    inside = nx ** 2 + ny ** 2 < 1
    n = np.stack([nx, ny, np.sqrt(np.clip(1 - nx ** 2 - ny ** 2, 0, 1))], -1)
    i = np.array([0.0, 0.0, -1.0])
    d = i - 2 * (n @ i)[..., None] * n
    u, v = equirect.direction_to_uv(d.reshape(-1, 3), frame)
    photo = probe[np.clip((v * h).astype(int), 0, h - 1), np.clip((u * 2 * h).astype(int), 0, 2 * h - 1)]
    photo = np.where(inside[..., None], 0.6 * photo.reshape(size, size, 3), 0.0).astype(np.float32)
    write_exr(tmp_path / "ball.exr", photo)
    runs = {}
    for kind in ("probe", "chrome_ball"):
        sc = {k: str(examples_dir / room[k]) for k in ("image", "depth", "normals", "albedo")}
        sc.update(fov_deg=room["fov_deg"], pitch_deg=room["pitch_deg"])
        sc["light"] = {"type": "probe", "hdr": str(tmp_path / "probe.exr")} if kind == "probe" else \
            {"type": "chrome_ball", "image": str(tmp_path / "ball.exr"), "center": [c, c], "radius": r}
        job = {k: v for k, v in m["jobs"][4].items() if k != "reference"}
        mm = {"version": 1, "defaults": {**m["defaults"], "resolution": [256, 192]}, "scenes": {"room_lit": sc},
              "objects": {k: {"mesh": str(examples_dir / o["mesh"])} for k, o in m["objects"].items()},
              "jobs": [job]}
        p = tmp_path / f"{kind}.yaml"
        p.write_text(yaml.safe_dump(mm))
        out = tmp_path / f"out_{kind}"
        res = CliRunner().invoke(cli, ["composite", str(p), "--out", str(out)])
        assert res.exit_code == 0, res.output
        rep = json.loads(next(out.glob("*/report.json")).read_text())
        runs[kind] = rep["renderer"]["info"]["light"]
    suns = {k: [x for x in v["lights"] if x["kind"] == "sun"] for k, v in runs.items()}
    assert suns["probe"] and suns["chrome_ball"], runs
    assert _angle(suns["probe"][0]["direction_camera"], sun) < 2.0
    assert _angle(suns["chrome_ball"][0]["direction_camera"], suns["probe"][0]["direction_camera"]) < 3.0
    assert "ball.exr" in runs["chrome_ball"]["probe"]
