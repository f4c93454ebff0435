"""zcomp make-benchmark: scene description, placement, pass conversion, and a tiny
Blender benchmark (2 cases, 64x48, few samples) checked against analytic geometry."""

from __future__ import annotations

import glob
import importlib.util
import json
import math

import numpy as np
import pytest
import yaml

from zcomp_cli.benchsuite import generate as gen
from zcomp_cli.benchsuite.objects import SHAPES, ObjectRecipe, build_object, shape_mesh, write_object_glb
from zcomp_cli.benchsuite.render import maps_from_passes
from zcomp_cli.blender.intrinsics import blender_camera_from_K as blender_camera
from zcomp_cli.benchsuite.scenes import (BenchScene, Box, Lamp, Material, Wall, cast_shadow_masks,
                                        floor_depth, lamps_for_blender, lights_at, matrix_to_euler_xyz,
                                        occluded, sample_scene, scene_for_blender, scene_geometry)
from zcomp_cli.errors import GeometryError, InputError, UsageError
from zcomp_cli.pose import euler_deg_to_matrix, transform_points

HAS_BPY = importlib.util.find_spec("bpy") is not None


def _scene(**kw):
    base = dict(width=64, height=48, fov_deg=50.0, camera_height=1.5, pitch_deg=20.0,
                walls=(Wall("back", 6.0),), boxes=(Box(1.2, -4.0, (0.4, 0.4, 0.4)),),
                lamps=(Lamp("SUN", (0.3, -1.0, -0.4), 3.0),))
    base.update(kw)
    return BenchScene(**base)


# -- frames and geometry ---------------------------------------------------------------------

@pytest.mark.parametrize("angles", [(10, 20, 30), (-80, 45, 170), (0, 0, 0), (90, 10, -40), (5, -89.9, 3)])
def test_matrix_to_euler_xyz_roundtrip(angles):
    R = euler_deg_to_matrix(*angles)
    ax, ay, az = matrix_to_euler_xyz(R)
    R2 = euler_deg_to_matrix(math.degrees(ax), math.degrees(ay), math.degrees(az))
    np.testing.assert_allclose(R2, R, atol=1e-6)


@pytest.mark.parametrize("pitch", [0.0, 20.0, -35.0])
def test_env_up_maps_to_scene_up(pitch):
    sc = _scene(pitch_deg=pitch, hdr_rotation_deg=73.0)
    M = sc.env_to_camera()
    np.testing.assert_allclose(M @ [0, 0, 1], sc.up, atol=1e-12)
    np.testing.assert_allclose(M @ M.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(M) == pytest.approx(1.0)
    if pitch == 0.0:
        np.testing.assert_allclose(sc.up, [0, 1, 0], atol=1e-12)


def test_floor_depth_is_the_analytic_plane():
    sc = _scene(pitch_deg=0.0)
    fd = floor_depth(sc)
    cam = sc.camera
    # Horizontal camera: rows above the centre see no floor; below, depth = h * fy / (v - cy).
    assert np.all(fd[: cam.height // 2] == 0)
    v = 40 + 0.5
    assert fd[40, 10] == pytest.approx(1.5 * cam.fy / (v - cam.cy), rel=1e-5)
    pts = cam.unproject(fd)[fd > 0]
    n, d = sc.floor_plane
    np.testing.assert_allclose(pts @ n, d, atol=1e-4)


# -- the true lights, as the object and the background see them ------------------------------

def _floor_point(sc, x, z):
    """Camera-frame point of the floor at scene-frame (x, z)."""
    return sc.scene_to_camera @ np.array([x, -sc.camera_height, z])


def test_a_wall_blocks_a_sun_behind_it():
    # The sun shines from behind the back wall (travelling toward the camera, +z): the
    # floor in front of the wall gets none of it; with the wall gone, it does.
    sun = Lamp("SUN", (0.0, -0.5, 1.0), 3.0)
    p = _floor_point(_scene(), 0.0, -3.0)
    blocked = lights_at(_scene(lamps=(sun,), boxes=()), p, with_hdr=False)
    free = lights_at(_scene(lamps=(sun,), boxes=(), walls=()), p, with_hdr=False)
    assert not blocked[0]["visible"] and blocked[0]["floor_irradiance"] == 0.0
    assert free[0]["visible"]
    travel = np.array(sun.direction)
    expected = -(_scene().scene_to_camera @ travel)
    np.testing.assert_allclose(free[0]["direction"], expected, atol=1e-12)
    assert free[0]["floor_irradiance"] == pytest.approx(3.0 * float(expected @ _scene().up))


def test_occluded_rays_and_reach():
    sc = _scene(lamps=(), walls=(Wall("back", 6.0),), boxes=())
    p = np.stack([_floor_point(sc, 0.0, -3.0)] * 2) + 0.05 * sc.up
    toward_wall = sc.scene_to_camera @ np.array([0.0, 0.0, -1.0])
    np.testing.assert_array_equal(occluded(sc, p, toward_wall), [True, True])
    # the wall stands 3 m away: a ray stopping short of it is free
    np.testing.assert_array_equal(occluded(sc, p, toward_wall, np.array([2.5, 3.5])), [False, True])
    np.testing.assert_array_equal(occluded(sc, p, -toward_wall), [False, False])
    assert not occluded(sc, p, toward_wall, parts=("box",)).any()


def test_an_area_lamp_is_seen_from_the_object_not_from_its_aim():
    # A lamp 4 m from its aim point, straight above it: from an object 2 m to the side
    # of the aim, the lamp is up and toward the aim, not straight up.
    lamp = Lamp("AREA", (0.0, -1.0, 0.0), 100.0, distance=4.0, target=(0.0, -1.5, -3.0))
    sc = _scene(lamps=(lamp,), walls=(), boxes=(), pitch_deg=0.0)
    li = lights_at(sc, _floor_point(sc, 2.0, -3.0), with_hdr=False)[0]
    pos = np.array([0.0, 2.5, -3.0])
    to = pos - (_floor_point(sc, 2.0, -3.0) + 0.05 * sc.up)
    np.testing.assert_allclose(li["direction"], to / np.linalg.norm(to), atol=1e-9)
    r = np.linalg.norm(to)
    cos = float(li["direction"] @ sc.up)
    assert li["floor_irradiance"] == pytest.approx(100.0 * cos * cos / (math.pi * r * r), rel=1e-9)


def test_cast_shadow_masks_of_a_box():
    # A sun from the left: the box's shadow lies on the floor to its right, beside it.
    sc = _scene(width=128, height=96, walls=(), lamps=(Lamp("SUN", (1.0, -0.6, 0.0), 3.0),),
                boxes=(Box(0.0, -4.0, (0.6, 0.6, 0.6)),))
    depth = floor_depth(sc)
    (shadowed, lit), = cast_shadow_masks(sc, depth, lamps_for_blender(sc))
    assert shadowed.sum() > 20 and lit.sum() > 1000 and not (shadowed & lit).any()
    pts = sc.camera.unproject(depth)[shadowed] @ sc.scene_to_camera  # back to the scene frame
    # (the analytic floor runs on under the box: leave its footprint out)
    out = pts[(np.abs(pts[:, 0]) > 0.3) | (np.abs(pts[:, 2] + 4.0) > 0.3)]
    assert len(out) > 20 and np.all(out[:, 0] > 0.3) and np.all(np.abs(out[:, 2] + 4.0) < 0.35)


def test_scene_geometry_normals_face_the_camera():
    sc = _scene(walls=(Wall("back", 6.0), Wall("left", 2.0), Wall("right", 3.0)))
    for m in scene_geometry(sc):
        v = np.asarray(m["vertices"])
        f = np.asarray(m["faces"])
        tri = v[f]
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        if m["name"] == "floor":
            np.testing.assert_allclose(n, np.broadcast_to(sc.up, n.shape), atol=1e-9)
            np.testing.assert_allclose(v @ sc.up, -sc.camera_height, atol=1e-9)
        elif m["name"].startswith("wall"):
            # A wall faces the camera at the origin: normal . (centroid - 0) < 0.
            assert np.all(np.einsum("ij,ij->i", n, tri.mean(axis=1)) < 0)
        else:  # a closed box: outward normals, volume positive
            vol = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6
            assert vol == pytest.approx(0.4 ** 3, rel=1e-6)
        assert len(m["uv"]) == len(v)


def test_blender_camera_from_K():
    from zcomp_cli.conventions import K_from_fov

    K = K_from_fov(50, 64, 48)
    c = blender_camera(K, 64, 48)
    assert c["lens_mm"] == pytest.approx(K[0, 0] * 36 / 64)
    assert c["shift_x"] == 0 and c["shift_y"] == 0
    K2 = K.copy()
    K2[0, 2] += 6.4  # principal point to the right -> the image shifts left
    K2[1, 2] += 4.8  # principal point lower -> shift_y positive (fraction of the width)
    c2 = blender_camera(K2, 64, 48)
    assert c2["shift_x"] == pytest.approx(-0.1)
    assert c2["shift_y"] == pytest.approx(0.075)
    with pytest.raises(InputError):
        blender_camera(np.diag([50.0, 60.0, 1.0]), 64, 48)
    with pytest.raises(InputError):
        blender_camera(np.full((3, 3), np.nan), 64, 48)


def test_scene_roundtrip_and_validation():
    rng = np.random.default_rng(3)
    for _ in range(5):
        sc = sample_scene(rng, 64, 48)
        assert BenchScene.from_dict(json.loads(json.dumps(sc.to_dict()))) == sc
    with pytest.raises(InputError):
        Material(color=(1.5, 0, 0))
    with pytest.raises(InputError):
        Lamp("SUN", (0, 0, 0), 1.0)
    with pytest.raises(InputError):
        Wall("ceiling", 3.0)
    with pytest.raises(InputError):
        _scene(pitch_deg=float("nan"))


def test_scene_for_blender_is_json():
    d = scene_for_blender(_scene())
    d2 = json.loads(json.dumps(d))
    assert d2["width"] == 64 and d2["hdr"] == "courtyard"
    assert len(d2["meshes"]) == 3 and d2["lamps"][0]["kind"] == "SUN"


# -- objects ---------------------------------------------------------------------------------

@pytest.mark.parametrize("shape", SHAPES)
def test_shapes_stand_on_the_origin_one_metre_tall(shape):
    m = shape_mesh(shape, 0.6)
    lo, hi = m.bounds
    assert hi[1] - lo[1] == pytest.approx(1.0)
    assert lo[1] == pytest.approx(0.0, abs=1e-9)
    assert (lo[0] + hi[0]) / 2 == pytest.approx(0.0, abs=1e-9)
    assert (lo[2] + hi[2]) / 2 == pytest.approx(0.0, abs=1e-9)
    assert np.all(np.isfinite(m.vertices))


def test_textured_glb_carries_uv_and_texture(tmp_path):
    import trimesh

    p = write_object_glb(ObjectRecipe("box", texture="checker"), tmp_path / "crate.glb")
    scene = trimesh.load(p, force="scene")
    geom = list(scene.geometry.values())[0]
    assert geom.visual.uv is not None and len(geom.visual.uv) == len(geom.vertices)
    img = geom.visual.material.baseColorTexture
    assert img is not None and np.asarray(img).std() > 10  # two colours, not flat
    plain = build_object(ObjectRecipe("cylinder", color=(0.2, 0.4, 0.6)))
    np.testing.assert_allclose(np.asarray(plain.visual.material.baseColorFactor[:3]) / 255.0,
                               [0.2, 0.4, 0.6], atol=1 / 255)
    with pytest.raises(InputError):
        ObjectRecipe("teapot")


# -- placement, exposure, masks ----------------------------------------------------------------

def test_place_on_floor_stands_in_frame():
    sc = _scene()
    m = shape_mesh("chair", 0.5)
    rng = np.random.default_rng(0)
    cam = sc.camera
    for _ in range(10):
        pose = gen.place_on_floor(sc, m.vertices, *m.bounds, rng, frame_fraction=(0.15, 0.35))
        n, d = sc.floor_plane
        assert float(np.dot(n, pose.position)) == pytest.approx(d, abs=1e-9)  # base on the floor
        np.testing.assert_allclose(pose.up, sc.up, atol=1e-9)  # stands upright
        p = transform_points(pose.object_to_camera(*m.bounds), m.vertices)
        assert float((p @ n).min()) == pytest.approx(d, abs=1e-9)  # touches, not sunk
        px, depth = cam.project(p)
        assert np.all(depth > 0)
        assert px[:, 0].min() >= 0 and px[:, 0].max() <= cam.width
        assert px[:, 1].min() >= 0 and px[:, 1].max() <= cam.height
        assert 0.08 <= pose.height <= 2.5


def test_place_on_floor_impossible_raises():
    sc = _scene(walls=(Wall("back", 0.3),))  # a wall right in front of the camera
    m = shape_mesh("box")
    with pytest.raises(GeometryError):
        gen.place_on_floor(sc, m.vertices, *m.bounds, np.random.default_rng(0), tries=30)


def test_exposure_scale_guards():
    img = np.zeros((10, 10, 3), np.float32)
    assert gen.exposure_scale(img) == 1.0
    img[:] = 0.4
    assert gen.exposure_scale(img, 0.8) == pytest.approx(2.0, rel=1e-5)
    img[0, 0] = np.nan
    assert gen.exposure_scale(img, 0.8) == pytest.approx(2.0, rel=1e-5)
    assert gen.exposure_scale(np.full((4, 4, 3), 1e4, np.float32), 0.8) == 1e-3  # 8e-5 clamped
    assert gen.exposure_scale(np.full((4, 4, 3), 100.0, np.float32), 0.8) == pytest.approx(8e-3, rel=1e-5)
    assert gen.exposure_scale(np.full((4, 4, 3), 1e-7, np.float32), 0.8) == 1e3
    with pytest.raises(InputError):
        gen.exposure_scale(np.zeros((4, 4)))


def test_object_mask():
    bg = np.array([[2.0, 2.0, 0.0, 3.0]])
    gt = np.array([[1.0, 2.0, 5.0, 0.0]])
    np.testing.assert_array_equal(gen.object_mask(bg, gt), [[True, False, True, False]])


def test_maps_from_passes_conventions():
    h, w = 3, 4
    z = np.full((h, w), 2.0, np.float32)
    z[0, 0] = 1e10
    z[0, 1] = np.nan
    n = np.zeros((h, w, 3), np.float32)
    n[..., 1] = 2.0  # unnormalised up
    beauty = {f"Combined.{c}": np.full((h, w), 0.5, np.float32) for c in "RGBA"}
    beauty.update({f"albedo.{c}": np.full((h, w), 0.3, np.float32) for c in "RGB"})
    beauty["Combined.R"][1, 1] = np.inf
    geometry = {"Depth.Z": z, **{f"Normal.{c}": n[..., i] for i, c in enumerate("XYZ")}}
    maps = maps_from_passes(beauty, geometry)
    assert maps.depth[0, 0] == 0 and maps.depth[0, 1] == 0 and maps.depth[2, 2] == 2.0
    np.testing.assert_allclose(maps.normals[2, 2], [0, 1, 0])
    np.testing.assert_array_equal(maps.normals[0, 0], [0, 0, 0])
    assert np.all(np.isfinite(maps.image)) and maps.image.dtype == np.float32
    assert maps.albedo.shape == (h, w, 3)
    from zcomp_cli.errors import RenderError

    with pytest.raises(RenderError):
        maps_from_passes({}, geometry)


def test_settings_validation():
    with pytest.raises(UsageError):
        gen.BenchmarkSettings(n=0)
    with pytest.raises(UsageError):
        gen.BenchmarkSettings(resolution=(8, 8))
    with pytest.raises(UsageError):
        gen.BenchmarkSettings(shapes=(), object_paths=())
    with pytest.raises(UsageError):
        gen.BenchmarkSettings(samples=0)


def test_plan_is_deterministic_for_a_seed(tmp_path):
    s = gen.BenchmarkSettings(n=3, seed=11, resolution=(64, 48), samples=2)

    def summary(plans):
        return [(p.id, p.seed, p.scene.to_dict(), p.object_name, p.pose.to_dict()) for p in plans]

    a = summary(gen.plan_benchmark(s, tmp_path / "a"))
    b = summary(gen.plan_benchmark(s, tmp_path / "b"))
    assert json.dumps(a) == json.dumps(b)
    c = summary(gen.plan_benchmark(gen.BenchmarkSettings(n=3, seed=12, resolution=(64, 48)), tmp_path / "c"))
    assert json.dumps(a) != json.dumps(c)
    # The GLBs written for the same seed are byte-identical.
    for f in sorted((tmp_path / "a" / "objects").glob("*.glb")):
        assert f.read_bytes() == (tmp_path / "b" / "objects" / f.name).read_bytes()


def test_user_mesh_is_used(tmp_path):
    import trimesh

    mesh = trimesh.creation.box(extents=[0.4, 0.8, 0.3])
    path = tmp_path / "user_box.obj"
    mesh.export(path)
    s = gen.BenchmarkSettings(n=2, seed=1, resolution=(64, 48), shapes=(), object_paths=(str(path),))
    plans = gen.plan_benchmark(s, tmp_path / "out")
    assert all(p.mesh_path == path.resolve() and p.object_name == "user_box" for p in plans)
    with pytest.raises(InputError):
        gen.plan_benchmark(gen.BenchmarkSettings(n=1, object_paths=(str(tmp_path / "missing.obj"),)), tmp_path)


def test_refuses_to_overwrite(tmp_path):
    (tmp_path / "jobs.yaml").write_text("x")
    with pytest.raises(UsageError):
        gen._prepare_out(tmp_path, overwrite=False)
    gen._prepare_out(tmp_path, overwrite=True)
    assert not (tmp_path / "jobs.yaml").exists()


# -- the tiny benchmark, rendered by Blender ---------------------------------------------------

@pytest.fixture(scope="module")
def tiny_bench(tmp_path_factory):
    if not HAS_BPY:
        pytest.skip("bpy not installed")
    out = tmp_path_factory.mktemp("bench")
    s = gen.BenchmarkSettings(n=2, seed=5, resolution=(64, 48), samples=8, denoise=False, max_bounces=4)
    res = gen.generate_benchmark(out, s, overwrite=True)
    return out, res


def _read(p):
    from zcomp_cli.imageio import read_map

    return read_map(p)


@pytest.mark.blender
@pytest.mark.slow
def test_tiny_benchmark_files_and_manifest(tiny_bench):
    out, res = tiny_bench
    bench = json.loads((out / "benchmark.json").read_text())
    assert len(bench["cases"]) == 2
    for c in bench["cases"]:
        for key, rel in c["files"].items():
            assert (out / rel).is_file(), key
        img = _read(out / c["files"]["image"])
        assert img.shape == (48, 64, 3) and np.all(np.isfinite(img)) and img.max() > 0
        assert _read(out / c["files"]["depth"]).shape == (48, 64)
        assert c["exposure"] > 0 and 0 < c["object_pixels_fraction"] < 0.5
    doc = yaml.safe_load((out / "jobs.yaml").read_text())
    assert doc["version"] == 1 and doc["defaults"]["resolution"] == [64, 48]
    assert len(doc["jobs"]) == 2
    for job in doc["jobs"]:
        assert (out / job["reference"]).is_file() and job["reference"].endswith("gt.exr")
        assert job["scene"] in doc["scenes"] and job["object"] in doc["objects"]
    from zcomp_cli.pipeline.manifest import load_manifest

    m = load_manifest(out / "jobs.yaml")
    assert len(m.jobs) == 2 and all(j.reference is not None and j.pose is not None for j in m.jobs)


@pytest.mark.blender
@pytest.mark.slow
def test_tiny_benchmark_maps_follow_the_conventions(tiny_bench):
    out, _ = tiny_bench
    bench = json.loads((out / "benchmark.json").read_text())
    for c in bench["cases"]:
        sc = BenchScene.from_dict(c["scene"])
        depth = _read(out / c["files"]["depth"])
        normals = _read(out / c["files"]["normals"])
        albedo = _read(out / c["files"]["albedo"])
        fd = floor_depth(sc)
        # The bottom-centre pixel always sees the floor (boxes stand far off-centre).
        assert depth[-1, 32] == pytest.approx(fd[-1, 32], rel=1e-4)
        on_floor = (fd > 0) & (np.abs(depth - fd) < 1e-4 * fd)
        assert on_floor.mean() > 0.3
        np.testing.assert_allclose(normals[on_floor], np.broadcast_to(sc.up, normals[on_floor].shape), atol=1e-3)
        valid = depth > 0
        np.testing.assert_allclose(np.linalg.norm(normals[valid], axis=-1), 1.0, atol=1e-4)
        assert np.all(normals[~valid] == 0)
        if sc.floor.checker_color is None:
            # Albedo is anti-aliased (soft coverage): compare away from other surfaces.
            from scipy.ndimage import binary_erosion

            inner = binary_erosion(on_floor, iterations=2)
            np.testing.assert_allclose(albedo[inner], np.broadcast_to(sc.floor.color, albedo[inner].shape),
                                       atol=2e-3)
        assert albedo.min() >= 0 and albedo.max() <= 1


@pytest.mark.blender
@pytest.mark.slow
def test_tiny_benchmark_gt_places_the_object_and_differs_only_near_it(tiny_bench):
    import trimesh

    out, _ = tiny_bench
    bench = json.loads((out / "benchmark.json").read_text())
    for c in bench["cases"]:
        sc = BenchScene.from_dict(c["scene"])
        cam = sc.camera
        gt_depth = _read(out / c["files"]["gt_depth"])
        mask = _read(out / c["files"]["object_mask"]) > 0.5
        assert mask.sum() >= 10
        # The object seen in the GT lies on the posed mesh's surface.
        mesh = trimesh.load(out / c["object"]["mesh"], force="mesh")
        M = np.asarray(c["object_to_camera"])
        mesh.apply_transform(M)
        pts = cam.unproject(gt_depth)[mask]
        # Distance to a dense surface sampling (no rtree needed); the sampling spacing
        # bounds the error of this distance.
        from scipy.spatial import cKDTree

        samples, _ = trimesh.sample.sample_surface(mesh, 60000, seed=0)
        spacing = math.sqrt(mesh.area / 60000)
        dist, _ = cKDTree(samples).query(pts)
        height = c["pose"]["height"]
        assert np.max(dist) < 0.01 * height + 2 * spacing
        # And where the posed mesh projects, the mask is (nearly) everywhere.
        px, _ = cam.project(mesh.vertices)
        x0, y0 = np.floor(px.min(axis=0)).astype(int)
        x1, y1 = np.ceil(px.max(axis=0)).astype(int)
        ys, xs = np.nonzero(mask)
        assert xs.min() >= x0 - 1 and xs.max() <= x1 and ys.min() >= y0 - 1 and ys.max() <= y1
        # GT = background away from the object and its shadow (same seed, same noise).
        img = _read(out / c["files"]["image"])
        gt = _read(out / c["files"]["gt"])
        diff = np.abs(gt - img).mean(axis=-1)
        hpx = max(y1 - y0, 2)
        near = np.zeros_like(mask)
        near[max(0, y0 - 2 * hpx):y1 + 2 * hpx, max(0, x0 - 2 * hpx):x1 + 2 * hpx] = True
        far = ~near
        if far.sum() > 50:
            assert np.median(diff[far]) <= 1e-3 * max(img.mean(), 1e-3)
            assert diff[far].mean() < 0.05 * img.mean()
        assert diff[mask].mean() > 10 * max(np.median(diff[far]) if far.any() else 0, 1e-6)


@pytest.mark.blender
@pytest.mark.slow
def test_environment_map_is_turned_to_the_scene_up(tmp_path):
    """Render only the sky and compare with the HDR file sampled in numpy along
    camera->env directions: checks the Mapping node's Euler convention end to end."""
    if not HAS_BPY:
        pytest.skip("bpy not installed")
    from zcomp_cli.benchsuite.render import render_scenes
    from zcomp_cli.blender.passes import read_multilayer_exr
    from zcomp_cli.imageio import read_map

    sc = BenchScene(width=48, height=32, fov_deg=90.0, pitch_deg=-25.0, hdr="courtyard",
                    hdr_rotation_deg=70.0, hdr_strength=1.0)
    desc = scene_for_blender(sc)
    desc["meshes"] = []
    render_scenes([{"id": "sky", "out_dir": str(tmp_path), "samples": 1, "seed": 0, "scene": desc,
                    "object": None}])
    # The 1-sample pixel-centre render: exact env lookups.
    ch = read_multilayer_exr(tmp_path / "geometry.exr")
    rendered = np.stack([ch["Combined.R"], ch["Combined.G"], ch["Combined.B"]], -1)
    root = importlib.util.find_spec("bpy").submodule_search_locations[0]
    env = read_map(glob.glob(f"{root}/*/datafiles/studiolights/world/courtyard.exr")[0])
    H, W = env.shape[:2]
    rays = sc.camera.pixel_rays()
    rays /= np.linalg.norm(rays, axis=-1, keepdims=True)

    def lookup(cam_to_env):
        d = rays @ cam_to_env.T
        u = 0.5 - np.arctan2(d[..., 1], d[..., 0]) / (2 * np.pi)  # Blender's equirectangular
        v = 0.5 + np.arcsin(np.clip(d[..., 2], -1, 1)) / np.pi
        col = np.clip((u * W).astype(int), 0, W - 1)
        row = np.clip(((1 - v) * H).astype(int), 0, H - 1)
        return env[row, col]

    good = np.abs(np.log((lookup(sc.env_to_camera().T) + 1e-3) / (rendered + 1e-3)))
    wrong = np.abs(np.log((lookup(np.eye(3)) + 1e-3) / (rendered + 1e-3)))  # env left Z-up
    assert np.median(good) < 0.1
    assert np.median(wrong) > 3 * np.median(good)


def test_cli_usage_errors(tmp_path):
    from zcomp_cli.cli import main

    with pytest.raises(SystemExit) as e:
        main(["make-benchmark", str(tmp_path / "b"), "--n", "0"])
    assert e.value.code == 2
    (tmp_path / "b").mkdir()
    (tmp_path / "b" / "jobs.yaml").write_text("version: 1\n")
    with pytest.raises(SystemExit) as e:  # refuses to overwrite without --overwrite
        main(["make-benchmark", str(tmp_path / "b"), "--n", "1"])
    assert e.value.code == 2
    assert (tmp_path / "b" / "jobs.yaml").read_text() == "version: 1\n"


def test_lights_setting_is_checked():
    from zcomp_cli.benchsuite.generate import BenchmarkSettings
    from zcomp_cli.errors import UsageError

    assert BenchmarkSettings(lights="probe").lights == "probe"
    with pytest.raises(UsageError, match="--lights must be mixed or probe"):
        BenchmarkSettings(lights="suns")


def _rerender_clean():
    """``benchmarks/rerender_clean.py`` as a module (it imports the project lazily)."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    import rerender_clean

    return rerender_clean


def test_rerender_clean_refuses_bad_input_before_writing(tmp_path):
    rr = _rerender_clean()
    assert rr.parse_cases("7, 4,4") == [4, 7]
    for bad in ("", "a,b", "-1"):
        with pytest.raises(SystemExit, match="--cases"):
            rr.parse_cases(bad)
    with pytest.raises(SystemExit, match="no benchmark.json"):
        rr.main([str(tmp_path), str(tmp_path / "out"), "--cases", "0"])
    bench = tmp_path / "b"
    bench.mkdir()
    (bench / "benchmark.json").write_text(json.dumps({"settings": {"n": 2, "seed": 5, "resolution": [64, 48]},
                                                      "cases": []}))
    with pytest.raises(SystemExit, match=r"has 2 cases \(0..1\)"):
        rr.main([str(bench), str(tmp_path / "out"), "--cases", "2"])
    with pytest.raises(SystemExit, match="--samples"):
        rr.main([str(bench), str(tmp_path / "out"), "--cases", "0", "--samples", "0"])
    assert not (tmp_path / "out").exists()


@pytest.mark.blender
@pytest.mark.slow
def test_rerender_clean_renders_the_chosen_background_again(tiny_bench, tmp_path):
    """The chosen case's background is rendered again with the sky's radiance scaled, its
    geometry passes kept; the other case and the original benchmark are untouched."""
    out, _ = tiny_bench
    before = {p: p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()}
    copy = tmp_path / "clean"
    rr = _rerender_clean()
    assert rr.main([str(out), str(copy), "--cases", "1", "--samples", "4", "--sky-scale", "0"]) == 0
    assert {p: p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()} == before
    bench = json.loads((copy / "benchmark.json").read_text())
    c0, c1 = bench["cases"]
    assert "rerendered" not in c0 and c1["rerendered"]["sky_scale"] == 0 and not c1["rerendered"]["denoise"]
    assert (copy / c0["files"]["image"]).read_bytes() == (out / c0["files"]["image"]).read_bytes()
    old, new = _read(out / c1["files"]["image"]), _read(copy / c1["files"]["image"])
    assert new.shape == old.shape and np.all(np.isfinite(new))
    assert not np.allclose(new, old)
    assert (copy / c1["files"]["depth"]).read_bytes() == (out / c1["files"]["depth"]).read_bytes()
