"""The ``cycles`` renderer (issue 35): its world lookup, its scene arrays, its settings and,
in Blender, its shadows against the physical renderer's under the same given light.

The renderer contract (``test_renderer_contract.py``) covers shapes, determinism, the
independence of the two passes and the known background reproduced exactly.
"""

from __future__ import annotations

import numpy as np
import pytest

from zcomp_cli import equirect
from zcomp_cli.errors import UsageError
from zcomp_cli.renderers.cycles import scene as sc
from zcomp_cli.renderers.cycles.settings import CyclesSettings
from zcomp_cli.worldframe import ground_frame, up_from_pitch_roll


@pytest.mark.parametrize("convention", equirect.CONVENTIONS)
@pytest.mark.parametrize("rotation", [0.0, 37.0, -120.0])
def test_world_rows_make_blenders_lookup_read_the_pixel_zcomp_names(convention, rotation):
    rng = np.random.default_rng(0)
    frame = ground_frame(up_from_pitch_roll(-25.0, 5.0))
    d = rng.normal(size=(500, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    R = sc.world_rows(frame, convention, rotation)
    u, v = sc.blender_uv(d @ R.T)
    u0, v0 = equirect.direction_to_uv(d, frame, convention, rotation)
    assert np.abs((u - u0 + 0.5) % 1.0 - 0.5).max() < 1e-9
    assert np.abs(v - v0).max() < 1e-9
    assert np.allclose(R @ R.T, np.eye(3))  # a rotation (a reflection for a mirrored probe)
    assert np.isclose(abs(np.linalg.det(R)), 1.0)


def test_the_sky_world_holds_the_sh_radiance_above_and_the_ground_below():
    from zcomp_cli.scene import sh
    from zcomp_cli.scene.lightmodel import Sky

    up = up_from_pitch_roll(-20.0, 0.0)
    L = 0.7 * np.ones(3)
    coeffs = np.zeros((sh.N_COEFFS, 3))
    coeffs[0] = L / sh.basis(up[None])[0, 0]  # a uniform sky of radiance L
    img, rows = sc.sky_image(Sky(radiance_sh=coeffs, ground=[0.1, 0.2, 0.3], up=up), 64)
    assert img.shape == (32, 64, 3) and img.dtype == np.float32
    assert np.allclose(img[:16], 0.7, atol=1e-5)
    assert np.allclose(img[16:], [0.1, 0.2, 0.3], atol=1e-6)
    assert np.allclose(rows, sc.world_rows(ground_frame(up)))


def test_lamps_in_blenders_units_and_probe_sources_left_to_the_world():
    from zcomp_cli.scene.lightparams import Origin
    from zcomp_cli.scene.lightmodel import Lamp, LightModel, Sky, Sun
    from zcomp_cli.scene import sh

    up = np.array([0.0, 1.0, 0.0])
    sky = Sky(radiance_sh=np.zeros((sh.N_COEFFS, 3)), ground=np.zeros(3), up=up)
    model = LightModel(suns=(Sun(direction=[0, 1, 1], radius_deg=2.0, irradiance=[2.0, 1.0, 0.0]),
                             Sun(direction=[1, 1, 0], radius_deg=0.3, irradiance=[1, 1, 1],
                                 direction_from=Origin.PROBE)),
                       lamps=(Lamp(position=[0, 2, -3], radius_m=0.1, intensity=[0.5, 0.5, 0.5]),
                              Lamp(position=[1, 2, -3], radius_m=0.2, intensity=[1, 1, 1], facing=[0, -1, 0])),
                       sky=sky)
    lamps = sc.lamps_of(model, skip_probe_sources=True)
    assert [x["kind"] for x in lamps] == ["SUN", "POINT", "AREA"]
    sun, point, area = lamps
    # a sun of E W/m^2 shades E / pi; it shines along minus its direction
    assert np.isclose(sun["energy"], 2.0 * np.pi) and np.allclose(sun["color"], [1.0, 0.5, 0.0])
    assert np.allclose(sun["direction"], -np.array([0, 1, 1]) / np.sqrt(2))
    assert np.isclose(sun["angle_rad"], np.radians(4.0))
    assert np.isclose(point["energy"], 0.5 * 4 * np.pi ** 2) and point["radius"] == 0.1
    assert area["size"] == pytest.approx(0.4) and np.allclose(area["direction"], [0, -1, 0])
    assert len(sc.lamps_of(model, skip_probe_sources=False)) == 4


def test_fill_behind_puts_the_support_plane_under_the_object():
    from zcomp_cli.testing import floor_scene

    s = floor_scene(64, 48)
    valid = s.depth > 0
    hidden = np.zeros_like(valid)
    hidden[30:40, 20:40] = True
    d, n, a, ok = sc.fill_behind(np.where(hidden, 0.0, s.depth), np.where(hidden[..., None], 0.0, s.normals),
                                 np.where(hidden[..., None], 0.0, s.albedo), valid & ~hidden, hidden, s.camera,
                                 s.up_cam)
    assert ok[hidden].all()
    assert np.allclose(d[hidden], s.depth[hidden], rtol=1e-4)
    assert np.allclose(n[hidden], s.normals[hidden], atol=1e-4)
    assert np.allclose(a[hidden], s.albedo[hidden])
    # no support: nothing to fill with, the hole stays
    d2, _, _, ok2 = sc.fill_behind(s.depth, s.normals, s.albedo, np.zeros_like(valid), hidden, s.camera, s.up_cam)
    assert not ok2.any()


def test_scene_mesh_arrays_keep_only_used_vertices_with_their_pixels_colour():
    from zcomp_cli.scene.depthmesh import build_depth_mesh
    from zcomp_cli.testing import floor_scene

    s = floor_scene(32, 24, with_box=True, box_center=(0.0, -3.0))
    albedo = np.random.default_rng(1).uniform(0, 1, s.albedo.shape)
    mesh = build_depth_mesh(s.depth, s.normals, s.camera, s.up_cam)
    arr = sc.scene_mesh_arrays(mesh, albedo)
    V, F, C = arr["vertices"], arr["faces"], arr["colors"]
    assert F.max() == len(V) - 1 and len(np.unique(F)) == len(V)
    # a pixel's vertex keeps its albedo
    h, w = s.depth.shape
    k = int(np.flatnonzero(np.all(np.isclose(V, mesh.vertices[h * w // 2 + 3].astype(np.float32)), 1))[0])
    assert np.allclose(C[k], albedo.reshape(-1, 3)[h * w // 2 + 3], atol=1e-6)


@pytest.mark.parametrize("kw, words", [
    ({"samples": 0}, "samples: expected a positive integer"),
    ({"samples": float("inf")}, "samples: expected a positive integer"),
    ({"samples": 1e30}, r"samples: expected a positive integer \(at most 4096\)"),
    ({"max_bounces": float("inf")}, "max_bounces: expected an integer"),
    ({"sky_width": 8192}, "sky_width: expected an integer in"),
    ({"exposure": "auto"}, "expected one of light, render"),
    ({"denoise": "yes"}, "expected true or false"),
    ({"sampels": 8}, "unknown cycles renderer setting"),
    ({"light": {"march_steps": 4}}, "cycles renderer setting light: unknown field"),
])
def test_bad_settings_are_usage_errors(kw, words):
    with pytest.raises(UsageError, match=words):
        CyclesSettings.from_kwargs(**kw)


# ----------------------------------------------------------------------------- in Blender
W, H = 64, 48


def _job(light, *, pitch=-25.0):
    """Background and composite requests of a sphere on a floor, with the manifest's
    ``light`` (parsed) and the sphere's own mesh as the occluder."""
    import trimesh

    from zcomp_cli.maps import SceneMaps
    from zcomp_cli.pipeline.lightspec import scene_light
    from zcomp_cli.posed_mesh import PosedMesh
    from zcomp_cli.renderers.base import RenderRequest
    from zcomp_cli.testing import floor_scene, insert_bundle, sphere_object_bundle

    s = floor_scene(W, H, pitch_deg=pitch, light_dir=(0.6, 1.0, 0.3), ambient=0.3)
    centre = s.world_to_camera([0.1, 0.3, -2.6])
    b = sphere_object_bundle(s.camera, centre, 0.3, (0.7, 0.6, 0.5), floor_normal=s.up_cam)
    d, n, a, sel = insert_bundle(s.depth, s.normals, s.albedo, b)
    known = np.ones((H, W), bool)
    known[8:, 4:60] = False
    params = scene_light(light, {"pitch_deg": pitch, "roll_deg": 0.0})
    sph = trimesh.creation.icosphere(subdivisions=3, radius=0.3)
    mesh = PosedMesh(np.asarray(sph.vertices) + np.asarray(centre), np.asarray(sph.faces))
    common = dict(shading=s.shading, known=known, camera=s.camera, roi=(0, 0, W, H), image=s.image,
                  scene_key="s", light=params)
    bg = RenderRequest(SceneMaps(s.depth, s.normals, s.albedo), **common)
    comp = RenderRequest(SceneMaps(d, n, a), **common, occluder=mesh, coverage=sel.astype(np.float32))
    return [bg, comp], sel


def _shadow(images, sel, known):
    bg, comp = (np.asarray(im, np.float64).mean(-1) for im in images)
    return (comp < 0.8 * bg) & ~sel & ~known


def _probe(tmp_path, direction_cam, frame, convention):
    from zcomp_cli.imageio import write_exr

    h, w = 64, 128
    dirs = equirect.pixel_directions(h, w, frame, convention, 0.0)
    sun = dirs @ (np.asarray(direction_cam) / np.linalg.norm(direction_cam)) > np.cos(np.radians(4.0))
    img = np.full((h, w, 3), 0.3, np.float32)
    img[sun] = 400.0
    path = tmp_path / f"probe_{convention}.exr"
    write_exr(path, img)
    return path


@pytest.mark.blender
@pytest.mark.parametrize("kind", ["sun", "probe-zcomp", "probe-mirrored"])
def test_cycles_shadow_falls_where_the_physical_renderers_does(tmp_path, kind):
    """Under one given light, the two transports' cast shadows of the sphere overlap: the
    sun's direction, the probe's lookup (both conventions' rows) and the units reach
    Blender as zcomp means them. A wrong yaw or a mirrored lookup puts Cycles' shadow
    elsewhere (IoU near 0)."""
    from zcomp_cli.pipeline.lightspec import parse_light
    from zcomp_cli.renderers import get_renderer

    up = up_from_pitch_roll(-25.0, 0.0)
    frame = ground_frame(up)
    sun_dir = 0.55 * frame[0] + 0.9 * up + 0.35 * frame[2]  # right, up, a little away
    sun_dir = sun_dir / np.linalg.norm(sun_dir)
    if kind == "sun":
        value = {"direction": sun_dir.tolist(), "angular_radius_deg": 2.0, "strength": 3.0}
    else:
        conv = kind.split("-")[1]
        value = {"type": "probe", "hdr": str(_probe(tmp_path, sun_dir, frame, conv)), "convention": conv}
    probs = []
    params = parse_light(value, "scenes.s.light", lambda c, k, w, m: probs.append((w, m)))
    assert not probs
    reqs, sel = _job(params)
    cyc = get_renderer("cycles", samples=16, denoise=False)
    try:
        out_c = cyc.render(reqs, seed=2)
    finally:
        cyc.close()
    out_p = get_renderer("physical").render(reqs, seed=2)
    known = np.asarray(reqs[0].known)
    sc_, sp = _shadow(out_c.images, sel, known), _shadow(out_p.images, sel, known)
    assert sp.sum() > 20, "the physical renderer draws no shadow: the test scene is wrong"
    iou = (sc_ & sp).sum() / max((sc_ | sp).sum(), 1)
    assert iou > 0.5, f"cycles and physical shadows overlap by IoU {iou:.2f}"
    # known pixels are the photograph's, bit for bit
    for req, im in zip(reqs, out_c.images):
        k = np.asarray(req.known)
        assert np.array_equal(im[k], (req.maps.albedo * req.shading).astype(np.float32)[k])


@pytest.mark.blender
def test_a_dead_blender_fails_no_later_job_and_bad_input_fails_its_own():
    """Blender killed between jobs: the next job starts a fresh one. A job whose object
    file cannot be read fails with Cycles' reason (a RenderError) and the renderer goes on."""
    from zcomp_cli.errors import RenderError
    from zcomp_cli.posed_mesh import PosedMesh
    from zcomp_cli.renderers import get_renderer

    reqs, _ = _job(None)
    r = get_renderer("cycles", samples=2, denoise=False)
    try:
        first = r.render(reqs, seed=1).images
        assert r.render(reqs, seed=1).images[1].shape == (H, W, 3)
        assert r._session.starts == 1  # one Blender for every job of the renderer (a worker)
        r._session.proc.kill()
        r._session.proc.wait()
        again = r.render(reqs, seed=1).images
        for a, b in zip(first, again):
            np.testing.assert_array_equal(a, b)
        assert r._session.starts == 2
        bad = PosedMesh(reqs[1].occluder.vertices, reqs[1].occluder.faces, "/nonexistent/object.glb", np.eye(4))
        import dataclasses

        with pytest.raises(RenderError, match="Cycles failed"):
            r.render([reqs[0], dataclasses.replace(reqs[1], occluder=bad)], seed=1)
        ok = r.render(reqs, seed=1).images
        np.testing.assert_array_equal(ok[1], first[1])
    finally:
        r.close()


@pytest.mark.blender
def test_aovs_bring_cycles_light_passes_that_add_up_to_its_render():
    """With --aovs each pass's Cycles light passes come back as layers; without the
    denoiser they recombine into the render: (diffuse direct + indirect) x diffuse colour
    + (glossy direct + indirect) x glossy colour + emission + environment."""
    import dataclasses

    from zcomp_cli.renderers import get_renderer

    reqs, sel = _job(None)
    reqs = [dataclasses.replace(r, aovs=True) for r in reqs]
    r = get_renderer("cycles", samples=4, denoise=False)
    try:
        out = r.render(reqs, seed=4)
    finally:
        r.close()
    L = out.aov_layers
    for tag in ("bg", "comp"):
        assert {f"cycles_{tag}_{p}" for p in ("diffuse_direct", "diffuse_indirect", "diffuse_color",
                                              "glossy_direct", "glossy_indirect", "glossy_color")} <= set(L)

    def g(name):
        return L.get(f"cycles_comp_{name}", np.zeros((H, W, 3), np.float32)).astype(np.float64)

    total = ((g("diffuse_direct") + g("diffuse_indirect")) * g("diffuse_color")
             + (g("glossy_direct") + g("glossy_indirect")) * g("glossy_color") + g("emission") + g("environment"))
    rendered = ~np.asarray(reqs[1].known)
    np.testing.assert_allclose(total[rendered], out.images[1][rendered], rtol=2e-3, atol=2e-4)
    # without --aovs: none
    r2 = get_renderer("cycles", samples=2, denoise=False)
    try:
        assert r2.render(_job(None)[0], seed=4).aov_layers == {}
    finally:
        r2.close()


def test_a_renderers_aov_layers_are_checked():
    from zcomp_cli.errors import RenderError
    from zcomp_cli.pipeline.job import check_aov_layers

    ok = check_aov_layers({"cycles_x": np.ones((4, 5)), "y3": np.zeros((4, 5, 3))}, (4, 5), "r", {"composite"})
    assert ok["cycles_x"].shape == (4, 5, 1) and ok["y3"].dtype == np.float32
    for bad, words in [({"composite": np.ones((4, 5))}, "named 'composite'"), ({"A b": np.ones((4, 5))}, "named"),
                       ({"x": np.ones((4, 6))}, "of shape"), ({"x": np.ones((4, 5, 2))}, "of shape"),
                       ({"x": np.full((4, 5), np.nan)}, "non-finite")]:
        with pytest.raises(RenderError, match=words):
            check_aov_layers(bad, (4, 5), "r", {"composite"})


def test_the_support_continues_beyond_the_frame_just_below_the_floor():
    from zcomp_cli.scene.depthmesh import build_depth_mesh
    from zcomp_cli.testing import floor_scene

    s = floor_scene(32, 24)
    mesh = build_depth_mesh(s.depth, s.normals, s.camera, s.up_cam)
    arr = sc.scene_mesh_arrays(mesh, s.albedo)
    out = sc.with_ground(arr, mesh, s.albedo)
    V = out["vertices"][-4:].astype(np.float64)
    assert len(out["vertices"]) == len(arr["vertices"]) + 4 and len(out["faces"]) == len(arr["faces"]) + 2
    heights = V @ s.up_cam
    floor = float(np.median(mesh.points[mesh.support] @ s.up_cam))
    assert np.allclose(heights, heights[0]) and floor - 0.1 < heights[0] < floor  # just below the floor
    assert np.abs(V - V.mean(0)).max() >= sc.GROUND_HALF_M * 0.99
    assert np.allclose(out["colors"][-4:], s.albedo[mesh.support].mean(0), atol=1e-6)
    # a mesh without a support gets no plane
    sky = build_depth_mesh(np.zeros((8, 8)), np.zeros((8, 8, 3)), floor_scene(8, 8).camera, s.up_cam)
    assert sc.with_ground({"vertices": np.zeros((0, 3)), "faces": np.zeros((0, 3)), "colors": np.zeros((0, 3))},
                          sky, np.zeros((8, 8, 3)))["vertices"].shape == (0, 3)
