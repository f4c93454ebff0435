"""The occluder of an object given as maps only (``zcomp_cli.maps_occluder``): its visible
surface extruded backwards to its footprint's far edge, a closed mesh the physical
renderer uses as it uses a real posed mesh."""

import dataclasses

import numpy as np
import pytest

from zcomp_cli.maps import SceneMaps
from zcomp_cli.maps_occluder import occluder_from_maps
from zcomp_cli.posed_mesh import PosedMesh
from zcomp_cli.renderers.base import RenderRequest
from zcomp_cli.testing import floor_scene, insert_bundle, light_context, sphere_object_bundle

R = 0.3


@pytest.fixture(scope="module")
def sphere():
    s = floor_scene(160, 120)
    c = s.world_to_camera([0.1, R, -3.0])
    b = sphere_object_bundle(s.camera, c, R, floor_normal=s.up_cam)
    occ = occluder_from_maps(b.depth, b.mask, b.footprint_depth, s.camera, normals=b.normals)
    return s, c, b, occ


def _analytic_shadow(points, centre, radius, l):
    rel = np.asarray(centre) - points
    t = np.maximum(rel @ l, 0.0)
    return np.linalg.norm(rel - t[..., None] * l, axis=-1) < radius


def _front_shell(occ):
    # the visible surface alone: the faces of the front vertices (the first half)
    nv = len(occ.vertices) // 2
    return PosedMesh(occ.vertices, occ.faces[np.all(occ.faces < nv, axis=1)])


def _iou(a, b):
    return (a & b).sum() / max((a | b).sum(), 1)


def test_the_extruded_sphere_is_a_closed_solid_holding_the_sphere(sphere):
    import trimesh

    from zcomp_cli.scene.objectshadow import mesh_silhouette

    s, c, b, occ = sphere
    assert isinstance(occ, PosedMesh) and occ.faces.dtype.kind == "i"
    assert np.all(np.isfinite(occ.vertices))
    tm = trimesh.Trimesh(occ.vertices, occ.faces, process=False)
    assert tm.is_watertight and tm.is_winding_consistent
    # wound outward (a positive volume), and between the sphere and the cylinder standing
    # on its footprint (the visual hull of the view and the footprint)
    assert 4 / 3 * np.pi * R ** 3 * 0.9 < tm.volume < np.pi * R ** 2 * 2 * R
    # nothing in front of the visible surface, nothing below the floor
    up = s.up_cam
    floor_h = float((np.asarray(c) - R * up) @ up)
    assert (occ.vertices @ up).min() > floor_h - 0.02
    # its silhouette is the object's pixels (and the ring of its edge pixels at most, as
    # ``mesh_silhouette`` marks them)
    import cv2

    sil = mesh_silhouette(occ, s.camera, s.depth.shape)
    cover = b.depth > 0
    ring = cv2.dilate(cover.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    assert (cover & ~sil).sum() <= 2 and not (sil & ~ring).any()


@pytest.mark.parametrize("light", [(1.0, 0.4, 0.0), (-1.0, 0.5, 0.2), (0.4, 0.6, -1.0), (0.0, 1.0, 0.0),
                                   (0.3, 0.5, 1.0)])
def test_its_cast_shadow_is_the_real_spheres(sphere, light):
    """Shadow maps of the extruded occluder (as the renderer casts them) against the
    analytic sphere's shadow on the floor."""
    from zcomp_cli.scene.objectshadow import mesh_shadow

    s, c, b, occ = sphere
    P = s.camera.unproject(s.depth).astype(np.float64)
    floor = (s.depth > 0) & ~(b.mask > 0)
    pts = P[floor]
    l = s.cam_to_world.T @ np.asarray(light, float)
    l /= np.linalg.norm(l)
    true = _analytic_shadow(pts, c, R, l)
    assert true.sum() > 50
    ups = np.tile(s.up_cam, (len(pts), 1))
    hull = mesh_shadow(occ, pts, ups, l)[0] < 0.5
    assert _iou(hull, true) > 0.75
    assert (hull & true).sum() > 0.95 * true.sum()  # the hull holds the sphere: its shadow too


def test_the_front_shell_alone_loses_the_side_lights_shadow(sphere):
    from zcomp_cli.scene.objectshadow import mesh_shadow

    s, c, b, occ = sphere
    P = s.camera.unproject(s.depth).astype(np.float64)
    pts = P[(s.depth > 0) & ~(b.mask > 0)]
    l = s.cam_to_world.T @ np.array([1.0, 0.4, 0.0])
    l /= np.linalg.norm(l)
    true = _analytic_shadow(pts, c, R, l)
    ups = np.tile(s.up_cam, (len(pts), 1))
    hull = mesh_shadow(occ, pts, ups, l)[0] < 0.5
    shell = mesh_shadow(_front_shell(occ), pts, ups, l)[0] < 0.5
    assert _iou(shell, true) < 0.6
    assert _iou(hull, true) > _iou(shell, true) + 0.25


def test_the_renderers_cast_shadow_from_the_maps_occluder():
    """End to end with a known low side light: the shadow the renderer draws behind the
    sphere from its maps' occluder covers the real one better than the 2.5D depth does."""
    from zcomp_cli.renderers.physical import PhysicalRenderer

    s = floor_scene(160, 120, light_dir=(1.0, 0.35, 0.0), ambient=0.3)
    r = 0.25
    c = s.world_to_camera([0.0, r, -3.0])
    b = sphere_object_bundle(s.camera, c, r, (0.7, 0.7, 0.7), floor_normal=s.up_cam)
    d, n, a, sel = insert_bundle(s.depth, s.normals, s.albedo, b)
    ys, xs = np.nonzero(sel)
    h = ys.max() - ys.min()
    known = np.ones(sel.shape, bool)
    known[max(0, ys.min() - 2 * h):ys.max() + 2 * h, max(0, xs.min() - 3 * h):xs.max() + 3 * h] = False
    light = light_context({"direction": [float(v) for v in s.light_dir_cam], "angular_radius_deg": 0.5,
                           "strength": 2.0})
    bg = RenderRequest(SceneMaps(s.depth, s.normals, s.albedo), s.shading, known, s.camera, scene_key="k",
                       light=light)
    comp = RenderRequest(SceneMaps(d, n, a), s.shading, known, s.camera, scene_key="k", light=light)
    P = s.camera.unproject(s.depth).astype(np.float64)
    l = s.light_dir_cam / np.linalg.norm(s.light_dir_cam)
    region = ~known & ~sel & (s.depth > 0)
    true = region & _analytic_shadow(P, c, r, l)
    occ = occluder_from_maps(b.depth, b.mask, b.footprint_depth, s.camera, normals=b.normals)
    iou = {}
    for name, o in (("2.5D", None), ("maps", occ)):
        out = PhysicalRenderer().render([bg, dataclasses.replace(comp, occluder=o)], seed=1)
        ratio = out.images[1].mean(-1) / np.maximum(out.images[0].mean(-1), 1e-6)
        assert np.all(np.isfinite(out.images[1]))
        # (the umbra's own ratio is ambient / (ambient + direct) = 0.59 here: a cut at 0.6
        # halved it at the slightest penumbra; 0.7 lies between it and the lit floor)
        iou[name] = _iou(region & (ratio < 0.7), true)
    assert iou["maps"] > 0.75
    assert iou["maps"] > iou["2.5D"] + 0.1


def test_no_footprint_extrudes_by_the_objects_width(sphere):
    import trimesh

    s, c, b, _ = sphere
    occ = occluder_from_maps(b.depth, b.mask, np.zeros_like(b.footprint_depth), s.camera, normals=b.normals,
                             up=s.up_cam)
    tm = trimesh.Trimesh(occ.vertices, occ.faces, process=False)
    assert tm.is_watertight and tm.volume > 4 / 3 * np.pi * R ** 3 * 0.9
    depth_span = -occ.vertices[:, 2].min() - b.depth[b.depth > 0].min()
    assert depth_span < 4 * R  # no deeper than its width behind its nearest point (and the floor)
    # an up that is not a direction: the camera's +y
    for bad in ("sideways", [1.0, 2.0], [np.nan, 1.0, 0.0], [0.0, 0.0, 0.0]):
        occ = occluder_from_maps(b.depth, b.mask, None, s.camera, up=bad)
        assert occ is not None and np.all(np.isfinite(occ.vertices))


def test_a_large_object_is_meshed_on_a_coarser_grid(sphere):
    s, c, b, occ = sphere
    small = occluder_from_maps(b.depth, b.mask, b.footprint_depth, s.camera, normals=b.normals,
                               max_grid_pixels=300)
    assert small is not None and len(small.faces) < len(occ.faces) / 2
    # without normals they come from the depth's differences; the solid is the same
    plain = occluder_from_maps(b.depth, b.mask, b.footprint_depth, s.camera)
    assert plain is not None and abs(len(plain.faces) - len(occ.faces)) < 0.1 * len(occ.faces)


def test_degenerate_maps_give_no_occluder_and_never_raise(sphere):
    s, c, b, _ = sphere
    cam = s.camera
    z = np.zeros_like(b.depth)
    nan = np.full_like(b.depth, np.nan)
    assert occluder_from_maps(b.depth, z, b.footprint_depth, cam) is None  # empty mask
    assert occluder_from_maps(z, b.mask, b.footprint_depth, cam) is None  # no depth
    assert occluder_from_maps(nan, b.mask, b.footprint_depth, cam) is None  # NaN depth
    assert occluder_from_maps(np.full_like(b.depth, np.inf), b.mask, nan, cam, normals=nan[..., None]) is None
    one = np.zeros_like(b.depth)
    one[60, 80] = 3.0
    assert occluder_from_maps(one, b.mask, b.footprint_depth, cam) is None  # a single pixel
    line = np.zeros_like(b.depth)
    line[60, 40:90] = 3.0
    assert occluder_from_maps(line, None, None, cam) is None  # a line: no triangle
    # NaN holes in the depth and the footprint, a NaN normal: a finite mesh still
    d = b.depth.copy()
    d[::7, ::5] = np.nan
    fp = b.footprint_depth.copy()
    fp[::3, ::3] = np.nan
    nrm = b.normals.copy()
    nrm[50:55, 70:90] = np.nan
    occ = occluder_from_maps(d, b.mask, fp, cam, normals=nrm)
    assert occ is not None and np.all(np.isfinite(occ.vertices)) and len(occ.faces)
    assert occ.faces.min() >= 0 and occ.faces.max() < len(occ.vertices)


def _scene(s):
    from zcomp_cli.pipeline.scene import Scene

    return Scene(name="floor", image=s.image, maps=SceneMaps(s.depth, s.normals, s.albedo), camera=s.camera,
                 key="floor")


def test_prepare_job_uses_the_maps_occluder_for_a_bundle_without_a_mesh(tmp_path):
    import trimesh

    from zcomp_cli.pipeline.job import prepare_job

    s = floor_scene(96, 72)
    c = s.world_to_camera([0.0, 0.25, -2.5])
    b = sphere_object_bundle(s.camera, c, 0.25, floor_normal=s.up_cam)
    prep = prepare_job(_scene(s), b)
    assert prep.report["occluder"] == "maps, extruded"
    occ = prep.requests[1].occluder
    assert isinstance(occ, PosedMesh) and prep.requests[0].occluder is None
    # it lies where the aligned depth puts the object
    assert abs(float(np.median(-occ.vertices[:, 2])) + float(c[2])) < 0.25

    # a bundle with a mesh uses the mesh
    m = trimesh.creation.icosphere(subdivisions=2, radius=0.25)
    m.export(tmp_path / "ball.glb")
    M = np.eye(4)
    M[:3, 3] = c
    meshed = dataclasses.replace(b, meta={**b.meta, "mesh": str(tmp_path / "ball.glb"), "object_to_camera": M.tolist()})
    assert prepare_job(_scene(s), meshed).report["occluder"] == "mesh"

    # an unreadable mesh: the maps stand in, and the notes say why
    (tmp_path / "bad.glb").write_bytes(b"not a mesh")
    bad = dataclasses.replace(b, meta={**b.meta, "mesh": str(tmp_path / "bad.glb"), "object_to_camera": M.tolist()})
    prep = prepare_job(_scene(s), bad)
    assert prep.report["occluder"] == "maps, extruded"
    assert any("object mesh not used" in n for n in prep.notes)


def test_prepare_job_keeps_2d_objects_on_the_depth_alone():
    from zcomp_cli.estimators.object2d import object_bundle_from_image
    from zcomp_cli.pipeline.job import prepare_job

    s = floor_scene(96, 72)
    img = np.full((40, 20, 3), 0.5, np.float32)
    mask = np.ones((40, 20), np.float32)
    b = object_bundle_from_image(img, mask, s.camera, (48, 50), 0.4, s.depth, s.normals)
    prep = prepare_job(_scene(s), b)
    assert prep.report["occluder"] is None and prep.requests[1].occluder is None
