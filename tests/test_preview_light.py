"""``zcomp preview-light``: the balls' maps (known values), where they stand, the sheet
through Blender on the shipped example (the given sun's numbers and shadow side), and
bad input refused before anything is written."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from click.testing import CliRunner

from zcomp_cli.camera import Camera
from zcomp_cli.cli import cli
from zcomp_cli.preview import balls as B


def _level_pose(dist=3.0, height=1.0):
    """The balls' row standing on a floor ``height`` below a level camera, ``dist`` ahead."""
    M = np.eye(4)
    M[:3, 3] = [0.0, -height, -dist]
    return M


def test_the_balls_maps_are_three_spheres_on_the_floor():
    cam = Camera.from_fov(50.0, 160, 120)
    d = 0.3
    bundle = B.ball_bundle(cam, _level_pose(), d)
    C = B.ball_centres(d) + [0.0, -1.0, -3.0]
    f = float(cam.K[0, 0])
    for k, c in enumerate(C):
        (x, y), z = cam.project(c[None])[0][0], cam.project(c[None])[1][0]
        i, j = int(y), int(x)
        # the front of the sphere, one radius nearer than its centre, at its centre pixel
        assert bundle.depth[i, j] == pytest.approx(z - d / 2, abs=0.01)
        assert np.linalg.norm(bundle.normals[i, j]) == pytest.approx(1.0, abs=1e-4)
        ray = cam.ray(j + 0.5, i + 0.5)
        assert bundle.normals[i, j] @ (-ray / np.linalg.norm(ray)) > 0.99  # facing the camera
        assert bundle.albedo[i, j, 0] == pytest.approx(B.BALLS[k].color)
        assert bundle.metallic[i, j] == pytest.approx(B.BALLS[k].metallic)
        assert bundle.roughness[i, j] == pytest.approx(B.BALLS[k].roughness)
    # coverage: three discs of the projected radius (a sphere's outline, nearly a disc)
    r_px = f * (d / 2) / 3.0
    assert bundle.mask.sum() == pytest.approx(3 * math.pi * r_px ** 2, rel=0.08)
    assert ((bundle.mask > 0) & (bundle.mask < 1)).any()  # anti-aliased edges
    # the footprint: the floor's own depth under the balls, where the alignment reads it
    fp = bundle.footprint_depth > 0
    assert fp.any()
    rays = cam.pixel_rays()
    floor_t = -1.0 / rays[..., 1]
    assert np.allclose(bundle.footprint_depth[fp], floor_t[fp], rtol=1e-4)
    for a in (bundle.depth, bundle.normals, bundle.albedo, bundle.mask, bundle.footprint_depth):
        assert np.isfinite(a).all()


def test_degenerate_poses_are_refused():
    cam = Camera.from_fov(50.0, 64, 48)
    with pytest.raises(ValueError, match="non-degenerate"):
        B.ball_bundle(cam, np.zeros((4, 4)), 0.3)
    M = _level_pose()
    M[0, 3] = np.nan
    with pytest.raises(ValueError, match="finite"):
        B.ball_bundle(cam, M, 0.3)
    with pytest.raises(ValueError, match="diameter"):
        B.ball_bundle(cam, _level_pose(), 0.0)


def test_the_balls_glb_holds_three_pbr_spheres(tmp_path):
    import trimesh

    p = tmp_path / "balls.glb"
    B.write_balls_glb(p, 0.2)
    sc = trimesh.load(p, force="scene")
    geoms = list(sc.geometry.values())
    assert len(geoms) == 3
    mats = sorted((g.visual.material.metallicFactor or 0.0, g.visual.material.roughnessFactor) for g in geoms)
    assert mats == sorted((m.metallic, m.roughness) for m in B.BALLS)
    lo = sc.bounds[0]
    assert lo[1] == pytest.approx(0.0, abs=1e-6)  # standing on y = 0
    assert sc.extents[0] == pytest.approx(0.2 * (2 * B.SPACING + 1), rel=1e-3)


def test_where_the_balls_stand(examples_dir):
    from zcomp_cli.errors import UsageError
    from zcomp_cli.pipeline.manifest import load_manifest
    from zcomp_cli.pipeline.scene import scene_camera
    from zcomp_cli.preview.run import choose_pixel

    m = load_manifest(examples_dir / "jobs.yaml")
    cam = scene_camera(m.scenes["room"], m.defaults.resolution)
    # the first job of 'room' gives a pose: its position, projected
    (x, y), why = choose_pixel(m, "room", cam)
    px, _ = cam.project(np.asarray(m.jobs[0].pose.position)[None])
    assert (x, y) == pytest.approx(tuple(px[0])) and "pose" in why
    assert choose_pixel(m, "room", cam, (100, 50)) == ((100.0, 50.0), "--pixel")
    with pytest.raises(UsageError, match="outside"):
        choose_pixel(m, "room", cam, (5000, 50))


@pytest.mark.parametrize("args, words", [
    (["--scene", "nope"], "no scene 'nope'"),
    (["--diameter", "-1"], "--diameter"),
    (["--pixel", "99999", "1"], "outside"),
])
def test_bad_options_exit_2_before_anything_is_written(tmp_path, examples_dir, args, words):
    out = tmp_path / "out"
    r = CliRunner().invoke(cli, ["preview-light", str(examples_dir / "jobs.yaml"), "--out", str(out),
                                 "--scene", "room", *args] if "--scene" not in args else
                           ["preview-light", str(examples_dir / "jobs.yaml"), "--out", str(out), *args])
    assert r.exit_code == 2, r.output
    assert not out.exists()
    assert words in r.output


@pytest.mark.blender
def test_the_sheet_of_the_shipped_example_shows_the_given_sun(tmp_path, examples_dir):
    """The shipped example's lit scene (a probe and a sun given): one sheet written with
    the photograph, the balls and the numbers; the printed azimuth and elevation are the
    manifest's sun in the world; the balls' shadows fall away from that sun in the
    picture; a second run refuses to overwrite, --overwrite replaces."""
    from zcomp_cli.imageio import read_image
    from zcomp_cli.pipeline.manifest import load_manifest
    from zcomp_cli.worldframe import angles_from_direction, up_from_pitch_roll

    out = tmp_path / "out"
    args = ["preview-light", str(examples_dir / "jobs.yaml"), "--out", str(out), "--scene", "room_lit",
            "--samples", "8"]
    r = CliRunner().invoke(cli, args)
    assert r.exit_code == 0, r.output
    png, js = out / "preview" / "room_lit.png", out / "preview" / "room_lit.json"
    info = json.loads(js.read_text())
    m = load_manifest(examples_dir / "jobs.yaml")
    sc = m.scenes["room_lit"]
    sun = np.asarray(sc.light.suns[0].direction.value, float)
    up = up_from_pitch_roll(sc.light.pitch_deg, 0.0)
    az, el = angles_from_direction(sun, up)
    line = next(ln for ln in info["lines"] if ln.startswith("sun:"))
    assert f"azimuth {az:.0f} deg, elevation {el:.0f} deg" in line, line
    assert any(ln.startswith("probe: probe.exr") for ln in info["lines"])
    # the sheet: the composite at the working size on the left
    sheet = read_image(png)
    photo = read_image(examples_dir / "scenes" / "room" / "image.png")
    H, W = photo.shape[:2]
    assert sheet.shape[0] > H and sheet.shape[1] > W
    comp = sheet[:H, :W]
    lum = lambda a: a @ np.array([0.2126, 0.7152, 0.0722])  # noqa: E731
    cam = Camera.from_fov(sc.fov_deg, W, H)
    M = np.asarray(info["object_to_camera"])
    balls = B.ball_bundle(cam, M, info["ball_diameter_m"]).mask > 0
    from scipy import ndimage

    near = ndimage.binary_dilation(balls, iterations=3)
    # the cast shadows: darker than the balls' occlusion of the sky, which takes up to a
    # fifth of the floor's light where the wall's shadow leaves it only the sky (at 0.8,
    # that ring around every ball made the shadow's centre sway by a pixel about the base)
    shadow = (lum(comp) < 0.6 * lum(photo)) & ~near
    assert shadow.sum() > 50
    # the shadow side: from the balls' base point, away from the sun along the ground
    base = M[:3, 3]
    away = -(sun - (sun @ up) * up)
    (x0, y0), (x1, y1) = cam.project(np.stack([base, base + 0.3 * away]))[0]
    ys, xs = np.nonzero(shadow)
    shift = np.array([xs.mean() - x0, ys.mean() - y0])
    assert shift @ np.array([x1 - x0, y1 - y0]) > 0, (shift, (x1 - x0, y1 - y0))
    # the balls are drawn: the composite differs from the photograph on them
    assert np.abs(comp[balls] - photo[balls]).mean() > 0.02
    # nothing else written but the scene's fitted light (the manifest's syntax); a
    # re-run refuses to overwrite, --overwrite replaces
    assert sorted(p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file()) == [
        "lights/room_lit.yaml", "preview/room_lit.json", "preview/room_lit.png"]
    r = CliRunner().invoke(cli, args)
    assert r.exit_code == 2 and "--overwrite" in r.output
    r = CliRunner().invoke(cli, args + ["--overwrite"])
    assert r.exit_code == 0, r.output
