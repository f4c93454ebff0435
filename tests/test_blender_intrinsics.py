"""Object intrinsics through Blender: numpy conversions, mesh checks, cache, and one
small Blender batch checked against geometry (ray casting the placed mesh)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from zcomp_cli.blender import cache as icache
from zcomp_cli.blender import intrinsics as ii
from zcomp_cli.blender.intrinsics import (
    IntrinsicsRequest,
    blender_camera_from_K,
    footprint_matrix,
    render_object_intrinsics,
)
from zcomp_cli.blender.meshes import check_in_view, content_hash, load_mesh_info, mesh_format
from zcomp_cli.blender.passes import (
    appearance_maps,
    footprint_depth,
    geometry_maps,
    read_multilayer_exr,
    unpremultiply,
)
from zcomp_cli.bundle import ObjectBundle
from zcomp_cli.camera import Camera
from zcomp_cli.conventions import srgb_to_linear
from zcomp_cli.errors import GeometryError, InputError
from zcomp_cli.pose import Pose, euler_deg_to_matrix, transform_points

import trimesh  # noqa: E402  (a hard dependency: a missing one must fail, not skip)


# ------------------------------------------------------------------------------------
# mesh fixtures
# ------------------------------------------------------------------------------------
def _box(extents=(1.0, 1.0, 1.0), offset=(0.0, 0.0, 0.0)):
    m = trimesh.creation.box(extents=extents)
    m.apply_translation(offset)
    return m


def _write_obj(path: Path, mesh, kd=None) -> Path:
    lines = []
    if kd is not None:
        path.with_suffix(".mtl").write_text(f"newmtl paint\nKd {kd[0]} {kd[1]} {kd[2]}\n")
        lines.append(f"mtllib {path.with_suffix('.mtl').name}")
    lines += [f"v {x!r} {y!r} {z!r}" for x, y, z in mesh.vertices]
    if kd is not None:
        lines.append("usemtl paint")
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in mesh.faces]
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture(scope="module")
def meshes(tmp_path_factory):
    d = tmp_path_factory.mktemp("meshes")
    # asymmetric and off-origin, so that any axis or placement mistake shows
    odd = _box((0.6, 1.0, 0.4), (2.0, 1.0, -1.0))
    paths = {}
    paths["obj"] = _write_obj(d / "odd.obj", odd)
    for ext in ("glb", "ply", "stl"):
        odd.export(d / f"odd.{ext}")
        paths[ext] = d / f"odd.{ext}"
    # the same box as a glTF node transform (rotation + translation) over a centred mesh
    T = trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0])
    T[:3, 3] = (2.0, 1.0, -1.0)
    sc = trimesh.Scene()
    sc.add_geometry(_box((0.4, 1.0, 0.6)), transform=T)
    sc.export(d / "node.glb")
    paths["node"] = d / "node.glb"
    cube = _box()
    cube.export(d / "cube.glb")
    paths["cube"] = d / "cube.glb"
    vc = cube.copy()
    vc.visual.vertex_colors = np.tile([255, 128, 0, 255], (len(vc.vertices), 1)).astype(np.uint8)
    vc.export(d / "vcol.ply")
    paths["vcol"] = d / "vcol.ply"
    paths["mtl"] = _write_obj(d / "paint.obj", cube, kd=(0.2, 0.4, 0.6))
    from PIL import Image

    tex = cube.copy()
    mat = trimesh.visual.material.PBRMaterial(
        baseColorTexture=Image.new("RGB", (4, 4), (64, 128, 192)), baseColorFactor=[255, 255, 255, 255],
        metallicFactor=0.0, roughnessFactor=0.5)
    tex.visual = trimesh.visual.TextureVisuals(uv=np.full((len(tex.vertices), 2), 0.5), material=mat)
    tex.export(d / "tex.glb")
    paths["tex"] = d / "tex.glb"
    metal = cube.copy()
    metal.visual = trimesh.visual.TextureVisuals(material=trimesh.visual.material.PBRMaterial(
        baseColorFactor=[230, 180, 60, 255], metallicFactor=1.0, roughnessFactor=0.2))
    metal.export(d / "metal.glb")
    paths["metal"] = d / "metal.glb"
    # OBJ + MTL + PNG texture (map_Kd), every vertex at the texture's centre
    Image.new("RGB", (4, 4), (200, 100, 50)).save(d / "paint.png")
    (d / "texobj.mtl").write_text("newmtl t\nKd 1 1 1\nmap_Kd paint.png\n")
    obj = ["mtllib texobj.mtl"] + [f"v {x!r} {y!r} {z!r}" for x, y, z in cube.vertices] + ["vt 0.5 0.5", "usemtl t"]
    obj += [f"f {a + 1}/1 {b + 1}/1 {c + 1}/1" for a, b, c in cube.faces]
    (d / "texobj.obj").write_text("\n".join(obj) + "\n")
    paths["texobj"] = d / "texobj.obj"
    (d / "corrupt.glb").write_bytes(b"glTF\x02\x00\x00\x00garbage" * 3)
    paths["corrupt"] = d / "corrupt.glb"
    (d / "cube.fbx").write_text("x")
    paths["fbx"] = d / "cube.fbx"
    paths["missing"] = d / "nope.obj"
    paths["odd_mesh"] = odd
    return paths


# ------------------------------------------------------------------------------------
# Blender camera from K, footprint placement
# ------------------------------------------------------------------------------------
def test_blender_camera_from_K_centred_and_shifted():
    K = Camera.from_fov(90.0, 64, 48).K  # fx = 32
    c = blender_camera_from_K(K, 64, 48)
    assert c["lens_mm"] == pytest.approx(18.0) and c["sensor_width_mm"] == 36.0
    assert c["shift_x"] == pytest.approx(0.0) and c["shift_y"] == pytest.approx(0.0)
    K2 = np.array([[60.0, 0, 28.0], [0, 60.0, 27.0], [0, 0, 1]])
    c2 = blender_camera_from_K(K2, 64, 48)
    assert c2["shift_x"] == pytest.approx(4.0 / 64) and c2["shift_y"] == pytest.approx(3.0 / 64)
    assert c2["lens_mm"] == pytest.approx(60 * 36 / 64)


@pytest.mark.parametrize("K,match", [
    ([[60, 0, 32], [0, 61, 24], [0, 0, 1]], "non-square"),
    ([[60, 1, 32], [0, 60, 24], [0, 0, 1]], "skew"),
    ([[-60, 0, 32], [0, -60, 24], [0, 0, 1]], "positive"),
    ([[np.nan, 0, 32], [0, 60, 24], [0, 0, 1]], "finite"),
])
def test_blender_camera_from_K_rejects(K, match):
    with pytest.raises(InputError, match=match):
        blender_camera_from_K(np.array(K, dtype=float), 64, 48)


def test_footprint_matrix_lands_on_support_plane():
    bmin, bmax = np.array([1.0, 0.5, -2.0]), np.array([2.0, 3.5, -1.0])
    pose = Pose(position=(0.3, -0.8, -4.0), rotation=euler_deg_to_matrix(20, 40, -10), height=1.2)
    M = pose.object_to_camera(bmin, bmax)
    F = footprint_matrix(M, bmin)
    pts = np.random.default_rng(0).uniform(bmin, bmax, size=(200, 3))
    flat = transform_points(F, pts)
    # every flattened point is on the plane through the base point perpendicular to up
    dist = (flat - np.asarray(pose.position)) @ pose.up
    assert np.max(np.abs(dist)) < 1e-5
    # and is the orthogonal projection of the placed point onto that plane
    placed = transform_points(M, pts)
    proj = placed - ((placed - pose.position) @ pose.up)[:, None] * pose.up
    np.testing.assert_allclose(flat, proj, atol=1e-5)


# ------------------------------------------------------------------------------------
# pass conversions
# ------------------------------------------------------------------------------------
def test_unpremultiply_known_values_and_extremes():
    v = np.array([[[0.4, 0.2, 0.1], [0.0, 0.0, 0.0]], [[np.nan, 1e4, np.inf], [0.3, 0.3, 0.3]]], dtype=np.float32)
    a = np.array([[0.5, 0.0], [0.5, 1e-6]], dtype=np.float32)
    out = unpremultiply(v, a)
    np.testing.assert_allclose(out[0, 0], [0.8, 0.4, 0.2], rtol=1e-6)
    np.testing.assert_array_equal(out[0, 1], 0.0)
    np.testing.assert_allclose(out[1, 0], [0.0, 2e4, 0.0])
    np.testing.assert_array_equal(out[1, 1], 0.0)  # below eps: empty, not 0.3 / 1e-6
    assert out.dtype == np.float32 and np.all(np.isfinite(out))
    np.testing.assert_allclose(unpremultiply(np.full((2, 2), 0.25), np.full((2, 2), 0.5)), 0.5)
    with pytest.raises(ValueError):
        unpremultiply(np.zeros((2, 2, 3)), np.zeros((3, 2)))


def _channels(alpha, z, n, albedo=None):
    ch = {"Combined.A": np.asarray(alpha, np.float32), "Depth.Z": np.asarray(z, np.float32)}
    for i, c in enumerate("XYZ"):
        ch[f"Normal.{c}"] = np.asarray(n, np.float32)[..., i]
    if albedo is not None:
        for i, c in enumerate("RGB"):
            ch[f"albedo.{c}"] = np.asarray(albedo, np.float32)[..., i]
        ch["albedo.A"] = np.asarray(alpha, np.float32)
    return ch


def test_geometry_maps_empty_depth_and_normals():
    alpha = [[1.0, 0.0], [1.0, 1.0]]
    z = [[2.5, 1e10], [np.nan, 3.0]]
    n = [[[0, 0, 2.0], [0, 0, 0]], [[0, 1, 0], [3.0, 0, 4.0]]]
    depth, normals, hit = geometry_maps(_channels(alpha, z, n))
    np.testing.assert_array_equal(depth, [[2.5, 0.0], [0.0, 3.0]])
    np.testing.assert_array_equal(hit, [[True, False], [False, True]])
    np.testing.assert_allclose(normals[0, 0], [0, 0, 1])
    np.testing.assert_allclose(normals[1, 1], [0.6, 0, 0.8], atol=1e-6)
    np.testing.assert_array_equal(normals[0, 1], 0.0)
    np.testing.assert_array_equal(normals[1, 0], 0.0)  # NaN depth: no normal either
    # a rotated Blender camera: world normals are rotated into its frame
    M = np.eye(4)
    M[:3, :3] = euler_deg_to_matrix(0, 90, 0)
    _, n2, _ = geometry_maps(_channels([[1.0]], [[1.0]], [[[1.0, 0, 0]]]), cam_to_world=M)
    np.testing.assert_allclose(n2[0, 0], [0, 0, 1], atol=1e-6)
    # footprint depth is the same depth conversion
    np.testing.assert_array_equal(footprint_depth(_channels(alpha, z, n)), depth)


def test_appearance_maps_unpremultiplies_albedo():
    alpha = np.array([[1.0, 0.5, 0.0]], np.float32)
    albedo = np.array([[[0.2, 0.4, 0.6], [0.1, 0.2, 0.3], [0.0, 0.0, 0.0]]], np.float32)
    ch = _channels(alpha, np.ones((1, 3)), np.zeros((1, 3, 3)), albedo)
    ch["metallic.X"] = np.array([[1.0, 0.5, 0.0]], np.float32)
    out = appearance_maps(ch)
    np.testing.assert_allclose(out["albedo"][0, 1], [0.2, 0.4, 0.6], rtol=1e-6)
    np.testing.assert_array_equal(out["albedo"][0, 2], 0.0)
    np.testing.assert_allclose(out["metallic"][0], [1.0, 1.0, 0.0])
    np.testing.assert_array_equal(out["mask"], alpha)
    assert "roughness" not in out


def test_read_multilayer_exr_multi_part(tmp_path):
    import OpenImageIO as oiio

    p = tmp_path / "ml.exr"
    a = np.arange(12, dtype=np.float32).reshape(3, 4, 1)
    b = np.random.default_rng(0).random((3, 4, 3)).astype(np.float32)
    s1 = oiio.ImageSpec(4, 3, 1, oiio.FLOAT)
    s1.channelnames = ("ViewLayer.Depth.Z",)
    s1.attribute("name", "ViewLayer.Depth")
    s2 = oiio.ImageSpec(4, 3, 3, oiio.FLOAT)
    s2.channelnames = ("ViewLayer.Normal.X", "ViewLayer.Normal.Y", "ViewLayer.Normal.Z")
    s2.attribute("name", "ViewLayer.Normal")
    out = oiio.ImageOutput.create(str(p))
    assert out.open(str(p), [s1, s2])
    out.write_image(a)
    assert out.open(str(p), s2, "AppendSubimage")
    out.write_image(b)
    out.close()
    ch = read_multilayer_exr(p)
    np.testing.assert_array_equal(ch["Depth.Z"], a[..., 0])
    np.testing.assert_array_equal(ch["Normal.Y"], b[..., 1])
    with pytest.raises(InputError):
        read_multilayer_exr(tmp_path / "nope.exr")


# ------------------------------------------------------------------------------------
# meshes and placement checks
# ------------------------------------------------------------------------------------
def test_mesh_format_and_load_errors(meshes, tmp_path):
    assert mesh_format("a/B.GLB") == "gltf" and mesh_format("x.stl") == "stl"
    with pytest.raises(InputError, match="unknown mesh format '.fbx'"):
        load_mesh_info(meshes["fbx"])
    with pytest.raises(InputError, match="not found") as ei:
        load_mesh_info(meshes["missing"])
    assert "nope.obj" in str(ei.value)
    with pytest.raises(InputError, match="corrupt.glb"):
        load_mesh_info(meshes["corrupt"])
    (tmp_path / "empty.stl").write_bytes(b"")
    with pytest.raises(InputError):
        load_mesh_info(tmp_path / "empty.stl")
    trimesh.PointCloud(np.random.default_rng(0).random((10, 3))).export(tmp_path / "pc.ply")
    with pytest.raises(InputError, match="no faces"):
        load_mesh_info(tmp_path / "pc.ply")


def test_mesh_bbox_is_the_same_for_every_format(meshes):
    want_min, want_max = np.array([1.7, 0.5, -1.2]), np.array([2.3, 1.5, -0.8])
    for ext in ("obj", "glb", "ply", "stl", "node"):
        info = load_mesh_info(meshes[ext])
        np.testing.assert_allclose(info.bbox_min, want_min, atol=1e-6, err_msg=ext)
        np.testing.assert_allclose(info.bbox_max, want_max, atol=1e-6, err_msg=ext)


def test_content_hash_follows_mtl(meshes, tmp_path):
    m = _box()
    a = _write_obj(tmp_path / "a.obj", m, kd=(0.1, 0.2, 0.3))
    h1 = content_hash(a)
    assert h1 == content_hash(a) and len(h1) == 64
    _write_obj(tmp_path / "a.obj", m, kd=(0.1, 0.2, 0.4))  # only the MTL changes
    assert content_hash(a) != h1


def test_check_in_view():
    cam = Camera.from_fov(50.0, 64, 48)
    cube = np.array(np.meshgrid([-0.5, 0.5], [-0.5, 0.5], [-0.5, 0.5])).reshape(3, -1).T
    check_in_view(cube + [0, 0, -3], cam)  # in front: fine
    check_in_view(cube + [0, 0, -0.2], cam)  # straddles the camera plane: fine
    with pytest.raises(GeometryError, match="behind"):
        check_in_view(cube + [0, 0, 3], cam)
    with pytest.raises(GeometryError, match="outside"):
        check_in_view(cube + [50, 0, -3], cam)  # far to the right
    with pytest.raises(GeometryError, match="outside"):
        check_in_view(cube + [0, -40, -3], cam)  # far below


# ------------------------------------------------------------------------------------
# cache
# ------------------------------------------------------------------------------------
def test_cache_key_sensitivity():
    base = dict(mesh_hash="ab", pose={"position": [0.0, 0.0, -3.0]}, K=np.eye(3), resolution=(64, 48),
                settings={"samples": 16}, version="1")
    k = icache.cache_key(**base)
    assert k == icache.cache_key(**{**base, "pose": {"position": [0.0, 1e-14, -3.0]}})
    for change in ({"mesh_hash": "ac"}, {"pose": {"position": [0.0, 0.0, -3.001]}}, {"resolution": (64, 49)},
                   {"settings": {"samples": 17}}, {"version": "2"}, {"K": np.diag([1.0, 1.0, 2.0])}):
        assert icache.cache_key(**{**base, **change}) != k, change


def _tiny_bundle(folder, with_rough=False):
    cam = Camera.from_fov(50, 4, 3)
    z = np.ones((3, 4), np.float32)
    ObjectBundle(depth=z, normals=np.zeros((3, 4, 3)), albedo=np.zeros((3, 4, 3)), mask=z, footprint_depth=z,
                 camera=cam, meta={"x": 1}, roughness=z if with_rough else None).save(folder)


def test_cache_lookup_ignores_incomplete_and_copy_cleans_stale(tmp_path):
    key = "ff" + "0" * 62
    entry = icache.entry_dir(tmp_path / "c", key)
    _tiny_bundle(entry)
    assert icache.lookup(tmp_path / "c", key) is None  # no recorded hashes: not trusted
    _tiny_bundle(tmp_path / "w")
    entry = icache.store(tmp_path / "c", key, tmp_path / "w")
    assert icache.lookup(tmp_path / "c", key) == entry
    (entry / "meta.json").unlink()
    assert icache.lookup(tmp_path / "c", key) is None
    src = tmp_path / "src"
    _tiny_bundle(src)
    dst = tmp_path / "dst"
    _tiny_bundle(dst, with_rough=True)
    icache.copy_bundle(src, dst)
    assert not (dst / "roughness.exr").exists() and ObjectBundle.is_complete(dst)


def test_a_copied_cache_hit_names_the_requests_own_mesh(tmp_path):
    """A cache entry names the mesh file it was first rendered from; a copy made for
    another request of the same content names that request's file (the first may be gone)."""
    src, dst = tmp_path / "src", tmp_path / "dst"
    _tiny_bundle(src)
    icache.copy_bundle(src, dst, meta_update={"mesh": "/now/here.glb"})
    got, was = ObjectBundle.load(dst), ObjectBundle.load(src)
    assert got.meta["mesh"] == "/now/here.glb" and got.meta["x"] == 1
    assert "mesh" not in was.meta and was.meta["x"] == 1  # the cache's entry is left as it was
    np.testing.assert_array_equal(got.camera.K, was.camera.K)  # the rest of meta.json kept


# ------------------------------------------------------------------------------------
# the API without Blender: failures are reported, not raised
# ------------------------------------------------------------------------------------
def _no_blender(*a, **k):
    raise AssertionError("Blender must not be started")


def test_bad_items_fail_before_blender(meshes, tmp_path, monkeypatch):
    monkeypatch.setattr("zcomp_cli.blender.runner.run_blender_batch", _no_blender)
    cam = Camera.from_fov(50, 32, 32)
    front = Pose(position=(0, -0.5, -3))
    K_ns = np.array([[40.0, 0, 16], [0, 41.0, 16], [0, 0, 1]])
    reqs = [
        IntrinsicsRequest("missing", meshes["missing"], front, cam),
        IntrinsicsRequest("corrupt", meshes["corrupt"], front, cam),
        IntrinsicsRequest("fbx", meshes["fbx"], front, cam),
        IntrinsicsRequest("behind", meshes["cube"], Pose(position=(0, 0, 2)), cam),
        IntrinsicsRequest("aside", meshes["cube"], Pose(position=(30, 0, -3)), cam),
        IntrinsicsRequest("nonsquare", meshes["cube"], front, Camera(K_ns, 32, 32)),
    ]
    seen = []
    res = render_object_intrinsics(reqs, cache_dir=tmp_path, progress=lambda d, t, i: seen.append((d, t, i)))
    assert [r.id for r in res] == [r.id for r in reqs]
    assert not any(r.ok for r in res)
    msgs = {r.id: r.error for r in res}
    assert "not found" in msgs["missing"] and "nope.obj" in msgs["missing"]
    assert "corrupt.glb" in msgs["corrupt"]
    assert "unknown mesh format" in msgs["fbx"]
    assert "behind the camera" in msgs["behind"]
    assert "outside" in msgs["aside"]
    assert "non-square" in msgs["nonsquare"]
    assert [s[0] for s in seen] == list(range(1, 7)) and all(s[1] == 6 for s in seen)
    with pytest.raises(InputError, match="unique"):
        render_object_intrinsics([reqs[0], reqs[0]], cache_dir=tmp_path)


# ------------------------------------------------------------------------------------
# Blender: one batch for everything below
# ------------------------------------------------------------------------------------
CAM_ODD = Camera(np.array([[60.0, 0.0, 28.0], [0.0, 60.0, 27.0], [0.0, 0.0, 1.0]]), 64, 48)
POSE_ODD = Pose(position=(0.2, -0.4, -3.0), rotation=euler_deg_to_matrix(10, 35, 5), height=0.8)
CAM_CUBE = Camera.from_fov(50.0, 64, 64)
POSE_CUBE = Pose(position=(0.0, -0.5, -3.0))


@pytest.fixture(scope="module")
def rendered(meshes, tmp_path_factory):
    root = tmp_path_factory.mktemp("render")
    reqs = [IntrinsicsRequest(f"odd_{e}", meshes[e], POSE_ODD, CAM_ODD, root / f"odd_{e}")
            for e in ("obj", "glb", "ply", "stl", "node")]
    reqs += [
        IntrinsicsRequest("cube", meshes["cube"], POSE_CUBE, CAM_CUBE, root / "cube"),
        IntrinsicsRequest("vcol", meshes["vcol"], POSE_CUBE, CAM_CUBE, root / "vcol"),
        IntrinsicsRequest("mtl", meshes["mtl"], POSE_CUBE, CAM_CUBE, root / "mtl"),
        IntrinsicsRequest("tex", meshes["tex"], POSE_CUBE, CAM_CUBE, root / "tex"),
        IntrinsicsRequest("texobj", meshes["texobj"], POSE_CUBE, CAM_CUBE, root / "texobj"),
        IntrinsicsRequest("metal", meshes["metal"], POSE_CUBE, CAM_CUBE, root / "metal"),
        IntrinsicsRequest("missing", meshes["missing"], POSE_CUBE, CAM_CUBE, root / "missing"),
        IntrinsicsRequest("behind", meshes["cube"], Pose(position=(0, 0, 5)), CAM_CUBE, root / "behind"),
    ]
    res = render_object_intrinsics(reqs, cache_dir=root / "cache", samples=8)
    return {"requests": reqs, "results": {r.id: r for r in res}, "root": root}


def _raycast(mesh, M, camera):
    """z-depth and camera-frame face normals of ``mesh`` placed by ``M``, by ray casting
    (Moller-Trumbore, every ray against every triangle) through each pixel centre."""
    tris = transform_points(M, mesh.vertices)[mesh.faces]  # (T, 3, 3)
    dirs = camera.pixel_rays().reshape(-1, 3)  # from the origin, z = -1
    v0, e1, e2 = tris[:, 0], tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]
    p = np.cross(dirs[:, None, :], e2[None])  # (R, T, 3)
    det = np.einsum("rtk,tk->rt", p, e1)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / det
        s = -v0[None]  # origin - v0
        u = np.einsum("rtk,rtk->rt", np.broadcast_to(s, p.shape), p) * inv
        q = np.cross(np.broadcast_to(s, p.shape), e1[None])
        v = np.einsum("rk,rtk->rt", dirs, q) * inv
        t = np.einsum("tk,rtk->rt", e2, q) * inv
    ok = (np.abs(det) > 1e-12) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
    t = np.where(ok, t, np.inf)
    best = np.argmin(t, axis=1)
    tbest = t[np.arange(len(dirs)), best]
    hit = np.isfinite(tbest)
    depth = np.where(hit, tbest, 0.0)  # rays have z = -1: t is the z-depth
    n = np.cross(e1, e2)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    normals = np.where(hit[:, None], n[best], 0.0)
    return depth.reshape(camera.height, camera.width), normals.reshape(camera.height, camera.width, 3)


@pytest.mark.blender
@pytest.mark.slow
def test_every_format_matches_ray_cast_geometry(rendered, meshes):
    M = POSE_ODD.object_to_camera(*meshes["odd_mesh"].bounds)
    want_depth, want_n = _raycast(meshes["odd_mesh"], M, CAM_ODD)
    want_hit = want_depth > 0
    assert want_hit.sum() > 100
    for e in ("obj", "glb", "ply", "stl", "node"):
        r = rendered["results"][f"odd_{e}"]
        assert r.ok, r.error
        b = ObjectBundle.load(r.bundle_dir)
        hit = b.depth > 0
        # the silhouette through pixel centres is exact up to ties on an edge
        assert np.sum(hit != want_hit) <= 3, e
        both = hit & want_hit
        assert np.max(np.abs(b.depth[both] - want_depth[both])) < 1e-3, e
        dots = np.sum(b.normals[both] * want_n[both], axis=-1)
        assert np.percentile(dots, 1) > 0.999, e
        # coverage agrees with the pixel-centre silhouette away from the edges
        assert np.all(b.mask[hit] > 0.0) and abs(b.mask.sum() - hit.sum()) < 0.1 * hit.sum()
        assert b.meta["object_height_m"] == pytest.approx(0.8)
        assert b.meta["blender_version"].startswith("5.")
        assert b.meta["mesh_hash"] == content_hash(meshes[e])


@pytest.mark.blender
@pytest.mark.slow
def test_unit_cube_depth_normals_mask_footprint(rendered):
    b = ObjectBundle.load(rendered["results"]["cube"].bundle_dir)
    # front face z = -2.5, facing the camera
    assert abs(float(b.depth[32, 32]) - 2.5) < 1e-3
    np.testing.assert_allclose(b.normals[32, 32], [0, 0, 1], atol=1e-3)
    # the only visible face is the front one: a square of side fx / 2.5 pixels
    side = CAM_CUBE.fx / 2.5
    assert b.mask.sum() == pytest.approx(side * side, rel=0.02)
    assert b.mask[32, 32] == pytest.approx(1.0) and b.mask[2, 2] == 0.0
    np.testing.assert_allclose(b.albedo[32, 32], [0.8, 0.8, 0.8], atol=1e-3)  # no material: grey 0.8
    # footprint: the bottom square y = -0.5, x in [-0.5, 0.5], z in [-3.5, -2.5]
    fp = b.footprint_depth
    assert (fp > 0).sum() > 20
    pts = CAM_CUBE.unproject(fp)[fp > 0]
    assert np.max(np.abs(pts[:, 1] + 0.5)) < 1e-3
    assert np.all(np.abs(pts[:, 0]) <= 0.5 + 1e-3)
    assert np.all((pts[:, 2] >= -3.5 - 1e-3) & (pts[:, 2] <= -2.5 + 1e-3))


@pytest.mark.blender
@pytest.mark.slow
def test_albedo_from_vertex_colours_mtl_and_texture(rendered):
    want = {
        "vcol": srgb_to_linear(np.array([255, 128, 0]) / 255.0),
        "mtl": np.array([0.2, 0.4, 0.6]),
        "tex": srgb_to_linear(np.array([64, 128, 192]) / 255.0),
        "texobj": srgb_to_linear(np.array([200, 100, 50]) / 255.0),
        # glTF baseColorFactor is linear: no sRGB decoding; albedo is the base colour even when metallic
        "metal": np.array([230, 180, 60]) / 255.0,
    }
    for name, colour in want.items():
        r = rendered["results"][name]
        assert r.ok, r.error
        b = ObjectBundle.load(r.bundle_dir)
        inside = b.mask > 0.99
        np.testing.assert_allclose(b.albedo[inside].mean(axis=0), colour, atol=2e-3, err_msg=name)
        # un-premultiplied edges keep the colour too
        edge = (b.mask > 0.2) & (b.mask < 0.8)
        assert edge.any()
        np.testing.assert_allclose(b.albedo[edge].mean(axis=0), colour, atol=2e-2, err_msg=name)


@pytest.mark.blender
@pytest.mark.slow
def test_roughness_metallic_only_when_the_material_has_them(rendered):
    m = ObjectBundle.load(rendered["results"]["metal"].bundle_dir)
    assert m.metallic is not None and m.roughness is not None
    inside = m.mask > 0.99
    np.testing.assert_allclose(m.metallic[inside], 1.0, atol=1e-3)
    np.testing.assert_allclose(m.roughness[inside], 0.2, atol=1e-3)
    assert m.metallic[m.mask == 0].max() == 0.0
    plain = ObjectBundle.load(rendered["results"]["cube"].bundle_dir)  # no material at all
    assert plain.metallic is None and plain.roughness is None
    assert not (Path(rendered["results"]["cube"].bundle_dir) / "metallic.exr").exists()


@pytest.mark.blender
@pytest.mark.slow
def test_bad_items_do_not_stop_the_batch_and_cache_answers(rendered, monkeypatch):
    res = rendered["results"]
    assert not res["missing"].ok and "nope.obj" in res["missing"].error
    assert not res["behind"].ok and "behind" in res["behind"].error
    assert sum(r.ok for r in res.values()) == 11
    # the same requests again: answered from the cache, Blender never starts
    monkeypatch.setattr("zcomp_cli.blender.runner.run_blender_batch", _no_blender)
    reqs = [r for r in rendered["requests"] if r.id in ("cube", "tex")]
    again = [IntrinsicsRequest(r.id, r.mesh, r.pose, r.camera, rendered["root"] / f"again_{r.id}") for r in reqs]
    out = render_object_intrinsics(again, cache_dir=rendered["root"] / "cache", samples=8)
    assert all(r.ok and r.cached for r in out)
    a = ObjectBundle.load(out[0].bundle_dir)
    b = ObjectBundle.load(res["cube"].bundle_dir)
    np.testing.assert_array_equal(a.depth, b.depth)
    np.testing.assert_array_equal(a.albedo, b.albedo)
    # different samples = a different key = not cached (here: Blender would be needed)
    miss = render_object_intrinsics(again[:1], cache_dir=rendered["root"] / "cache", samples=9)
    assert not miss[0].ok and not miss[0].cached


@pytest.mark.blender
def test_script_reports_a_failing_item_and_goes_on(meshes, tmp_path):
    from zcomp_cli.blender.runner import run_blender_batch

    def item(iid, mesh, fmt):
        wd = tmp_path / iid
        wd.mkdir()
        M = POSE_CUBE.object_to_camera(*trimesh.load(meshes["cube"], force="scene").bounds)
        return {"id": iid, "mesh": str(mesh), "format": fmt, "mesh_to_camera": M.tolist(),
                "footprint_to_camera": footprint_matrix(M, [-0.5, -0.5, -0.5]).tolist(),
                "K": CAM_CUBE.K.tolist(), "width": 16, "height": 16,
                "camera": blender_camera_from_K(Camera.from_fov(50, 16, 16).K, 16, 16), "work_dir": str(wd)}

    items = [item("bad", tmp_path / "none.obj", "obj"), item("good", meshes["cube"], "gltf")]
    batch = run_blender_batch(ii.SCRIPT, items, common={"samples": 1})
    assert batch.results["bad"]["event"] == "error" and "none.obj" in batch.results["bad"]["error"]
    assert batch.results["good"]["event"] == "done"
    assert Path(batch.results["good"]["files"]["geometry"]).is_file()
    assert batch.startup_s and batch.startup_s[0] > 0
    json.dumps(batch.results)  # events are plain JSON


# ------------------------------------------------------------------------------------
# border renders: the window holding the object, pasted back
# ------------------------------------------------------------------------------------
def test_render_box_bounds_the_projected_points_and_refuses_unbounded():
    from zcomp_cli.blender.intrinsics import render_box

    cam = Camera.from_fov(60.0, 64, 48)
    cube = np.array(np.meshgrid([-0.3, 0.3], [-0.3, 0.3], [-0.3, 0.3])).reshape(3, -1).T + [0.2, 0.1, -3.0]
    x0, x1, y0, y1 = render_box(cube, cam, pad=2)
    px, _ = cam.project(cube)
    assert x0 <= px[:, 0].min() - 2 + 1 and x1 >= px[:, 0].max() + 2 - 1e-9
    assert y0 <= px[:, 1].min() - 2 + 1 and y1 >= px[:, 1].max() + 2 - 1e-9
    assert 0 <= x0 < x1 <= 64 and 0 <= y0 < y1 <= 48
    assert all(isinstance(v, int) for v in (x0, x1, y0, y1))
    # straddling the camera plane: the image is unbounded -> the whole frame
    assert render_box(cube + [0, 0, 3.0], cam) is None
    # filling the frame -> the whole frame; partly outside -> clipped
    assert render_box((cube - [0.2, 0.1, -3.0]) * 8 + [0, 0, -5.0], cam) is None
    x0, x1, y0, y1 = render_box(cube + [1.2, 0, 0], cam)
    assert x1 == 64 and x0 > 0
    assert render_box(np.array([[np.nan, 0, -1.0]]), cam) is None


def test_paste_window_places_and_checks():
    from zcomp_cli.blender.passes import paste_window
    from zcomp_cli.errors import RenderError

    win = np.arange(6, dtype=np.float32).reshape(2, 3)
    out = paste_window(win, [1, 4, 2, 4], 5, 6)
    assert out.shape == (6, 5) and out.dtype == np.float32
    np.testing.assert_array_equal(out[2:4, 1:4], win)
    assert out.sum() == win.sum()
    n = paste_window(np.ones((2, 3, 3)), [1, 4, 2, 4], 5, 6)
    assert n.shape == (6, 5, 3) and n[0, 0].sum() == 0
    assert paste_window(np.ones((6, 5)), None, 5, 6).shape == (6, 5)
    with pytest.raises(RenderError):
        paste_window(win, [1, 3, 2, 4], 5, 6)  # window size disagrees
    with pytest.raises(RenderError):
        paste_window(win, [4, 7, 2, 4], 5, 6)  # off the frame
    with pytest.raises(RenderError):
        paste_window(np.ones((6, 4)), None, 5, 6)


@pytest.mark.blender
def test_poses_of_one_mesh_share_the_scene_and_match_ray_casting(meshes, tmp_path):
    """Consecutive poses of one mesh reuse the imported mesh (only the camera moves):
    every pose, whatever its scale and rotation, must still match ray casting, with
    another mesh in the same batch."""
    pytest.importorskip("bpy")
    poses = [POSE_ODD, Pose(position=(-0.3, -0.2, -4.0), rotation=euler_deg_to_matrix(-15, 120, 0), height=1.3),
             Pose(position=(0.0, -0.5, -2.5), rotation=euler_deg_to_matrix(0, -60, 20), height=0.5)]
    reqs = [IntrinsicsRequest(f"p{i}", meshes["obj"], p, CAM_ODD, tmp_path / f"p{i}") for i, p in enumerate(poses)]
    reqs.insert(1, IntrinsicsRequest("other", meshes["ply"], poses[1], CAM_ODD, tmp_path / "other"))
    res = {r.id: r for r in render_object_intrinsics(reqs, use_cache=False, samples=4)}
    assert all(r.ok for r in res.values()), [r.error for r in res.values()]
    for i, pose in enumerate(poses):
        b = ObjectBundle.load(res[f"p{i}"].bundle_dir)
        M = pose.object_to_camera(*meshes["odd_mesh"].bounds)
        want_depth, want_n = _raycast(meshes["odd_mesh"], M, CAM_ODD)
        hit, want_hit = b.depth > 0, want_depth > 0
        assert want_hit.sum() > 50 and np.sum(hit != want_hit) <= 3, i
        both = hit & want_hit
        assert np.max(np.abs(b.depth[both] - want_depth[both])) < 1e-3, i
        assert np.percentile(np.sum(b.normals[both] * want_n[both], axis=-1), 1) > 0.999, i
        # the footprint lies on the support plane
        fp = b.footprint_depth
        pts = CAM_ODD.unproject(fp)[fp > 0]
        assert len(pts) > 3 and np.max(np.abs((pts - np.asarray(pose.position)) @ pose.up)) < 1e-3, i
    # the parent sorts items by mesh: only the first pose of the OBJ imported it
    metas = [json.loads((Path(res[f"p{i}"].bundle_dir) / "meta.json").read_text()) for i in range(3)]
    assert [m["blender_mesh_reused"] for m in metas] == [False, True, True]
    assert all(m["render_timings"]["appearance_s"] > 0 for m in metas)


@pytest.mark.blender
def test_blender_session_keeps_one_process_and_replaces_a_dead_one(meshes, tmp_path):
    """A BlenderSession answers several batches with one Blender start-up, and keeps
    the imported mesh between them; a process killed while idle is replaced."""
    pytest.importorskip("bpy")
    from zcomp_cli.blender.runner import BlenderSession

    def reqs(tag, n):
        return [IntrinsicsRequest(f"{tag}{i}", meshes["cube"], Pose(position=(0.1 * i, -0.5, -3.0)), CAM_CUBE,
                                  tmp_path / f"{tag}{i}") for i in range(n)]

    with BlenderSession(ii.SCRIPT) as session:
        a = render_object_intrinsics(reqs("a", 2), use_cache=False, samples=2, session=session)
        pid = session.proc.pid
        b = render_object_intrinsics(reqs("b", 2), use_cache=False, samples=2, session=session)
        assert all(r.ok for r in a + b), [r.error for r in a + b]
        assert session.starts == 1 and session.proc.pid == pid
        meta = json.loads((Path(b[0].bundle_dir) / "meta.json").read_text())
        assert meta["blender_mesh_reused"] is True  # the second batch found the cube loaded
        np.testing.assert_array_equal(ObjectBundle.load(a[0].bundle_dir).depth,
                                      ObjectBundle.load(b[0].bundle_dir).depth)
        session.proc.kill()
        session.proc.wait()
        c = render_object_intrinsics(reqs("c", 1), use_cache=False, samples=2, session=session)
        assert c[0].ok and session.starts == 2
    assert session.proc is None
    assert session.log_path.exists()  # a process died: the log is kept for whoever looks


def test_a_dead_blender_fails_only_the_item_it_was_on():
    from zcomp_cli.blender.runner import BatchResult, _fail_after_death

    seen = []
    items = [{"id": "a"}, {"id": "b"}, {"id": "c"}]
    res = BatchResult()
    left = _fail_after_death(res, items, "b", "LOG", seen.append)
    assert [it["id"] for it in left] == ["a", "c"]
    assert "crashed while processing" in res.results["b"]["error"] and "LOG" in res.results["b"]["error"]
    # died before starting anything: Blender itself does not start, every item fails
    res = BatchResult()
    assert _fail_after_death(res, items, None, "LOG", seen.append) == []
    assert all("failed to start" in res.results[i]["error"] for i in "abc")
    assert len(seen) == 4


@pytest.mark.blender
@pytest.mark.slow
def test_the_default_samples_draw_the_silhouette_within_its_error(tmp_path):
    """The object's coverage is the share of a pixel's filter samples that hit it, so
    its error falls as the samples grow (at most binomially, sqrt(m (1 - m) / N); Cycles'
    stratified samples do better). Against 1024 samples, a sphere's edge measured 0.047
    rms at the 16 samples the default was (a ragged silhouette,
    ``benchmarks/fit_object_samples.py``), 0.027 at 32, 0.016 at 64: the default's
    within 0.03."""
    from zcomp_cli.blender import DEFAULT_SAMPLES

    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.5)
    sphere.export(tmp_path / "sphere.glb")
    cam = Camera.from_fov(40.0, 64, 64)
    pose = Pose(position=(0.0, 0.0, -2.2))

    def mask(n):
        req = IntrinsicsRequest(f"s{n}", tmp_path / "sphere.glb", pose, cam, tmp_path / f"s{n}")
        (res,) = render_object_intrinsics([req], cache_dir=tmp_path / "cache", samples=n)
        return ObjectBundle.load(res.bundle_dir).mask.astype(np.float64)

    ref, got = mask(1024), mask(DEFAULT_SAMPLES)
    edge = (ref > 0.02) & (ref < 0.98)
    assert edge.sum() > 60
    rms = float(np.sqrt(np.mean((got[edge] - ref[edge]) ** 2)))
    assert rms < 0.03, f"the coverage at {DEFAULT_SAMPLES} samples is {rms:.3f} rms off at the silhouette"
